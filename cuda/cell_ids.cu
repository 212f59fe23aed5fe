// Stage 1, cell IDs (GPU Gems 3 ch. 32, section 32.2.2), one thread per particle: the H cell and
// up to 2^d - 1 P cells of each particle's box, through the same bin_particle() as the CPU (its
// geometry is immune to FMA contraction, so both bin every particle identically), and the count
// of valid entries by a CUB reduction, left in device memory for the later stages.
#include <cub/device/device_reduce.cuh>
#include <thrust/iterator/transform_iterator.h>

#include "stages.cuh"

namespace cellforce::cuda {
namespace {

__global__ void cell_ids_kernel(Grid grid, const double* __restrict__ positions, std::size_t n,
                                uint32_t* __restrict__ keys, uint32_t* __restrict__ object_ids,
                                Control* __restrict__ control) {
  const std::size_t i = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  const int dim = grid.dim;
  double x[kMaxDim] = {0, 0, 0};
  for (int a = 0; a < dim; ++a) x[a] = positions[i * dim + a];
  uint32_t ids[kMaxCellTypes];
  control[i] = bin_particle(grid, x, ids);
  const std::size_t slots = std::size_t(1) << dim;
  for (std::size_t t = 0; t < slots; ++t) {
    const bool ok = ids[t] != kInvalidCell;
    keys[i * slots + t] = ok ? (ids[t] << 1) | uint32_t(t != 0) : kInvalidCell;
    object_ids[i * slots + t] = uint32_t(i);
  }
}

struct IsValid {
  __host__ __device__ std::size_t operator()(uint32_t key) const { return key != kInvalidCell; }
};

}  // namespace

void build_cell_ids(const Grid& grid, const double* positions, std::size_t n, uint32_t* keys,
                    uint32_t* object_ids, Control* control, cudaStream_t stream) {
  if (n == 0) return;
  constexpr int kBlock = 256;
  const unsigned blocks = unsigned((n + kBlock - 1) / kBlock);
  cell_ids_kernel<<<blocks, kBlock, 0, stream>>>(grid, positions, n, keys, object_ids, control);
  CF_CUDA_CHECK_LAUNCH();
}

void count_valid(const uint32_t* keys, std::size_t entries, PipelineCounts* counts,
                 DeviceBuffer<std::byte>& scratch, cudaStream_t stream) {
  static_assert(sizeof(unsigned long long) == sizeof(std::size_t));
  auto* result = reinterpret_cast<std::size_t*>(&counts->valid);
  if (entries == 0) {
    CF_CUDA_CHECK(cudaMemsetAsync(result, 0, sizeof(*result), stream));
    return;
  }
  auto valid = thrust::make_transform_iterator(keys, IsValid{});
  std::size_t bytes = 0;
  CF_CUDA_CHECK(cub::DeviceReduce::Sum(nullptr, bytes, valid, result, entries, stream));
  scratch.reserve(bytes);
  CF_CUDA_CHECK(cub::DeviceReduce::Sum(scratch.data(), bytes, valid, result, entries, stream));
}

}  // namespace cellforce::cuda
