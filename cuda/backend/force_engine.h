// The CUDA backend's force job (backend/force_engine.cpp): GpuEngine behind the backends'
// ForceEngine interface, and its resident evaluations (cuda::ResidentForces) for the CUDA MD engine
// that owns it (backend/md_engine.cu). Plain C++.
#pragma once

#include <memory>
#include <string>

#include "backends/force_engine.h"
#include "backend/engine.h"
#include "backend/resident_forces.h"

namespace cellforce {

class CudaForceEngine final : public ForceEngine {
 public:
  explicit CudaForceEngine(const EngineChoice& choice);

  void evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                ForceResult& result) override;
  void evaluate_local(const SystemView& system, std::size_t n_local, const ForceField& ff,
                      const Request& request, ForceResult& result) override {
    engine_.evaluate_local(system, n_local, ff, request, result);
  }
  void evaluate_device(const DeviceInput& input, const ForceField& ff, const DeviceOutputs& out,
                       void* stream) override;
  void synchronize(const ForceField& ff) override { engine_.synchronize(ff); }
  PipelineStats stats(const SystemView& system, const ForceField& ff, bool counts) override;
  const PipelineStats& stats() const override { return engine_.stats(); }
  std::vector<std::pair<const char*, std::size_t>> buffers() const override { return engine_.buffers(); }
  std::vector<std::pair<uint32_t, uint32_t>> visited_pairs(const SystemView& system, const ForceField& ff) override {
    return engine_.visited_pairs(system, ff);
  }
  ReuseState reuse_state() const override;
  void restore_reuse(const SystemView& built_from, const ForceField& ff, int64_t served) override;
  Backend backend() const override { return Backend::kCuda; }
  std::string description() const override;
  std::string traversal() const override;
  std::string sort() const override;

  // What an MD engine whose state stays on the device asks of the force side.
  cuda::ResidentForces& resident() { return engine_; }
  // The engine itself, for tests and diagnostics (its build counters, options).
  const GpuEngine& engine() const { return engine_; }

 private:
  GpuEngine engine_;
};

}  // namespace cellforce
