// cellforce::Context (include/cellforce/cellforce.hpp): the physics the caller describes, checked
// where it enters, and the engine (src/backends) built from the engine choices on first use and
// again after any of them changes.
#include <cellforce/cellforce.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>
#include <sstream>

#include "api/context_impl.h"
#include "reference/brute_force.h"
#include "core/error.h"
#include "core/force_field.h"
#include "core/names.h"
#include "core/numbers.h"
#include "core/option_table.h"
#include "core/system.h"
#include "core/text.h"

namespace cellforce {

inline namespace CELLFORCE_ABI_NAMESPACE {
const char* version() { return CELLFORCE_VERSION_STRING; }
}  // namespace CELLFORCE_ABI_NAMESPACE

namespace {

constexpr const char* kAxis[3] = {"x", "y", "z"};

template <class E, std::size_t N>
E parse_option(std::string_view key, std::string_view value, const Named<E> (&table)[N]) {
  if (const std::optional<E> v = parse_name(value, table)) return *v;
  throw Error("option " + std::string(key) + ": " + quote_excerpt(std::string(value)) + " is not one of " +
              name_list(table));
}

double parse_number(std::string_view key, std::string_view value, const char* expected = "a number") {
  double v = 0;
  const NumberText r = read_real(value, v);
  if (r == NumberText::kOutOfRange) throw Error("option " + std::string(key) + ": " + real_problem(value, r));
  if (r != NumberText::kOk)
    throw Error("option " + std::string(key) + ": " + quote_excerpt(std::string(value)) + " is not " + expected);
  return v;
}

template <class Int = int>
Int parse_int(std::string_view key, std::string_view value) {
  Int v = 0;
  const NumberText r = read_decimal(value, v);
  if (r == NumberText::kOutOfRange) throw Error("option " + std::string(key) + ": " + integer_problem<Int>(value, r));
  if (r != NumberText::kOk)
    throw Error("option " + std::string(key) + ": " + quote_excerpt(std::string(value)) + " is not an integer");
  return v;
}

}  // namespace

void Context::Impl::record_statistics() {
  const PipelineStats st = engine->stats(SystemView{}, ff, false);
  statistics.pipeline_seconds = st.t_total - st.t_transfer;
  statistics.cell_ids_seconds = st.t_cell_ids + st.t_count;
  statistics.sort_seconds = st.t_sort;
  statistics.collision_cells_seconds = st.t_collision_cells;
  statistics.traversal_seconds = st.t_traversal;
  statistics.accumulate_seconds = st.t_accumulate;
  statistics.transfer_seconds = st.t_transfer;
  statistics.builds = st.builds;
  statistics.rebuilt = st.rebuilt;
  statistics.buffer_bytes = st.buffer_bytes;
}

void Context::Impl::set_physics(const Box& b, const ForceField& f, const std::string& setting) {
  if (md) {
    carry(b, f, choice, false, setting);  // takes b and f
  } else {
    // An automatic skin was resolved for the engine's box and cutoff: where the new ones resolve
    // to another, the engine is made again, after what its pending calls found is raised (which
    // leaves the context as it was).
    if (engine && choice.reuse.automatic) {
      const ReuseOptions before = resolved(box, false).reuse, after = resolved(choice, b, f.cutoff, false).reuse;
      if (before.skin != after.skin || before.list != after.list) {
        synchronize();
        engine.reset();
      }
    }
    box = b;
    ff = f;
  }
}

void Context::Impl::set_engine(const EngineChoice& c, const std::string& setting) {
  if (md) {
    carry(md_box, md_ff, c, true, setting);  // takes c; the old force engine is dropped
    return;
  }
  choice = c;
  engine.reset();  // the engine's destructor waits for its queued work; what it flagged is dropped
  device_pending = false;
}

Context::Impl& Context::self() const {
  if (!impl_) throw Error("this cellforce::Context was moved from: it holds no box, types or engine any more");
  return *impl_;
}

// Every option as the table's default (core/option_table.h: CPU backend, double precision,
// Lorentz-Berthelot mixing, skin auto, ...).
Context::Context(int dim) : impl_(std::make_unique<Impl>(dim)) {
  for (const OptionSpec& option : kOptions) set_option(option.key, option.default_value);
}
Context::~Context() = default;
Context::Context(Context&&) noexcept = default;
Context& Context::operator=(Context&&) noexcept = default;

void Context::set_box(const double* lengths, const bool* periodic) { set_box(lengths, periodic, false); }

void Context::set_box(const double* lengths, const bool* periodic, bool scale_positions) {
  Impl& s = self();
  if (!lengths) throw Error("box lengths is a null pointer");
  if (!periodic) throw Error("box periodic is a null pointer");
  Box box;
  box.dim = s.dim;
  for (int a = 0; a < box.dim; ++a) {
    box.periodic[a] = periodic[a];
    box.length[a] = periodic[a] ? lengths[a] : 0.0;  // an open axis' length is not used
    if (periodic[a] && (!std::isfinite(lengths[a]) || lengths[a] <= 0.0))
      throw Error(std::string("box edge ") + kAxis[a] + " is " + format_number(lengths[a]) +
                  "; a periodic edge must be finite and > 0");
  }
  if (scale_positions && s.md) {
    // Each axis periodic before and after: its coordinates scaled by the edges' ratio.
    double scale[kMaxDim] = {1.0, 1.0, 1.0};
    for (int a = 0; a < box.dim; ++a)
      if (box.periodic[a] && s.md_box.periodic[a]) scale[a] = box.length[a] / s.md_box.length[a];
    s.carry(box, s.ff, s.choice, false, "set_box (positions scaled)", scale);
  } else {
    s.set_physics(box, s.ff, "set_box");
  }
  s.has_box = true;
}

void Context::set_cutoff(double rc) { set_cutoff(rc, self().ff.mode); }

void Context::set_cutoff(double rc, CutoffMode mode) {
  Impl& s = self();
  if (!std::isfinite(rc) || rc <= 0.0)
    throw Error("cutoff is " + format_number(rc) + "; it must be finite and > 0");
  if (mode != CutoffMode::kTruncate && mode != CutoffMode::kShift && mode != CutoffMode::kForceShift)
    throw Error("cutoff mode " + std::to_string(int(mode)) + " is not a CutoffMode");
  ForceField ff = s.ff;
  ff.cutoff = rc;
  ff.mode = mode;
  s.set_physics(s.box, ff, "set_cutoff " + format_number(rc));
  s.has_cutoff = true;
}

void Context::set_mixing(Mixing mixing) {
  Impl& s = self();
  if (mixing != Mixing::kLorentzBerthelot && mixing != Mixing::kGeometric)
    throw Error("mixing " + std::to_string(int(mixing)) + " is not a Mixing");
  ForceField ff = s.ff;
  ff.mixing = mixing;
  s.set_physics(s.box, ff, std::string("set_mixing ") + name_of(mixing, kMixingNames));
}

uint32_t Context::add_type(std::string_view name_view, double sigma, double epsilon) {
  Impl& s = self();
  const std::string name(name_view);
  for (const ParticleType& t : s.ff.types)
    if (t.name == name) throw Error("type " + quote_excerpt(name) + " is already added");
  ForceField trial = s.ff;
  trial.types.push_back(ParticleType{name, sigma, epsilon});
  ForceField check = trial;
  if (!s.has_cutoff) check.cutoff = 1.0;  // the types are checked here, the cutoff elsewhere
  check.validate();
  s.set_physics(s.box, trial, "add_type " + quote_excerpt(name));
  return uint32_t(s.ff.types.size() - 1);
}

void Context::set_pair(uint32_t a, uint32_t b, double sigma, double epsilon) {
  Impl& s = self();
  const std::size_t types = s.ff.types.size();
  if (a >= types || b >= types)
    throw Error("pair (" + std::to_string(a) + ", " + std::to_string(b) + "): type index " +
                std::to_string(a >= types ? a : b) + " is out of range (" + std::to_string(types) + " types)");
  ForceField trial = s.ff;
  std::erase_if(trial.overrides, [&](const PairOverride& o) {
    return (o.a == a && o.b == b) || (o.a == b && o.b == a);
  });
  trial.overrides.push_back(PairOverride{a, b, sigma, epsilon});
  ForceField check = trial;
  if (!s.has_cutoff) check.cutoff = 1.0;
  check.validate();
  s.set_physics(s.box, trial, "set_pair (" + std::to_string(a) + ", " + std::to_string(b) + ")");
}

void Context::set_backend(Backend backend) { set_backend(backend, self().choice.device); }

void Context::set_backend(Backend backend, int device) {
  Impl& s = self();
  if (backend != Backend::kAuto && backend != Backend::kCpu && backend != Backend::kCuda)
    throw Error("backend " + std::to_string(int(backend)) + " is not a Backend");
  if (device < 0) throw Error("device " + std::to_string(device) + ": expected an ordinal >= 0");
  EngineChoice c = s.choice;
  const bool new_device = c.device != device;
  c.backend = backend;
  c.device = device;
  s.set_engine(c, new_device ? "device " + std::to_string(device) : std::string("backend ") + to_string(backend));
}

void Context::set_precision(Precision precision) {
  Impl& s = self();
  if (precision != Precision::kSingle && precision != Precision::kMixed && precision != Precision::kDouble)
    throw Error("precision " + std::to_string(int(precision)) + " is not a Precision");
  EngineChoice c = s.choice;
  c.precision = precision;
  s.set_engine(c, std::string("precision ") + to_string(precision));
}

void Context::set_skin(double skin) {
  Impl& s = self();
  EngineChoice c = s.choice;
  c.reuse.skin = skin;
  c.reuse.automatic = false;
  validate_reuse(c.reuse);
  s.set_engine(c, "skin " + format_number(skin));
}

namespace {

// The engine choices with option `id` set to `value` (an engine option: not backend, device,
// precision, skin, mixing or cutoff-mode, which have their own setters). Throws naming the option
// when the value is not one of its values.
EngineChoice with_option(EngineChoice c, OptionId id, std::string_view key, std::string_view value) {
  switch (id) {
    case OptionId::kNeighborCheck:
    case OptionId::kNeighborAudit:
    case OptionId::kNeighborList: {
      const std::optional<bool> v = parse_name(value, kBooleanNames);
      if (!v)
        throw Error("option " + std::string(key) + ": " + quote_excerpt(std::string(value)) + " is not true or false");
      bool& flag = id == OptionId::kNeighborCheck ? c.reuse.check
                   : id == OptionId::kNeighborAudit ? c.reuse.audit
                                                    : c.reuse.list;
      flag = *v;
      validate_reuse(c.reuse);
      break;
    }
    case OptionId::kNeighborEvery:
      c.reuse.every = parse_int<int64_t>(key, value);
      validate_reuse(c.reuse);
      break;
    case OptionId::kAccumulation: c.accumulation = parse_option(key, value, kAccumulationNames); break;
    case OptionId::kCellRule: c.rule = parse_option(key, value, kCellRuleNames); break;
    case OptionId::kTraversal: c.traversal = parse_option(key, value, kTraversalNames); break;
    case OptionId::kSort: c.sort = parse_option(key, value, kSortNames); break;
    case OptionId::kMemory: c.memory = parse_option(key, value, kListMemoryNames); break;
    case OptionId::kThreads: {
      const int threads = same_name(value, kAutoThreads) ? 0 : parse_int(key, value);
      if (threads < 0)
        throw Error("option " + std::string(key) + ": " + std::to_string(threads) +
                    " is not a thread count: expected N >= 1, or 0 or auto for OpenMP's default");
      c.threads = threads;
      break;
    }
    default:
      throw Error("internal error: option " + std::string(key) + " is not an engine option of with_option");
  }
  return c;
}

}  // namespace

void Context::set_option(std::string_view key, std::string_view value) {
  Impl& s = self();
  const OptionSpec* option = find_option(key);
  if (!option) throw Error("unknown option " + quote_excerpt(std::string(key)) + "; options: " + option_keys());
  const EngineChoice& c = s.choice;
  switch (option->id) {
    case OptionId::kBackend:
      set_backend(parse_option(key, value, kBackendNames), c.device);
      break;
    case OptionId::kDevice:
      set_backend(c.backend, parse_int(key, value));
      break;
    case OptionId::kPrecision:
      set_precision(parse_option(key, value, kPrecisionNames));
      break;
    case OptionId::kMixing:
      set_mixing(parse_option(key, value, kMixingNames));
      break;
    case OptionId::kCutoffMode: {
      ForceField ff = s.ff;
      ff.mode = parse_option(key, value, kCutoffModeNames);
      s.set_physics(s.box, ff, "option cutoff-mode " + std::string(name_of(ff.mode, kCutoffModeNames)));
      break;
    }
    case OptionId::kSkin:
      if (same_name(value, kAutoSkin)) {
        EngineChoice next = c;
        next.reuse.automatic = true;  // skin and lists from the rule; a later skin length restores the caller's
        next.reuse.skin = 0.0;
        s.set_engine(next, "skin auto");
      } else {
        set_skin(parse_number(key, value, "auto or a number"));
      }
      break;
    default:
      s.set_engine(with_option(c, option->id, key, value), "option " + std::string(key) + " " + std::string(value));
      break;
  }
}

void Context::compute(std::size_t n, const double* positions, const uint32_t* types, const Outputs& out) {
  Impl& s = self();
  s.synchronize();
  s.check_ready();
  check_output(positions, "positions", n);
  check_output(out.forces, "forces", n);
  const SystemView system{s.box, n, positions, types};  // the engine validates it
  const Request request{out.energies != nullptr || out.energy != nullptr, out.virial != nullptr};
  s.get_engine().evaluate(system, s.ff, request, s.result);
  const std::size_t dim = std::size_t(s.dim);
  if (n) std::memcpy(out.forces, s.result.forces.data(), n * dim * sizeof(double));
  if (out.energies && n) std::memcpy(out.energies, s.result.energies.data(), n * sizeof(double));
  if (out.energy) *out.energy = s.result.energy;
  if (out.virial)
    for (std::size_t r = 0; r < dim; ++r)
      for (std::size_t c = 0; c < dim; ++c) out.virial[r * dim + c] = s.result.virial[r][c];
  s.record_statistics();
}

void Context::compute_device(std::size_t n, const double* positions, const uint32_t* types,
                             const Outputs& out, void* stream) {
  Impl& s = self();
  s.check_ready();
  check_output(positions, "positions", n);
  check_output(out.forces, "forces", n);
  ForceEngine& engine = s.get_engine();
  if (engine.backend() != Backend::kCuda)
    throw Error("compute_device needs the cuda backend; this context runs on the CPU (set_backend)");
  s.device_pending = true;  // statistics and errors come with synchronize() (also after a throw
                            // here, which may leave work queued)
  engine.evaluate_device(DeviceInput{s.box, n, positions, Scalar::kFloat64, 0, types}, s.ff,
                         DeviceOutputs{out.forces, out.energies, out.energy, out.virial}, stream);
}

namespace {

// The checks of arrays as the caller holds them that need no element: the enumerations and the
// stride.
void check_layout(const Positions& positions, const Types& types, int dim) {
  if (positions.scalar != Scalar::kFloat64 && positions.scalar != Scalar::kFloat32)
    throw Error("positions: scalar " + std::to_string(int(positions.scalar)) + " is neither float64 nor float32");
  if (types.index != Index::kUInt32 && types.index != Index::kInt32)
    throw Error("types: index " + std::to_string(int(types.index)) + " is neither uint32 nor int32");
  if (positions.stride != 0 && positions.stride < std::size_t(dim))
    throw Error("positions: a row stride of " + std::to_string(positions.stride) + " elements is less than the " +
                std::to_string(dim) + " coordinates of a row");
}

}  // namespace

void Context::compute(std::size_t n, const Positions& positions, const Types& types, const Outputs& out) {
  Impl& s = self();
  check_layout(positions, types, s.dim);
  check_output(positions.data, "positions", n);
  const std::size_t dim = std::size_t(s.dim), stride = positions.stride ? positions.stride : dim;
  // The rows as packed float64 (a float32 coordinate converts exactly) and int32 types checked.
  std::vector<double> packed(n * dim);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t a = 0; a < dim; ++a)
      packed[i * dim + a] = positions.scalar == Scalar::kFloat32
                                ? double(static_cast<const float*>(positions.data)[i * stride + a])
                                : static_cast<const double*>(positions.data)[i * stride + a];
  if (types.data && types.index == Index::kInt32)
    for (std::size_t i = 0; i < n; ++i)
      if (static_cast<const int32_t*>(types.data)[i] < 0)
        throw Error("particle " + std::to_string(i) + " has type index " +
                    std::to_string(static_cast<const int32_t*>(types.data)[i]) + ": type indices are >= 0");
  // An int32 index >= 0 has the bits of the same uint32.
  compute(n, packed.data(), static_cast<const uint32_t*>(types.data), out);
}

