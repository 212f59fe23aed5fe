// Stage 4, traversal (GPU Gems 3 ch. 32, section 32.2.5), as kernels: each collision cell tests
// every H occupant against every other occupant, H and P, skips the pairs that the control-bit
// rule assigns to another cell, and evaluates Lennard-Jones directly for the pairs with r < rc.
// Three forms:
//  - thread per cell (the chapter's): one thread walks its cell's pairs serially;
//  - warp per cell (the chapter's future work): a warp shares one cell. Rows of 32 H occupants
//    are held in registers, columns of 32 occupants staged in shared memory; in step k lane l
//    pairs its row occupant with column occupant (l + k) mod 32, so that no two lanes touch one
//    column accumulator in a step. A __syncwarp after each step orders the steps.
//  - block per row tile (below): each tile of 32 occupants of a cell is one block's work, its
//    warps taking the column tiles in turn.
// All write each occupant's sums into the cell's own output slot (Jacobi) or, one cell type per
// launch, into the single output (Gauss-Seidel), with no atomics: every addition happens in an
// order fixed by the cell's layout, so results are bitwise reproducible.
//
// This header holds the templates; traversal_{single,mixed,double}.cu instantiate them.
#pragma once

#include <cmath>
#include <type_traits>

#include "check.cuh"
#include "core/cell_totals.h"
#include "forces/traversal.cuh"

