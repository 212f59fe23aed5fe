// The CPU engine: plans the grid and runs the stages in order, timing each.
#include "cpu/engine.h"

#include <chrono>

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

  std::size_t bytes() const {
    std::size_t b = 0;
    auto add = [&b](const auto& v) { b += v.capacity() * sizeof(v[0]); };
    add(ids.keys), add(ids.object_ids), add(ids.control);
    add(sort.keys), add(sort.values), add(sort.counts);
    add(cells), add(type_start);
    add(acc_float.force), add(acc_float.energy), add(acc_float.cell_energy), add(acc_float.cell_virial);
    add(acc_double.force), add(acc_double.energy), add(acc_double.cell_energy), add(acc_double.cell_virial);
    return b;
  }
};

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

}  // namespace

CpuEngine::CpuEngine(CpuOptions options)
    : options_(std::move(options)), scratch_(std::make_unique<Scratch>()) {}
CpuEngine::~CpuEngine() = default;

// Stages 1-3, shared by evaluate() and visited_pairs().
void CpuEngine::build(const SystemView& system, const ForceField& ff, bool split) {
  validate_system(system, ff);
  const CpuOptions& options = options_;
  Scratch& s = *scratch_;
  PipelineStats& stats = stats_;
  auto t = Clock::now();
  if (options.grid_override) {
    stats.grid = *options.grid_override;
  } else {
    stats.grid = plan_grid(system.box, ff.cutoff, system.positions, system.n, options.grid);
    check_grid(stats.grid, system.box, ff.cutoff, options.grid.rule);
  }
  cpu::build_cell_ids(stats.grid, system, s.ids);
  stats.t_cell_ids = seconds_since(t);

  t = Clock::now();
  cpu::radix_sort(s.ids.keys, s.ids.object_ids, stats.grid.key_bits, s.sort);
  stats.t_sort = seconds_since(t);

  t = Clock::now();
  cpu::find_collision_cells(s.ids.keys.data(), s.ids.valid, s.cells);
  if (split) cpu::split_by_type(stats.grid, s.cells, s.type_start);
  stats.t_collision_cells = seconds_since(t);

  stats.entries = s.ids.keys.size();
  stats.valid_entries = s.ids.valid;
  stats.collision_cells = s.cells.size();
}

void CpuEngine::evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                         ForceResult& result) {
  const auto t0 = Clock::now();
  Scratch& s = *scratch_;
  const bool gauss_seidel = options_.accumulation == Accumulation::kGaussSeidel;
  build(system, ff, gauss_seidel);

  const cpu::TraversalInput in{stats_.grid, system,        ff,         s.ids.object_ids.data(),
                               s.ids.control.data(), s.cells, s.type_start};
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
  if (report.bad) throw_close_pair(system, report.bad_i, report.bad_j, report.bad_r2);

  t = Clock::now();
  if (options_.precision == Precision::kSingle)
    cpu::accumulate(s.acc_float, options_.accumulation, system.box.dim, system.n, request, result);
  else
    cpu::accumulate(s.acc_double, options_.accumulation, system.box.dim, system.n, request, result);
  stats_.t_accumulate = seconds_since(t);
  stats_.buffer_bytes = s.bytes();
  stats_.t_total = seconds_since(t0);
}

std::vector<std::pair<uint32_t, uint32_t>> CpuEngine::visited_pairs(const SystemView& system,
                                                                    const ForceField& ff) {
  Scratch& s = *scratch_;
  build(system, ff, false);
  const cpu::TraversalInput in{stats_.grid, system,        ff,         s.ids.object_ids.data(),
                               s.ids.control.data(), s.cells, s.type_start};
  return cpu::traverse_pairs(in);
}

}  // namespace cellforce
