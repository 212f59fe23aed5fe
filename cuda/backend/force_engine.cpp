// The CUDA backend's force job: GpuEngine (backend/engine.h) behind the ForceEngine interface.
#include "backend/force_engine.h"
#include "backend/memory_plan.h"

namespace cellforce {
namespace {

GpuOptions options(const EngineChoice& choice) {
  GpuOptions o;
  o.precision = choice.precision;
  o.accumulation = choice.accumulation;
  o.grid.rule = choice.rule;
  o.traversal = choice.traversal;
  o.sort = choice.sort;
  o.reuse = choice.reuse;
  o.device = choice.device;
  o.memory = choice.memory;
  o.stream = choice.stream;
  o.test = choice.test;
  return o;
}

}  // namespace

CudaForceEngine::CudaForceEngine(const EngineChoice& choice) : engine_(options(choice)) {}

void CudaForceEngine::evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                               ForceResult& result) {
  engine_.evaluate(system, ff, request, result);
}

void CudaForceEngine::evaluate_device(const DeviceInput& input, const ForceField& ff,
                                      const DeviceOutputs& out, void* stream) {
  engine_.evaluate_device(input, ff, out, stream);
}

PipelineStats CudaForceEngine::stats(const SystemView& system, const ForceField& ff, bool counts) {
  const PipelineStats timing = engine_.stats();
  if (!counts) return timing;
  engine_.count_pairs(system, ff);  // candidate and interacting counts, no stage times
  PipelineStats merged = engine_.stats();  // the extra pass's counts and build ...
  merged.t_cell_ids = timing.t_cell_ids;   // ... with the evaluation's times and reuse figures
  merged.t_count = timing.t_count;
  merged.t_sort = timing.t_sort;
  merged.t_collision_cells = timing.t_collision_cells;
  merged.t_traversal = timing.t_traversal;
  merged.t_accumulate = timing.t_accumulate;
  merged.t_transfer = timing.t_transfer;
  merged.t_total = timing.t_total;
  merged.t_check = timing.t_check;
  merged.rebuilt = timing.rebuilt;
  merged.max_displacement = timing.max_displacement;
  merged.missed_pairs = timing.missed_pairs;
  merged.repeated_pairs = timing.repeated_pairs;
  return merged;
}

ReuseState CudaForceEngine::reuse_state() const { return engine_.reuse_state(); }

void CudaForceEngine::restore_reuse(const SystemView& built_from, const ForceField& ff, int64_t served) {
  engine_.restore_reuse(built_from, ff, served);
}

// The traversal in use (auto: what it chose at the last build, "auto: block-per-tile"; plain
// "auto" before the first build).
std::string CudaForceEngine::traversal() const {
  const TraversalForm used = engine_.traversal();
  if (engine_.options().traversal != TraversalForm::kAuto || used == TraversalForm::kAuto) return to_string(used);
  return std::string("auto: ") + to_string(used);
}
std::string CudaForceEngine::description() const {
  return "CUDA on " + engine_.device_name() + ", " + traversal() + ", " + to_string(engine_.options().sort) + " sort";
}
std::string CudaForceEngine::sort() const { return to_string(engine_.options().sort); }

std::unique_ptr<ForceEngine> make_cuda_force_engine(const EngineChoice& choice) {
  return std::make_unique<CudaForceEngine>(choice);
}

std::string cuda_unavailable() { return GpuEngine::unavailable(); }
bool cuda_device_pointer(const void* p) { return GpuEngine::device_pointer(p); }
ListMemory cuda_lists_memory(ListMemory asked, std::size_t n, int device) {
  return cuda::lists_memory(asked, n, GpuEngine::memory_bytes(device));
}
std::shared_ptr<void> cuda_make_stream(int device) { return GpuEngine::make_stream(device); }

}  // namespace cellforce
