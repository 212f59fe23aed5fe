#include "cli/backend.h"

#include <omp.h>

#include "core/error.h"
#include "cpu/engine.h"

#ifdef CELLFORCE_HAVE_CUDA
#include "engine.h"  // cuda/engine.h
#endif

namespace cellforce {

struct ForceBackend::Impl {
  std::unique_ptr<CpuEngine> cpu;
#ifdef CELLFORCE_HAVE_CUDA
  std::unique_ptr<GpuEngine> gpu;
#endif
};

ForceBackend::ForceBackend(const BackendChoice& choice) : impl_(std::make_unique<Impl>()) {
  if (choice.backend != "cpu" && choice.backend != "cuda" && choice.backend != "auto")
    throw Error("backend '" + choice.backend + "': expected cpu, cuda or auto");
  if (choice.traversal != "warp" && choice.traversal != "thread")
    throw Error("traversal '" + choice.traversal + "': expected warp or thread");
  if (choice.sort != "cub" && choice.sort != "chapter")
    throw Error("sort '" + choice.sort + "': expected cub or chapter");
  name_ = choice.backend;
#ifdef CELLFORCE_HAVE_CUDA
  if (name_ == "auto") name_ = GpuEngine::unavailable().empty() ? "cuda" : "cpu";
  if (name_ == "cuda") {
    GpuOptions g;
    g.precision = choice.precision;
    g.accumulation = choice.accumulation;
    g.grid.rule = choice.rule;
    g.traversal = choice.traversal == "thread" ? TraversalForm::kThreadPerCell : TraversalForm::kWarpPerCell;
    g.sort = choice.sort == "chapter" ? SortMethod::kChapter : SortMethod::kCub;
    g.reuse = choice.reuse;
    impl_->gpu = std::make_unique<GpuEngine>(g);
    description_ = "CUDA on " + impl_->gpu->device_name() + ", " + to_string(g.traversal) + ", " +
                   to_string(g.sort) + " sort";
    return;
  }
#else
  if (name_ == "auto") name_ = "cpu";
  if (name_ == "cuda") throw Error("backend cuda: this cellforce was built without CUDA");
#endif
  CpuOptions c;
  c.precision = choice.precision;
  c.accumulation = choice.accumulation;
  c.grid.rule = choice.rule;
  c.reuse = choice.reuse;
  impl_->cpu = std::make_unique<CpuEngine>(c);
  description_ = "CPU, " + std::to_string(omp_get_max_threads()) + " OpenMP threads";
}

ForceBackend::~ForceBackend() = default;

void ForceBackend::evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                            ForceResult& result) {
#ifdef CELLFORCE_HAVE_CUDA
  if (impl_->gpu) return impl_->gpu->evaluate(system, ff, request, result);
#endif
  impl_->cpu->evaluate(system, ff, request, result);
}

PipelineStats ForceBackend::stats(const SystemView& system, const ForceField& ff, bool counts) {
#ifdef CELLFORCE_HAVE_CUDA
  if (impl_->gpu) {
    const PipelineStats timing = impl_->gpu->stats();
    if (!counts) return timing;
    impl_->gpu->count_pairs(system, ff);  // candidate and interacting counts, no stage times
    PipelineStats merged = impl_->gpu->stats();
    merged.t_cell_ids = timing.t_cell_ids;
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
#endif
  (void)system, (void)ff, (void)counts;
  return impl_->cpu->stats();  // the CPU engine counts pairs on every evaluation
}

ReuseState ForceBackend::reuse_state() const {
#ifdef CELLFORCE_HAVE_CUDA
  if (impl_->gpu) return impl_->gpu->reuse_state();
#endif
  return impl_->cpu->reuse_state();
}

void ForceBackend::restore_reuse(const SystemView& built_from, const ForceField& ff, int64_t served) {
#ifdef CELLFORCE_HAVE_CUDA
  if (impl_->gpu) return impl_->gpu->restore_reuse(built_from, ff, served);
#endif
  impl_->cpu->restore_reuse(built_from, ff, served);
}

std::string ForceBackend::traversal() const {
#ifdef CELLFORCE_HAVE_CUDA
  if (impl_->gpu) return to_string(impl_->gpu->options().traversal);
#endif
  return "-";
}

std::string ForceBackend::sort() const {
#ifdef CELLFORCE_HAVE_CUDA
  if (impl_->gpu) return to_string(impl_->gpu->options().sort);
#endif
  return "-";
}

}  // namespace cellforce
