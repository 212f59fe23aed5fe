#include "backends.h"

#ifdef CELLFORCE_HAVE_CUDA
#include "backend/engine.h"  // cuda/backend/engine.h
#endif

namespace cftest {
namespace {

// The engine choice a spec describes.
cellforce::EngineChoice choice_from(const EngineSpec& spec, cellforce::Backend backend) {
  cellforce::EngineChoice c;
  c.backend = backend;
  c.precision = spec.precision;
  c.accumulation = spec.accumulation;
  c.test.grid_override = spec.grid_override;
  c.reuse = spec.reuse;
  return c;
}

#ifdef CELLFORCE_HAVE_CUDA
Backend gpu_backend(std::string name, cellforce::TraversalForm form, cellforce::SortMethod sort) {
  return Backend{std::move(name), [] { return cellforce::GpuEngine::unavailable(); },
                 [form, sort](const EngineSpec& spec) -> std::unique_ptr<EngineUnderTest> {
                   cellforce::EngineChoice c = choice_from(spec, cellforce::Backend::kCuda);
                   c.traversal = form;
                   c.sort = sort;
                   return cellforce::make_cuda_force_engine(c);
                 }};
}
#endif

}  // namespace

const std::vector<Backend>& backends() {
  static const std::vector<Backend> list = {
      Backend{"cpu", [] { return std::string(); },
              [](const EngineSpec& spec) -> std::unique_ptr<EngineUnderTest> {
                return cellforce::make_cpu_force_engine(choice_from(spec, cellforce::Backend::kCpu));
              }},
#ifdef CELLFORCE_HAVE_CUDA
      // The CUDA engine in its three traversal forms and with the chapter's sort; they skip where
      // no CUDA device exists.
      gpu_backend("gpuwarp", cellforce::TraversalForm::kWarpPerCell, cellforce::SortMethod::kCub),
      gpu_backend("gputhread", cellforce::TraversalForm::kThreadPerCell, cellforce::SortMethod::kCub),
      gpu_backend("gputile", cellforce::TraversalForm::kWarpPerTile, cellforce::SortMethod::kCub),
      gpu_backend("gpuchaptersort", cellforce::TraversalForm::kWarpPerCell,
                  cellforce::SortMethod::kChapter),
#endif
  };
  return list;
}

std::vector<std::size_t> backend_ids() {
  std::vector<std::size_t> ids(backends().size());
  for (std::size_t k = 0; k < ids.size(); ++k) ids[k] = k;
  return ids;
}

}  // namespace cftest