void Context::compute_device(std::size_t n, const Positions& positions, const Types& types, const Outputs& out,
                             void* stream) {
  Impl& s = self();
  check_layout(positions, types, s.dim);
  s.check_ready();
  check_output(positions.data, "positions", n);
  check_output(out.forces, "forces", n);
  ForceEngine& engine = s.get_engine();
  if (engine.backend() != Backend::kCuda)
    throw Error("compute_device needs the cuda backend; this context runs on the CPU (set_backend)");
  s.device_pending = true;  // as compute_device of packed arrays
  DeviceInput input{s.box, n, positions.data, positions.scalar, positions.stride,
                    static_cast<const uint32_t*>(types.data)};  // int32: a negative index reads as out of range
  engine.evaluate_device(input, s.ff, DeviceOutputs{out.forces, out.energies, out.energy, out.virial}, stream);
}

void Context::synchronize() { self().synchronize(); }

PairCounts Context::count_pairs(std::size_t n, const double* positions, const uint32_t* types) {
  Impl& s = self();
  s.synchronize();
  s.check_ready();
  const SystemView system{s.box, n, positions, types};  // the engine validates it
  ForceEngine& engine = s.get_engine();
  if (engine.backend() == Backend::kCpu) {  // the CPU counts on every evaluation
    ForceResult scratch;
    engine.evaluate(system, s.ff, Request{false, false}, scratch);
  }
  return pair_counts(engine.stats(system, s.ff, true));
}

