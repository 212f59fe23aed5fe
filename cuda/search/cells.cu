// The stages' view of the collision cells, prepared for the walks (search/cells.cuh): staging (the
// GPU analogue of the CPU's per-cell staging, and of the chapter's loading of a cell's objects):
// one thread per sorted entry writes the occupant's position relative to the centre of its cell,
// formed in double through the shared core's relative_coordinate(), so that both backends stage
// identical values, then rounded to the pair precision; and the tile form's tile starts (a scan
// over the cells' row tiles), which the tile traversal and the pair-list build walk.
#include <cub/device/device_scan.cuh>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/iterator/transform_iterator.h>

#include <algorithm>

#include "check.cuh"
#include "search/cells.cuh"

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

}  // namespace cellforce::cuda