namespace cellforce::cuda {
namespace detail {

constexpr int kThreadsPerBlock = 128;          // thread per cell: cells per block
constexpr int kWarpsPerBlock = 4;              // warp per cell: most cells (warps) per block;
                                               // tile form: the warps sharing a row tile

template <class T, class Real, class Accum>
__device__ __forceinline__ LJParams<Real> pair_params(const TraversalArgs<Real, Accum>& args,
                                                      const LJParams<Real>& single, uint32_t meta_a,
                                                      uint32_t meta_b) {
  if constexpr (T::kMultiType) return args.table[type_of(meta_a) * args.num_types + type_of(meta_b)];
  else return single;
}

__device__ __forceinline__ void record_pair(const TraversalArgs<double, double>& args, uint32_t i,
                                            uint32_t j) {
  const unsigned long long k = atomicAdd(&args.flags->recorded, 1ull);
  if (k < args.pair_capacity) args.pairs[k] = make_uint2(i < j ? i : j, i < j ? j : i);
}

// Record mode: a warp's candidate and interacting pair counts, added to the flags once per warp.
__device__ __forceinline__ void add_pair_counts(DeviceFlags* flags, unsigned long long candidates,
                                                unsigned long long interacting, int lane) {
  candidates = warp_sum(candidates);
  interacting = warp_sum(interacting);
  if (lane == 0) {
    atomicAdd(&flags->candidates, candidates);
    atomicAdd(&flags->interacting, interacting);
  }
}

// ---- thread per collision cell ----------------------------------------------------------------
template <class T, class Real, class Accum, bool Record>
__global__ void __launch_bounds__(kThreadsPerBlock)
    thread_per_cell(const TraversalArgs<Real, Accum> args) {
  constexpr int D = T::kDim;
  const uint32_t ci = args.cell_range[0] + blockIdx.x * blockDim.x + threadIdx.x;
  if (ci >= args.cell_range[1]) return;
  const CollisionCell cell = args.cells[ci];
  const unsigned type = cell_type_of_id(args.grid, cell.cell);
  Accum* force = args.force + type * args.force_slot_stride;
  Accum* energy = T::kObservables ? args.energy + type * args.energy_slot_stride : nullptr;
  const LJParams<Real> single = args.table[0];
  const StagedEntry<Real>* occ = args.staged + cell.start;
  const uint32_t* ids = args.sorted_ids + cell.start;
  const uint32_t m = cell.h + cell.p;
  CellTotals<Accum, true, true> totals;  // core/cell_totals.h
  unsigned long long candidates = 0, interacting = 0;

  for (uint32_t a = 0; a < cell.h; ++a) {
    const StagedEntry<Real> A = occ[a];
    const uint32_t ia = ids[a];
    if (ia >= args.n) {
      args.flags->impossible = 1;
      return;
    }
    Accum fa[D] = {};
    Accum ea = 0;
    for (uint32_t b = a + 1; b < m; ++b) {
      const StagedEntry<Real> B = occ[b];
      if (b >= cell.h && skip_pair(type, control_of(A.meta), control_of(B.meta))) continue;
      ++candidates;
      Real d[3];
      const Real r2 = separation<T>(A, B, args.length, args.inv_length, d);
      Real fr, e = 0;
      if (!lj_pair<T::kMode, T::kObservables>(r2, args.rc2, pair_params<T>(args, single, A.meta, B.meta),
                                              fr, e))
        continue;
      ++interacting;
      const uint32_t ib = ids[b];
      if (ib >= args.n) {
        args.flags->impossible = 1;
        return;
      }
      if constexpr (Record) {
        record_pair(args, ia, ib);
        continue;
      } else {
        if (!isfinite(fr)) flag_bad_pair(args.flags, ia, ib);
        for (int c = 0; c < D; ++c) {
          const Real f = mul_rn(fr, d[c]);  // no FMA: the same bits with and without observables
          fa[c] += Accum(f);
          force[std::size_t(ib) * D + c] -= Accum(f);
        }
        if constexpr (T::kObservables) {
          const Accum half = Accum(Real(0.5) * e);
          ea += half;
          energy[ib] += half;
          totals.template add<D>(e, fr, d);
        }
      }
    }
    if constexpr (!Record) {
      for (int c = 0; c < D; ++c) force[std::size_t(ia) * D + c] += fa[c];
      if constexpr (T::kObservables) energy[ia] += ea;
    }
  }
  if constexpr (Record) {
    atomicAdd(&args.flags->candidates, candidates);
    atomicAdd(&args.flags->interacting, interacting);
  } else if constexpr (T::kObservables) {
    totals.finish();
    for (int k = 0; k < kCellSums; ++k)
      args.cell_sums[std::size_t(ci) * kCellSums + k] = totals.v[k];
  }
}

// ---- warp per collision cell ------------------------------------------------------------------
// One warp's shared memory: a column tile of occupants and its accumulators.
template <class T, class Real, class Accum>
struct ColumnTile {
  StagedEntry<Real> occ[32];
  Accum force[T::kDim][32];
  Accum energy[T::kObservables ? 32 : 1];
};

template <class T, class Real, class Accum, bool Record>
__global__ void __launch_bounds__(kWarpsPerBlock * 32)
    warp_per_cell(const TraversalArgs<Real, Accum> args) {
  constexpr int D = T::kDim;
  // Dynamic: the launcher picks 1 or kWarpsPerBlock warps per block from the cell count.
  extern __shared__ __align__(32) unsigned char shared_bytes[];
  const int warp = int(threadIdx.x / 32), lane = int(threadIdx.x % 32);
  ColumnTile<T, Real, Accum>& tile = reinterpret_cast<ColumnTile<T, Real, Accum>*>(shared_bytes)[warp];
  const uint32_t ci = args.cell_range[0] + blockIdx.x * (blockDim.x / 32) + uint32_t(warp);
  if (ci >= args.cell_range[1]) return;  // the whole warp: the cell index is warp-uniform
  const CollisionCell cell = args.cells[ci];
  const unsigned type = cell_type_of_id(args.grid, cell.cell);
  Accum* force = args.force + type * args.force_slot_stride;
  Accum* energy = T::kObservables ? args.energy + type * args.energy_slot_stride : nullptr;
  const LJParams<Real> single = args.table[0];
  const StagedEntry<Real>* occ = args.staged + cell.start;
  const uint32_t* ids = args.sorted_ids + cell.start;
  const uint32_t h = cell.h, m = cell.h + cell.p;
  CellTotals<Accum, true, true> totals;  // core/cell_totals.h
  unsigned long long candidates = 0, interacting = 0;
  bool impossible = false;

  for (uint32_t row = 0; row < h; row += 32) {
    const uint32_t a = row + uint32_t(lane);
    const bool row_ok = a < h;
    const StagedEntry<Real> A = row_ok ? occ[a] : StagedEntry<Real>{};
    const uint32_t ia = row_ok ? ids[a] : 0;
    Accum fa[D] = {};
    Accum ea = 0;
    for (uint32_t col = row; col < m; col += 32) {
      const uint32_t own = col + uint32_t(lane);
      if (own < m) tile.occ[lane] = occ[own];
      for (int c = 0; c < D; ++c) tile.force[c][lane] = 0;
      if constexpr (T::kObservables) tile.energy[lane] = 0;
      __syncwarp();
      for (int k = 0; k < 32; ++k) {
        const int bl = (lane + k) & 31;
        const uint32_t b = col + uint32_t(bl);
        if (row_ok && b < m) {
          const StagedEntry<Real> B = tile.occ[bl];
          // H x H once (b > a); H x P unless the control-bit rule gives the pair to another cell.
          const bool test = b < h ? b > a : !skip_pair(type, control_of(A.meta), control_of(B.meta));
          if (test) {
            ++candidates;
            Real d[3];
            const Real r2 = separation<T>(A, B, args.length, args.inv_length, d);
            Real fr, e = 0;
            if (lj_pair<T::kMode, T::kObservables>(r2, args.rc2,
                                                   pair_params<T>(args, single, A.meta, B.meta), fr, e)) {
              ++interacting;
              if constexpr (Record) {
                const uint32_t ib = ids[b];
                if (ia >= args.n || ib >= args.n) impossible = true;
                else record_pair(args, ia, ib);
              } else {
                if (!isfinite(fr)) flag_bad_pair(args.flags, ia, ids[b]);
                for (int c = 0; c < D; ++c) {
                  const Real f = mul_rn(fr, d[c]);  // no FMA: the same bits with and without observables
                  fa[c] += Accum(f);
                  tile.force[c][bl] -= Accum(f);
                }
                if constexpr (T::kObservables) {
                  const Accum half = Accum(Real(0.5) * e);
                  ea += half;
                  tile.energy[bl] += half;
                  totals.template add<D>(e, fr, d);
                }
              }
            }
          }
        }
        __syncwarp();
      }
      if constexpr (!Record) {
        if (own < m) {
          const uint32_t ib = ids[own];
          if (ib >= args.n) {
            impossible = true;
          } else {
            for (int c = 0; c < D; ++c) force[std::size_t(ib) * D + c] += tile.force[c][lane];
            if constexpr (T::kObservables) energy[ib] += tile.energy[lane];
          }
        }
      }
      __syncwarp();
    }
    if constexpr (!Record) {
      if (row_ok && ia < args.n) {
        for (int c = 0; c < D; ++c) force[std::size_t(ia) * D + c] += fa[c];
        if constexpr (T::kObservables) energy[ia] += ea;
      }
    }
    __syncwarp();
  }
  if (impossible) args.flags->impossible = 1;
  if constexpr (Record) {
    add_pair_counts(args.flags, candidates, interacting, lane);
  } else if constexpr (T::kObservables) {
    totals.finish();
    for (int k = 0; k < kCellSums; ++k) {
      const Accum v = warp_sum(totals.v[k]);
      if (lane == 0) args.cell_sums[std::size_t(ci) * kCellSums + k] = v;
    }
  }
}

// ---- block per row tile ------------------------------------------------------------------------
// A collision cell's occupants (H first, then P) in rows of 32; each row tile of each cell is one
// block's work, so a cell of m occupants keeps ceil(m / 32) blocks busy. The block computes the
// whole force on each of its row occupants from every column occupant of the cell that the
// chapter's rule pairs it with here (H x H; H x P unless the control bits give the pair to another
// cell; never P x P), so each pair is evaluated from both sides and nothing but the row's own sums
// is written: a particle's slot is written by the one block that holds its row in the one cell of
// that type it occupies, with no atomics. The block's warps take the column tiles in turn (warp k:
// tiles k, k + kWarpsPerBlock, ...) and their partial sums are added in warp order in shared
// memory, so the order is fixed and the result bitwise repeatable. Row tiles of P occupants only
// need the H columns. Twice the pair evaluations of warp_per_cell, for many times its parallelism:
// what a small system needs. Energy and virial: half of each pair from each side, summed per row
// tile (args.cell_sums is indexed by the global tile) and then over the tiles in a fixed order.
//
// With ghosts (T::kLocal, traverse_local): a row of a ghost is skipped (a tile of ghosts only ends
// at once), so no pair of two ghosts is tested; a pair of two locals is evaluated from both sides
// as above, a pair of a local and a ghost from the local's side only. Each local row sums its half
// of each pair's energy and virial into its slots (args.virial); the totals are the locals' sums,
// formed after (GpuEngine::evaluate_local), so no cell sums are written. Candidate and interacting
// pairs are counted (each pair once: the canonical side above, or the local's side) into the flags.
template <class T, class Real, class Accum>
struct RowTileSums {
  static constexpr bool kVirials = T::kLocal && T::kObservables;
  Accum force[kWarpsPerBlock][T::kDim][32];
  Accum energy[kWarpsPerBlock][T::kObservables ? 32 : 1];
  Accum totals[kWarpsPerBlock][T::kObservables && !T::kLocal ? kCellSums : 1];
  Accum virial[kWarpsPerBlock][kVirials ? kVirialComponents : 1][kVirials ? 32 : 1];
};

// A local's half of a pair's virial, F/r = fr at separation d, added to its components w
// (core/cell_totals.h's order: xx, yy, zz, xy, xz, yz; 2D: xx, yy, xy).
template <int D, class Real, class Accum>
__device__ __forceinline__ void add_virial_share(Accum* w, Real fr, const Real* d) {
  const Real h = Real(0.5) * fr;
  w[0] += Accum(h * d[0] * d[0]);
  w[1] += Accum(h * d[1] * d[1]);
  w[3] += Accum(h * d[0] * d[1]);
  if constexpr (D == 3) {
    w[2] += Accum(h * d[2] * d[2]);
    w[4] += Accum(h * d[0] * d[2]);
    w[5] += Accum(h * d[1] * d[2]);
  }
}

template <class T, class Real, class Accum, bool Record>
__global__ void __launch_bounds__(kWarpsPerBlock * 32)
    warp_per_tile(const TraversalArgs<Real, Accum> args) {
  constexpr int D = T::kDim;
  __shared__ StagedEntry<Real> column_tiles[kWarpsPerBlock][32];
  __shared__ uint32_t column_id_tiles[kWarpsPerBlock][T::kLocal ? 32 : 1];  // ghosts: the columns' particles
  __shared__ RowTileSums<T, Real, Accum> partial;
  constexpr bool kVirials = RowTileSums<T, Real, Accum>::kVirials;
  const int warp = int(threadIdx.x / 32), lane = int(threadIdx.x % 32);
  StagedEntry<Real>* column = column_tiles[warp];
  uint32_t* column_ids = column_id_tiles[warp];
  const uint32_t first_cell = args.cell_range[0], end_cell = args.cell_range[1];
  const uint32_t w = args.tile_start[first_cell] + blockIdx.x;
  if (w >= args.tile_start[end_cell]) return;  // the whole block: the tile index is block-uniform
  uint32_t row = 0;
  const CollisionCell cell = args.cells[tile_cell(args, w, row)];
  const unsigned type = cell_type_of_id(args.grid, cell.cell);
  const LJParams<Real> single = args.table[0];
  const StagedEntry<Real>* occ = args.staged + cell.start;
  const uint32_t* ids = args.sorted_ids + cell.start;
  const uint32_t h = cell.h, m = cell.h + cell.p;
  CellTotals<Accum, true, true> totals;  // core/cell_totals.h
  unsigned long long candidates = 0, interacting = 0;
  bool impossible = false;

  const uint32_t a = row + uint32_t(lane);
  const bool a_home = a < h;
  const uint32_t ia = a < m ? ids[a] : 0;
  if (a < m && ia >= args.n) impossible = true;
  bool row_ok = a < m;
  if constexpr (T::kLocal) {
    row_ok = row_ok && ia < args.n_local;  // a ghost's row is not walked
    if (!__syncthreads_or(row_ok)) {       // block-uniform: a tile of ghosts only
      if (impossible) args.flags->impossible = 1;
      return;
    }
  }
  const StagedEntry<Real> A = row_ok ? occ[a] : StagedEntry<Real>{};
  Accum fa[D] = {};
  Accum ea = 0;
  Accum wa[kVirials ? kVirialComponents : 1] = {};
  const uint32_t columns = row >= h ? h : m;  // a tile of P rows pairs with H columns only
  for (uint32_t col = uint32_t(warp) * 32u; col < columns; col += 32u * kWarpsPerBlock) {
    const uint32_t own = col + uint32_t(lane);
    if (own < columns) {
      column[lane] = occ[own];
      if constexpr (T::kLocal) column_ids[lane] = ids[own];
    }
    __syncwarp();
    const uint32_t count = columns - col < 32u ? columns - col : 32u;
    for (uint32_t k = 0; k < count; ++k) {
      const uint32_t b = col + k;
      const StagedEntry<Real> B = column[k];  // the same address for every lane: a broadcast
      const bool b_home = b < h;
      // H x H; H x P (either way round) unless the control-bit rule gives it to another cell.
      const bool test = row_ok && b != a &&
                        (a_home ? (b_home || !skip_pair(type, control_of(A.meta), control_of(B.meta)))
                                : (b_home && !skip_pair(type, control_of(A.meta), control_of(B.meta))));
      if (!test) continue;
      // Each pair is seen from both sides; it is counted (and recorded) from one: the H side of an
      // H x P pair, the lower slot of an H x H pair.
      // With ghosts, a pair of a local and a ghost is seen from the local's side alone.
      bool canonical = a_home && (!b_home || a < b);
      if constexpr (T::kLocal) canonical = canonical || column_ids[k] >= args.n_local;
      if (canonical) ++candidates;
      Real d[3];
      const Real r2 = separation<T>(A, B, args.length, args.inv_length, d);
      Real fr, e = 0;
      if (!lj_pair<T::kMode, T::kObservables>(r2, args.rc2, pair_params<T>(args, single, A.meta, B.meta), fr, e))
        continue;
      if (canonical) ++interacting;
      if constexpr (Record) {
        if (canonical) {
          const uint32_t ib = ids[b];
          if (ia >= args.n || ib >= args.n) impossible = true;
          else record_pair(args, ia, ib);
        }
      } else {
        if (!isfinite(fr)) flag_bad_pair(args.flags, ia, ids[b]);
        for (int c = 0; c < D; ++c) fa[c] += Accum(mul_rn(fr, d[c]));  // no FMA, as warp_per_cell
        if constexpr (T::kObservables) {
          const Real half_e = Real(0.5) * e;
          ea += Accum(half_e);
          if constexpr (T::kLocal) add_virial_share<D>(wa, fr, d);
          else totals.template add<D>(half_e, Real(0.5) * fr, d);
        }
      }
    }
    __syncwarp();
  }
  if (impossible) args.flags->impossible = 1;
  if constexpr (Record || T::kLocal) add_pair_counts(args.flags, candidates, interacting, lane);
  if constexpr (!Record) {
    // The warps' partial sums, added in warp order by warp 0 (and the totals by one thread each).
    for (int c = 0; c < D; ++c) partial.force[warp][c][lane] = fa[c];
    if constexpr (kVirials)
      for (int k = 0; k < kVirialComponents; ++k) partial.virial[warp][k][lane] = wa[k];
    if constexpr (T::kObservables) partial.energy[warp][lane] = ea;
    if constexpr (T::kObservables && !T::kLocal) {
      totals.finish();
      for (int k = 0; k < kCellSums; ++k) {
        const Accum v = warp_sum(totals.v[k]);
        if (lane == 0) partial.totals[warp][k] = v;
      }
    }
    __syncthreads();
    if (warp == 0 && row_ok && ia < args.n) {
      Accum* force = args.force + type * args.force_slot_stride;
      for (int c = 0; c < D; ++c) {
        Accum f = partial.force[0][c][lane];
        for (int k = 1; k < kWarpsPerBlock; ++k) f += partial.force[k][c][lane];
        force[std::size_t(ia) * D + c] += f;
      }
      if constexpr (T::kObservables) {
        Accum e = partial.energy[0][lane];
        for (int k = 1; k < kWarpsPerBlock; ++k) e += partial.energy[k][lane];
        args.energy[type * args.energy_slot_stride + ia] += e;
      }
      if constexpr (kVirials) {
        Accum* w = args.virial + type * args.virial_slot_stride + std::size_t(ia) * kVirialComponents;
        for (int c = 0; c < kVirialComponents; ++c) {
          Accum v = partial.virial[0][c][lane];
          for (int k = 1; k < kWarpsPerBlock; ++k) v += partial.virial[k][c][lane];
          w[c] += v;
        }
      }
    }
    if constexpr (T::kObservables && !T::kLocal) {
      if (threadIdx.x < unsigned(kCellSums)) {
        Accum v = partial.totals[0][threadIdx.x];
        for (int k = 1; k < kWarpsPerBlock; ++k) v += partial.totals[k][threadIdx.x];
        args.cell_sums[std::size_t(w) * kCellSums + threadIdx.x] = v;
      }
    }
  }
}

template <class T, class Real, class Accum, bool Record>
void launch(TraversalForm form, const TraversalArgs<Real, Accum>& args, cudaStream_t stream) {
  if (args.max_cells == 0) return;
  if (form == TraversalForm::kThreadPerCell) {
    const unsigned blocks = (args.max_cells + kThreadsPerBlock - 1) / kThreadsPerBlock;
    thread_per_cell<T, Real, Accum, Record><<<blocks, kThreadsPerBlock, 0, stream>>>(args);
  } else if (form == TraversalForm::kWarpPerTile) {  // a block per row tile
    if (args.max_tiles) warp_per_tile<T, Real, Accum, Record><<<args.max_tiles, kWarpsPerBlock * 32, 0, stream>>>(args);
  } else {
    // Few cells (a small system; the bound on them): one warp per block spreads them over every
    // multiprocessor; many cells: kWarpsPerBlock per block, for more resident warps than the per-SM block limit
    // allows with one.
    const unsigned warps =
        args.max_cells <= 32u * unsigned(args.multiprocessors) ? 1u : unsigned(kWarpsPerBlock);
    const unsigned blocks = (args.max_cells + warps - 1) / warps;
    warp_per_cell<T, Real, Accum, Record>
        <<<blocks, warps * 32, warps * sizeof(ColumnTile<T, Real, Accum>), stream>>>(args);
  }
  CF_CUDA_CHECK_LAUNCH();
}

}  // namespace detail

template <class Real, class Accum>
void traverse(TraversalForm form, const Switches& sw, const TraversalArgs<Real, Accum>& args,
              cudaStream_t stream) {
  detail::dispatch(sw, [&](auto traits) {
    detail::launch<decltype(traits), Real, Accum, false>(form, args, stream);
  });
}

template <class Real, class Accum>
void traverse_local(const Switches& sw, const TraversalArgs<Real, Accum>& args, cudaStream_t stream) {
  if (args.max_cells == 0 || args.max_tiles == 0) return;
  detail::dispatch<true>(sw, [&](auto traits) {  // the tile form alone takes ghosts
    detail::warp_per_tile<decltype(traits), Real, Accum, false>
        <<<args.max_tiles, detail::kWarpsPerBlock * 32, 0, stream>>>(args);
  });
  CF_CUDA_CHECK_LAUNCH();
}

}  // namespace cellforce::cuda
