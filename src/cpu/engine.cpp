// The CPU engine: plans the grid and runs the stages in order, timing each.
#include "cpu/engine.h"

#include <chrono>

#include <omp.h>

#include "core/error.h"
#include "cpu/stages.h"
#include "cpu/traversal.h"

namespace cellforce {

struct CpuEngine::Scratch {
  cpu::CellIdArrays ids;
  cpu::SortScratch sort;
  std::vector<cpu::CollisionCell> cells;
  std::vector<std::size_t> type_start;
  cpu::Accumulators<float> acc_float;
  cpu::Accumulators<double> acc_double;
  std::vector<double> build_positions;  // reuse: positions at the build in use (n x dim)
  std::vector<uint32_t> build_keys;     // audit: stage 1's keys of that build, user order

  // Calls add(name, bytes) for every stage buffer.
  template <class F>
  void for_each_buffer(F&& f) const {
    auto add = [&f](const char* name, const auto& v) { f(name, v.capacity() * sizeof(v[0])); };
    add("cell IDs: keys", ids.keys), add("cell IDs: object IDs", ids.object_ids), add("cell IDs: control bits", ids.control);
    add("sort: keys", sort.keys), add("sort: values", sort.values), add("sort: counts", sort.counts);
    add("collision cells", cells), add("collision cells: type starts", type_start);
    add("Jacobi slots: forces (float)", acc_float.force), add("Jacobi slots: energies (float)", acc_float.energy);
    add("cell sums: energies (float)", acc_float.cell_energy), add("cell sums: virials (float)", acc_float.cell_virial);
    add("Jacobi slots: forces (double)", acc_double.force), add("Jacobi slots: energies (double)", acc_double.energy);
    add("Jacobi slots: virials (float)", acc_float.virial), add("Jacobi slots: virials (double)", acc_double.virial);
    add("cell sums: energies (double)", acc_double.cell_energy), add("cell sums: virials (double)", acc_double.cell_virial);
    add("build positions", build_positions), add("audit: build keys", build_keys);
  }
  std::size_t bytes() const {
    std::size_t b = 0;
    for_each_buffer([&b](const char*, std::size_t bytes) { b += bytes; });
    return b;
  }
  std::vector<std::pair<const char*, std::size_t>> buffers() const {  // those that hold any
    std::vector<std::pair<const char*, std::size_t>> out;
    for_each_buffer([&out](const char* name, std::size_t bytes) {
      if (bytes) out.emplace_back(name, bytes);
    });
    return out;
  }
};

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// For its lifetime, the parallel regions that the calling thread starts run `threads` threads
// (0: as before); the count before is restored at the end. OpenMP keeps the count per thread, so
// other threads of the program, and other engines, keep theirs.
class ThreadCount {
 public:
  explicit ThreadCount(int threads) : before_(omp_get_max_threads()), set_(threads > 0) {
    if (set_) omp_set_num_threads(threads);
  }
  ~ThreadCount() {
    if (set_) omp_set_num_threads(before_);
  }
  ThreadCount(const ThreadCount&) = delete;
  ThreadCount& operator=(const ThreadCount&) = delete;

 private:
  int before_;
  bool set_;
};

}  // namespace

CpuEngine::CpuEngine(CpuOptions options)
    : options_(std::move(options)), reuse_(options_.reuse), scratch_(std::make_unique<Scratch>()) {
  validate_reuse(options_.reuse);
}
CpuEngine::~CpuEngine() = default;

int CpuEngine::threads() const { return options_.threads > 0 ? options_.threads : omp_get_max_threads(); }

// Validates the input, then rebuilds the structure (stages 1-3) or keeps the last one: shared by
// evaluate() and visited_pairs().
void CpuEngine::prepare(const SystemView& system, const ForceField& ff) {
  validate_system(system, ff);
  Scratch& s = *scratch_;
  stats_.t_check = 0;
  const bool rebuild = reuse_.decide(system, ff.cutoff, [&] {
    const auto t = Clock::now();
    const double d2 = max_displacement2(system.box, system.n, system.positions, s.build_positions.data());
    stats_.t_check = seconds_since(t);
    return d2;
  }, stats_);
  if (rebuild) {
    build(system, ff);
  } else {
    reuse_.reused();
    stats_.t_cell_ids = stats_.t_sort = stats_.t_collision_cells = 0;
  }
  stats_.builds = reuse_.builds();
}

// Stages 1-3.
void CpuEngine::build(const SystemView& system, const ForceField& ff) {
  const CpuOptions& options = options_;
  Scratch& s = *scratch_;
  PipelineStats& stats = stats_;
  const double skin = options.reuse.skin;
  reuse_.invalidate();  // until this build completes
  auto t = Clock::now();
  if (options.grid_override) {
    stats.grid = *options.grid_override;
  } else {
    stats.grid = plan_grid(system.box, ff.cutoff, system.positions, system.n, options.grid, skin);
    check_grid(stats.grid, system.box, ff.cutoff, options.grid.rule, skin);
    check_staging(stats.grid, ff.cutoff, options.precision, skin, options.grid.rule);
  }
  check_precision_range(ff, options.precision);
  cpu::build_cell_ids(stats.grid, system, s.ids);
  stats.t_cell_ids = seconds_since(t);
  if (reuse_.enabled()) {
    s.build_positions.assign(system.positions, system.positions + system.n * std::size_t(system.box.dim));
    if (options.reuse.audit) s.build_keys = s.ids.keys;  // before the sort reorders them
  }

  t = Clock::now();
  cpu::radix_sort(s.ids.keys, s.ids.object_ids, stats.grid.key_bits, s.sort);
  stats.t_sort = seconds_since(t);

  t = Clock::now();
  cpu::find_collision_cells(s.ids.keys.data(), s.ids.valid, stats.grid.slab_bits, s.cells);
  // Gauss-Seidel passes need the cells by type; the split is part of the (reusable) build.
  if (options.accumulation == Accumulation::kGaussSeidel)
    cpu::split_by_type(stats.grid, s.cells, s.type_start);
  stats.t_collision_cells = seconds_since(t);

  stats.entries = s.ids.keys.size();
  stats.valid_entries = s.ids.valid;
  stats.collision_cells = s.cells.size();
  reuse_.built(system, ff.cutoff);
}

