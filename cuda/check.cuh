// Every CUDA call is checked: a failure becomes a cellforce::DeviceError naming the call and the place.
#pragma once

#include <cuda_runtime.h>

#include <string>

#include "core/error.h"

namespace cellforce::cuda {

inline void check(cudaError_t err, const char* call, const char* file, int line) {
  if (err != cudaSuccess)
    throw DeviceError(std::string("CUDA error ") + cudaGetErrorName(err) + " (" + cudaGetErrorString(err) +
                ") in " + call + " at " + file + ":" + std::to_string(line));
}

}  // namespace cellforce::cuda

#define CF_CUDA_CHECK(call) ::cellforce::cuda::check((call), #call, __FILE__, __LINE__)
// After a launch: the launch's own error (bad configuration), not the kernel's completion.
#define CF_CUDA_CHECK_LAUNCH() CF_CUDA_CHECK(cudaGetLastError())
