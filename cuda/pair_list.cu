// Pair lists for a reused structure: the build (ranks, counts, the list stored as a row per rank)
// and the force kernel of the evaluations it serves. See pair_list.cuh.
#include <cub/device/device_partition.cuh>
#include <cub/device/device_scan.cuh>
#include <cub/device/device_select.cuh>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/iterator/transform_iterator.h>

#include <algorithm>
#include <cmath>

#include "core/error.h"
#include "pair_list.cuh"
#include "step_gate.cuh"
#include "traversal_impl.cuh"  // Traits, dispatch, warp_sum, flag_bad_pair
#include "verlet_step.cuh"
#include "with_dim.cuh"

namespace cellforce::cuda {
namespace {

constexpr int kBlock = 128;  // threads per block of every list kernel (4 warps; fused_block may double it)

// A sorted entry that is some particle's H entry (the key's phantom bit clear; invalid keys are
// all ones).
struct IsHome {
  const uint32_t* keys;
  int slab_bits;
  __device__ bool operator()(uint32_t e) const { return !key_is_phantom(keys[e], slab_bits); }
};

// Also zeroes the two sizes sum_slot_counts adds to later in the build (change 80: no memset).
__global__ void invert_order(const uint32_t* __restrict__ order, std::size_t n, uint32_t* __restrict__ rank,
                             unsigned long long* __restrict__ sizes) {
  const std::size_t p = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (p < n) rank[order[p]] = uint32_t(p);
  if (p == 0) sizes[0] = sizes[1] = 0;
}

// The minimum-image separation a - b along axis `a` of the grid (positions already wrapped).
__device__ __forceinline__ double image(const Grid& g, int a, double d) {
  return minimum_image(d, g.length[a], g.inv_length[a]);
}

template <int D>
__device__ __forceinline__ double distance2(const Grid& g, const RankedParticle& a, const RankedParticle& b,
                                            double d[3]) {
  d[0] = image(g, 0, a.x - b.x);
  d[1] = image(g, 1, a.y - b.y);
  d[2] = D == 3 ? image(g, 2, a.z - b.z) : 0.0;
  return d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
}

// The squared minimum-image distance of particles i and j from their user-order positions, in
// double (separation: each coordinate wrapped exactly, then the minimum image): the build's
// decision for pairs within the staged coordinates' rounding of the list cutoff, the same number
// distance2 forms from gathered RankedParticles but for the order of the rounded sum. Inlined:
// __noinline__ measured 2.5% slower passes (change 18c).
template <int D>
__device__ __forceinline__ double distance2(const Grid& g, const double* __restrict__ positions, uint32_t i,
                                            uint32_t j) {
  double r2 = 0;
  for (int a = 0; a < D; ++a) {
    const double d = separation(positions[std::size_t(i) * D + a], positions[std::size_t(j) * D + a], g.length[a],
                                g.inv_length[a]);
    r2 += d * d;
  }
  return r2;
}

// The separation P - Q of two gathered particles in the pair precision: formed in double and
// rounded once (RankedParticle), or as the fixed-point difference (FixedParticle, float), scaled
// by L_a / 2^32 (`scale`, from the host: fixed_separation in list_build.h).
template <int D, class Real>
__device__ __forceinline__ void pair_separation(const Grid& g, const RankedParticle& a, const RankedParticle& b,
                                                const FixedScales&, Real d[3]) {
  double dd[3];
  distance2<D>(g, a, b, dd);
  for (int c = 0; c < 3; ++c) d[c] = Real(dd[c]);
}
template <int D, class Real>
__device__ __forceinline__ void pair_separation(const Grid&, const FixedParticle& a, const FixedParticle& b,
                                                const FixedScales& scale, Real d[3]) {
  static_assert(std::is_same_v<Real, float>, "fixed-point positions serve float pairs");
  d[0] = fixed_separation(a.x, b.x, scale.axis[0]);
  d[1] = fixed_separation(a.y, b.y, scale.axis[1]);
  d[2] = D == 3 ? fixed_separation(a.z, b.z, scale.axis[2]) : 0.0f;
}

// A walk's entries of one rank's list, from entry `first` on (the partners found before this walk),
// one after the other: each chunk the walk fills whole is one 16-byte store, and the chunks it
// shares with the walks before and after it (its first and last) are written entry by entry. The
// list's 4-byte stores, each lane at its own row's place (each its own L2 transaction), held the
// fill to ~25% of its issue rate at 1M particles (Nsight Compute: L2 69% busy, 4.4 useful bytes
// per stored sector). The walked fill (units without masks) uses it; the fill from masks writes a
// warp's entries 32 at a time, neighbouring lanes at neighbouring places of a row (change 66).
class ChunkWriter {
 public:
  // chunk0: the rank's chunk 0 (chunk c at chunk0 + c * kGroup: list_entry's layout), or null for a
  // lane with no row (nothing is put).
  __device__ ChunkWriter(uint32_t* chunk0, uint32_t first) : chunk0_(chunk0), first_(first), next_(first) {}
  __device__ __forceinline__ void put(uint32_t value) {
    const uint32_t slot = next_ % kChunk;
    v0_ = slot == 0 ? value : v0_;
    v1_ = slot == 1 ? value : v1_;
    v2_ = slot == 2 ? value : v2_;
    v3_ = slot == 3 ? value : v3_;
    ++next_;
    if (slot == kChunk - 1) store(next_ - kChunk);
  }
  // The last chunk, when the walk ends inside it.
  __device__ __forceinline__ void finish() {
    if (next_ % kChunk) store(next_ - next_ % kChunk);
  }

