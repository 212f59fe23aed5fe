// Stage 2, sort (GPU Gems 3 ch. 32, section 32.2.3), two implementations behind one interface.
// radix_sort_cub is CUB's device radix sort (LSD, hence stable) on the bits the grid needs.
// radix_sort_chapter is the chapter's own three-phase sort, kept as an independent second
// implementation to check and time the pipeline against: per pass, (1) each thread group (a warp)
// tabulates its segment of a tile in its own shared counters, (2) one block per digit turns the
// (digit, tile) counters into prefix sums, (3) each block finishes the prefix over the digit
// totals and reorders its tile. Stability comes from the chapter's mapping: tiles, warps, rounds
// and lanes all follow input order, and ranks are handed out in that order. Departures, for a
// current GPU rather than a G80: the serialised counter updates of Figures 32-11 and 32-18 become
// one __match_any_sync per round (the same ranks, no atomics, deterministic); a tile is reordered
// in shared memory first so that each digit's run is written contiguously instead of scattered
// (the chapter's 50 percent penalty); many 4096-key tiles replace one block per multiprocessor;
// and key_bits is split evenly over the passes (17 bits: 6 + 6 + 5), which keeps the pass count
// of 8-bit digits with fewer counters.
#include <cub/device/device_radix_sort.cuh>

#include <string>

#include "search/stages.cuh"

namespace cellforce::cuda {

void radix_sort_cub(const uint32_t* keys_in, const uint32_t* values_in, uint32_t* keys_out,
                    uint32_t* values_out, std::size_t entries, int key_bits,
                    DeviceBuffer<std::byte>& scratch, cudaStream_t stream, ScratchLoan loan) {
  if (entries == 0) return;
  std::size_t bytes = radix_sort_cub_bytes(entries, key_bits);  // refuses more than 2^31 entries
  const int n = int(entries);
  std::byte* room = loan.data;
  if (bytes > loan.bytes || !loan.data) {
    scratch.reserve(bytes);
    room = scratch.data();
  }
  CF_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(room, bytes, keys_in, keys_out, values_in,
                                                values_out, n, 0, key_bits, stream));
}

std::size_t radix_sort_cub_bytes(std::size_t entries, int key_bits) {
  if (entries == 0) return 0;
  if (entries > std::size_t(INT32_MAX)) throw Error("sort of more than 2^31 entries");
  std::size_t bytes = 0;
  CF_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(nullptr, bytes, static_cast<const uint32_t*>(nullptr),
                                                static_cast<uint32_t*>(nullptr), static_cast<const uint32_t*>(nullptr),
                                                static_cast<uint32_t*>(nullptr), int(entries), 0, key_bits));
  return bytes;
}

