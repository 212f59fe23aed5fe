// Stage 1, cell IDs (GPU Gems 3 ch. 32, section 32.2.2), one thread per particle: the H cell and
// up to 2^d - 1 P cells of each particle's box, through the same bin_particle_in<D>() as the CPU (its
// geometry is immune to FMA contraction, so both bin every particle identically), and the count
// of valid entries, left in device memory for the later stages: counted by the cell-ID kernel
// itself (the engine's builds) or by a CUB reduction over the keys (count_valid).
#include <cub/device/device_reduce.cuh>
#include <thrust/iterator/transform_iterator.h>

#include "search/stages.cuh"
#include "with_dim.cuh"

namespace cellforce::cuda {
namespace {

// D = grid.dim at compile time: the loops unroll and the arrays stay in registers (with a run-time
// dimension the Grid and the arrays went to local memory, 56 local loads and stores a thread), and
// a particle's 2^D keys and IDs go out in 16-byte stores.
// With `valid` (zeroed before the launch), each block adds its particles' valid entries to it: one
// integer atomic a block (the sum is the same in any order). With `copy`, each particle's
// coordinates as read are stored there too (the build's positions: no copy of the array after it).
constexpr int kCellIdBlock = 256;
template <int D>
__global__ void __launch_bounds__(kCellIdBlock)
    cell_ids_kernel(Grid grid, const double* __restrict__ positions, std::size_t n, uint32_t* __restrict__ keys,
                    uint32_t* __restrict__ object_ids, Control* __restrict__ control,
                    unsigned long long* __restrict__ valid, double* __restrict__ copy) {
  const std::size_t i = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  constexpr int kSlots = 1 << D;
  unsigned found = 0;  // this particle's valid entries
  if (i < n) {
    double x[kMaxDim] = {0, 0, 0};
    for (int a = 0; a < D; ++a) x[a] = positions[i * D + a];
    if (copy)
      for (int a = 0; a < D; ++a) copy[i * D + a] = x[a];
    uint32_t ids[kMaxCellTypes];
    uint32_t slab = 0;
    control[i] = bin_particle_in<D>(grid, x, ids, &slab);
    uint32_t key[kSlots];
    for (int t = 0; t < kSlots; ++t) {
      const bool ok = ids[t] != kInvalidCell;
      key[t] = ok ? sort_key(grid, ids[t], t != 0, slab) : kInvalidCell;
      found += ok ? 1u : 0u;
    }
    const uint32_t id = uint32_t(i);
    auto* key4 = reinterpret_cast<uint4*>(keys + i * kSlots);  // 16-byte aligned: kSlots is 4 or 8
    auto* id4 = reinterpret_cast<uint4*>(object_ids + i * kSlots);
    for (int q = 0; q < kSlots / 4; ++q) {
      key4[q] = uint4{key[4 * q], key[4 * q + 1], key[4 * q + 2], key[4 * q + 3]};
      id4[q] = uint4{id, id, id, id};
    }
  }
  if (valid) {  // a kernel argument: the whole block takes part
    __shared__ unsigned warp_found[kCellIdBlock / 32];
    found = __reduce_add_sync(0xffffffffu, found);
    if (threadIdx.x % 32 == 0) warp_found[threadIdx.x / 32] = found;
    __syncthreads();
    if (threadIdx.x == 0) {
      unsigned long long block = 0;
      for (int w = 0; w < kCellIdBlock / 32; ++w) block += warp_found[w];
      if (block) atomicAdd(valid, block);
    }
  }
}

struct IsValid {
  __host__ __device__ std::size_t operator()(uint32_t key) const { return key != kInvalidCell; }
};

}  // namespace

void build_cell_ids(const Grid& grid, const double* positions, std::size_t n, uint32_t* keys,
                    uint32_t* object_ids, Control* control, cudaStream_t stream, PipelineCounts* counts,
                    double* copy) {
  if (counts) CF_CUDA_CHECK(cudaMemsetAsync(counts, 0, sizeof(PipelineCounts), stream));
  if (n == 0) return;
  const unsigned blocks = unsigned((n + kCellIdBlock - 1) / kCellIdBlock);
  with_dim(grid.dim, [&](auto d) {
    cell_ids_kernel<decltype(d)::value><<<blocks, kCellIdBlock, 0, stream>>>(
        grid, positions, n, keys, object_ids, control, counts ? &counts->valid : nullptr, copy);
  });
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