 private:
  // Entries [max(c, first), next) of the chunk that starts at entry c.
  __device__ __forceinline__ void store(uint32_t c) {
    uint32_t* chunk = chunk0_ + std::size_t(c / kChunk) * kGroup * kChunk;
    if (c >= first_ && next_ - c == kChunk) {
      *reinterpret_cast<uint4*>(chunk) = uint4{v0_, v1_, v2_, v3_};
      return;
    }
    for (uint32_t k = max(c, first_) - c; k < next_ - c; ++k)
      chunk[k] = k == 0 ? v0_ : k == 1 ? v1_ : k == 2 ? v2_ : v3_;
  }
  uint32_t* chunk0_;
  uint32_t first_, next_;
  uint32_t v0_ = 0, v1_ = 0, v2_ = 0, v3_ = 0;
};

// The sum of `value` over the warp's lanes before this one (the whole warp calls it), and the
// warp's total into `total`.
__device__ __forceinline__ uint32_t warp_exclusive_sum(uint32_t value, int lane, uint32_t& total) {
  uint32_t sum = value;  // inclusive, then exclusive
#pragma unroll
  for (int step = 1; step < 32; step <<= 1) {
    const uint32_t v = __shfl_up_sync(0xffffffffu, sum, step);
    if (lane >= step) sum += v;
  }
  total = __shfl_sync(0xffffffffu, sum, 31);
  return sum - value;
}

// Where a row's entries go in the fill from masks (change 66): its list's chunk 0 (an index into the
// list, so that the store is a global one), and its next entry's place less the row's first place
// in the warp's queue, so that queue entry q goes to place base + q.
struct alignas(16) FillRow {
  std::size_t chunk0;  // list_entry(group's first chunk, rank, 0)
  uint32_t base;
};

template <int D, class Particle>
__global__ void gather_ranked(Grid g, const double* __restrict__ positions, const uint32_t* __restrict__ types,
                              const uint32_t* __restrict__ order, std::size_t n, uint32_t num_types,
                              Particle* __restrict__ ranked, DeviceFlags* flags) {
  const std::size_t p = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (p >= n) return;
  const std::size_t i = order[p];
  double v[3] = {0, 0, 0};
  for (int a = 0; a < D; ++a) v[a] = positions[i * D + a];
  store_ranked<D>(ranked, p, g, v, types ? types[i] : 0u, num_types, i, flags);
}

// The 32 x 32 bit matrix a warp holds (lane l: row l, bit k: column k) transposed (lane k gets
// column k, its bit l from row l): five butterfly stages, each swapping the off-diagonal blocks of
// half the size with the partner lane.
__device__ __forceinline__ uint32_t transpose_bits(uint32_t x, int lane) {
  constexpr uint32_t kLow[5] = {0x0000ffffu, 0x00ff00ffu, 0x0f0f0f0fu, 0x33333333u, 0x55555555u};
#pragma unroll
  for (int i = 0, j = 16; i < 5; ++i, j >>= 1) {
    const uint32_t y = __shfl_xor_sync(0xffffffffu, x, j);
    x = (lane & j) ? (x & ~kLow[i]) | ((y & ~kLow[i]) >> j) : (x & kLow[i]) | ((y & kLow[i]) << j);
  }
  return x;
}

// The build's passes over the work units (list_rows): count (every unit but the P tiles whose
// masks are kept, which their H rows write), mirrored (with several column splits: those P tiles'
// counts, from their masks; with one, the count pass adds them itself: change 62), fill.
enum class ListPass { kCount, kMirrored, kFill };

// The mask words of each work unit (BuildMasks): a word per column tile of its range and lane; 0
// past the tiles there are (and at `units`, so that an exclusive scan over units + 1 ends with the
// total).
template <class Real, class Accum>
__global__ void unit_mask_words(const TraversalArgs<Real, Accum> args, uint32_t splits, uint32_t units,
                                unsigned long long* __restrict__ words) {
  const uint32_t unit = blockIdx.x * blockDim.x + threadIdx.x;
  if (unit > units) return;
  const uint32_t w = args.tile_start[args.cell_range[0]] + unit / splits;
  unsigned long long n = 0;
  if (unit < units && w < args.tile_start[args.cell_range[1]]) {
    uint32_t row = 0;
    const CollisionCell cell = args.cells[detail::tile_cell(args, w, row)];
    const ColumnRange range = split_columns(row >= cell.h ? cell.h : cell.h + cell.p, splits, unit % splits);
    n = (unsigned long long)((range.end - range.begin + 31u) / 32u) * 32u;
  }
  words[unit] = n;
}

// Whether the count pass walks a unit (change 41): a row tile of the range, but not a P tile whose
// masks are kept (its H rows write them, and count it: change 62). The units are partitioned by
// this before the count pass so that its warps are those that walk, side by side: in launch order
// each cell's few H tiles came with its many P tiles (~70% of the units at 1M), which return at
// once but held their block's room until its H tiles were done (26% of the warps active against
// 44% possible, the pass latency-bound).
template <class Real, class Accum>
struct CountWalks {
  TraversalArgs<Real, Accum> args;
  uint32_t splits;
  BuildMasks masks;
  __device__ bool operator()(uint32_t unit) const {
    const uint32_t w = args.tile_start[args.cell_range[0]] + unit / splits;
    if (w >= args.tile_start[args.cell_range[1]]) return false;
    uint32_t row = 0;
    const CollisionCell cell = args.cells[detail::tile_cell(args, w, row)];
    return !(row >= cell.h && masks.kept(unit));
  }
};

// One warp per work unit: a row tile of a collision cell (the tile form's work units and candidate
// rule) and one of `splits` contiguous ranges of its columns (build_splits): lane l holds row
// occupant a, and every lane walks the same columns (from its own column tile on for an H row tile
// with change 62's mirror, below). The occupants come from the staged array (fast memory, and a
// lean build's count pass where the last list's array holds them, change 70), or, without one,
// are staged as they are loaded (detail::stage_entry, the values stage_kernel would write).
// Count: the partners of each row within the list cutoff, into slot_counts[rank * 2^d + cell
// type] (a store with one split and no masks, an integer atomic add with masks, change 62; with
// several splits, each range's count is added there, an integer sum, and kept per unit and lane
// in split_counts). Fill: the same walk writes them, after the partners the row's particle found
// in cells of lower type and in the ranges before this one (so the list does not depend on the
// splits). With masks (BuildMasks: every unit's in fast memory mode, a prefix of the units' in
// lean mode), the count pass keeps each decision as a bit, writes the bits of the P-only tiles
// that keep masks from their H rows' side (those tiles are not walked; with one column split, the
// later H row tiles' bits for the earlier ones' columns too, and their counts: change 62, below;
// with several, the mirrored pass counts the P tiles), and the fill of a unit that keeps masks
// writes the list from its bits. Per tile of 32 columns, the
// distance test of every column comes first, as a bit mask, then the rule for those within. With
// compensated coordinates (float) and no wrap inside a cell, that first test reads the hi parts
// alone: hi-part r^2 >= pre2 (prefilter_bound) implies the compensated r^2 >= out2, so it drops
// only what the full test drops, and the few survivors take the full test. The test reads the
// staged coordinates (relative to the cell centre, in the pair precision): below the cutoff by more
// than their rounding (1e-5 relative in r^2) a pair is in, above it by as much it is out, and
// between, the double positions decide, so that the list is exactly the pairs closer than the
// cutoff in double.
template <class T, ListPass Pass, class Real, class Accum>
__global__ void __launch_bounds__(kBlock)
    list_rows(const TraversalArgs<Real, Accum> args, const ListStaging staging,
              const uint32_t* __restrict__ rank, Real in2, Real out2,
              Real pre2, double cutoff2, uint32_t splits, uint32_t* __restrict__ slot_counts,
              uint32_t* __restrict__ split_counts, const unsigned long long* __restrict__ group_chunks,
              uint32_t* __restrict__ neighbors, const BuildMasks masks, const uint32_t* __restrict__ walk_order,
              const uint32_t* __restrict__ walked, const unsigned long long* __restrict__ fill_chunks,
              unsigned long long fill_room) {
  constexpr int D = T::kDim;
  constexpr uint32_t kSlots = 1u << D;
  constexpr bool Fill = Pass == ListPass::kFill, Mirrored = Pass == ListPass::kMirrored;
  // A column occupant as staged (with the lo parts of compensated coordinates: r_ij then keeps the
  // digits check_staging guarantees, well within the margin between in2 and out2), and its rank.
  using Column = StagedEntry<Real>;
  __shared__ Column columns[kBlock / 32][32];
  __shared__ uint32_t column_rank[kBlock / 32][32];
  const int warp = int(threadIdx.x / 32), lane = int(threadIdx.x % 32);
  Column* column = columns[warp];
  uint32_t* column_ranks = column_rank[warp];
  const uint32_t first_cell = args.cell_range[0], end_cell = args.cell_range[1];
  // A fill queued before the host knew the list's size (change 65): nothing, where the list needs
  // more chunks than its array holds (the host then makes room and fills again).
  if constexpr (Fill)
    if (fill_chunks && *fill_chunks > fill_room) return;  // the whole warp
  // This warp's unit (row tile x column range): the fill and the mirrored pass take the units in
  // order; the count pass the ones it walks, from walk_order (CountWalks) where the build
  // partitioned them (splits = 1, with masks), or in order (then the early returns below skip the
  // units a pass leaves).
  const uint32_t slot = blockIdx.x * (kBlock / 32) + uint32_t(warp);
  uint32_t unit = slot;
  if constexpr (Pass == ListPass::kCount) {
    if (walk_order) {
      if (slot >= *walked) return;  // the whole warp
      unit = walk_order[slot];
    }
  }
  const uint32_t w = args.tile_start[first_cell] + unit / splits, split = unit % splits;
  if (w >= args.tile_start[end_cell]) return;  // the whole warp
  uint32_t row = 0;
  const uint32_t cell_index = detail::tile_cell(args, w, row);
  const CollisionCell cell = args.cells[cell_index];
  const unsigned type = cell_type_of_id(args.grid, cell.cell);
  const uint32_t* keys = staging.sorted_keys + cell.start;
  const uint32_t* ids = args.sorted_ids + cell.start;
  const StagedEntry<Real>* occ = args.staged ? args.staged + cell.start : nullptr;
  auto stage = [&](uint32_t e) {  // staged already, or staged here (the same values)
    return occ ? occ[e]
               : detail::stage_entry<Real>(args.grid, keys[e], ids[e], staging.positions, staging.types,
                                           staging.num_types, staging.control);
  };
  const uint32_t h = cell.h, m = cell.h + cell.p;
  const uint32_t a = row + uint32_t(lane);
  const bool row_ok = a < m, a_home = a < h;
  const uint32_t pa = row_ok ? rank[ids[a]] : 0u;
  // A tile of P rows pairs with H columns only; rows beyond the cell (row_ok false) test nothing.
  // This unit's columns: range `split` of the tile's, in whole column tiles of 32.
  const uint32_t ncols = row >= h ? h : m;
  const uint32_t row_cols = row_ok ? (a_home ? m : h) : 0u;
  const ColumnRange range = split_columns(ncols, splits, split);
  const uint32_t c0 = range.begin, c1 = range.end;
  // The fill's place in the row's list: after the partners found in cells of lower type and in
  // the ranges before this one.
  uint32_t* chunk0 = nullptr;
  uint32_t written = 0;
  if constexpr (Fill) {
    if (row_ok) {
      for (unsigned t = 0; t < type; ++t) written += slot_counts[std::size_t(pa) * kSlots + t];
      for (uint32_t s = 0; s < split; ++s) written += split_counts[std::size_t(unit - split + s) * 32u + lane];
      chunk0 = neighbors + list_entry(group_chunks[pa / kGroup], pa, 0);
    }
  }
  ChunkWriter out(chunk0, written);
  // The unit's masks (BuildMasks), when it keeps them: the count pass writes them (a tile of P rows
  // only gets them from the H rows it pairs with, and with change 62 an H row tile gets those for
  // the column tiles of the cell's earlier H row tiles from them: mirrored), the fill reads them.
  const bool kept = masks.base && masks.kept(unit);
  const uint32_t* my_words = kept ? masks.words + masks.base[unit] : nullptr;
  const bool p_tile = row >= h;  // P rows only (a multiple of 32: no H row in it)
  uint32_t count = 0;
  // Change 62: with one column range per row tile (splits = 1) and masks, a row tile that holds H
  // rows tests only the column tiles from its own on; the cell's earlier H row tiles test it (their
  // columns) and write its words for their column tiles, transposed, as they do for the P tiles;
  // and the count pass adds the counts of those words to the rows they belong to itself (integer
  // atomic adds: the sums do not depend on their order), so there is no mirrored pass. A pair's
  // decision is the same from either side (the control-bit rule is symmetric, the separations
  // change sign exactly). A unit whose words are not kept tests all its columns, and gets no
  // mirrored words or counts.
  const bool mirror_h = !Fill && splits == 1u && masks.words != nullptr;
  if constexpr (Mirrored) {
    // A P tile whose words its H rows wrote: its counts, from the words (several column splits
    // only). Every other unit counted in the count pass.
    if (!(p_tile && kept)) return;
    for (uint32_t col = c0; col < c1; col += 32u)
      if (row_ok) count += __popc(my_words[(col - c0) + uint32_t(lane)]);
  }
  if constexpr (Pass == ListPass::kCount) {
    if (p_tile && kept) return;  // mirrored: counted by the H rows' atomics (one split) or the mirrored pass
  }
  // The walk's survivors' queue (below), which the fill from masks uses for its entries.
  __shared__ uint16_t survivors[kBlock / 32][32 * 32];
  uint16_t* queue = survivors[warp];
  if constexpr (Fill) {
    if (kept) {
      if (masks.filled && lane == 0) atomicAdd(masks.filled, 1ull);  // tests only
      // The whole warp: the count pass's decisions, kFillBatch column tiles at a time (their words,
      // IDs and ranks loaded together: one tile at a time, the walk waited on three dependent
      // loads per tile), the columns' ranks shared through `batch_ranks`.
      constexpr uint32_t kFillBatch = 4;
      constexpr uint32_t kQueue = 32 * 32;  // entries the queue holds: a tile's at most
      static_assert(kQueue <= sizeof(survivors[0]) / sizeof(survivors[0][0]), "the queue is the walk's");
      static_assert(32 * kFillBatch <= 128, "an entry's column in the batch fits the queue's 7 bits");
      __shared__ uint32_t batch_ranks[kBlock / 32][32 * kFillBatch];
      __shared__ FillRow fill_rows[kBlock / 32][32];
      uint32_t* ranks = batch_ranks[warp];
      FillRow* places = fill_rows[warp];
      for (uint32_t col = c0; col < c1; col += 32u * kFillBatch) {
        uint32_t keep[kFillBatch], id[kFillBatch];
#pragma unroll
        for (uint32_t b = 0; b < kFillBatch; ++b) {
          const uint32_t tile = col + 32u * b, own = tile + uint32_t(lane);
          keep[b] = tile < c1 && row_ok ? my_words[(tile - c0) + uint32_t(lane)] : 0u;
          id[b] = own < c1 ? ids[own] : ~0u;
        }
        // Only the columns some row keeps load their rank (change 53): the rank is a dependent
        // gather by particle index, and a cell's far column tiles pair with none of a row tile.
        uint32_t wanted[kFillBatch], any = 0;
#pragma unroll
        for (uint32_t b = 0; b < kFillBatch; ++b) {
          wanted[b] = __reduce_or_sync(0xffffffffu, keep[b]);
          any |= wanted[b];
        }
        if (!any) continue;  // the whole warp: no row keeps a column of the batch
#pragma unroll
        for (uint32_t b = 0; b < kFillBatch; ++b)
          if (id[b] != ~0u && (wanted[b] >> lane & 1u)) ranks[32u * b + uint32_t(lane)] = rank[id[b]];
        // Change 66: the batch's entries are written by the whole warp, 32 at a time. Each lane
        // queues its row's entries (lane << 7 | the column in the batch, in list order) after the
        // rows before it; in each round lane l writes the next queue entry 32 j + l to its row's
        // list, at the row's next place plus the entry's place among the row's entries. A lane
        // that put its own row's entries ran as many rounds as the fullest row, ~25 instructions
        // a round, each waiting on its rank's shared load (Nsight Compute at 1M: 479M warp
        // instructions for a list of ~110M entries). Neighbouring lanes write neighbouring entries
        // of a row, so the 4-byte stores of a round mostly fill the rows' 16-byte chunks whole, as
        // the chunk stores did, and never touch an entry of another walk. A batch whose entries
        // overflow the queue takes its tiles one at a time (each at most 32 x 32 entries).
        uint32_t found = 0;
#pragma unroll
        for (uint32_t b = 0; b < kFillBatch; ++b) found += __popc(keep[b]);
        const bool whole = __reduce_add_sync(0xffffffffu, found) <= kQueue;
        for (uint32_t g = 0; g < (whole ? 1u : kFillBatch); ++g) {  // the whole warp
          uint32_t mine = 0;  // this row's entries in pass g's tiles (the whole batch, or tile g)
#pragma unroll
          for (uint32_t b = 0; b < kFillBatch; ++b)
            if (whole || b == g) mine += __popc(keep[b]);
          uint32_t total = 0;
          const uint32_t first = warp_exclusive_sum(mine, lane, total);
          uint32_t q = first;
#pragma unroll
          for (uint32_t b = 0; b < kFillBatch; ++b) {
            if (!(whole || b == g)) continue;
            for (uint32_t left = keep[b]; left; left &= left - 1u, ++q)
              queue[q] = uint16_t(uint32_t(lane) << 7 | (32u * b + uint32_t(__ffs(int(left)) - 1)));
          }
          // Queue entry q of this row: place written - first + q.
          places[lane] = FillRow{chunk0 ? std::size_t(chunk0 - neighbors) : 0u, written - first};
          __syncwarp();
          for (uint32_t r = uint32_t(lane); r < total; r += 32u) {
            const uint32_t e = queue[r];
            const FillRow place = places[e >> 7];
            const uint32_t k = place.base + r;
            neighbors[place.chunk0 + std::size_t(k / kChunk) * kGroup * kChunk + k % kChunk] = ranks[e & 127u];
          }
          written += mine;
          __syncwarp();
        }
      }
      return;
    }
  }
  // A row tile's mirror: for a column tile of P-only tiles (past p_end), or with change 62's mirror
  // any later column tile, the words of that tile's rows for this tile's columns (its rows), in
  // that tile's unit for the range that holds them.
  const uint32_t p_end = (h + 31u) & ~31u;  // the first row of the cell's P-only tiles
  const uint32_t h_chunk = split_columns(h, splits, 0).end;  // a P tile's range length (whole tiles)
  const uint32_t h_split = h_chunk ? row / h_chunk : 0u, h_begin = h_split * h_chunk;
  const uint32_t tile0 = args.tile_start[cell_index] - args.tile_start[first_cell];  // the cell's first unit / splits
  const StagedEntry<Real> A = Mirrored || !row_ok ? StagedEntry<Real>{} : stage(a);
  // The walk's survivors, decided by the whole warp (below): the rows as staged, the queue of
  // (row, column) survivors of a column tile (`survivors`, above: at most 32 x 32), and each row's
  // decided columns.
  __shared__ Column row_entries[kBlock / 32][32];
  __shared__ uint32_t decided_words[kBlock / 32][32];
  Column* rows = row_entries[warp];
  uint32_t* decided = decided_words[warp];
  rows[lane] = A;
  // The first column tile this unit tests: its own with mirror_h (the ones before are mirrored
  // into it), else its range's first.
  const uint32_t walk0 = mirror_h && kept && !p_tile ? row : c0;
  for (uint32_t col = walk0; col < (Mirrored ? c0 : c1); col += 32u) {
    const uint32_t own = col + uint32_t(lane);
    // Whether this column tile's rows get their words for this unit's rows from here (the whole
    // warp: uniform): the P-only tiles', and with mirror_h every later tile's.
    const bool mirrors = masks.words && !p_tile && (mirror_h ? col > row : col >= p_end);
    uint32_t own_rank = 0;  // mirror_h: the rank of column `own`, whose count the mirror adds to
    if (own < c1) {
      column[lane] = stage(own);
      if constexpr (Fill) column_ranks[lane] = rank[ids[own]];
      if (mirror_h && mirrors) own_rank = rank[ids[own]];  // used after the tests: its latency hidden
    }
    __syncwarp();
    const uint32_t cnt = min(c1 - col, 32u);
    // The distance test of every column first, without a branch: bit k of `near` marks column k
    // within out2 of this lane's row. ~93% fail it; a branch per column would run the rule below
    // in the one or two lanes that pass on almost every column, with the warp's other lanes idle.
    uint32_t near = 0;
    auto within = [&](uint32_t k) {
      if constexpr (StagedCoordinate<Real>::kCompensated && !T::kWrap) {
        const Column& H = column[k];  // the hi parts only: hi-part r^2 >= pre2 implies r^2 >= out2
        const Real hx = A.x - H.x, hy = A.y - H.y, hz = D == 3 ? A.z - H.z : Real(0);
        return hx * hx + hy * hy + hz * hz < pre2;
      } else {
        Real d[3];
        return detail::separation<T>(A, column[k], args.length, args.inv_length, d) < out2;
      }
    };
    if (cnt == 32u) {
#pragma unroll
      for (uint32_t k = 0; k < 32u; ++k) near |= uint32_t(within(k)) << k;
    } else {
      for (uint32_t k = 0; k < cnt; ++k) near |= uint32_t(within(k)) << k;
    }
    // Then the columns that passed, decided by the whole warp (change 63): the candidate rule, and
    // the double decision for the few within the staged coordinates' rounding of the cutoff.
    // Each lane queues its survivors (row lane << 5 | column k, ~3 a lane at 1M), and the warp
    // takes the queue 32 at a time; a lane that decides a pair sets the column's bit in its row's
    // word. A lane walking its own survivors ran as many rounds as the fullest lane (~10, with ~10
    // lanes active: half the count pass's instructions, which is issue-bound). `keep`: the
    // partners. Rows beyond the cell, columns past the row's (row_cols) and the row itself are
    // dropped before the queue.
    if (row_cols <= col) near = 0;  // rows beyond the cell too (row_cols 0)
    else if (row_cols - col < 32u) near &= (1u << (row_cols - col)) - 1u;
    if (a >= col && a - col < 32u) near &= ~(1u << (a - col));
    const uint32_t survived = __popc(near);
    uint32_t queued = 0;
    const uint32_t before = warp_exclusive_sum(survived, lane, queued);
    for (uint32_t q = before; near; ++q) {
      queue[q] = uint16_t(uint32_t(lane) << 5 | uint32_t(__ffs(int(near)) - 1));
      near &= near - 1u;
    }
    decided[lane] = 0u;
    __syncwarp();
    for (uint32_t q = uint32_t(lane); q < queued; q += 32u) {
      const uint32_t e = queue[q], l = e >> 5, k = e & 31u;
      const uint32_t al = row + l, b = col + k;
      const Column& R = rows[l];
      const Column& B = column[k];
      // H x H; H x P (either way round) unless the control-bit rule gives it to another cell.
      if (!(al < h && b < h) && skip_pair(type, detail::control_of(R.meta), detail::control_of(B.meta))) continue;
      Real d[3];
      const Real r2 = detail::separation<T>(R, B, args.length, args.inv_length, d);
      if (!(r2 < out2)) continue;  // the prefilter's survivors: the compensated test
      if (!(r2 < in2) &&
          !(distance2<D>(args.grid, staging.positions, ids[al], ids[b]) < cutoff2))
        continue;
      atomicOr(&decided[l], 1u << k);
    }
    __syncwarp();
    const uint32_t keep = decided[lane];
    count += __popc(keep);
    if constexpr (Fill) {
      for (uint32_t left = keep; left; left &= left - 1u) out.put(column_ranks[__ffs(int(left)) - 1]);
    }
    if constexpr (!Fill) {
      if (kept) masks.words[masks.base[unit] + (col - c0) + uint32_t(lane)] = keep;
      if (mirrors) {  // the whole warp (uniform)
        const uint32_t mirror = transpose_bits(keep, lane);  // column col + lane's bits, row by row
        const uint32_t p_unit = (tile0 + col / 32u) * splits + h_split;
        if (masks.kept(p_unit) && own < c1) {
          masks.words[masks.base[p_unit] + (row - h_begin) + uint32_t(lane)] = mirror;
          const uint32_t found = __popc(mirror);
          if (mirror_h && found) atomicAdd(&slot_counts[std::size_t(own_rank) * kSlots + type], found);
        }
      }
    }
    __syncwarp();
  }
  if constexpr (Fill) out.finish();
  if constexpr (!Fill) {
    if (mirror_h) {  // mirrored counts may come to these rows' slots meanwhile
      if (row_ok && count) atomicAdd(&slot_counts[std::size_t(pa) * kSlots + type], count);
    } else if (splits == 1) {
      if (row_ok) slot_counts[std::size_t(pa) * kSlots + type] = count;
    } else {
      split_counts[std::size_t(unit) * 32u + lane] = count;  // 0 for rows beyond the cell
      if (row_ok && count) atomicAdd(&slot_counts[std::size_t(pa) * kSlots + type], count);
    }
  }
}

// Each rank's list length (its counts over the cell types summed), and each group's length in
// whole chunks (its longest list), into group_chunks[g] for the scan that makes them the groups'
// first chunks; group_chunks[groups] = 0, so that the scan ends with the total. A group is a warp's
// ranks (blocks of kBlock ranks start on a group): one warp-wide max, where a scan over groups that
// read its 32 lengths per item took ~48 us a build at 256k and at 1M alike (latency-bound).
// Launched over n + kGroup threads, so that a warp exists for group_chunks[groups]. Also the
// longest list into sizes[0] and the sum of the lengths into sizes[1] (zeroed before: one atomic
// of each per block; integers, so the order does not matter): change 57, in place of two CUB
// reductions over the lengths, whose host-side dispatch held the device idle at small sizes.
template <int D>
__global__ void sum_slot_counts(const uint32_t* __restrict__ slot_counts, std::size_t n, std::size_t groups,
                                uint32_t* __restrict__ length, unsigned long long* __restrict__ group_chunks,
                                unsigned long long* __restrict__ sizes, uint32_t force_blocks,
                                uint32_t* __restrict__ force_blocks_out) {
  static_assert(kGroup == 32 && kBlock % kGroup == 0, "a group of ranks is one warp's");  // __reduce_max_sync: sm_80+
  const std::size_t p = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (p == 0) *force_blocks_out = force_blocks;  // for sum_cells (change 80: no copy from the host)
  uint32_t s = 0;
  if (p < n) {
    for (int t = 0; t < (1 << D); ++t) s += slot_counts[p * (1u << D) + t];
    length[p] = s;
  }
  const uint32_t longest = __reduce_max_sync(0xffffffffu, s);  // the whole warp: no return above
  unsigned long long total = s;  // the warp's sum, in 64 bits (a list may be as long as n)
  for (int offset = 16; offset > 0; offset >>= 1) total += __shfl_xor_sync(0xffffffffu, total, offset);
  const std::size_t g = p / kGroup;
  const int warp = int(threadIdx.x / 32);
  __shared__ uint32_t warp_longest[kBlock / 32];
  __shared__ unsigned long long warp_total[kBlock / 32];
  if (threadIdx.x % 32 == 0) {
    if (g <= groups) group_chunks[g] = g < groups ? (longest + kChunk - 1) / kChunk : 0u;
    warp_longest[warp] = longest;
    warp_total[warp] = total;
  }
  __syncthreads();
  if (threadIdx.x == 0) {
    uint32_t most = 0;
    unsigned long long sum = 0;
    for (int w = 0; w < kBlock / 32; ++w) most = max(most, warp_longest[w]), sum += warp_total[w];
    if (most) atomicMax(&sizes[0], (unsigned long long)most);
    if (sum) atomicAdd(&sizes[1], sum);
  }
}

// The four sizes the host reads, posted into its mapped memory (SizesReadback; change 80: one launch
// where two device copies were, change 82: no copy to the host after it): the longest list and the
// sum of the lengths (sum_slot_counts), the words every unit's masks take (masks_end null: none,
// 0) and the list's chunks; a system-wide fence, then the build's tag.
__global__ void gather_sizes(const unsigned long long* __restrict__ sizes,
                             const unsigned long long* __restrict__ masks_end,
                             const unsigned long long* __restrict__ chunks_end, PostedSizes* out,
                             unsigned long long tag) {
  if (threadIdx.x == 0) {
    volatile PostedSizes* o = out;
    o->value[0] = sizes[0];
    o->value[1] = sizes[1];
    o->value[2] = masks_end ? *masks_end : 0ull;
    o->value[3] = *chunks_end;
    __threadfence_system();  // the sizes reach the host before the tag
    o->tag = tag;
  }
}

// A cube's fixed-point scale folded into the pair's constants, for the force kernel's FixedParticle
// pairs of one type: every axis has the same scale s = s_hi (1 + eps) (fixed_scale: a float pair,
// |eps| <= 2^-24). The kernel forms the separation d' = f (s_hi / lambda) (f the integer difference
// as a float: one multiply per axis, not two; lambda the pair's power-of-two length unit, so the
// division is exact), which is the true one over G = g lambda with g = 1 + eps: r'^2 = r^2 / G^2 is
// already r^2 in the pair's unit up to g, and needs no multiply by inv_s2. With q = lambda^2 / r^2 =
// u / g^2 (u = 1 / r'^2), the force (f12 q^7 - f6 q^4) d is the same expression of u and d' with
// f12 lambda / g^13 and f6 lambda / g^7 (minus f_rc d' / r' with force shift, f_rc unchanged),
// compared with rc^2 / G^2. Every kernel of such a system takes the fold, with observables or
// without, so that a step's forces do not depend on what else it was asked for (a restart between
// output steps repeats the run bit for bit: PairListRequests). With e12 / (g^13 lambda), e6 /
// (g^7 lambda), u_rc / G and rc / G the pair energy and F(r)/r d'_a d'_b come out as the true ones
// over G: the particle energies and the totals are multiplied by g (as v + v eps) and by lambda (a
// power of two, exact) once, at the end. The constants take one more rounding (2^-24 relative,
// against the two roundings per axis the fold saves).
struct FixedFold {
  // The single type's constants (table[0]), folded on the host: f12 lambda g^-13, f6 lambda g^-7,
  // e12 g^-13 / lambda, e6 g^-7 / lambda, u_rc / G and rc / G (f_rc as it is).
  float f12 = 0, f6 = 0, e12 = 0, e6 = 0, u_rc = 0, rc = 0;
  float hi = 0;              // s_hi / lambda
  float rc2 = 0;             // rc^2 / G^2
  double eps = 0;            // g - 1: the observables' sums times g, as v + v eps
  double lambda = 1;         // then times lambda
};

// S threads per rank (S = 1, 2, 4 or 8, adjacent lanes of one warp). With one, the thread reads its
// list a chunk at a time (one 16-byte load for kChunk entries). With S > 1 (small systems, to fill
// the GPU), thread j takes entries j, j + S, ..., kChunk at a time (whole chunks per thread would
// leave the longest share up to a chunk longer: measured 10% slower at 32,000 particles, S = 8),
// and the S partial sums are added by a butterfly over the S lanes. Either way the whole force on
// the particle is summed in an order fixed by its list. A batch's kChunk partners are gathered
// before any of its pairs is evaluated (kChunk gathers in flight, not one: the loop waits on the
// gathers' latency otherwise), and its pairs are added in list order.
static_assert(kChunk == 4, "a chunk is one uint4");

// The next step's kick-drift (change 59), for a gated Verlet evaluation's force kernel (Drift) on the
// chunk's rank-order state: the block's particles are consecutive ranks, so after their forces are
// summed the block kicks and drifts them a thread per coordinate (the separate kernel's coalesced
// loads and stores, and no register of the force loop held for them), raises the next step's
// displacement into the gate and places the new positions into `next` (the list's other
// rank-ordered array: the partners' positions are read from `ranked` by the kernel's other blocks
// meanwhile). The forces go through shared memory and are never stored. The arithmetic is
// gated_kick_drift_kernel's (cuda/md_engine.cu), coordinate for coordinate (verlet_step.cuh).
template <int D, int S, int B, class Particle>
__device__ __forceinline__ void next_kick_drift(const NextKickDrift& s, std::size_t n, std::size_t p, uint32_t part,
                                                const double (&force)[D], uint32_t type, Particle* __restrict__ next,
                                                const Grid& grid, uint32_t num_types, DeviceFlags* dflags,
                                                const GateView& gate_next) {
  constexpr int kParticles = B / S;  // the block's ranks
  __shared__ double value[kParticles * D];  // the forces, then the new positions
  __shared__ double square[kParticles * D];
  __shared__ uint32_t types[kParticles];
  const std::size_t first = std::size_t(blockIdx.x) * kParticles;
  const int local = int(threadIdx.x) / S;
  if (p < n && part == 0) {
#pragma unroll
    for (int c = 0; c < D; ++c) value[local * D + c] = force[c];
    types[local] = type;
  }
  __syncthreads();
  for (int c = int(threadIdx.x); c < kParticles * D; c += B) {
    const std::size_t q = first + std::size_t(c / D);
    double term = 0;
    if (q < n) {
      const std::size_t k = first * D + std::size_t(c);
      const int a = c % D;
      const double m = s.mass ? s.mass[q] : s.mass_value, then = s.built[k];
      double xa = s.x[k], va = s.v[k];
      va = kick_value(va, value[c], m, s.h, 2);
      s.v[k] = va;
      const DriftAxis axis = drift_axis(s.box, a);
      bool bad;
      xa = drift_value(xa, va, s.dt, axis, true, bad);
      s.x[k] = xa;
      if (bad) flag_diverged(true, s.order[q], a, s.dt, va, s.flags);
      term = displacement_term(xa, then, axis.length, axis.inv_length);
      value[c] = xa;  // this thread read the force at c above
    }
    square[c] = term;
  }
  __syncthreads();
  double worst = 0;
  if (threadIdx.x < unsigned(kParticles)) {
    const std::size_t q = first + threadIdx.x;
    if (q < n) {
      double d2 = 0, moved[3] = {0, 0, 0};
#pragma unroll
      for (int a = 0; a < D; ++a) d2 += square[threadIdx.x * D + a], moved[a] = value[threadIdx.x * D + a];
      worst = gate_displacement(d2);
      store_ranked<D>(next, q, grid, moved, types[threadIdx.x], num_types, s.order[q], dflags);
    }
  }
  raise_block_displacement(worst, gate_next);
}

// Programmatic dependent launch's two instructions (PTX griddepcontrol, compute capability 9.0):
// let the kernel launched after this one be scheduled; wait for the kernel before this one to
// complete, its memory visible. No-ops for a kernel launched without the attribute, and on older
// devices.
__device__ __forceinline__ void pdl_launch_dependents() {
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
  asm volatile("griddepcontrol.launch_dependents;" ::: "memory");
#endif
}
__device__ __forceinline__ void pdl_wait() {
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
  asm volatile("griddepcontrol.wait;" ::: "memory");
#endif
}

// `ranked` is not __restrict__ (change 91): in a gated chunk the kernel before this one wrote it (a
// fused force kernel's `next`, or a drift's placing), and this one may run before that one ends
// (programmatic dependent launch), so it must be read only after pdl_wait(). Through a const
// __restrict__ pointer nvcc may read it on the non-coherent path (ld.global.nc), which it takes as
// unchanging while the kernel runs, and issue that read before griddepcontrol.wait (performance.md,
// change 91: the SASS of such a kernel, and the fused runs it broke).
template <class T, int S, bool Folded, bool Drift, class Particle, class Real, class Accum, int B = kBlock>
__global__ void __launch_bounds__(B)
    list_force_kernel(const ListArgs<Real, Accum> args, const uint32_t* __restrict__ order,
                      const Particle* ranked, const uint32_t* __restrict__ length,
                      const unsigned long long* __restrict__ group_chunks, const uint32_t* __restrict__ neighbors,
                      const FixedScales scale, const FixedFold fold, Accum* __restrict__ block_sums,
                      GateView gate, bool by_rank, const NextKickDrift then, Particle* __restrict__ next) {
  static_assert(!Folded || (std::is_same_v<Particle, FixedParticle> && !T::kMultiType),
                "the fold serves fixed-point pairs of one type");
  static_assert(!Drift || !T::kObservables, "the next step's kick-drift follows an evaluation of forces only");
  static_assert(B == kBlock || Drift, "blocks of another size run the next step's kick-drift only");
  constexpr int D = T::kDim;
  const std::size_t n = args.n;
  const std::size_t t = std::size_t(blockIdx.x) * B + threadIdx.x;  // launched with B threads a block
  const std::size_t p = t / S;
  const uint32_t part = uint32_t(t % S);
  // Programmatic dependent launch (change 75; the gated evaluations, list_forces): the next step's
  // force kernel may be scheduled once every block of this one has started, and waits below for
  // this one to complete, so that its blocks take the multiprocessors this one's last wave leaves
  // idle instead of waiting for the launch after it. Without the launch attribute both are no-ops.
  // The list's lengths and group chunks come from the build, which completed before the gated
  // evaluations began: read before the wait in the source (nvcc issues them after it; issuing them
  // before it, change 92, gained nothing measurable); everything the last kernel wrote (positions,
  // the gate) after it.
  pdl_launch_dependents();
  // The particle, its list's length and its group's first chunk are loaded before the gate's
  // barrier (a shut gate discards them), so that their round trip overlaps the gate's (change 33).
  Particle P{};
  uint32_t len = 0;
  unsigned long long group_chunk0 = 0;
  if (p < n) len = length[p], group_chunk0 = group_chunks[p / kGroup];
  pdl_wait();
  if (p < n) P = ranked[p];
  // The whole block: before any shuffle or barrier. Drift: the next step's first kernel's test, which
  // closes the gate where this step's displacement ran past the limit.
  if constexpr (Drift) {
    if (step_gate_shut(next_step(gate))) return;
  } else {
    if (gate_shut(gate)) return;
  }
  if (gate.gate && t == 0) atomicMax(&gate.gate->served, gate.gate->d2[gate.step % 3]);  // served: this step's
  CellTotals<Accum, true, true> totals;
  Accum f[D] = {};
  Accum ea = 0;
  if (p < n) {
    LJParams<Real> single = args.first;
    Real rc2 = args.rc2;
    if constexpr (Folded) {
      single.inv_s2 = Real(1);  // d' is in the pair's unit already: lj_terms' multiply folds away
      single.f12 = fold.f12, single.f6 = fold.f6, single.e12 = fold.e12, single.e6 = fold.e6;
      single.u_rc = fold.u_rc, single.rc = fold.rc;
      rc2 = fold.rc2;
    }
    // Entry k at entries[(k / kChunk) * kGroup * kChunk + k % kChunk] (list_entry): a warp's
    // threads read consecutive chunks.
    const uint32_t* entries = neighbors + list_entry(group_chunk0, p, 0);
    constexpr uint32_t kStride = S;  // between a batch's entries
    // The batch of entries from k0 on (k0 < len): one 16-byte chunk (S = 1), or kChunk entries
    // S apart.
    auto load_batch = [&](uint32_t k0, uint32_t (&q)[kChunk]) {
      if constexpr (S == 1) {
        const uint4 v = reinterpret_cast<const uint4*>(entries)[std::size_t(k0 / kChunk) * kGroup];
        q[0] = v.x, q[1] = v.y, q[2] = v.z, q[3] = v.w;
      } else {
#pragma unroll
        for (uint32_t b = 0; b < kChunk; ++b) {
          const uint32_t k = k0 + b * kStride;
          q[b] = k < len ? entries[std::size_t(k / kChunk) * kGroup * kChunk + k % kChunk] : 0u;
        }
      }
    };
    constexpr uint32_t kStep = uint32_t(S * kChunk);  // between a thread's batches
    // One batch: its kChunk entries q from k0 on, gathered, then evaluated in list order. In the
    // last batch (Tail), entries past the list are padding (never written): q = p.
    auto batch = [&](auto tail, uint32_t k0, uint32_t (&q)[kChunk], auto&& on_pair) {
      constexpr bool Tail = decltype(tail)::value;
      if constexpr (Tail) {
#pragma unroll
        for (uint32_t b = 0; b < kChunk; ++b)
          if (k0 + b * kStride >= len) q[b] = uint32_t(p);
      }
      Particle Q[kChunk];
#pragma unroll
      for (int b = 0; b < kChunk; ++b) Q[b] = ranked[q[b]];
#pragma unroll
      for (uint32_t b = 0; b < kChunk; ++b) {
        const bool listed = !Tail || k0 + b * kStride < len;  // past the list: the batch's rest is too
        if constexpr (T::kObservables)
          if (!listed) break;
        Real d[3];
        if constexpr (Folded) {
          d[0] = float(int32_t(P.x - Q[b].x)) * fold.hi;
          d[1] = float(int32_t(P.y - Q[b].y)) * fold.hi;
          d[2] = D == 3 ? float(int32_t(P.z - Q[b].z)) * fold.hi : 0.0f;
        } else {
          pair_separation<D>(args.grid, P, Q[b], scale, d);
        }
        Real r2 = d[0] * d[0] + d[1] * d[1];
        if constexpr (D == 3) r2 += d[2] * d[2];
        LJParams<Real> prm;
        if constexpr (T::kMultiType) prm = args.table[P.type * args.num_types + Q[b].type];
        else prm = single;
        Real fr, e = 0;
        if constexpr (T::kObservables) {
          if (!lj_pair<T::kMode, true>(r2, rc2, prm, fr, e)) continue;
        } else {
          // Without observables a pair beyond rc, and a padding entry past the list (q = p),
          // adds fr = 0: +-0 to each sum, which leaves it bitwise as it was (a sum from +0 is
          // never -0). That needs d finite: fixed-point separations always are, padding has
          // d = 0, and a coordinate that is not finite was flagged by the gather (the
          // evaluation then fails naming it; its particles' sums may be NaN instead of
          // skipping the pair). So neither test is a branch: a warp's lanes take both sides of
          // the cutoff anyway, and with no branch in the batch its kChunk gathers stay ahead of
          // its pairs (behind a branch per pair nvcc issues each gather just before its pair).
          lj_terms<T::kMode, false>(r2, prm, fr, e);
          fr = listed && r2 < rc2 ? fr : Real(0);
        }
        on_pair(q[b], d, fr, e);
      }
    };
    // Every entry of this thread's share of the list, in list order: on_pair(q, d, fr, e). With
    // observables only the pairs within rc; without, every entry, fr = 0 beyond rc and past the
    // list (the select in `batch`).
    // The next batch's entries are loaded before this batch's pairs (change 34): the list comes
    // from DRAM, and a batch that loads its own entries first waits the whole round trip before
    // its gathers can start (a third of the kernel's stall samples at 1M were on that load). The
    // whole batches come first, with no test of the list's end per entry (change 38), then the
    // last one if the list ends inside it.
    auto walk = [&](auto&& on_pair) {
      uint32_t k0 = S == 1 ? 0u : part;
      uint32_t next[kChunk] = {0u, 0u, 0u, 0u};
      if (k0 < len) load_batch(k0, next);
      for (; k0 + (kChunk - 1) * kStride < len; k0 += kStep) {
        uint32_t q[kChunk];
#pragma unroll
        for (uint32_t b = 0; b < kChunk; ++b) q[b] = next[b];
        if (k0 + kStep < len) load_batch(k0 + kStep, next);
        batch(std::false_type{}, k0, q, on_pair);
      }
      if (k0 < len) batch(std::true_type{}, k0, next, on_pair);
    };
    walk([&](uint32_t, const Real (&d)[3], Real fr, Real e) {
      for (int c = 0; c < D; ++c) f[c] += Accum(mul_rn(fr, d[c]));  // no FMA, as the traversals
      if constexpr (T::kObservables) {
        const Real half_e = Real(0.5) * e;
        ea += Accum(half_e);
        totals.template add<D>(half_e, Real(0.5) * fr, d);
      }
    });
    // A pair whose force is not finite leaves every component of the sum not finite (inf x 0 is
    // NaN): only then is the share walked again to flag it, every such pair as a test per pair
    // would (the flag keeps the smallest). Not per pair: ~2 instructions of ~50 an entry.
    bool finite = true;
    for (int c = 0; c < D; ++c) finite = finite && isfinite(f[c]);
    if (!finite)
      walk([&](uint32_t q, const Real (&)[3], Real fr, Real) {
        if (!isfinite(fr)) detail::flag_bad_pair(args.flags, order[p], order[q]);
      });
  }
  // The S parts of a particle (a whole warp takes the shuffles: p < n or not).
  for (int offset = S / 2; offset > 0; offset >>= 1) {
    for (int c = 0; c < D; ++c) f[c] += __shfl_xor_sync(0xffffffffu, f[c], offset);
    if constexpr (T::kObservables) ea += __shfl_xor_sync(0xffffffffu, ea, offset);
  }
  if constexpr (Drift) {
    double force[D];
#pragma unroll
    for (int c = 0; c < D; ++c) force[c] = double(f[c]);  // the values a stored force would hold
    next_kick_drift<D, S, B>(then, n, p, part, force, P.type, next, args.grid, args.num_types, args.flags,
                          next_step(gate));
    return;
  }
  if (p < n && part == 0) {
    const std::size_t i = by_rank ? p : order[p];  // rank order: a gated evaluation's (change 51)
    for (int c = 0; c < D; ++c) args.forces[i * D + c] = double(f[c]);
    if (args.energies) {
      double e = double(ea);
      if constexpr (Folded) e = (e + e * fold.eps) * fold.lambda;  // FixedFold: the folded energy is the true one over G
      args.energies[i] = e;
    }
  }
  if constexpr (T::kObservables) {
    // The block's sums: each warp's butterfly, then the warps in order (a fixed tree).
    __shared__ Accum partial[kBlock / 32][kCellSums];
    totals.finish();
    const int warp = int(threadIdx.x / 32), lane = int(threadIdx.x % 32);
    for (int k = 0; k < kCellSums; ++k) {
      const Accum v = detail::warp_sum(totals.v[k]);
      if (lane == 0) partial[warp][k] = v;
    }
    __syncthreads();
    if (threadIdx.x < unsigned(kCellSums)) {
      Accum v = partial[0][threadIdx.x];
      for (int w = 1; w < kBlock / 32; ++w) v += partial[w][threadIdx.x];
      if constexpr (Folded) v = (v + v * Accum(fold.eps)) * Accum(fold.lambda);  // FixedFold: the folded totals are the true ones over G
      block_sums[std::size_t(blockIdx.x) * kCellSums + threadIdx.x] = v;
    }
  }
}

unsigned blocks_for(std::size_t count) { return unsigned((count + kBlock - 1) / kBlock); }

// The scratch bytes of a CUB call over `items` (query(bytes): the call with no scratch, which only
// sizes it), asked of CUB only when the count differs from the last one (PairList::CubBytes).
template <class Query>
std::size_t cub_bytes(PairList::CubBytes& cached, std::size_t items, Query&& query) {
  if (cached.items != (long long)items) {
    cached.bytes = 0;
    CF_CUDA_CHECK(query(cached.bytes));
    cached.items = (long long)items;
  }
  return cached.bytes;
}

template <class Particle, class Real, class Accum>
void gather(const ListArgs<Real, Accum>& args, PairList& list, DeviceBuffer<Particle>& ranked, cudaStream_t stream) {
  ranked.reserve(std::max<std::size_t>(args.n, 1));
  with_dim(args.grid.dim, [&](auto d) {
    gather_ranked<decltype(d)::value><<<blocks_for(args.n), kBlock, 0, stream>>>(
        args.grid, args.positions, args.types, list.order.data(), args.n, args.num_types, ranked.data(), args.flags);
  });
  CF_CUDA_CHECK_LAUNCH();
}

// Waits for the stream and trims the device's current pool (which cudaMallocAsync uses) to nothing,
// so that what was freed in stream order is free again: cudaMemGetInfo counts it, and a buffer
// taken next cannot stand beside the one it replaces.
void trim_pool(cudaStream_t stream) {
  CF_CUDA_CHECK(cudaStreamSynchronize(stream));
  int device = 0;
  cudaMemPool_t pool = nullptr;
  CF_CUDA_CHECK(cudaGetDevice(&device));
  CF_CUDA_CHECK(cudaDeviceGetMemPool(&pool, device));
  CF_CUDA_CHECK(cudaMemPoolTrimTo(pool, 0));
}

// Room for the next builds' masks (BuildMasks): `words` and 1/8 more, where the device's free
// memory keeps 1/16 of it (at least 512 MiB) to spare after it; otherwise none (their fills walk
// the columns again). Lean memory (`part`, change 71): as much of that as the free memory holds with
// 1/8 of it (at least 2 GiB) and list.later_bytes (what the engine may still take: its gathered
// positions and energies where it has none yet) to spare, so that the units the room holds (a
// prefix) read their masks and the rest walk again; no room where it would hold less than 1/16 of
// the demand (too little to pay for the partition and the mirror). After the fill that read the old
// masks (freed in stream order, the pool trimmed so that the free memory counts them); growing is
// rare: the first build, a system that grew denser, and in lean mode the first build of each system
// size and the build after the list grew (the room given up). A demand refused is not asked again
// (masks_refused), nor is a lean room granted in part (masks_settled), until the room is given up
// (give_up_masks: a growing list, a new system).
void grow_masks(PairList& list, std::size_t words, bool part, cudaStream_t stream) {
  list.masks.release();
  trim_pool(stream);
  std::size_t free_bytes = 0, total_bytes = 0;
  CF_CUDA_CHECK(cudaMemGetInfo(&free_bytes, &total_bytes));
  std::size_t want = words + words / 8;
  if (list.mask_limit) want = std::min(want, list.mask_limit);
  if (part) {
    const std::size_t spare = std::max<std::size_t>(free_bytes / 8, std::size_t(2) << 30) + list.later_bytes;
    want = std::min(want, free_bytes > spare ? (free_bytes - spare) / sizeof(uint32_t) : 0);
    if (want < words / 16) want = 0;
    if (want < words) list.masks_settled = true;
  } else {
    const std::size_t spare = std::max<std::size_t>(free_bytes / 16, std::size_t(512) << 20);
    if (want * sizeof(uint32_t) + spare > free_bytes) want = 0;
  }
  if (want > 0) list.masks.reserve(want);
  if (want < words) list.masks_refused = words;  // not asked again for as many or more: each ask waits for the device
}

// Whether the evaluations of these args read FixedParticles (float pairs, fixed_point_serves) or
// RankedParticles.
template <class Real, class Accum>
bool gathers_fixed(const ListArgs<Real, Accum>& args) {
  return std::is_same_v<Real, float> && fixed_point_serves(args.grid, std::sqrt(double(args.rc2)));
}

}  // namespace

template <class Real, class Accum>
bool build_pair_list(const TraversalArgs<Real, Accum>& cells, const uint32_t* sorted_keys, const Control* control,
                     std::size_t entries, double list_cutoff, const ListArgs<Real, Accum>& args, PairList& list,
                     cudaStream_t stream, const StagedEntry<Real>* count_staged, const ListBuildHead& head) {
  const std::size_t n = args.n;
  const bool queue = head.queue;  // false: the build's graph queued the head's operations (build_graph.cuh)
  const int dim = args.grid.dim;
  const std::size_t slots = std::size_t(1) << dim;
  list.order.reserve(std::max<std::size_t>(n, 1));
  list.rank.reserve(std::max<std::size_t>(n, 1));
  list.slot_counts.reserve(std::max<std::size_t>(n * slots, 1));
  list.length.reserve(std::max<std::size_t>(n, 1));
  list.sizes.reserve(2);
  list.selected.reserve(1);
  list.width = list.pairs = list.slots = 0;
  if (n == 0) return true;

  // Ranks: the particles of the H entries in sorted order (each particle has exactly one).
  const auto home = thrust::make_transform_iterator(thrust::counting_iterator<uint32_t>(0), IsHome{sorted_keys, cells.grid.slab_bits});
  std::size_t bytes = cub_bytes(list.select_bytes, entries, [&](std::size_t& b) {
    return cub::DeviceSelect::Flagged(nullptr, b, cells.sorted_ids, home, list.order.data(), list.selected.data(),
                                      int(entries), stream);
  });
  list.scratch.reserve(std::max<std::size_t>(bytes, 1));
  if (queue) {
    CF_CUDA_CHECK(cub::DeviceSelect::Flagged(list.scratch.data(), bytes, cells.sorted_ids, home, list.order.data(),
                                             list.selected.data(), int(entries), stream));
    invert_order<<<blocks_for(n), kBlock, 0, stream>>>(list.order.data(), n, list.rank.data(), list.sizes.data());
    CF_CUDA_CHECK_LAUNCH();
  }

  // Count, size, fill.
  if (queue) CF_CUDA_CHECK(cudaMemsetAsync(list.slot_counts.data(), 0, n * slots * sizeof(uint32_t), stream));
  const double cutoff2 = list_cutoff * list_cutoff;
  const Real in2 = Real(cutoff2 * (1 - 1e-5)), out2 = Real(cutoff2 * (1 + 1e-5));
  const Real pre2 = Real(prefilter_bound(cells.grid, double(out2)));  // used with float coordinates
  list.splits = list.forced_splits > 0 ? std::min(list.forced_splits, 8)
                                       : build_splits(cells.max_tiles, cells.multiprocessors);
  const std::size_t units = std::size_t(cells.max_tiles) * std::size_t(list.splits);
  const unsigned row_blocks = unsigned((units + kBlock / 32 - 1) / (kBlock / 32));
  if (list.splits > 1) list.split_counts.reserve(std::size_t(row_blocks) * kBlock);  // a word per warp lane
  // The count pass's masks for the fill, in the room the previous builds asked for (none at the
  // first: it walks twice); in lean memory mode (cells without staged occupants) that room may hold
  // a prefix of the units only (grow_masks, change 71).
  const bool lean = cells.staged == nullptr;
  const uint32_t launched_units = row_blocks * (kBlock / 32);
  BuildMasks masks;
  if (list.use_masks && row_blocks) {
    list.mask_base.reserve(std::size_t(launched_units) + 1);
    if (queue) {
      unit_mask_words<<<blocks_for(std::size_t(launched_units) + 1), kBlock, 0, stream>>>(
          cells, uint32_t(list.splits), launched_units, list.mask_base.data());
      CF_CUDA_CHECK_LAUNCH();
    }
    std::size_t base_bytes = cub_bytes(list.base_bytes, launched_units + 1, [&](std::size_t& b) {
      return cub::DeviceScan::ExclusiveSum(nullptr, b, list.mask_base.data(), list.mask_base.data(),
                                           int(launched_units + 1), stream);
    });
    list.scratch.reserve(std::max<std::size_t>(base_bytes, 1));
    if (queue)
      CF_CUDA_CHECK(cub::DeviceScan::ExclusiveSum(list.scratch.data(), base_bytes, list.mask_base.data(),
                                                  list.mask_base.data(), int(launched_units + 1), stream));
    masks = BuildMasks{list.masks.data(), list.masks.capacity(), list.mask_base.data()};
    if (list.count_masked_units) {  // never in a graph (engine.cu)
      list.filled.reserve(1);
      CF_CUDA_CHECK(cudaMemsetAsync(list.filled.data(), 0, sizeof(unsigned long long), stream));
      masks.filled = list.filled.data();
    }
  } else {
    give_up_masks(list);
    list.mask_base.release();
  }
  // The count pass's units first (CountWalks), the rest after them (change 41), where a row tile's
  // columns are one unit (splits = 1, from ~67,000 particles): with splits (small systems) the
  // partition cost more than it saved (H100, 32,000: the count pass 88.6 -> 85.2 us, steps/s -1.7%).
  // Only with masks in use: without (a build before the room for them, or with none) the count pass
  // walks every unit of the range, and those come first in launch order already, so walk_order is
  // not kept.
  const bool partitioned = row_blocks && list.splits == 1 && masks.words;
  if (!partitioned) {
    list.walk_order.release();
    list.walked.release();
  } else {
    list.walk_order.reserve(launched_units);
    list.walked.reserve(1);
    const CountWalks<Real, Accum> walks{cells, uint32_t(list.splits), masks};
    const thrust::counting_iterator<uint32_t> all(0);
    std::size_t part_bytes = cub_bytes(list.part_bytes, launched_units, [&](std::size_t& b) {
      return cub::DevicePartition::If(nullptr, b, all, list.walk_order.data(), list.walked.data(),
                                      int(launched_units), walks, stream);
    });
    list.scratch.reserve(std::max<std::size_t>(part_bytes, 1));
    if (queue)
      CF_CUDA_CHECK(cub::DevicePartition::If(list.scratch.data(), part_bytes, all, list.walk_order.data(),
                                             list.walked.data(), int(launched_units), walks, stream));
  }
  const ListStaging staging{sorted_keys, args.positions, args.types, args.num_types, control};
  // The rows' walk, counting or filling, in the geometry's instantiation (2D/3D, wrap in a cell).
  // fill_chunks, fill_room: a fill's guard (list_rows), or none.
  // The count pass reads count_staged where the cells have no staged occupants (lean memory, change
  // 70): they lie in the list's array, which the fill then writes, so only the count pass reads them.
  // `cells` keeps staged null: the list's headroom and the masks' room below take a null
  // cells.staged for lean mode.
  TraversalArgs<Real, Accum> count_cells = cells;
  if (!cells.staged && count_staged) {
    count_cells.staged = count_staged;
    if (row_blocks) ++list.staged_counts;
  }
  auto walk_rows = [&](auto pass_constant, const unsigned long long* fill_chunks = nullptr,
                       unsigned long long fill_room = 0) {
    constexpr ListPass kPass = decltype(pass_constant)::value;
    constexpr bool kFill = kPass == ListPass::kFill;
    Switches sw;
    sw.dim = dim;
    sw.wrap = cells.grid.any_wrap_inside_cell();
    detail::dispatch(sw, [&](auto traits) {
      using T = decltype(traits);
      if constexpr (!T::kMultiType && T::kMode == CutoffMode::kTruncate && !T::kObservables) {
        const TraversalArgs<Real, Accum>& walked_cells = kPass == ListPass::kCount ? count_cells : cells;
        list_rows<T, kPass><<<row_blocks, kBlock, 0, stream>>>(
            walked_cells, staging, list.rank.data(), in2, out2, pre2, cutoff2, uint32_t(list.splits),
            list.slot_counts.data(), list.splits > 1 ? list.split_counts.data() : nullptr, list.group_chunks.data(),
            kFill ? list.neighbors.data() : nullptr, masks, partitioned ? list.walk_order.data() : nullptr,
            list.walked.data(), fill_chunks, fill_room);
      }
    });
    CF_CUDA_CHECK_LAUNCH();
  };
  if (head.done) head.done();  // the build's fixed part ends here
  if (row_blocks) walk_rows(std::integral_constant<ListPass, ListPass::kCount>{});
  // With one column split the count pass added the mirrored counts itself (change 62).
  if (masks.words && list.splits > 1) walk_rows(std::integral_constant<ListPass, ListPass::kMirrored>{});
  // Each group of kGroup ranks is as long as its longest list, in whole chunks: the groups' lengths,
  // then (the scan below) their first chunks.
  const std::size_t groups = (n + kGroup - 1) / kGroup;
  list.group_chunks.reserve(groups + 1);
  // Threads per particle: enough threads to fill half the device (1,024 per multiprocessor), at
  // most 8.
  const std::size_t wanted = std::size_t(std::max(cells.multiprocessors, 1)) * 1024;
  list.threads_per_particle = 1;
  list.multiprocessors = cells.multiprocessors;
  while (list.threads_per_particle < 8 && n * std::size_t(list.threads_per_particle) < wanted)
    list.threads_per_particle *= 2;
  if (list.forced_threads > 0) list.threads_per_particle = list.forced_threads;
  // The lengths (sizes[0] and [1] were zeroed by invert_order), and the force kernel's block count
  // for sum_cells.
  const uint32_t blocks = blocks_for(n * std::size_t(list.threads_per_particle));
  list.blocks.reserve(1);
  with_dim(dim, [&](auto d) {
    sum_slot_counts<decltype(d)::value><<<blocks_for(n + kGroup), kBlock, 0, stream>>>(
        list.slot_counts.data(), n, groups, list.length.data(), list.group_chunks.data(), list.sizes.data(), blocks,
        list.blocks.data());
    CF_CUDA_CHECK_LAUNCH();
  });
  std::size_t scan_bytes = cub_bytes(list.scan_bytes, groups + 1, [&](std::size_t& b) {
    return cub::DeviceScan::ExclusiveSum(nullptr, b, list.group_chunks.data(), list.group_chunks.data(),
                                         int(groups + 1), stream);
  });
  list.scratch.reserve(std::max<std::size_t>(scan_bytes, 1));
  CF_CUDA_CHECK(cub::DeviceScan::ExclusiveSum(list.scratch.data(), scan_bytes, list.group_chunks.data(),
                                              list.group_chunks.data(), int(groups + 1), stream));
  // The host reads the four sizes with one wait (three waits in a row cost ~25 us a build): the
  // longest list, the pairs, the words every unit's masks would take and the list's chunks, posted
  // into its mapped memory (change 82).
  unsigned long long tag = 0;
  PostedSizes* post = list.readback.begin(tag);
  gather_sizes<<<1, 32, 0, stream>>>(list.sizes.data(), masks.base ? masks.base + launched_units : nullptr,
                                     list.group_chunks.data() + groups, post, tag);
  CF_CUDA_CHECK_LAUNCH();
  // Where the list has an array already, the fill is queued behind the sizes' post before the host
  // reads them (change 65), so that the device fills while the host waits, decides and queues
  // what follows, instead of waiting for the host's launch (~17-23 us a build at 256k-1M). It
  // writes nothing where the list needs more chunks than the array holds (its guard reads the
  // total); the host then fills again after making room, as before. A list the host then drops
  // (the cells serve) was written in vain, and its array is freed in stream order.
  const unsigned long long room = list.neighbors.capacity() / (std::size_t(kGroup) * kChunk);
  const bool early = row_blocks && room > 0;
  if (early) walk_rows(std::integral_constant<ListPass, ListPass::kFill>{}, list.group_chunks.data() + groups, room);
  const SizesReadback::Sizes read = list.readback.wait(stream);
  const unsigned long long* sizes = read.value;
  const std::size_t width = std::size_t(sizes[0]), pairs = std::size_t(sizes[1]);
  const std::size_t mask_words = masks.base ? std::size_t(sizes[2]) : 0;  // what every unit's masks would take
  const std::size_t entries_total = std::size_t(sizes[3]) * kGroup * kChunk;  // the list's slots, padding included
  // A few crowded particles (the cells are cheaper), or a list that would not fit in the device's
  // free memory with 1/16 of it (at least 512 MiB) to spare (a dense cluster: n^2 partners): the
  // cells serve this structure. The list in use counts as free: it is replaced. A list that fits the
  // array it has takes no memory, and the free memory is not asked for (cudaMemGetInfo, ~8 us
  // with the device idle before a fill that waits for the host: the one after making room).
  const bool held = entries_total <= list.neighbors.capacity();
  std::size_t free_bytes = 0, total_bytes = 0;
  if (!held) {
    CF_CUDA_CHECK(cudaMemGetInfo(&free_bytes, &total_bytes));
    free_bytes += list.neighbors.bytes() + list.masks.bytes();  // the masks give way to a growing list
  }
  const std::size_t spare = std::max<std::size_t>(free_bytes / 16, std::size_t(512) << 20);
  const std::size_t need = entries_total * sizeof(uint32_t);
  if (entries_total > 2 * pairs + 64 * n || (!held && need + spare > free_bytes)) {
    list.neighbors.release();  // dead: the cells serve, and need the room
    give_up_masks(list);
    list.mask_base.release();
    return false;
  }
  if (entries_total > list.neighbors.capacity()) {
    // The largest buffer: the old one is freed and the pool it came from (the device's current
    // one, which cudaMallocAsync uses) trimmed before the new one is taken (in stream order alone
    // the pool could hold both). Room to spare, so that the next builds' lists rarely outgrow it,
    // where that still leaves the spare free: 1/16 with a staged build (fast mode), 1/64 in lean
    // mode (whose array the next builds also lend to their sort first, engine.cu).
    list.neighbors.release();
    give_up_masks(list);  // counted as free above: this fill walks every unit again (the same list);
    masks.words = nullptr;  // the masks are asked for again below, in the room the new list leaves
    trim_pool(stream);
    const std::size_t headroom = entries_total / (lean ? 64 : 16);
    const bool roomy = need + headroom * sizeof(uint32_t) + 2 * spare <= free_bytes;
    list.neighbors.reserve(roomy ? entries_total + headroom : entries_total);
  }
  if (row_blocks && width && !(early && held)) walk_rows(std::integral_constant<ListPass, ListPass::kFill>{});
  list.mask_words = row_blocks && width ? mask_words : 0;
  list.mask_words_held = row_blocks && width && masks.words ? std::min<std::size_t>(mask_words, masks.capacity) : 0;
  if (list.mask_words_held) {
    if (mask_words <= masks.capacity) ++list.masked_fills;
    else ++list.partly_masked_fills;
  }
  list.masked_units = 0;
  if (masks.filled && row_blocks && width) {  // tests only: a wait for the fill
    unsigned long long filled = 0;
    CF_CUDA_CHECK(cudaMemcpyAsync(&filled, masks.filled, sizeof(filled), cudaMemcpyDeviceToHost, stream));
    CF_CUDA_CHECK(cudaStreamSynchronize(stream));
    list.masked_units = std::size_t(filled);
  }
  list.width = width;
  list.pairs = pairs;
  list.slots = entries_total;
  if (masks.base && mask_words > list.masks.capacity() && !list.masks_settled &&
      (!list.masks_refused || mask_words < list.masks_refused))
    grow_masks(list, mask_words, lean, stream);
  return true;
}

template <class Real, class Accum>
RankOrder rank_order(const ListArgs<Real, Accum>& args, PairList& list, bool forces_by_rank, bool fused) {
  RankOrder to;
  to.rank = list.rank.data();
  to.order = list.order.data();
  if (forces_by_rank) {
    list.ranked_forces.reserve(std::max<std::size_t>(args.n * std::size_t(args.grid.dim), 1));
    to.forces = list.ranked_forces.data();
  } else {
    list.ranked_forces.release();
  }
  to.fixed = gathers_fixed(args);
  const std::size_t n = std::max<std::size_t>(args.n, 1);
  if (to.fixed) {
    list.ranked.release();
    list.ranked_next.release();
    list.fixed.reserve(n);
    if (fused) list.fixed_next.reserve(n);
    else list.fixed_next.release();
    to.particles = list.fixed.data();
  } else {
    list.fixed.release();
    list.fixed_next.release();
    list.ranked.reserve(n);
    if (fused) list.ranked_next.reserve(n);
    else list.ranked_next.release();
    to.particles = list.ranked.data();
  }
  to.grid = args.grid;
  to.types = args.types;
  to.num_types = args.num_types;
  to.flags = args.flags;
  return to;
}

// The fused force kernel's block size (change 76, list_build.h fused_block_size), from the
// occupancy calculator's resident blocks of the kernel's two forms, asked once per kernel, and the
// build's multiprocessor count.
namespace {
int fused_block(PairList& list, const void* narrow, const void* wide, std::size_t threads) {
  if (list.forced_block) return list.forced_block;
  if (list.threads_per_particle != 1) return kBlock;
  PairList::BlockShape& shape = list.shape;
  if (shape.kernel != narrow) {
    CF_CUDA_CHECK(cudaOccupancyMaxActiveBlocksPerMultiprocessor(&shape.resident[0], narrow, kBlock, 0));
    CF_CUDA_CHECK(cudaOccupancyMaxActiveBlocksPerMultiprocessor(&shape.resident[1], wide, 2 * kBlock, 0));
    shape.kernel = narrow;
  }
  return fused_block_size(threads, list.threads_per_particle, kBlock, shape.resident, list.multiprocessors);
}
}  // namespace

template <class Real, class Accum>
void list_forces(const Switches& sw, const ListArgs<Real, Accum>& given, PairList& list, cudaStream_t stream,
                 const GateView& gate, bool by_rank, const NextKickDrift* then) {
  if (given.n == 0) return;
  if (by_rank && (sw.observables || given.energies))
    throw Error("internal error: forces in rank order are for evaluations of forces only");
  if (then && (sw.observables || given.energies || !gate.gate || sw.dim != then->box.dim))
    throw Error("internal error: the next step's kick-drift follows a gated evaluation of forces only");
  ListArgs<Real, Accum> args = given;
  if (by_rank) {
    list.ranked_forces.reserve(std::max<std::size_t>(args.n * std::size_t(args.grid.dim), 1));
    args.forces = list.ranked_forces.data();
  }
  const unsigned blocks = blocks_for(args.n * std::size_t(list.threads_per_particle));
  list.block_sums.reserve(std::size_t(blocks) * kCellSums * sizeof(Accum));
  Switches s = sw;
  s.wrap = false;  // positions are absolute: the minimum image is on every periodic axis
  FixedScales scale;  // FixedParticle: L_a / 2^32 per axis, once per evaluation
  for (int a = 0; a < 3; ++a) scale.axis[a] = fixed_scale(args.grid.length[a]);
  // A cube (every axis the same scale): the fold (FixedFold) for the kernels that take it.
  bool cube = true;
  for (int a = 1; a < args.grid.dim; ++a)
    cube = cube && scale.axis[a].hi == scale.axis[0].hi && scale.axis[a].lo == scale.axis[0].lo;
  FixedFold fold;
  {
    const float hi = scale.axis[0].hi;  // 0 only for an empty axis: no fold (g = 1)
    const double g = hi != 0.0f ? 1.0 + double(scale.axis[0].lo) / double(hi) : 1.0;
    const int k = -std::ilogb(double(args.first.inv_s2)) / 2;  // the single type's unit lambda = 2^k
    const double lambda = std::ldexp(1.0, k), g13 = std::pow(g, -13.0), g7 = std::pow(g, -7.0);
    fold.f12 = float(double(args.first.f12) * (lambda * g13));
    fold.f6 = float(double(args.first.f6) * (lambda * g7));
    fold.e12 = float(double(args.first.e12) * (g13 / lambda));
    fold.e6 = float(double(args.first.e6) * (g7 / lambda));
    fold.u_rc = float(double(args.first.u_rc) / (g * lambda));
    fold.rc = float(double(args.first.rc) / (g * lambda));
    fold.hi = std::ldexp(hi, -k);
    fold.eps = g - 1.0;
    fold.lambda = lambda;
    fold.rc2 = float(double(args.rc2) / (g * g * lambda * lambda));
  }
  auto evaluate = [&](auto& ranked, auto& next) {
    using Particle = typename std::remove_reference_t<decltype(ranked)>::value_type;
    if (!gate.gate) gather(args, list, ranked, stream);  // gated: the step's drift placed them
    if (then && next.capacity() < args.n)
      throw Error("internal error: the next step's kick-drift without the list's second array (rank_order)");
    detail::dispatch(s, [&](auto traits) {
      using T = decltype(traits);
      if constexpr (!T::kWrap) {
        auto go = [&](auto split) {
          auto launch = [&](auto folded) {
            auto with = [&](auto drift) {
              // Gated evaluations follow each other: each may be scheduled while the last one
              // runs (programmatic dependent launch, change 75; the kernel waits for it).
              cudaLaunchAttribute overlap{};
              overlap.id = cudaLaunchAttributeProgrammaticStreamSerialization;
              overlap.val.programmaticStreamSerializationAllowed = 1;
              cudaLaunchConfig_t config{};
              config.stream = stream;
              const bool overlapped = gate.gate && list.dependent_launch;
              config.attrs = overlapped ? &overlap : nullptr;
              config.numAttrs = overlapped ? 1 : 0;
              const std::size_t threads = args.n * std::size_t(list.threads_per_particle);
              auto go = [&](auto kernel, unsigned block) {
                config.gridDim = dim3(unsigned((threads + block - 1) / block));
                config.blockDim = dim3(block);
                CF_CUDA_CHECK(cudaLaunchKernelEx(
                    &config, kernel, args, static_cast<const uint32_t*>(list.order.data()),
                    static_cast<const Particle*>(ranked.data()), static_cast<const uint32_t*>(list.length.data()),
                    static_cast<const unsigned long long*>(list.group_chunks.data()),
                    static_cast<const uint32_t*>(list.neighbors.data()), scale, fold,
                    reinterpret_cast<Accum*>(list.block_sums.data()), gate, by_rank, then ? *then : NextKickDrift{},
                    next.data()));
              };
              using Split = std::remove_reference_t<decltype(split)>;
              using Fold = std::remove_reference_t<decltype(folded)>;
              auto kernel = list_force_kernel<T, Split::value, Fold::value, decltype(drift)::value, Particle, Real,
                                              Accum>;
              if constexpr (decltype(drift)::value) {
                // The next step's kick-drift: blocks of 2 kBlock where they fill the last wave
                // better (fused_block, change 76).
                auto wide = list_force_kernel<T, Split::value, Fold::value, true, Particle, Real, Accum, 2 * kBlock>;
                list.fused_block = fused_block(list, reinterpret_cast<const void*>(kernel),
                                               reinterpret_cast<const void*>(wide), threads);
                if (list.fused_block == 2 * kBlock) return go(wide, 2 * kBlock);
              }
              go(kernel, kBlock);
            };
            if constexpr (!T::kObservables) {
              if (then) return with(std::true_type{});
            }
            with(std::false_type{});
          };
          if constexpr (std::is_same_v<Particle, FixedParticle> && !T::kMultiType) {
            if (cube) launch(std::true_type{});
            else launch(std::false_type{});
          } else {
            launch(std::false_type{});
          }
        };
        switch (list.threads_per_particle) {
          case 1: go(std::integral_constant<int, 1>{}); break;
          case 2: go(std::integral_constant<int, 2>{}); break;
          case 4: go(std::integral_constant<int, 4>{}); break;
          default: go(std::integral_constant<int, 8>{}); break;
        }
      }
    });
    CF_CUDA_CHECK_LAUNCH();
    if (then) std::swap(ranked, next);  // the next evaluation reads what this one placed
  };
  if constexpr (std::is_same_v<Real, float>) {
    if (gathers_fixed(args)) {
      list.ranked.release();
      evaluate(list.fixed, list.fixed_next);
      return;
    }
  }
  list.fixed.release();
  evaluate(list.ranked, list.ranked_next);
}

namespace {
// A thread per coordinate of the caller's order (change 87): the stores coalesced, the loads
// gathered by rank. With the scattered stores of a thread per rank the kernel ran 31.6 us at 1M
// particles in lattice order and 99.8 shuffled (Nsight Compute, 7e818de).
template <int D>
__global__ void unrank_kernel(const uint32_t* __restrict__ rank, const double* __restrict__ ranked, std::size_t n,
                              double* __restrict__ out) {
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= n * D) return;
  const std::size_t i = k / D, a = k % D;
  out[k] = ranked[std::size_t(rank[i]) * D + a];
}
}  // namespace

