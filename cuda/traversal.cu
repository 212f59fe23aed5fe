// Stage 4's preparation and its pair recorder. Staging (the GPU analogue of the CPU's per-cell
// staging, and of the chapter's loading of a cell's objects): one thread per sorted entry writes
// the occupant's position relative to the centre of its cell, formed in double through the shared
// core's relative_coordinate(), so that both backends stage identical values, then rounded to the
// pair precision. The pair recorder is the force kernels' own template (same candidate loop, same
// form) instantiated in double for one type, truncation and no observables, with one launch over
// all cells: it records what that loop finds, so that the tests check the traversal's geometry.
// The Gauss-Seidel launches per cell type are checked through their forces.
#include <cub/device/device_scan.cuh>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/iterator/transform_iterator.h>

#include <algorithm>

#include "traversal_impl.cuh"

namespace cellforce::cuda {
namespace {

template <class Real>
__global__ void stage_kernel(const Grid grid, const uint32_t* __restrict__ sorted_keys,
                             const uint32_t* __restrict__ sorted_ids, std::size_t entries,
                             const unsigned long long* __restrict__ valid, const double* __restrict__ positions,
                             const uint32_t* __restrict__ types, uint32_t num_types,
                             const Control* __restrict__ control, StagedEntry<Real>* __restrict__ staged) {
  const std::size_t e = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (e >= entries || e >= *valid) return;
  staged[e] = detail::stage_entry<Real>(grid, sorted_keys[e], sorted_ids[e], positions, types, num_types, control);
}

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

template <class Real>
void stage_occupants(const Grid& grid, const uint32_t* sorted_keys, const uint32_t* sorted_ids,
                     std::size_t entries, const unsigned long long* valid, const double* positions,
                     const uint32_t* types, uint32_t num_types, const Control* control,
                     StagedEntry<Real>* staged, cudaStream_t stream) {
  if (entries == 0) return;
  constexpr int kBlock = 256;
  const unsigned blocks = unsigned((entries + kBlock - 1) / kBlock);
  stage_kernel<Real><<<blocks, kBlock, 0, stream>>>(grid, sorted_keys, sorted_ids, entries, valid, positions,
                                                    types, num_types, control, staged);
  CF_CUDA_CHECK_LAUNCH();
}

template void stage_occupants<float>(const Grid&, const uint32_t*, const uint32_t*, std::size_t,
                                     const unsigned long long*, const double*, const uint32_t*, uint32_t,
                                     const Control*, StagedEntry<float>*, cudaStream_t);
template void stage_occupants<double>(const Grid&, const uint32_t*, const uint32_t*, std::size_t,
                                      const unsigned long long*, const double*, const uint32_t*, uint32_t,
                                      const Control*, StagedEntry<double>*, cudaStream_t);

namespace {

struct TileCount {
  const CollisionCell* cells;
  const uint32_t* cell_range;
  __device__ uint32_t operator()(uint32_t c) const {
    if (c >= cell_range[1]) return 0;
    const CollisionCell cell = cells[c];
    return (cell.h + cell.p + 31u) / 32u;
  }
};

}  // namespace

void tile_starts(const CollisionCell* cells, const uint32_t* cell_range, std::size_t cell_bound,
                 uint32_t* tile_start, DeviceBuffer<std::byte>& scratch, cudaStream_t stream) {
  auto counts = thrust::make_transform_iterator(thrust::counting_iterator<uint32_t>(0), TileCount{cells, cell_range});
  std::size_t bytes = 0;
  CF_CUDA_CHECK(cub::DeviceScan::ExclusiveSum(nullptr, bytes, counts, tile_start, int(cell_bound + 1), stream));
  scratch.reserve(std::max<std::size_t>(bytes, 1));
  CF_CUDA_CHECK(
      cub::DeviceScan::ExclusiveSum(scratch.data(), bytes, counts, tile_start, int(cell_bound + 1), stream));
}

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
