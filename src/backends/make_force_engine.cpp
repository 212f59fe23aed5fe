// Picks the backend: the one place that knows whether this build has CUDA.
#include "backends/force_engine.h"
#include "core/error.h"

namespace cellforce {

Backend resolve_backend(Backend backend) {
  if (backend != Backend::kAuto) return backend;
#ifdef CELLFORCE_HAVE_CUDA
  return cuda_unavailable().empty() ? Backend::kCuda : Backend::kCpu;
#else
  return Backend::kCpu;
#endif
}

ListMemory md_list_memory(const EngineChoice& choice, std::size_t n) {
  if (!choice.reuse.automatic || resolve_backend(choice.backend) != Backend::kCuda) return choice.memory;
#ifdef CELLFORCE_HAVE_CUDA
  return cuda_lists_memory(choice.memory, n, choice.device);
#else
  return choice.memory;
#endif
}

std::shared_ptr<void> make_engine_stream(const EngineChoice& choice) {
#ifdef CELLFORCE_HAVE_CUDA
  if (resolve_backend(choice.backend) == Backend::kCuda) return cuda_make_stream(choice.device);
#else
  (void)choice;
#endif
  return nullptr;
}

std::unique_ptr<ForceEngine> make_force_engine(const EngineChoice& choice) {
  if (choice.reuse.automatic)  // the caller resolves it for its system (resolve_reuse)
    throw Error("internal error: an engine was asked for with an unresolved automatic skin");
  const Backend backend = resolve_backend(choice.backend);
#ifdef CELLFORCE_HAVE_CUDA
  if (backend == Backend::kCuda) return make_cuda_force_engine(choice);
#else
  if (backend == Backend::kCuda) throw DeviceError("backend cuda: this cellforce was built without CUDA");
#endif
  return make_cpu_force_engine(choice);
}

}  // namespace cellforce