Statistics Context::statistics() const { return self().statistics; }

void Context::compute_brute_force(std::size_t n, const double* positions, const uint32_t* types,
                                  const Outputs& out) {
  const Impl& s = self();
  s.check_physics();  // not the precision's range: the brute force is double
  check_output(positions, "positions", n);
  check_output(out.forces, "forces", n);
  ForceResult r;  // brute_force validates the system as the engines do
  brute_force(SystemView{s.box, n, positions, types}, s.ff,
              Request{out.energies != nullptr || out.energy != nullptr, out.virial != nullptr}, r);
  const std::size_t dim = std::size_t(s.dim);
  if (n) std::memcpy(out.forces, r.forces.data(), n * dim * sizeof(double));
  if (out.energies && n) std::memcpy(out.energies, r.energies.data(), n * sizeof(double));
  if (out.energy) *out.energy = r.energy;
  if (out.virial)
    for (std::size_t a = 0; a < dim; ++a)
      for (std::size_t b = 0; b < dim; ++b) out.virial[a * dim + b] = r.virial[a][b];
}

int Context::dim() const { return self().dim; }
std::size_t Context::num_types() const { return self().ff.types.size(); }
// The neighbour structure of the MD state when there is one, else of force calls (resolved here:
// no engine is made for it).
double Context::skin() { return self().neighbor().choice.reuse.skin; }

