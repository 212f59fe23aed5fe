// Picks the backend: the one place that knows whether this build has CUDA.
#include "backends/force_engine.h"
#include "core/error.h"

namespace cellforce {

std::unique_ptr<ForceEngine> make_force_engine(const EngineChoice& choice) {
  Backend backend = choice.backend;
#ifdef CELLFORCE_HAVE_CUDA
  if (backend == Backend::kAuto) backend = cuda_unavailable().empty() ? Backend::kCuda : Backend::kCpu;
  if (backend == Backend::kCuda) return make_cuda_force_engine(choice);
#else
  if (backend == Backend::kAuto) backend = Backend::kCpu;
  if (backend == Backend::kCuda) throw DeviceError("backend cuda: this cellforce was built without CUDA");
#endif
  return make_cpu_force_engine(choice);
}

}  // namespace cellforce
