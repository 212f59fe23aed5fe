// cellforce::Context (include/cellforce/cellforce.hpp): the physics the caller describes, checked
// where it enters, and the engine (src/backends) built from the engine choices on first use and
// again after any of them changes.
#include <cellforce/cellforce.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>
#include <sstream>

#include "backends/force_engine.h"
#include "backends/md_engine.h"
#include "md/minimize.h"
#include "reference/brute_force.h"
#include "core/error.h"
#include "core/force_field.h"
#include "core/names.h"
#include "core/numbers.h"
#include "core/option_table.h"
#include "core/system.h"
#include "core/text.h"
#include "state/stable_start.h"

#ifndef CELLFORCE_VERSION
#define CELLFORCE_VERSION "unknown"
#endif

namespace cellforce {

const char* version() { return CELLFORCE_VERSION; }

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

void check_output(const void* p, const char* what, std::size_t n) {
  if (n > 0 && p == nullptr)
    throw Error(std::string(what) + " is a null pointer (" + std::to_string(n) + " particles)");
}

}  // namespace

struct Context::Impl {
  int dim = 3;
  Box box;
  bool has_box = false, has_cutoff = false;
  ForceField ff;
  EngineChoice choice;  // the engine options (set_option; a new context's: core/option_table.h)
  // The device stream every engine of this context runs on (CUDA; null on the CPU): made here and
  // given to each engine, so that force calls and MD steps are one ordered queue. Declared before
  // the engines, so that it outlives them.
  std::shared_ptr<void> stream;
  int stream_device = -1;
  std::unique_ptr<ForceEngine> engine;
  ForceResult result;  // compute()'s staging (the engine's layout), reused across calls
  Statistics statistics;
  bool device_pending = false;  // compute_device calls since the last synchronize()
  // Molecular dynamics: the engine holding the state, and what set_state gave it.
  std::unique_ptr<MdEngine> md;
  IntegratorOptions integrator;
  Box md_box;
  ForceField md_ff;
  std::vector<double> masses;
  std::vector<uint32_t> types;

  explicit Impl(int d) : dim(d) {
    if (d != 2 && d != 3) throw Error("dimension " + std::to_string(d) + ": expected 2 or 3");
    box.dim = d;
    ff.types.clear();
  }

  // What the engines are made from: the backend kAuto stands for, and an automatic skin resolved
  // for the force calls' or the MD engine's use (md), `b`, the cutoff and the lists' memory mode
  // (resolve_reuse: a rule of the backend, the system and the device; md_list_memory).
  EngineChoice resolved(const Box& b, bool for_md, ListMemory memory = ListMemory::kFast) const {
    EngineChoice c = choice;
    c.backend = resolve_backend(choice.backend);
    c.reuse = resolve_reuse(choice.reuse, c.backend, choice.accumulation, for_md, b, ff.cutoff, memory);
    return c;
  }
  // `c` with the context's stream for its device (made at the first engine on it).
  EngineChoice with_stream(EngineChoice c) {
    if (c.backend != Backend::kCuda) return c;
    if (!stream || stream_device != c.device) {
      if (stream && (engine || md))  // an engine change drops the engines first (engine_changed)
        throw Error("internal error: the context's stream was replaced while an engine still ran on it");
      stream = make_engine_stream(c);
      stream_device = c.device;
    }
    c.stream = stream.get();
    return c;
  }
  ReuseOptions md_reuse;  // what `md` was made with
  ListMemory md_memory = ListMemory::kAuto;  // and the lists' memory mode its skin was resolved for

  static bool same_reuse(const ReuseOptions& a, const ReuseOptions& b) {
    return a.skin == b.skin && a.list == b.list && a.check == b.check && a.every == b.every && a.audit == b.audit;
  }

  // The neighbour structure in use: the MD state's as set_state resolved it, else force calls' on
  // the current box.
  struct Neighbor {
    EngineChoice choice;  // backend resolved, reuse as the engine runs it
    Box box;
    double cutoff;
    bool md;
    ListMemory memory;  // what an automatic skin was resolved for
  };
  Neighbor neighbor() const {
    const bool has_md = md != nullptr;
    const ListMemory memory = has_md ? md_memory : ListMemory::kFast;
    Neighbor nb{resolved(has_md ? md_box : box, has_md, memory), has_md ? md_box : box,
                has_md ? md_ff.cutoff : ff.cutoff, has_md, memory};
    if (has_md) nb.choice.reuse = md_reuse;
    return nb;
  }