namespace {

// Launch shapes of the chapter's sort.
struct ChapterSortPolicy {
  static constexpr int kMaxDigitBits = 8;                     // the chapter's L
  static constexpr int kMaxRadix = 1 << kMaxDigitBits;
  static constexpr int kThreads = 256;                        // phases 1 and 3: one per digit
  static constexpr int kWarps = kThreads / 32;                // thread groups per block
  static constexpr int kItemsPerThread = 16;
  static constexpr int kWarpItems = 32 * kItemsPerThread;     // a thread group's segment
  static constexpr int kTile = kThreads * kItemsPerThread;    // a block's section: 4096 keys
  static constexpr int kReorderMinBlocks = 3;  // per SM: caps phase 3 at 80 registers, no spills
  static constexpr int kScanThreads = 256;                    // phase 2
  static constexpr int kScanItemsPerThread = 16;
  static constexpr int kScanChunk = kScanThreads * kScanItemsPerThread;
};
using P = ChapterSortPolicy;
static_assert(P::kThreads == P::kMaxRadix, "phase 3 gives each digit one thread");

// Marks the lanes past the end of the last tile: never a digit, so they rank with nobody.
constexpr uint32_t kNoDigit = 0xffffffffu;

__device__ __forceinline__ uint32_t digit_of(uint32_t key, int shift, uint32_t mask) {
  return (key >> shift) & mask;
}

// Exclusive prefix sum of one value per thread over a block of kBlockThreads threads; `total`
// gets the block's sum. Every thread must call it; s_warp may be reused as soon as it returns.
template <int kBlockThreads>
__device__ uint32_t block_exclusive_scan(uint32_t x, uint32_t* s_warp, uint32_t& total) {
  constexpr int kBlockWarps = kBlockThreads / 32;
  const int lane = int(threadIdx.x) & 31, warp = int(threadIdx.x) >> 5;
  uint32_t inclusive = x;
#pragma unroll
  for (int offset = 1; offset < 32; offset <<= 1) {
    const uint32_t y = __shfl_up_sync(0xffffffffu, inclusive, offset);
    if (lane >= offset) inclusive += y;
  }
  if (lane == 31) s_warp[warp] = inclusive;
  __syncthreads();
  uint32_t before = 0;
  total = 0;
#pragma unroll
  for (int w = 0; w < kBlockWarps; ++w) {
    const uint32_t s = s_warp[w];
    if (w < warp) before += s;
    total += s;
  }
  __syncthreads();
  return before + inclusive - x;
}

// A thread's keys in the chapter's layout (Figures 32-12 to 32-14): a block's tile is split into
// one contiguous segment per warp, read by the warp's lanes interleaved (coalesced), so round k of
// lane l holds entry tile + warp * kWarpItems + 32 k + l; `first` is round 0's entry.
__device__ __forceinline__ uint32_t entry_of(uint32_t first, int k) {
  return first + 32u * uint32_t(k);
}

__device__ __forceinline__ void load_tile_keys(const uint32_t* __restrict__ keys, uint32_t n,
                                               uint32_t first,
                                               uint32_t (&key)[P::kItemsPerThread]) {
#pragma unroll
  for (int k = 0; k < P::kItemsPerThread; ++k)
    key[k] = entry_of(first, k) < n ? keys[entry_of(first, k)] : 0u;
}

// Phase 1, tabulation. counts[digit * tiles + tile] = occurrences of the digit in the tile.
__global__ void __launch_bounds__(P::kThreads)
    tabulate(const uint32_t* __restrict__ keys, uint32_t n, int shift, int bits, uint32_t tiles,
             uint32_t* __restrict__ counts) {
  __shared__ uint32_t s_count[P::kWarps][P::kMaxRadix];  // per thread group, as the chapter
  const int lane = int(threadIdx.x) & 31, warp = int(threadIdx.x) >> 5;
  for (int i = int(threadIdx.x); i < P::kWarps * P::kMaxRadix; i += P::kThreads)
    s_count[i / P::kMaxRadix][i % P::kMaxRadix] = 0;
  __syncthreads();

  const uint32_t mask = (1u << bits) - 1u;
  const uint32_t first = blockIdx.x * uint32_t(P::kTile) + uint32_t(warp * P::kWarpItems + lane);
  uint32_t key[P::kItemsPerThread];
  load_tile_keys(keys, n, first, key);
  const uint32_t lanes_below = (1u << lane) - 1u;
  uint32_t* my_count = s_count[warp];
#pragma unroll
  for (int k = 0; k < P::kItemsPerThread; ++k) {
    const uint32_t digit = entry_of(first, k) < n ? digit_of(key[k], shift, mask) : kNoDigit;
    const uint32_t peers = __match_any_sync(0xffffffffu, digit);
    if (digit != kNoDigit && (peers & lanes_below) == 0) my_count[digit] += __popc(peers);
    __syncwarp();  // the next round's first lane of a digit may be another lane
  }
  __syncthreads();

  const int d = int(threadIdx.x);
  if (d < (1 << bits)) {
    uint32_t tile_count = 0;
#pragma unroll
    for (int w = 0; w < P::kWarps; ++w) tile_count += s_count[w][d];
    counts[std::size_t(d) * tiles + blockIdx.x] = tile_count;
  }
}

// Phase 2, one block per digit: the digit's row of counters becomes its exclusive prefix sum over
// tiles (where each tile's run of the digit starts within the digit's section of the output);
// digit_totals[digit] = the row's sum. The prefix sum over digits is left to phase 3.
__global__ void __launch_bounds__(P::kScanThreads)
    scan_tiles_per_digit(uint32_t* __restrict__ counts, uint32_t tiles,
                         uint32_t* __restrict__ digit_totals) {
  __shared__ uint32_t s_warp[P::kScanThreads / 32];
  uint32_t* row = counts + std::size_t(blockIdx.x) * tiles;
  uint32_t carry = 0;
  for (uint32_t chunk = 0; chunk < tiles; chunk += uint32_t(P::kScanChunk)) {
    const uint32_t first = chunk + threadIdx.x * uint32_t(P::kScanItemsPerThread);
    uint32_t c[P::kScanItemsPerThread], sum = 0;
#pragma unroll
    for (int k = 0; k < P::kScanItemsPerThread; ++k) {
      c[k] = first + uint32_t(k) < tiles ? row[first + k] : 0u;
      sum += c[k];
    }
    uint32_t chunk_total = 0;
    uint32_t offset = carry + block_exclusive_scan<P::kScanThreads>(sum, s_warp, chunk_total);
#pragma unroll
    for (int k = 0; k < P::kScanItemsPerThread; ++k) {
      if (first + uint32_t(k) < tiles) row[first + k] = offset;
      offset += c[k];
    }
    carry += chunk_total;
  }
  if (threadIdx.x == 0) digit_totals[blockIdx.x] = carry;
}

// Phase 3, reordering. Each block ranks its tile as phase 1 counted it, places it in digit order
// in shared memory, then writes each digit's run to its place in the output.
__global__ void __launch_bounds__(P::kThreads, P::kReorderMinBlocks)
    reorder(const uint32_t* __restrict__ keys_in, const uint32_t* __restrict__ values_in,
            uint32_t n, int shift, int bits, uint32_t tiles, const uint32_t* __restrict__ counts,
            const uint32_t* __restrict__ digit_totals, uint32_t* __restrict__ keys_out,
            uint32_t* __restrict__ values_out) {
  __shared__ uint32_t s_keys[P::kTile];
  __shared__ uint32_t s_values[P::kTile];
  // Per (thread group, digit): the running count while ranking, then where the group's entries
  // of the digit start in the tile's digit order.
  __shared__ uint32_t s_count[P::kWarps][P::kMaxRadix];
  // Per digit: output position of the tile's shared slot 0 (slot i of the digit goes to
  // s_out_base[digit] + i; wraps modulo 2^32 on purpose, the sum is always in range).
  __shared__ uint32_t s_out_base[P::kMaxRadix];
  __shared__ uint32_t s_warp[P::kWarps];
  const int lane = int(threadIdx.x) & 31, warp = int(threadIdx.x) >> 5;
  for (int i = int(threadIdx.x); i < P::kWarps * P::kMaxRadix; i += P::kThreads)
    s_count[i / P::kMaxRadix][i % P::kMaxRadix] = 0;
  __syncthreads();

  // Rank: round by round, the lanes holding one digit take consecutive ranks after the group's
  // running count, in lane order; the first of them advances the count.
  const uint32_t mask = (1u << bits) - 1u;
  const uint32_t tile_first = blockIdx.x * uint32_t(P::kTile);
  const uint32_t first = tile_first + uint32_t(warp * P::kWarpItems + lane);
  uint32_t key[P::kItemsPerThread], rank[P::kItemsPerThread];
  load_tile_keys(keys_in, n, first, key);
  const uint32_t lanes_below = (1u << lane) - 1u;
  uint32_t* my_count = s_count[warp];
#pragma unroll
  for (int k = 0; k < P::kItemsPerThread; ++k) {
    const uint32_t digit = entry_of(first, k) < n ? digit_of(key[k], shift, mask) : kNoDigit;
    const uint32_t peers = __match_any_sync(0xffffffffu, digit);
    const uint32_t peers_below = __popc(peers & lanes_below);
    const uint32_t base = digit != kNoDigit ? my_count[digit] : 0u;
    __syncwarp();  // every peer has read the count before it moves
    if (digit != kNoDigit && peers_below == 0) my_count[digit] = base + __popc(peers);
    __syncwarp();
    rank[k] = base + peers_below;
  }
  __syncthreads();

  // Thread d: prefix sums over (digit, group) inside the tile, then, as the chapter's phase 3
  // begins, the prefix sum over the digit totals of phase 2, giving absolute output positions.
  {
    const int d = int(threadIdx.x);
    const bool used = d < (1 << bits);
    uint32_t tile_count = 0;
#pragma unroll
    for (int w = 0; w < P::kWarps; ++w) {
      const uint32_t c = s_count[w][d];
      s_count[w][d] = tile_count;
      tile_count += c;
    }
    uint32_t unused = 0;
    const uint32_t tile_start = block_exclusive_scan<P::kThreads>(tile_count, s_warp, unused);
#pragma unroll
    for (int w = 0; w < P::kWarps; ++w) s_count[w][d] += tile_start;
    const uint32_t digit_start =
        block_exclusive_scan<P::kThreads>(used ? digit_totals[d] : 0u, s_warp, unused);
    if (used)
      s_out_base[d] = digit_start + counts[std::size_t(d) * tiles + blockIdx.x] - tile_start;
  }
  __syncthreads();

#pragma unroll
  for (int k = 0; k < P::kItemsPerThread; ++k) {
    if (entry_of(first, k) >= n) continue;
    const uint32_t slot = s_count[warp][digit_of(key[k], shift, mask)] + rank[k];
    s_keys[slot] = key[k];
    s_values[slot] = values_in[entry_of(first, k)];
  }
  __syncthreads();

  const uint32_t tile_n = min(uint32_t(P::kTile), n - tile_first);
  for (uint32_t i = threadIdx.x; i < tile_n; i += uint32_t(P::kThreads)) {
    const uint32_t sorted_key = s_keys[i];
    const uint32_t to = s_out_base[digit_of(sorted_key, shift, mask)] + i;
    keys_out[to] = sorted_key;
    values_out[to] = s_values[i];
  }
}

}  // namespace

