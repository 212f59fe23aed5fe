// Stage 3, collision cells (GPU Gems 3 ch. 32, section 32.2.5): the sorted keys are scanned for
// transitions in parallel: (1) flag every entry that starts a cell, (2) compact the flagged
// positions (CUB select), (3) one thread per cell finds where its H entries end (they sort first)
// and whether it is a collision cell (H >= 1, H + P >= 2), (4) compact those. The list comes out
// in cell order, identical to the CPU stage's.
#include <cub/device/device_radix_sort.cuh>
#include <cub/device/device_select.cuh>
#include <thrust/iterator/counting_iterator.h>

#include "stages.cuh"

namespace cellforce::cuda {
namespace {

constexpr int kBlock = 256;

unsigned blocks_for(std::size_t n) { return unsigned((n + kBlock - 1) / kBlock); }

__global__ void flag_cell_starts(const uint32_t* __restrict__ keys, std::size_t n,
                                 uint8_t* __restrict__ flags) {
  const std::size_t i = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  flags[i] = i == 0 || (keys[i] >> 1) != (keys[i - 1] >> 1);
}

__global__ void describe_cells(const uint32_t* __restrict__ keys, std::size_t n,
                               const uint32_t* __restrict__ run_start, int runs,
                               CollisionCell* __restrict__ out, uint8_t* __restrict__ keep) {
  const int r = int(blockIdx.x * blockDim.x + threadIdx.x);
  if (r >= runs) return;
  const uint32_t start = run_start[r];
  const uint32_t end = r + 1 < runs ? run_start[r + 1] : uint32_t(n);
  uint32_t lo = start, hi = end;  // first P entry: keys are H (low bit 0) then P (low bit 1)
  while (lo < hi) {
    const uint32_t mid = lo + (hi - lo) / 2;
    if (keys[mid] & 1u) hi = mid;
    else lo = mid + 1;
  }
  const uint32_t h = lo - start, total = end - start;
  out[r] = CollisionCell{start, h, total - h, keys[start] >> 1};
  keep[r] = h >= 1 && total >= 2;
}

template <class In, class Out>
int select_flagged(In in, const uint8_t* flags, Out out, std::size_t n, CollisionScratch& s,
                   cudaStream_t stream) {
  std::size_t bytes = 0;
  CF_CUDA_CHECK(cub::DeviceSelect::Flagged(nullptr, bytes, in, flags, out, s.count.data(), int(n), stream));
  s.cub.reserve(bytes);
  CF_CUDA_CHECK(cub::DeviceSelect::Flagged(s.cub.data(), bytes, in, flags, out, s.count.data(), int(n), stream));
  int selected = 0;
  CF_CUDA_CHECK(cudaMemcpyAsync(&selected, s.count.data(), sizeof(int), cudaMemcpyDeviceToHost, stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(stream));
  return selected;
}

}  // namespace

std::size_t find_collision_cells(const uint32_t* sorted_keys, std::size_t valid,
                                 DeviceBuffer<CollisionCell>& cells, CollisionScratch& s,
                                 cudaStream_t stream) {
  if (valid == 0) return 0;
  if (valid > std::size_t(INT32_MAX)) throw Error("collision cells of more than 2^31 entries");
  s.flags.reserve(valid);
  s.run_start.reserve(valid);
  s.count.reserve(1);
  flag_cell_starts<<<blocks_for(valid), kBlock, 0, stream>>>(sorted_keys, valid, s.flags.data());
  CF_CUDA_CHECK_LAUNCH();
  const int runs = select_flagged(thrust::counting_iterator<uint32_t>(0), s.flags.data(),
                                  s.run_start.data(), valid, s, stream);
  s.runs.reserve(std::size_t(runs));
  describe_cells<<<blocks_for(std::size_t(runs)), kBlock, 0, stream>>>(
      sorted_keys, valid, s.run_start.data(), runs, s.runs.data(), s.flags.data());
  CF_CUDA_CHECK_LAUNCH();
  cells.reserve(std::size_t(runs));
  return std::size_t(select_flagged(s.runs.data(), s.flags.data(), cells.data(), std::size_t(runs), s, stream));
}

}  // namespace cellforce::cuda

// ---- split by cell type (Gauss-Seidel) ---------------------------------------------------------
// The cells of one type share no particle, so each type is one race-free pass. The list is
// split stably by a 3-bit radix sort of (type, position), which keeps cell order within a type.
namespace cellforce::cuda {
namespace {

__global__ void cell_types(const Grid grid, const CollisionCell* __restrict__ cells, std::size_t n,
                           uint32_t* __restrict__ types, uint32_t* __restrict__ positions,
                           unsigned* __restrict__ counts) {
  const std::size_t c = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (c >= n) return;
  const uint32_t t = cell_type_of_id(grid, cells[c].cell);
  types[c] = t;
  positions[c] = uint32_t(c);
  atomicAdd(&counts[t], 1u);  // integer counts: the result does not depend on the order
}

__global__ void gather_cells(const CollisionCell* __restrict__ in, const uint32_t* __restrict__ order,
                             std::size_t n, CollisionCell* __restrict__ out) {
  const std::size_t c = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (c < n) out[c] = in[order[c]];
}

}  // namespace

void split_by_type(const Grid& grid, DeviceBuffer<CollisionCell>& cells, std::size_t count,
                   SplitScratch& s, std::size_t type_start[kMaxCellTypes + 1], cudaStream_t stream) {
  const int types = grid.num_types();
  for (int t = 0; t <= types; ++t) type_start[t] = 0;
  if (count == 0) return;
  s.keys.reserve(count);
  s.keys_out.reserve(count);
  s.order.reserve(count);
  s.order_out.reserve(count);
  s.cells.reserve(count);
  s.counts.reserve(kMaxCellTypes);
  CF_CUDA_CHECK(cudaMemsetAsync(s.counts.data(), 0, kMaxCellTypes * sizeof(unsigned), stream));
  cell_types<<<blocks_for(count), kBlock, 0, stream>>>(grid, cells.data(), count, s.keys.data(),
                                                       s.order.data(), s.counts.data());
  CF_CUDA_CHECK_LAUNCH();
  std::size_t bytes = 0;
  CF_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(nullptr, bytes, s.keys.data(), s.keys_out.data(),
                                                s.order.data(), s.order_out.data(), int(count), 0,
                                                grid.dim, stream));
  s.cub.reserve(bytes);
  CF_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(s.cub.data(), bytes, s.keys.data(), s.keys_out.data(),
                                                s.order.data(), s.order_out.data(), int(count), 0,
                                                grid.dim, stream));
  gather_cells<<<blocks_for(count), kBlock, 0, stream>>>(cells.data(), s.order_out.data(), count,
                                                         s.cells.data());
  CF_CUDA_CHECK_LAUNCH();
  std::swap(cells, s.cells);
  unsigned counts[kMaxCellTypes] = {};
  CF_CUDA_CHECK(cudaMemcpyAsync(counts, s.counts.data(), sizeof(counts), cudaMemcpyDeviceToHost, stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(stream));
  for (int t = 0; t < types; ++t) type_start[t + 1] = type_start[t] + counts[t];
}

}  // namespace cellforce::cuda