void unrank(const uint32_t* rank, const double* ranked, std::size_t n, int dim, double* out, cudaStream_t stream) {
  if (n == 0) return;
  with_dim(dim, [&](auto d) {
    constexpr int D = decltype(d)::value;
    unrank_kernel<D><<<blocks_for(n * D), kBlock, 0, stream>>>(rank, ranked, n, out);
  });
  CF_CUDA_CHECK_LAUNCH();
}

void unrank_forces(const PairList& list, std::size_t n, int dim, double* forces, cudaStream_t stream) {
  unrank(list.rank.data(), list.ranked_forces.data(), n, dim, forces, stream);
}

#define CF_PAIR_LIST(Real, Accum)                                                                              \
  template bool build_pair_list<Real, Accum>(const TraversalArgs<Real, Accum>&, const uint32_t*, const Control*, \
                                             std::size_t, double, const ListArgs<Real, Accum>&, PairList&,       \
                                             cudaStream_t, const StagedEntry<Real>*, const ListBuildHead&);      \
  template void list_forces<Real, Accum>(const Switches&, const ListArgs<Real, Accum>&, PairList&, cudaStream_t, \
                                         const GateView&, bool, const NextKickDrift*);                          \
  template RankOrder rank_order<Real, Accum>(const ListArgs<Real, Accum>&, PairList&, bool, bool);
CF_PAIR_LIST(float, float)
CF_PAIR_LIST(float, double)
CF_PAIR_LIST(double, double)
#undef CF_PAIR_LIST

}  // namespace cellforce::cuda