void radix_sort_chapter(const uint32_t* keys_in, const uint32_t* values_in, uint32_t* keys_out,
                        uint32_t* values_out, std::size_t entries, int key_bits,
                        ChapterSortScratch& scratch, cudaStream_t stream) {
  if (key_bits < 1 || key_bits > 32)
    throw Error("chapter radix sort: key_bits " + std::to_string(key_bits) + " outside 1..32");
  if (entries == 0) return;
  if (entries > std::size_t(INT32_MAX)) throw Error("sort of more than 2^31 entries");
  const uint32_t n = uint32_t(entries);
  const int passes = (key_bits + P::kMaxDigitBits - 1) / P::kMaxDigitBits;
  const uint32_t tiles = (n + uint32_t(P::kTile) - 1) / uint32_t(P::kTile);
  // The first pass has the most bits (the remainder of the even split goes to the first passes).
  const int widest = key_bits / passes + (key_bits % passes ? 1 : 0);
  scratch.counts.reserve((std::size_t(1) << widest) * tiles);
  scratch.digit_totals.reserve(std::size_t(1) << widest);
  if (passes > 1) {
    scratch.keys.reserve(n);
    scratch.values.reserve(n);
  }

  // Passes alternate between the output and the scratch, ending on the output; the first reads
  // the input, which is never written.
  const uint32_t* src_keys = keys_in;
  const uint32_t* src_values = values_in;
  int shift = 0;
  for (int pass = 0; pass < passes; ++pass) {
    const int bits = key_bits / passes + (pass < key_bits % passes ? 1 : 0);
    const bool to_output = (passes - 1 - pass) % 2 == 0;
    uint32_t* dst_keys = to_output ? keys_out : scratch.keys.data();
    uint32_t* dst_values = to_output ? values_out : scratch.values.data();
    tabulate<<<tiles, P::kThreads, 0, stream>>>(src_keys, n, shift, bits, tiles,
                                                 scratch.counts.data());
    CF_CUDA_CHECK_LAUNCH();
    scan_tiles_per_digit<<<1u << bits, P::kScanThreads, 0, stream>>>(scratch.counts.data(), tiles,
                                                                     scratch.digit_totals.data());
    CF_CUDA_CHECK_LAUNCH();
    reorder<<<tiles, P::kThreads, 0, stream>>>(src_keys, src_values, n, shift, bits, tiles,
                                                scratch.counts.data(), scratch.digit_totals.data(),
                                                dst_keys, dst_values);
    CF_CUDA_CHECK_LAUNCH();
    src_keys = dst_keys;
    src_values = dst_values;
    shift += bits;
  }
}

}  // namespace cellforce::cuda