  // The force engine (force calls: an automatic skin resolves to none whatever the box).
  ForceEngine& get_engine() {
    if (!engine) engine = make_force_engine(with_stream(resolved(box, false)));
    return *engine;
  }
  ForceEngine& named_engine() { return md ? md->forces() : get_engine(); }
  void engine_changed() {
    engine.reset();  // the engine's destructor waits for its queued work; what it flagged is dropped
    device_pending = false;
    md.reset();  // the state must be set again
  }

  MdEngine& get_md() {
    if (!md) throw Error("no MD state: call set_state first (after any change of backend, precision or skin)");
    return *md;
  }

  IntegratorSettings settings() const {
    IntegratorSettings s;
    s.langevin = integrator.kind == Integrator::kLangevin;
    s.dt = integrator.dt;
    s.kT = integrator.temperature;
    s.friction = integrator.friction;
    s.seed = integrator.seed;
    return s;
  }

  // What compute needs before any array is read; the arrays themselves are checked by the engine
  // (validate_system: non-finite coordinates, type indices, rc against the box).
  void check_ready() const {
    check_physics();
    check_precision_range(ff, choice.precision);
  }
  void check_physics() const {
    if (!has_box) throw Error("no box: call set_box (cf_set_box) before computing");
    if (!has_cutoff) throw Error("no cutoff: call set_cutoff (cf_set_cutoff) before computing");
    if (ff.types.empty()) throw Error("no particle types: add one with add_type (cf_add_type) before computing");
    ff.validate();
  }

  // The device's verdict on the compute_device calls since the last one (throws what it found).
  void synchronize() {
    if (!engine || !device_pending) return;
    device_pending = false;
    engine->synchronize(ff);
    record_statistics();
  }

  void record_statistics() {
    const PipelineStats s = engine->stats(SystemView{}, ff, false);
    statistics.pipeline_seconds = s.t_total - s.t_transfer;
    statistics.cell_ids_seconds = s.t_cell_ids + s.t_count;
    statistics.sort_seconds = s.t_sort;
    statistics.collision_cells_seconds = s.t_collision_cells;
    statistics.traversal_seconds = s.t_traversal;
    statistics.accumulate_seconds = s.t_accumulate;
    statistics.transfer_seconds = s.t_transfer;
    statistics.builds = s.builds;
    statistics.rebuilt = s.rebuilt;
    statistics.buffer_bytes = s.buffer_bytes;
  }
};

// Every option as the table's default (core/option_table.h: CPU backend, double precision,
// Lorentz-Berthelot mixing, skin auto, ...).
Context::Context(int dim) : impl_(std::make_unique<Impl>(dim)) {
  for (const OptionSpec& option : kOptions) set_option(option.key, option.default_value);
}
Context::~Context() = default;
Context::Context(Context&&) noexcept = default;
Context& Context::operator=(Context&&) noexcept = default;

void Context::set_box(const double* lengths, const bool* periodic) {
  if (!lengths) throw Error("box lengths is a null pointer");
  if (!periodic) throw Error("box periodic is a null pointer");
  Box box;
  box.dim = impl_->dim;
  for (int a = 0; a < box.dim; ++a) {
    box.periodic[a] = periodic[a];
    box.length[a] = periodic[a] ? lengths[a] : 0.0;  // an open axis' length is not used
    if (periodic[a] && (!std::isfinite(lengths[a]) || lengths[a] <= 0.0))
      throw Error(std::string("box edge ") + kAxis[a] + " is " + format_number(lengths[a]) +
                  "; a periodic edge must be finite and > 0");
  }
  impl_->box = box;
  impl_->has_box = true;
}

void Context::set_cutoff(double rc, CutoffMode mode) {
  if (!std::isfinite(rc) || rc <= 0.0)
    throw Error("cutoff is " + format_number(rc) + "; it must be finite and > 0");
  if (mode != CutoffMode::kTruncate && mode != CutoffMode::kShift && mode != CutoffMode::kForceShift)
    throw Error("cutoff mode " + std::to_string(int(mode)) + " is not a CutoffMode");
  impl_->ff.cutoff = rc;
  impl_->ff.mode = mode;
  impl_->has_cutoff = true;
}

