// Host/device qualifiers for the shared core: every helper in src/core is compiled for the CPU
// path, the CUDA kernels and the tests from the same source, so CPU and GPU bin particles and
// evaluate pairs identically.
#pragma once

#if defined(__CUDACC__)
#define CF_HD __host__ __device__ __forceinline__
#else
#define CF_HD inline
#endif

namespace cellforce {

// A product that the compiler may not fuse with a following add or subtract into an FMA (nvcc
// fuses by default; the host compiler, in ISO C++ mode, does not). The geometry helpers use it so
// that the CPU and the GPU wrap and bin every particle identically; the pair arithmetic keeps FMA.
CF_HD double mul_rn(double a, double b) {
#if defined(__CUDA_ARCH__)
  return __dmul_rn(a, b);
#else
  return a * b;
#endif
}
CF_HD float mul_rn(float a, float b) {
#if defined(__CUDA_ARCH__)
  return __fmul_rn(a, b);
#else
  return a * b;
#endif
}

}  // namespace cellforce
