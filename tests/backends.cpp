#include "backends.h"

#ifdef CELLFORCE_HAVE_CUDA
#include "engine.h"  // cuda/engine.h
#endif

namespace cftest {
namespace {

// Any engine with evaluate() and visited_pairs(), built from its own options.
template <class Engine>
class UnderTest final : public EngineUnderTest {
 public:
  template <class Options>
  explicit UnderTest(const Options& options) : engine_(options) {}

  void evaluate(const cellforce::SystemView& system, const cellforce::ForceField& ff,
                const cellforce::Request& request, cellforce::ForceResult& result) override {
    engine_.evaluate(system, ff, request, result);
  }
  std::vector<Pair> visited_pairs(const cellforce::SystemView& system,
                                  const cellforce::ForceField& ff) override {
    return engine_.visited_pairs(system, ff);
  }
  const cellforce::PipelineStats& stats() const override { return engine_.stats(); }

 private:
  Engine engine_;
};

// The options every engine shares, taken from the spec.
template <class Options>
Options options_from(const EngineSpec& spec) {
  Options o;
  o.precision = spec.precision;
  o.accumulation = spec.accumulation;
  o.grid_override = spec.grid_override;
  o.reuse = spec.reuse;
  return o;
}

#ifdef CELLFORCE_HAVE_CUDA
Backend gpu_backend(std::string name, cellforce::TraversalForm form, cellforce::SortMethod sort) {
  return Backend{std::move(name), [] { return cellforce::GpuEngine::unavailable(); },
                 [form, sort](const EngineSpec& spec) -> std::unique_ptr<EngineUnderTest> {
                   auto o = options_from<cellforce::GpuOptions>(spec);
                   o.traversal = form;
                   o.sort = sort;
                   return std::make_unique<UnderTest<cellforce::GpuEngine>>(o);
                 }};
}
#endif

}  // namespace

const std::vector<Backend>& backends() {
  static const std::vector<Backend> list = {
      Backend{"cpu", [] { return std::string(); },
              [](const EngineSpec& spec) -> std::unique_ptr<EngineUnderTest> {
                return std::make_unique<UnderTest<cellforce::CpuEngine>>(
                    options_from<cellforce::CpuOptions>(spec));
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