void Context::set_mixing(Mixing mixing) {
  if (mixing != Mixing::kLorentzBerthelot && mixing != Mixing::kGeometric)
    throw Error("mixing " + std::to_string(int(mixing)) + " is not a Mixing");
  impl_->ff.mixing = mixing;
}

uint32_t Context::add_type(const std::string& name, double sigma, double epsilon) {
  for (const ParticleType& t : impl_->ff.types)
    if (t.name == name) throw Error("type " + quote_excerpt(name) + " is already added");
  ForceField trial = impl_->ff;
  trial.types.push_back(ParticleType{name, sigma, epsilon});
  if (!impl_->has_cutoff) trial.cutoff = 1.0;  // the types are checked here, the cutoff elsewhere
  trial.validate();
  impl_->ff.types.push_back(ParticleType{name, sigma, epsilon});
  return uint32_t(impl_->ff.types.size() - 1);
}

void Context::set_pair(uint32_t a, uint32_t b, double sigma, double epsilon) {
  const std::size_t types = impl_->ff.types.size();
  if (a >= types || b >= types)
    throw Error("pair (" + std::to_string(a) + ", " + std::to_string(b) + "): type index " +
                std::to_string(a >= types ? a : b) + " is out of range (" + std::to_string(types) + " types)");
  ForceField trial = impl_->ff;
  std::erase_if(trial.overrides, [&](const PairOverride& o) {
    return (o.a == a && o.b == b) || (o.a == b && o.b == a);
  });
  trial.overrides.push_back(PairOverride{a, b, sigma, epsilon});
  ForceField check = trial;
  if (!impl_->has_cutoff) check.cutoff = 1.0;
  check.validate();
  impl_->ff = std::move(trial);
}

void Context::set_backend(Backend backend, int device) {
  if (backend != Backend::kAuto && backend != Backend::kCpu && backend != Backend::kCuda)
    throw Error("backend " + std::to_string(int(backend)) + " is not a Backend");
  if (device < 0) throw Error("device " + std::to_string(device) + ": expected an ordinal >= 0");
  impl_->choice.backend = backend;
  impl_->choice.device = device;
  impl_->engine_changed();
}

void Context::set_precision(Precision precision) {
  if (precision != Precision::kSingle && precision != Precision::kMixed && precision != Precision::kDouble)
    throw Error("precision " + std::to_string(int(precision)) + " is not a Precision");
  impl_->choice.precision = precision;
  impl_->engine_changed();
}

void Context::set_skin(double skin) {
  ReuseOptions reuse = impl_->choice.reuse;
  reuse.skin = skin;
  reuse.automatic = false;
  validate_reuse(reuse);
  impl_->choice.reuse = reuse;
  impl_->engine_changed();
}

void Context::set_option(std::string_view key, std::string_view value) {
  const OptionSpec* option = find_option(key);
  if (!option) throw Error("unknown option " + quote_excerpt(std::string(key)) + "; options: " + option_keys());
  EngineChoice& c = impl_->choice;
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
    case OptionId::kCutoffMode:
      impl_->ff.mode = parse_option(key, value, kCutoffModeNames);
      break;
    case OptionId::kSkin:
      if (same_name(value, kAutoSkin)) {
        c.reuse.automatic = true;  // skin and lists from the rule; a later skin length restores the caller's
        c.reuse.skin = 0.0;
        impl_->engine_changed();
      } else {
        set_skin(parse_number(key, value, "auto or a number"));
      }
      break;
    case OptionId::kNeighborCheck:
    case OptionId::kNeighborAudit:
    case OptionId::kNeighborList: {
      const std::optional<bool> v = parse_name(value, kBooleanNames);
      if (!v)
        throw Error("option " + std::string(key) + ": " + quote_excerpt(std::string(value)) + " is not true or false");
      ReuseOptions reuse = c.reuse;
      (option->id == OptionId::kNeighborCheck   ? reuse.check
       : option->id == OptionId::kNeighborAudit ? reuse.audit
                                                : reuse.list) = *v;
      validate_reuse(reuse);
      c.reuse = reuse;
      impl_->engine_changed();
      break;
    }
    case OptionId::kNeighborEvery: {
      ReuseOptions reuse = c.reuse;
      reuse.every = parse_int<int64_t>(key, value);
      validate_reuse(reuse);
      c.reuse = reuse;
      impl_->engine_changed();
      break;
    }
    case OptionId::kAccumulation:
      c.accumulation = parse_option(key, value, kAccumulationNames);
      impl_->engine_changed();
      break;
    case OptionId::kCellRule:
      c.rule = parse_option(key, value, kCellRuleNames);
      impl_->engine_changed();
      break;
    case OptionId::kTraversal:
      c.traversal = parse_option(key, value, kTraversalNames);
      impl_->engine_changed();
      break;
    case OptionId::kSort:
      c.sort = parse_option(key, value, kSortNames);
      impl_->engine_changed();
      break;
    case OptionId::kMemory:
      c.memory = parse_option(key, value, kListMemoryNames);
      impl_->engine_changed();
      break;
  }
}

