// The fixture every GPU test derives from: it skips, with the reason, where no CUDA device can be
// used (CI and the development machines have nvcc but no GPU).
#pragma once

#include <cuda_runtime.h>
#include <gtest/gtest.h>

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

}  // namespace cftest
