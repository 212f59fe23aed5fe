// The fixture every GPU test derives from: it skips, with the reason, where no CUDA device can be
// used (CI and the development machines have nvcc but no GPU).
#pragma once

#include <cuda_runtime.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <vector>

#include "check.cuh"
#include "device_buffer.cuh"

namespace cftest {

class NeedsCudaDevice : public ::testing::Test {
 protected:
  void SetUp() override {
    int count = 0;
    const cudaError_t err = cudaGetDeviceCount(&count);
    if (err != cudaSuccess) {
      (void)cudaGetLastError();  // clear the error this call left
      GTEST_SKIP() << "no CUDA device: cudaGetDeviceCount failed with " << cudaGetErrorName(err)
                   << " (" << cudaGetErrorString(err) << ")";
    }
    if (count == 0) GTEST_SKIP() << "no CUDA device: cudaGetDeviceCount returned 0";
  }
};

// Host <-> device copies for tests; a failed CUDA call throws cellforce::Error (the test fails).
template <class T>
void upload(cellforce::cuda::DeviceBuffer<T>& d, const std::vector<T>& h) {
  d.reserve(std::max<std::size_t>(h.size(), 1));
  if (!h.empty())
    CF_CUDA_CHECK(cudaMemcpy(d.data(), h.data(), h.size() * sizeof(T), cudaMemcpyHostToDevice));
}

template <class T>
std::vector<T> download(const cellforce::cuda::DeviceBuffer<T>& d, std::size_t n) {
  std::vector<T> h(n);
  if (n) CF_CUDA_CHECK(cudaMemcpy(h.data(), d.data(), n * sizeof(T), cudaMemcpyDeviceToHost));
  return h;
}

}  // namespace cftest