void Context::compute(std::size_t n, const double* positions, const uint32_t* types, const Outputs& out) {
  Impl& s = *impl_;
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
  Impl& s = *impl_;
  s.check_ready();
  check_output(positions, "positions", n);
  check_output(out.forces, "forces", n);
  ForceEngine& engine = s.get_engine();
  if (engine.backend() != Backend::kCuda)
    throw Error("compute_device needs the cuda backend; this context runs on the CPU (set_backend)");
  s.device_pending = true;  // statistics and errors come with synchronize() (also after a throw
                            // here, which may leave work queued)
  engine.evaluate_device(DeviceSystemView{s.box, n, positions, types}, s.ff,
                         DeviceOutputs{out.forces, out.energies, out.energy, out.virial}, stream);
}

void Context::synchronize() { impl_->synchronize(); }

PairCounts Context::count_pairs(std::size_t n, const double* positions, const uint32_t* types) {
  Impl& s = *impl_;
  s.synchronize();
  s.check_ready();
  const SystemView system{s.box, n, positions, types};  // the engine validates it
  ForceEngine& engine = s.get_engine();
  if (engine.backend() == Backend::kCpu) {  // the CPU counts on every evaluation
    ForceResult scratch;
    engine.evaluate(system, s.ff, Request{false, false}, scratch);
  }
  const PipelineStats stats = engine.stats(system, s.ff, true);
  PairCounts counts;
  counts.tested = stats.candidate_pairs;
  counts.within_cutoff = stats.interacting_pairs;
  for (int a = 0; a < kMaxDim; ++a) {
    counts.grid_cells[a] = stats.grid.n[a];
    counts.cell_edge[a] = a < stats.grid.dim ? stats.grid.cell[a] : 0.0;
  }
  counts.half_width = stats.grid.half_width;
  counts.entries = stats.entries;
  counts.valid_entries = stats.valid_entries;
  counts.collision_cells = stats.collision_cells;
  counts.max_occupancy = stats.max_occupancy;
  return counts;
}

Statistics Context::statistics() const { return impl_->statistics; }

