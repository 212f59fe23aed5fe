// Whether a public-API backend can run here, for tests that take it as a parameter: the reason it
// cannot (a test skips with it), empty where it can.
#pragma once

#include <cellforce/options.hpp>

#include <string>
#include <vector>

#ifdef CELLFORCE_HAVE_CUDA
#include "backend/engine.h"  // cuda/backend/engine.h: GpuEngine::unavailable
#endif

namespace cftest {

inline std::string unavailable(cellforce::Backend backend) {
  if (backend != cellforce::Backend::kCuda) return {};
#ifdef CELLFORCE_HAVE_CUDA
  return cellforce::GpuEngine::unavailable();
#else
  return "this build has no CUDA";
#endif
}

// The CPU, and CUDA where a device can be used.
inline std::vector<cellforce::Backend> usable_backends() {
  std::vector<cellforce::Backend> b{cellforce::Backend::kCpu};
  if (unavailable(cellforce::Backend::kCuda).empty()) b.push_back(cellforce::Backend::kCuda);
  return b;
}

}  // namespace cftest
