// Stage 3, collision cells (GPU Gems 3 ch. 32, section 32.2.5): the sorted keys are scanned for
// transitions in parallel: (1-2) compact the positions of the entries that start a cell (CUB
// select with the test as its predicate, so that no kernel flags them into an array first),
// (3) describe each run, finding where its H entries end (they sort
// first), and compact those that are collision cells (H >= 1, H + P >= 2) (CUB select on the
// descriptions). The list comes out in cell order, identical to the CPU stage's. Every count stays
// in device memory (PipelineCounts); the launches cover the host's bounds.
#include <cub/device/device_radix_sort.cuh>
#include <cub/device/device_select.cuh>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/iterator/transform_iterator.h>

#include <algorithm>

#include "core/error.h"

#include "search/stages.cuh"

namespace cellforce::cuda {
namespace {

constexpr int kBlock = 256;

unsigned blocks_for(std::size_t n) { return unsigned((n + kBlock - 1) / kBlock); }

// Entry i starts a cell: it is valid and its cell differs from entry i - 1's.
struct StartsCell {
  const uint32_t* keys;
  int slab_bits;
  const PipelineCounts* counts;
  __device__ bool operator()(uint32_t i) const {
    return i < counts->valid && (i == 0 || key_cell(keys[i], slab_bits) != key_cell(keys[i - 1], slab_bits));
  }
};

// Run r (one cell's entries) as a CollisionCell: where its H entries end (they sort first) by a
// binary search over the phantom bit. Runs beyond the count come out empty (h = 0).
struct DescribeRun {
  const uint32_t* keys;
  int slab_bits;
  const uint32_t* run_start;
  const PipelineCounts* counts;
  __device__ CollisionCell operator()(uint32_t r) const {
    const uint32_t runs = counts->runs;
    if (r >= runs) return CollisionCell{0, 0, 0, 0};
    const uint32_t start = run_start[r];
    const uint32_t end = r + 1 < runs ? run_start[r + 1] : uint32_t(counts->valid);
    uint32_t lo = start, hi = end;  // first P entry: keys are H (phantom bit 0) then P (phantom bit 1)
    while (lo < hi) {
      const uint32_t mid = lo + (hi - lo) / 2;
      if (key_is_phantom(keys[mid], slab_bits)) hi = mid;
      else lo = mid + 1;
    }
    const uint32_t h = lo - start, total = end - start;
    return CollisionCell{start, h, total - h, key_cell(keys[start], slab_bits)};
  }
};

// A collision cell: at least one home occupant and at least two occupants.
struct IsCollisionCell {
  __host__ __device__ bool operator()(const CollisionCell& c) const { return c.h >= 1 && c.h + c.p >= 2; }
};

}  // namespace

PipelineCounts read_counts(const PipelineCounts* counts, cudaStream_t stream) {
  PipelineCounts host{};
  CF_CUDA_CHECK(cudaMemcpyAsync(&host, counts, sizeof(host), cudaMemcpyDeviceToHost, stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(stream));
  return host;
}

void find_collision_cells(const uint32_t* sorted_keys, int slab_bits, std::size_t entries, std::size_t run_bound,
                          std::size_t cell_bound, PipelineCounts* counts, DeviceBuffer<CollisionCell>& cells,
                          CollisionScratch& s, cudaStream_t stream, bool zeroed) {
  // cell_range[0] stays 0; the count goes to cell_range[1].
  if (!zeroed)
    CF_CUDA_CHECK(cudaMemsetAsync(&counts->runs, 0, sizeof(counts->runs) + sizeof(counts->cell_range), stream));
  cells.reserve(std::max<std::size_t>(cell_bound, 1));
  if (entries == 0 || run_bound == 0) return;
  if (entries > std::size_t(INT32_MAX)) throw Error("collision cells of more than 2^31 entries");
  s.run_start.reserve(run_bound);
  // The runs' first entries, then the runs that are collision cells, each compacted by CUB with
  // the count left in device memory.
  const thrust::counting_iterator<uint32_t> index(0);
  const StartsCell starts{sorted_keys, slab_bits, counts};
  auto runs = thrust::make_transform_iterator(index, DescribeRun{sorted_keys, slab_bits, s.run_start.data(), counts});
  std::size_t starts_bytes = 0, cells_bytes = 0;
  CF_CUDA_CHECK(cub::DeviceSelect::If(nullptr, starts_bytes, index, s.run_start.data(), &counts->runs, int(entries),
                                      starts, stream));
  CF_CUDA_CHECK(cub::DeviceSelect::If(nullptr, cells_bytes, runs, cells.data(), &counts->cell_range[1],
                                      int(run_bound), IsCollisionCell{}, stream));
  s.cub.reserve(std::max(starts_bytes, cells_bytes));
  CF_CUDA_CHECK(cub::DeviceSelect::If(s.cub.data(), starts_bytes, index, s.run_start.data(), &counts->runs,
                                      int(entries), starts, stream));
  CF_CUDA_CHECK(cub::DeviceSelect::If(s.cub.data(), cells_bytes, runs, cells.data(), &counts->cell_range[1],
                                      int(run_bound), IsCollisionCell{}, stream));
}

}  // namespace cellforce::cuda

// ---- split by cell type (Gauss-Seidel) ---------------------------------------------------------
// The cells of one type share no particle, so each type is one race-free pass. The list is
// split stably by a 3-bit radix sort of (type, position), which keeps cell order within a type.
namespace cellforce::cuda {
namespace {

// The key of each of the `bound` cell slots: its cell type, or `types` (sorting last) beyond the
// count; the per-type counts by integer atomics (the result does not depend on their order).
__global__ void cell_types(const Grid grid, const CollisionCell* __restrict__ cells, std::size_t bound,
                           const PipelineCounts* __restrict__ counts, uint32_t* __restrict__ types,
                           uint32_t* __restrict__ positions, unsigned* __restrict__ per_type) {
  const std::size_t c = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (c >= bound) return;
  positions[c] = uint32_t(c);
  if (c >= counts->cell_range[1]) {
    types[c] = 1u << grid.dim;  // the number of cell types: past every real one
    return;
  }
  const uint32_t t = cell_type_of_id(grid, cells[c].cell);
  types[c] = t;
  atomicAdd(&per_type[t], 1u);
}

__global__ void gather_cells(const CollisionCell* __restrict__ in, const uint32_t* __restrict__ order,
                             std::size_t n, CollisionCell* __restrict__ out) {
  const std::size_t c = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (c < n) out[c] = in[order[c]];
}

__global__ void type_starts(const unsigned* __restrict__ per_type, int types, PipelineCounts* counts) {
  if (threadIdx.x != 0) return;
  counts->type_start[0] = 0;
  for (int t = 0; t < types; ++t) counts->type_start[t + 1] = counts->type_start[t] + per_type[t];
}

}  // namespace

void split_by_type(const Grid& grid, DeviceBuffer<CollisionCell>& cells, std::size_t bound,
                   PipelineCounts* counts, SplitScratch& s, cudaStream_t stream) {
  const int types = grid.num_types();
  s.counts.reserve(kMaxCellTypes);
  CF_CUDA_CHECK(cudaMemsetAsync(s.counts.data(), 0, kMaxCellTypes * sizeof(unsigned), stream));
  if (bound > 0) {
    s.keys.reserve(bound);
    s.keys_out.reserve(bound);
    s.order.reserve(bound);
    s.order_out.reserve(bound);
    s.cells.reserve(bound);
    cell_types<<<blocks_for(bound), kBlock, 0, stream>>>(grid, cells.data(), bound, counts, s.keys.data(),
                                                         s.order.data(), s.counts.data());
    CF_CUDA_CHECK_LAUNCH();
    // Keys 0 .. types (the sentinel): dim + 1 bits.
    std::size_t bytes = 0;
    CF_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(nullptr, bytes, s.keys.data(), s.keys_out.data(),
                                                  s.order.data(), s.order_out.data(), int(bound), 0,
                                                  grid.dim + 1, stream));
    s.cub.reserve(bytes);
    CF_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(s.cub.data(), bytes, s.keys.data(), s.keys_out.data(),
                                                  s.order.data(), s.order_out.data(), int(bound), 0,
                                                  grid.dim + 1, stream));
    gather_cells<<<blocks_for(bound), kBlock, 0, stream>>>(cells.data(), s.order_out.data(), bound,
                                                           s.cells.data());
    CF_CUDA_CHECK_LAUNCH();
    std::swap(cells, s.cells);
  }
  type_starts<<<1, 32, 0, stream>>>(s.counts.data(), types, counts);
  CF_CUDA_CHECK_LAUNCH();
}

}  // namespace cellforce::cuda
