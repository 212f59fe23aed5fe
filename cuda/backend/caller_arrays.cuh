// The caller's device positions as it holds them (float32 or float64 rows of any stride, the first
// dim used: DeviceInput) written as the packed float64 rows the engine computes on. A float32
// coordinate converts to float64 exactly, so an evaluation of the converted rows is bitwise one of
// float64 arrays holding the same values.
#pragma once

#include <cuda_runtime.h>

#include <cstddef>

#include <cellforce/options.hpp>  // Scalar

namespace cellforce::cuda {

// n rows of `stride` elements of `scalar` at `in` (stride >= dim) into n x dim doubles at `out`,
// on `stream`.
void pack_positions(const void* in, Scalar scalar, std::size_t stride, std::size_t n, int dim, double* out,
                    cudaStream_t stream);

}  // namespace cellforce::cuda
