// Stage 4's device input check and its pair recorder. The device input check (compute_device)
// flags the first coordinate that is not finite and the first type index out of range. The pair
// recorder is the force kernels' own template (same candidate loop, same
// form) instantiated in double for one type, truncation and no observables, with one launch over
// all cells: it records what that loop finds, so that the tests check the traversal's geometry.
// The Gauss-Seidel launches per cell type are checked through their forces.
#include <cub/device/device_scan.cuh>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/iterator/transform_iterator.h>

#include <algorithm>

#include "forces/traversal_impl.cuh"

namespace cellforce::cuda {
namespace {

__global__ void check_input_kernel(const double* __restrict__ positions, const uint32_t* __restrict__ types,
                                   std::size_t n, int dim, uint32_t num_types, DeviceFlags* flags) {
  const std::size_t i = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  for (int a = 0; a < dim; ++a)
    if (!isfinite(positions[i * dim + a])) {
      atomicMin(&flags->bad_coordinate, static_cast<unsigned long long>(i) << 32 | unsigned(a));
      break;
    }
  if (types && types[i] >= num_types)
    atomicMin(&flags->bad_type, static_cast<unsigned long long>(i) << 32 | types[i]);
}

}  // namespace

void check_input(const double* positions, const uint32_t* types, std::size_t n, int dim,
                 uint32_t num_types, DeviceFlags* flags, cudaStream_t stream) {
  if (n == 0) return;
  constexpr int kBlock = 256;
  check_input_kernel<<<unsigned((n + kBlock - 1) / kBlock), kBlock, 0, stream>>>(positions, types, n, dim,
                                                                                  num_types, flags);
  CF_CUDA_CHECK_LAUNCH();
}

void record_pairs(TraversalForm form, int dim, bool wrap, const TraversalArgs<double, double>& args,
                  cudaStream_t stream) {
  Switches sw;
  sw.dim = dim;
  sw.wrap = wrap;
  detail::dispatch(sw, [&](auto traits) {
    using T = decltype(traits);
    // Only the geometry matters when recording: one type, truncation, no observables.
    if constexpr (!T::kMultiType && T::kMode == CutoffMode::kTruncate && !T::kObservables)
      detail::launch<T, double, double, true>(form, args, stream);
  });
}

}  // namespace cellforce::cuda
