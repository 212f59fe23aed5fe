// Host/device qualifiers for the shared core: every helper in src/core is compiled for the CPU
// path, the CUDA kernels and the tests from the same source, so CPU and GPU bin particles and
// evaluate pairs identically.
#pragma once

#if defined(__CUDACC__)
#define CF_HD __host__ __device__ __forceinline__
#else
#define CF_HD inline
#endif
