// The search stages of the CUDA pipeline, with the same names and array layouts as src/cpu:
// stage 1 (cell IDs and the count of valid entries), stage 2 (the sort, with CUB or the chapter's
// own radix sort) and stage 3 (the collision-cell list); stages 4 and 5 are forces/traversal.cuh's.
// All work is enqueued on `stream`; pointers are device pointers.
#pragma once

#include <cuda_runtime.h>

#include <cstddef>
#include <cstdint>

#include "core/grid.h"
#include "device_buffer.cuh"

namespace cellforce::cuda {

// What the stages count, kept in device memory: the kernels of later stages read the counts there,
// so that the host never waits for one to size a buffer. Buffers are sized instead by bounds the
// host knows (GpuEngine's plan: entries = n x 2^d for the valid entries, min(entries, grid cells)
// for the runs, min(n, grid cells) for the collision cells, since every collision cell holds at
// least one particle's home entry). The host reads the counts only when it synchronises anyway
// (statistics, the pair recorder).
struct PipelineCounts {
  unsigned long long valid;                 // valid cell-ID entries (stage 1)
  uint32_t runs;                            // distinct cells among them (stage 3)
  uint32_t cell_range[2];                   // collision cells [0, count): {0, count} (stage 3)
  uint32_t type_start[kMaxCellTypes + 1];   // Gauss-Seidel: cells of type t in [start[t], start[t + 1])
};

// The counts on the host (synchronises the stream): for the tests and benchmarks of the stages.
PipelineCounts read_counts(const PipelineCounts* counts, cudaStream_t stream);

// Stage 1 (GPU Gems 3 ch. 32, section 32.2.2): one thread per particle. positions: n x grid.dim
// doubles, user order. Writes keys and object_ids (n x 2^d, entry i * 2^d + t as on the CPU:
// sort_key(): (cell << 1 | phantom) << slab bits | slab, kInvalidCell where unused) and control (n). keys and object_ids are
// 16-byte aligned (the kernel stores 4 entries at a time). With `counts`, every count is zeroed
// first (stage 3 then needs no zeroing of its own: find_collision_cells' `zeroed`) and the valid
// entries are counted into counts->valid by the kernel itself (an integer atomic add per block: the
// same count as count_valid, without a second pass over the keys). With `copy` (n x grid.dim), the
// positions as read are stored there too (the build's positions of a reused structure).
void build_cell_ids(const Grid& grid, const double* positions, std::size_t n, uint32_t* keys,
                    uint32_t* object_ids, Control* control, cudaStream_t stream, PipelineCounts* counts = nullptr,
                    double* copy = nullptr);

// The count of valid entries into counts->valid, by a device reduction; `scratch` grows as CUB
// asks.
void count_valid(const uint32_t* keys, std::size_t entries, PipelineCounts* counts,
                 DeviceBuffer<std::byte>& scratch, cudaStream_t stream);

// Device memory lent for a call's scratch (a dead buffer's room): used where it is large enough.
struct ScratchLoan {
  std::byte* data = nullptr;  // 256-byte aligned
  std::size_t bytes = 0;
};

// Stage 2 with CUB's device radix sort: stable, on bits [0, key_bits) only, so that invalid
// entries (all ones in the window) sort last and each cell's H entries precede its P entries.
// Sorts (keys_in, values_in) into (keys_out, values_out). Its scratch: `loan` where it is large
// enough, else `scratch`, grown as CUB asks.
void radix_sort_cub(const uint32_t* keys_in, const uint32_t* values_in, uint32_t* keys_out,
                    uint32_t* values_out, std::size_t entries, int key_bits,
                    DeviceBuffer<std::byte>& scratch, cudaStream_t stream, ScratchLoan loan = {});

// The scratch bytes radix_sort_cub asks for, for `entries` keys of `key_bits` bits (CUB's query:
// no device work).
std::size_t radix_sort_cub_bytes(std::size_t entries, int key_bits);

// Stage 2 with the chapter's own three-phase radix sort (section 32.2.3): the same contract as
// radix_sort_cub (stable, bits [0, key_bits) only, key_bits in 1..32, else cellforce::Error) and
// the same result element for element. The inputs are only read; outputs must not overlap them.
// Deterministic, no atomics. The scratch grows from the counts and is reused across calls.
struct ChapterSortScratch {
  DeviceBuffer<uint32_t> keys, values;  // entries each: the outputs' partners between passes
  DeviceBuffer<uint32_t> counts;        // radix x tiles, counts[digit * tiles + tile]
  DeviceBuffer<uint32_t> digit_totals;  // radix: entries per digit in the current pass
};
void radix_sort_chapter(const uint32_t* keys_in, const uint32_t* values_in, uint32_t* keys_out,
                        uint32_t* values_out, std::size_t entries, int key_bits,
                        ChapterSortScratch& scratch, cudaStream_t stream);

// Stage 3 (section 32.2.5): the collision cells of the first counts->valid of the `entries`
// sorted keys, in cell order, written to `cells` with their number in counts->cell_range[1] (and
// the runs in counts->runs). `run_bound` >= the runs and `cell_bound` >= the collision cells (see
// PipelineCounts) size the buffers, which grow to them.
// `zeroed`: counts->runs and cell_range were zeroed since the last stage 3 (build_cell_ids with counts).
struct CollisionScratch {
  DeviceBuffer<uint32_t> run_start;
  DeviceBuffer<std::byte> cub;
};
void find_collision_cells(const uint32_t* sorted_keys, int slab_bits, std::size_t entries, std::size_t run_bound,
                          std::size_t cell_bound, PipelineCounts* counts, DeviceBuffer<CollisionCell>& cells,
                          CollisionScratch& scratch, cudaStream_t stream, bool zeroed = false);

// Stage 3's option for Gauss-Seidel: splits the counts->cell_range[1] cells (at most `cell_bound`)
// stably by cell type (cell order kept within a type); counts->type_start[t] ..
// counts->type_start[t + 1] - 1 are the cells of type t afterwards, all on the device.
struct SplitScratch {
  DeviceBuffer<uint32_t> keys, keys_out, order, order_out;
  DeviceBuffer<CollisionCell> cells;
  DeviceBuffer<unsigned> counts;
  DeviceBuffer<std::byte> cub;
};
void split_by_type(const Grid& grid, DeviceBuffer<CollisionCell>& cells, std::size_t cell_bound,
                   PipelineCounts* counts, SplitScratch& scratch, cudaStream_t stream);

// Reuse (src/core/reuse.h): the largest squared displacement between the device arrays now and
// then (n x box.dim, minimum image on periodic axes). Synchronises the stream to return it.
double max_displacement2(const Box& box, const double* now, const double* then, std::size_t n,
                         DeviceBuffer<std::byte>& scratch, cudaStream_t stream);

// The smallest and largest coordinate along each axis of n x dim device positions (lo[dim],
// hi[dim]; 0 for n = 0). Synchronises the stream to return them: what plans an open axis' cells.
void bounding_box(const double* positions, std::size_t n, int dim, double lo[], double hi[],
                  DeviceBuffer<std::byte>& scratch, cudaStream_t stream);

}  // namespace cellforce::cuda
