#include "backends.h"

#ifdef CELLFORCE_HAVE_CUDA
#include "engine.h"  // cuda/engine.h
#endif

namespace cftest {
namespace {

class CpuUnderTest final : public EngineUnderTest {
 public:
  explicit CpuUnderTest(const EngineSpec& spec) : engine_(options(spec)) {}

  void evaluate(const cellforce::SystemView& system, const cellforce::ForceField& ff,
                const cellforce::Request& request, cellforce::ForceResult& result) override {
    engine_.evaluate(system, ff, request, result);
  }
  std::vector<Pair> visited_pairs(const cellforce::SystemView& system,
                                  const cellforce::ForceField& ff) override {
    return engine_.visited_pairs(system, ff);
  }

 private:
  static cellforce::CpuOptions options(const EngineSpec& spec) {
    cellforce::CpuOptions o;
    o.precision = spec.precision;
    o.accumulation = spec.accumulation;
    o.grid_override = spec.grid_override;
    return o;
  }
  cellforce::CpuEngine engine_;
};

#ifdef CELLFORCE_HAVE_CUDA
class GpuUnderTest final : public EngineUnderTest {
 public:
  GpuUnderTest(const EngineSpec& spec, cellforce::TraversalForm form, cellforce::SortMethod sort)
      : engine_(options(spec, form, sort)) {}

  void evaluate(const cellforce::SystemView& system, const cellforce::ForceField& ff,
                const cellforce::Request& request, cellforce::ForceResult& result) override {
    engine_.evaluate(system, ff, request, result);
  }
  std::vector<Pair> visited_pairs(const cellforce::SystemView& system,
                                  const cellforce::ForceField& ff) override {
    return engine_.visited_pairs(system, ff);
  }

 private:
  static cellforce::GpuOptions options(const EngineSpec& spec, cellforce::TraversalForm form,
                                       cellforce::SortMethod sort) {
    cellforce::GpuOptions o;
    o.precision = spec.precision;
    o.accumulation = spec.accumulation;
    o.grid_override = spec.grid_override;
    o.traversal = form;
    o.sort = sort;
    return o;
  }
  cellforce::GpuEngine engine_;
};

Backend gpu_backend(std::string name, cellforce::TraversalForm form, cellforce::SortMethod sort) {
  return Backend{std::move(name), [] { return cellforce::GpuEngine::unavailable(); },
                 [form, sort](const EngineSpec& spec) -> std::unique_ptr<EngineUnderTest> {
                   return std::make_unique<GpuUnderTest>(spec, form, sort);
                 }};
}
#endif

}  // namespace

const std::vector<Backend>& backends() {
  static const std::vector<Backend> list = {
      Backend{"cpu", [] { return std::string(); },
              [](const EngineSpec& spec) -> std::unique_ptr<EngineUnderTest> {
                return std::make_unique<CpuUnderTest>(spec);
              }},
#ifdef CELLFORCE_HAVE_CUDA
      // The CUDA engine in both traversal forms and with the chapter's sort; they skip where no
      // CUDA device exists.
      gpu_backend("gpuwarp", cellforce::TraversalForm::kWarpPerCell, cellforce::SortMethod::kCub),
      gpu_backend("gputhread", cellforce::TraversalForm::kThreadPerCell, cellforce::SortMethod::kCub),
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
