// The CPU backend's force job: CpuEngine (src/cpu) behind the ForceEngine interface.
#include "backends/force_engine.h"
#include "core/error.h"
#include "cpu/engine.h"

namespace cellforce {
namespace {

class CpuForceEngine final : public ForceEngine {
 public:
  explicit CpuForceEngine(const EngineChoice& choice) : engine_(options(choice)) {}

  void evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                ForceResult& result) override {
    engine_.evaluate(system, ff, request, result);
  }
  void evaluate_local(const SystemView& system, std::size_t n_local, const ForceField& ff, const Request& request,
                      ForceResult& result) override {
    engine_.evaluate_local(system, n_local, ff, request, result);
  }
  void evaluate_device(const DeviceInput&, const ForceField&, const DeviceOutputs&, void*) override {
    throw Error("device arrays need the cuda backend; this context runs on the CPU (backend cpu)");
  }
  void synchronize(const ForceField&) override {}  // nothing is queued: evaluate() returns with its results
  PipelineStats stats(const SystemView&, const ForceField&, bool) override {
    return engine_.stats();  // the CPU engine counts pairs on every evaluation
  }
  const PipelineStats& stats() const override { return engine_.stats(); }
  std::vector<std::pair<const char*, std::size_t>> buffers() const override { return engine_.buffers(); }
  std::vector<std::pair<uint32_t, uint32_t>> visited_pairs(const SystemView& system, const ForceField& ff) override {
    return engine_.visited_pairs(system, ff);
  }
  ReuseState reuse_state() const override { return engine_.reuse_state(); }
  void restore_reuse(const SystemView& built_from, const ForceField& ff, int64_t served) override {
    engine_.restore_reuse(built_from, ff, served);
  }
  Backend backend() const override { return Backend::kCpu; }
  std::string description() const override {
    const int threads = engine_.threads();
    return "CPU, " + std::to_string(threads) + (threads == 1 ? " OpenMP thread" : " OpenMP threads");
  }
  std::string traversal() const override { return "-"; }
  std::string sort() const override { return "-"; }

 private:
  static CpuOptions options(const EngineChoice& choice) {
    CpuOptions o;
    o.precision = choice.precision;
    o.accumulation = choice.accumulation;
    o.grid.rule = choice.rule;
    o.reuse = choice.reuse;
    o.threads = choice.threads;
    o.grid_override = choice.test.grid_override;
    return o;
  }
  CpuEngine engine_;
};

}  // namespace

std::unique_ptr<ForceEngine> make_cpu_force_engine(const EngineChoice& choice) {
  return std::make_unique<CpuForceEngine>(choice);
}

}  // namespace cellforce
