#include "backends.h"

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

}  // namespace

const std::vector<Backend>& backends() {
  static const std::vector<Backend> list = {
      Backend{"cpu", [] { return std::string(); },
              [](const EngineSpec& spec) -> std::unique_ptr<EngineUnderTest> {
                return std::make_unique<CpuUnderTest>(spec);
              }},
      // A CUDA engine goes here: Backend{"gpu", <"" or "no CUDA device: ...">, <factory>}.
  };
  return list;
}

std::vector<std::size_t> backend_ids() {
  std::vector<std::size_t> ids(backends().size());
  for (std::size_t k = 0; k < ids.size(); ++k) ids[k] = k;
  return ids;
}

}  // namespace cftest