void Context::compute_brute_force(std::size_t n, const double* positions, const uint32_t* types,
                                  const Outputs& out) {
  const Impl& s = *impl_;
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

void Context::set_integrator(const IntegratorOptions& o) {
  if (o.kind != Integrator::kVerlet && o.kind != Integrator::kLangevin)
    throw Error("integrator " + std::to_string(int(o.kind)) + " is not an Integrator");
  if (!std::isfinite(o.dt) || o.dt <= 0) throw Error("dt is " + format_number(o.dt) + "; it must be finite and > 0");
  if (o.kind == Integrator::kLangevin) {
    if (!std::isfinite(o.temperature) || o.temperature < 0)
      throw Error("temperature is " + format_number(o.temperature) + "; it must be finite and >= 0");
    if (!std::isfinite(o.friction) || o.friction <= 0)
      throw Error("friction is " + format_number(o.friction) + "; it must be finite and > 0");
  }
  if (impl_->md) check_step_arithmetic(o.dt, impl_->masses, impl_->types, impl_->md_ff);
  impl_->integrator = o;
}

void Context::set_state(std::size_t n, const double* positions, const double* velocities, const uint32_t* types,
                        const double* masses, int64_t step) {
  Impl& s = *impl_;
  s.check_ready();
  check_output(positions, "positions", n);
  check_output(masses, "masses", n);
  if (step < 0) throw Error("step " + std::to_string(step) + ": expected a step >= 0");
  const std::size_t dim = std::size_t(s.dim);
  MdState state;
  state.config.box = s.box;
  state.config.positions.assign(positions, positions + n * dim);
  state.config.types = types ? std::vector<uint32_t>(types, types + n) : std::vector<uint32_t>(n, 0);
  state.velocities = velocities ? std::vector<double>(velocities, velocities + n * dim) : std::vector<double>(n * dim, 0.0);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t a = 0; a < dim; ++a)
      if (s.box.periodic[a] && std::isfinite(state.config.positions[i * dim + a]))
        state.config.positions[i * dim + a] = wrap_coordinate(state.config.positions[i * dim + a], s.box.length[a]);
  for (std::size_t k = 0; k < n * dim; ++k)
    if (!std::isfinite(state.velocities[k]))
      throw Error("particle " + std::to_string(k / dim) + " has a non-finite velocity (" +
                  format_number(state.velocities[k]) + ")");
  state.step = step;
  state.time = double(step) * s.integrator.dt;
  std::vector<double> m(masses, masses + n);
  validate_masses(m, n);
  check_step_arithmetic(s.integrator.dt, m, state.config.types, s.ff);
  const ListMemory memory = md_list_memory(s.choice, n);
  const EngineChoice resolved = s.resolved(s.box, true, memory);
  // An automatic skin for another box, or another memory mode (another particle count)
  if (s.md && !Impl::same_reuse(resolved.reuse, s.md_reuse)) s.md.reset();
  if (!s.md) {
    s.md = make_md_engine(s.with_stream(resolved));
    s.md_reuse = resolved.reuse;
  }
  s.md_memory = memory;
  try {
    s.md->set_state(state, m, s.ff);
  } catch (...) {
    s.md.reset();  // no half-set state: the next step() asks for set_state again
    throw;
  }
  s.md_box = s.box;
  s.md_ff = s.ff;
  s.masses = std::move(m);
  s.types = std::move(state.config.types);
}

void Context::step(int64_t count, bool observe) {
  if (count < 0) throw Error("step count " + std::to_string(count) + ": expected >= 0");
  impl_->get_md().advance(count, impl_->settings(), observe);
}

int64_t Context::current_step() const {
  if (!impl_->md) throw Error("no MD state: call set_state first");
  return impl_->md->step();
}

void Context::get_state(double* positions, double* velocities, double* forces) {
  MdState state;
  impl_->get_md().get_state(state);
  const std::size_t count = state.config.positions.size();
  if (positions) std::memcpy(positions, state.config.positions.data(), count * sizeof(double));
  if (velocities) std::memcpy(velocities, state.velocities.data(), count * sizeof(double));
  if (forces) std::memcpy(forces, state.forces.data(), count * sizeof(double));
}

Thermo Context::thermo() {
  Impl& s = *impl_;
  const Observables o = s.get_md().observables();
  const int dim = s.md_box.dim;
  const bool com_conserved = s.integrator.kind == Integrator::kVerlet;
  Thermo t;
  t.kinetic = o.kinetic;
  t.potential = o.potential;
  t.total = t.kinetic + t.potential;
  t.temperature = 2.0 * t.kinetic / degrees_of_freedom(s.masses.size(), dim, com_conserved);
  double trace = 0;
  bool closed = true;
  for (int a = 0; a < dim; ++a) {
    trace += o.virial[a][a];
    closed = closed && s.md_box.periodic[a];
    for (int b = 0; b < dim; ++b) t.virial[a * dim + b] = o.virial[a][b];
  }
  t.pressure = closed ? (2.0 * t.kinetic + trace) / (dim * s.md_box.volume()) : std::nan("");
  return t;
}

MinimizeResult Context::minimize(const MinimizeOptions& options) {
  FireSettings fire;
  fire.force_tolerance = options.force_tolerance;
  fire.max_steps = options.max_steps;
  fire.dt = options.dt;
  fire.dt_max = options.dt_max;
  fire.max_displacement = options.max_displacement;
  // In place where the state lives (CUDA: kernels on the device); after a throw the engine holds
  // the state it had, with its forces.
  const FireResult r = impl_->get_md().minimize(fire);
  MinimizeResult out;
  out.steps = r.steps;
  out.initial_energy = r.initial_energy;
  out.final_energy = r.final_energy;
  out.initial_max_force = r.initial_max_force;
  out.final_max_force = r.final_max_force;
  out.final_max_force_particle = r.final_max_force_particle;
  return out;
}

NeighborState Context::neighbor_state() {
  const ReuseState r = impl_->get_md().forces().reuse_state();
  return NeighborState{r.build_positions, r.served};
}