bool Context::neighbor_lists() {
  const Impl::Neighbor nb = self().neighbor();
  return nb.choice.backend == Backend::kCuda &&
         pair_lists_serve(nb.choice.reuse, nb.choice.accumulation, nb.box, nb.cutoff);
}

// The engine named is the MD engine's force engine when there is one (no second engine is built just
// to be named).
const char* Context::text(Text which) const {
  Impl& s = self();
  switch (which) {
    case Text::kBackendName: s.held_text = to_string(s.named_engine().backend()); break;
    case Text::kDescription: s.held_text = s.named_engine().description(); break;
    case Text::kTraversal: s.held_text = s.named_engine().traversal(); break;
    case Text::kSort: s.held_text = s.named_engine().sort(); break;
    case Text::kNeighbor: {
      const Impl::Neighbor nb = s.neighbor();
      s.held_text = describe_reuse(s.choice.reuse, nb.choice.reuse, nb.choice.backend, nb.choice.accumulation, nb.md,
                              nb.box, nb.cutoff, nb.memory);
      break;
    }
    case Text::kStatisticsJson: s.held_text = statistics_text(*this, s); break;
    default: throw Error("internal error: text " + std::to_string(int(which)) + " is not known");
  }
  return s.held_text.c_str();
}

}  // namespace cellforce
