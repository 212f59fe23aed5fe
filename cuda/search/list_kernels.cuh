// The pair-list build's kernels (search/list_build.cu runs them): the ranks, the work units' mask
// words, the count, mirrored and fill passes over the collision cells' row tiles (list_rows), the
// lists' lengths by group, and the sizes posted to the host. Device code for the one translation
// unit that launches it.
#pragma once

#include <cstddef>
#include <cstdint>

#include "search/pair_list.cuh"

namespace cellforce::cuda {
namespace {

constexpr int kBlock = kListBlock;
unsigned blocks_for(std::size_t count) { return unsigned((count + kBlock - 1) / kBlock); }

// A sorted entry that is some particle's H entry (the key's phantom bit clear; invalid keys are
// all ones).
struct IsHome {
  const uint32_t* keys;
  int slab_bits;
  __device__ bool operator()(uint32_t e) const { return !key_is_phantom(keys[e], slab_bits); }
};

// Also zeroes the two sizes sum_slot_counts adds to later in the build (so the build needs no memset).
__global__ void invert_order(const uint32_t* __restrict__ order, std::size_t n, uint32_t* __restrict__ rank,
                             unsigned long long* __restrict__ sizes) {
  const std::size_t p = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (p < n) rank[order[p]] = uint32_t(p);
  if (p == 0) sizes[0] = sizes[1] = 0;
}

// The squared minimum-image distance of particles i and j from their user-order positions, in
// double (separation: each coordinate wrapped exactly, then the minimum image): the build's
// decision for pairs within the staged coordinates' rounding of the list cutoff, the same number
// distance2 forms from gathered RankedParticles but for the order of the rounded sum. Inlined:
// the passes run slower with it __noinline__.
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

// A walk's entries of one rank's list, from entry `first` on (the partners found before this walk),
// one after the other: each chunk the walk fills whole is one 16-byte store, and the chunks it
// shares with the walks before and after it (its first and last) are written entry by entry:
// 4-byte stores, each lane at its own row's place, would each be its own L2 transaction and hold
// the fill far below its issue rate. The walked fill (units without masks) uses it; the fill from
// masks writes a warp's entries 32 at a time, neighbouring lanes at neighbouring places of a row.
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

// Where a row's entries go in the fill from masks: its list's chunk 0 (an index into the
// list, so that the store is a global one), and its next entry's place less the row's first place
// in the warp's queue, so that queue entry q goes to place base + q.
struct alignas(16) FillRow {
  std::size_t chunk0;  // list_entry(group's first chunk, rank, 0)
  uint32_t base;
};

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
// counts, from their masks; with one, the count pass adds them itself: list_rows), fill.
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

// Whether the count pass walks a unit: a row tile of the range, but not a P tile whose masks are
// kept (its H rows write them, and count it: list_rows's mirror). The units are partitioned by
// this before the count pass so that its warps are those that walk, side by side: in launch order
// each cell's few H tiles come with its many P tiles (most of the units), which return at once but
// would hold their block's room until its H tiles were done, leaving the pass latency-bound.
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
// with the mirror, below). The occupants come from the staged array (fast memory, and a lean
// build's count pass where the last list's array holds them), or, without one,
// are staged as they are loaded (detail::stage_entry, the values stage_kernel would write).
// Count: the partners of each row within the list cutoff, into slot_counts[rank * 2^d + cell
// type] (a store with one split and no masks, an integer atomic add with masks: the mirror; with
// several splits, each range's count is added there, an integer sum, and kept per unit and lane
// in split_counts). Fill: the same walk writes them, after the partners the row's particle found
// in cells of lower type and in the ranges before this one (so the list does not depend on the
// splits). With masks (BuildMasks: every unit's in fast memory mode, a prefix of the units' in
// lean mode), the count pass keeps each decision as a bit, writes the bits of the P-only tiles
// that keep masks from their H rows' side (those tiles are not walked; with one column split, the
// later H row tiles' bits for the earlier ones' columns too, and their counts: the mirror, below;
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
  // A fill queued before the host knew the list's size: nothing, where the list needs
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
  // only gets them from the H rows it pairs with, and with mirror_h an H row tile gets those for
  // the column tiles of the cell's earlier H row tiles from them: mirrored), the fill reads them.
  const bool kept = masks.base && masks.kept(unit);
  const uint32_t* my_words = kept ? masks.words + masks.base[unit] : nullptr;
  const bool p_tile = row >= h;  // P rows only (a multiple of 32: no H row in it)
  uint32_t count = 0;
  // The mirror: with one column range per row tile (splits = 1) and masks, a row tile that holds H
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
        // Only the columns some row keeps load their rank: the rank is a dependent
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
        // The batch's entries are written by the whole warp, 32 at a time. Each lane queues its
        // row's entries (lane << 7 | the column in the batch, in list order) after the rows before
        // it; in each round lane l writes the next queue entry 32 j + l to its row's list, at the
        // row's next place plus the entry's place among the row's entries. A lane that put its own
        // row's entries would run as many rounds as the fullest row, each round waiting on its
        // rank's shared load. Neighbouring lanes write neighbouring entries of a row, so the 4-byte
        // stores of a round mostly fill the rows' 16-byte chunks whole, as ChunkWriter's stores do,
        // and never touch an entry of another walk. A batch whose entries overflow the queue takes
        // its tiles one at a time (each at most 32 x 32 entries).
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
  // A row tile's mirror: for a column tile of P-only tiles (past p_end), or with mirror_h
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
    // Then the columns that passed, decided by the whole warp: the candidate rule, and the double
    // decision for the few within the staged coordinates' rounding of the cutoff. Each lane queues
    // its survivors (row lane << 5 | column k, a few a lane), and the warp takes the queue 32 at a
    // time; a lane that decides a pair sets the column's bit in its row's word. A lane walking its
    // own survivors would run as many rounds as the fullest lane, with most lanes idle, and the
    // count pass is issue-bound. `keep`: the partners. Rows beyond the cell, columns past the row's
    // (row_cols) and the row itself are dropped before the queue.
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
// ranks (blocks of kBlock ranks start on a group): one warp-wide max, not a scan over groups that
// reads its 32 lengths per item (latency-bound at every size).
// Launched over n + kGroup threads, so that a warp exists for group_chunks[groups]. Also the
// longest list into sizes[0] and the sum of the lengths into sizes[1] (zeroed before: one atomic
// of each per block; integers, so the order does not matter), not two CUB reductions over the
// lengths, whose host-side dispatch would hold the device idle at small sizes.
template <int D>
__global__ void sum_slot_counts(const uint32_t* __restrict__ slot_counts, std::size_t n, std::size_t groups,
                                uint32_t* __restrict__ length, unsigned long long* __restrict__ group_chunks,
                                unsigned long long* __restrict__ sizes, uint32_t force_blocks,
                                uint32_t* __restrict__ force_blocks_out) {
  static_assert(kGroup == 32 && kBlock % kGroup == 0, "a group of ranks is one warp's");  // __reduce_max_sync: sm_80+
  const std::size_t p = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (p == 0) *force_blocks_out = force_blocks;  // for sum_cells (written here: no copy from the host)
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

// The four sizes the host reads, posted into its mapped memory (SizesReadback: one launch, no
// device copy and no copy to the host): the longest list and the sum of the lengths
// (sum_slot_counts), the words every unit's masks take (masks_end null: none, 0) and the list's
// chunks; a system-wide fence, then the build's tag.
__global__ void gather_sizes(const unsigned long long* __restrict__ sizes,
                             const unsigned long long* __restrict__ masks_end,
                             const unsigned long long* __restrict__ chunks_end, PostedSizes* out,
                             unsigned long long tag, const unsigned long long* __restrict__ device_tag) {
  if (threadIdx.x == 0) {
    volatile PostedSizes* o = out;
    o->value[0] = sizes[0];
    o->value[1] = sizes[1];
    o->value[2] = masks_end ? *masks_end : 0ull;
    o->value[3] = *chunks_end;
    __threadfence_system();  // the sizes reach the host before the tag
    o->tag = device_tag ? (*device_tag | SizesReadback::kDeviceTag) : tag;
  }
}

// A build the device decided (PairList::overflow): whether the early fill found the list longer
// than the array (it then wrote nothing), or the list so crowded that the host would decline it
// (plan_list_room: a layout of more than twice the pairs and 64 slots a particle; the cells serve).
__global__ void flag_overflow(const unsigned long long* __restrict__ chunks_end, unsigned long long chunks_held,
                              const unsigned long long* __restrict__ sizes, unsigned long long n,
                              unsigned long long* overflow) {
  if (threadIdx.x != 0) return;
  const unsigned long long chunks = *chunks_end, slots = chunks * kGroup * kChunk;
  const unsigned long long over = chunks > chunks_held || slots > 2 * sizes[1] + 64 * n ? 1ull : 0ull;
  overflow[0] = over;
  overflow[1] += over;
}

}  // namespace
}  // namespace cellforce::cuda