void Context::restore_neighbor_state(const NeighborState& state) {
  Impl& s = *impl_;
  MdEngine& md = s.get_md();
  const std::size_t n = s.masses.size();
  if (state.build_positions.size() != n * std::size_t(s.md_box.dim))
    throw Error("neighbour state of " + std::to_string(state.build_positions.size()) + " coordinates for " +
                std::to_string(n) + " particles in " + std::to_string(s.md_box.dim) + "D");
  const SystemView built{s.md_box, n, state.build_positions.data(), s.types.data()};
  md.forces().restore_reuse(built, s.md_ff, state.served);
  md.reevaluate();  // the current forces from the restored structure, as the uninterrupted run had them
}

RunStatistics Context::run_statistics() const {
  RunStatistics r;
  if (!impl_->md) return r;
  const MdCounters& c = impl_->md->counters();
  r.steps = c.steps;
  r.evaluations = c.evaluations;
  r.force_seconds = c.force_seconds;
  r.integration_seconds = c.integration_seconds;
  r.step_call_seconds = c.host_wait_seconds;
  r.bytes_to_host = c.bytes_to_host;
  r.bytes_to_device = c.bytes_to_device;
  r.stage_samples = c.stage_samples;
  const double per = c.stage_samples ? 1.0 / double(c.stage_samples) : 0.0;
  r.cell_ids = per * (c.stages.t_cell_ids + c.stages.t_count);
  r.sort = per * c.stages.t_sort;
  r.collision_cells = per * c.stages.t_collision_cells;
  r.traversal = per * c.stages.t_traversal;
  r.accumulate = per * c.stages.t_accumulate;
  r.check = per * c.stages.t_check;
  r.total = per * c.stages.t_total;
  r.builds = c.builds;
  r.largest_served_displacement = c.served;
  r.dangerous_builds = c.dangerous_builds;
  r.gated_steps = c.gated_steps;
  r.list_evaluations = c.list_evaluations;
  r.missed_pairs = c.missed_pairs;
  r.repeated_pairs = c.repeated_pairs;
  r.buffer_bytes = impl_->md->forces().stats().buffer_bytes;
  r.list_pairs = impl_->md->forces().stats().list_pairs;
  r.list_slots = impl_->md->forces().stats().list_slots;
  r.list_mask_words = impl_->md->forces().stats().list_mask_words;
  r.list_mask_words_held = impl_->md->forces().stats().list_mask_words_held;
  r.graph_builds = c.graph_builds;
  r.list_block = c.list_block;
  r.gate_closings = c.gate_closings;
  r.gate_closings_early = c.gate_closings_early;
  r.state_bytes = impl_->md->state_bytes();
  for (const auto& [name, bytes] : impl_->md->forces().buffers()) r.memory.emplace_back(name, bytes);
  for (const auto& [name, bytes] : impl_->md->state_buffers())
    if (bytes) r.memory.emplace_back(name, bytes);
  std::stable_sort(r.memory.begin(), r.memory.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
  return r;
}

void Context::reset_run_statistics() {
  if (impl_->md) impl_->md->reset_counters();
}
int Context::dim() const { return impl_->dim; }
std::size_t Context::num_types() const { return impl_->ff.types.size(); }
// The neighbour structure of the MD state when there is one, else of force calls (resolved here:
// no engine is made for it).
double Context::skin() { return impl_->neighbor().choice.reuse.skin; }

bool Context::neighbor_lists() {
  const Impl::Neighbor nb = impl_->neighbor();
  return nb.choice.backend == Backend::kCuda &&
         pair_lists_serve(nb.choice.reuse, nb.choice.accumulation, nb.box, nb.cutoff);
}

std::string Context::neighbor() {
  const Impl::Neighbor nb = impl_->neighbor();
  return describe_reuse(impl_->choice.reuse, nb.choice.reuse, nb.choice.backend, nb.choice.accumulation, nb.md,
                        nb.box, nb.cutoff, nb.memory);
}

// The MD engine's force engine when there is one (no second engine is built just to be named).
std::string Context::backend_name() { return to_string(impl_->named_engine().backend()); }
std::string Context::description() { return impl_->named_engine().description(); }
std::string Context::traversal() { return impl_->named_engine().traversal(); }
std::string Context::sort() { return impl_->named_engine().sort(); }

}  // namespace cellforce