std::vector<std::pair<const char*, std::size_t>> CpuEngine::buffers() const { return scratch_->buffers(); }

ReuseState CpuEngine::reuse_state() const {
  if (reuse_.served() == 0) return {};
  return {scratch_->build_positions, reuse_.served()};
}

void CpuEngine::restore_reuse(const SystemView& built_from, const ForceField& ff, int64_t served) {
  if (!reuse_.enabled()) return;
  const ThreadCount threads(options_.threads);
  validate_system(built_from, ff);
  build(built_from, ff);
  reuse_.set_served(served);
}

// The audit of a reused structure: pairs closer than rc now that it misses or repeats.
void CpuEngine::audit(const SystemView& system, const ForceField& ff) {
  if (!options_.reuse.audit || stats_.rebuilt) return;
  const ReuseAudit a = audit_reuse(stats_.grid, scratch_->build_keys.data(), scratch_->ids.control.data(),
                                   system, ff.cutoff, pairs_within(system, ff.cutoff));
  stats_.missed_pairs = a.missed;
  stats_.repeated_pairs = a.repeated;
}

void CpuEngine::evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                         ForceResult& result) {
  run(system, ff, request, result, std::nullopt);
}

void CpuEngine::evaluate_local(const SystemView& system, std::size_t n_local, const ForceField& ff,
                               const Request& request, ForceResult& result) {
  if (n_local > system.n)
    throw Error("internal error: " + std::to_string(n_local) + " locals of " + std::to_string(system.n) + " particles");
  run(system, ff, request, result, n_local);
}

void CpuEngine::run(const SystemView& system, const ForceField& ff, const Request& request, ForceResult& result,
                    std::optional<std::size_t> n_local) {
  const auto t0 = Clock::now();
  const ThreadCount threads(options_.threads);
  Scratch& s = *scratch_;
  prepare(system, ff);

  const bool local = n_local.has_value();
  const cpu::TraversalInput in{stats_.grid,          system,  ff,           s.ids.object_ids.data(),
                               s.ids.control.data(), s.cells, s.type_start, local,
                               local ? *n_local : system.n};
  auto t = Clock::now();
  cpu::TraversalReport report;
  switch (options_.precision) {
    case Precision::kSingle:
      report = cpu::traverse<float, float>(in, request, options_.accumulation, s.acc_float);
      break;
    case Precision::kMixed:
      report = cpu::traverse<float, double>(in, request, options_.accumulation, s.acc_double);
      break;
    case Precision::kDouble:
      report = cpu::traverse<double, double>(in, request, options_.accumulation, s.acc_double);
      break;
  }
  stats_.t_traversal = seconds_since(t);
  stats_.candidate_pairs = report.candidates;
  stats_.interacting_pairs = report.interacting;
  stats_.max_occupancy = report.max_occupancy;
  if (report.bad) throw_close_pair(system, report.bad_i, report.bad_j, report.bad_r2, &ff, options_.precision);

  t = Clock::now();
  auto sum = [&](const auto& acc) {
    if (local)
      cpu::accumulate_local(acc, options_.accumulation, system.box.dim, system.n, *n_local, request, result);
    else
      cpu::accumulate(acc, options_.accumulation, system.box.dim, system.n, request, result);
  };
  if (options_.precision == Precision::kSingle) sum(s.acc_float);
  else sum(s.acc_double);
  if (!local) result.virials.clear();
  stats_.t_accumulate = seconds_since(t);
  stats_.buffer_bytes = s.bytes();
  stats_.t_total = seconds_since(t0);
  if (!local) audit(system, ff);  // after the total: its host search is no part of the engine's time
}

std::vector<std::pair<uint32_t, uint32_t>> CpuEngine::visited_pairs(const SystemView& system,
                                                                    const ForceField& ff,
                                                                    std::optional<std::size_t> n_local) {
  const ThreadCount threads(options_.threads);
  Scratch& s = *scratch_;
  if (n_local && *n_local > system.n)
    throw Error("internal error: " + std::to_string(*n_local) + " locals of " + std::to_string(system.n) + " particles");
  prepare(system, ff);
  if (!n_local) audit(system, ff);
  const cpu::TraversalInput in{stats_.grid,          system,  ff,           s.ids.object_ids.data(),
                               s.ids.control.data(), s.cells, s.type_start, n_local.has_value(),
                               n_local.value_or(system.n)};
  return cpu::traverse_pairs(in);
}

}  // namespace cellforce
