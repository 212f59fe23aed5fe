// The collision cells as every walk over them reads them: the staged occupants, the argument block
// of the walks (the traversal kernels of forces/ and the pair-list build of search/list_build.cu
// take the same one), the flags kernels raise, and the device helpers both walks share (staging an
// entry, the tile a warp walks, the separation of two staged occupants, the switch from run-time
// choices to one template instantiation). Stage 3 (search/stages.cuh) makes the cells; this header
// is how the stages after it see them.
#pragma once

#include <cuda_runtime.h>

#include <cstddef>
#include <cstdint>
#include <type_traits>

#include "core/cell_totals.h"
#include "core/grid.h"
#include "core/lj.h"
#include "device_buffer.cuh"

namespace cellforce::cuda {

// Per collision cell the traversal writes its pair-energy sum and the six virial components
// (core/cell_totals.h's layout), so that the totals are summed in a fixed order afterwards.
inline constexpr int kCellSums = kCellTotals;

// One occupant of a collision cell in sorted order, staged by stage_occupants(): its position
// relative to the centre of the cell it occupies (formed in double, then rounded to Real, so that
// r_ij keeps its digits far from the origin and needs no wrap when a periodic axis has two or more
// cells), and meta = control bits | type index << 16.
template <class Real>
struct StagedEntry;
template <>
struct alignas(32) StagedEntry<float> {
  float x, y, z;
  uint32_t meta;
  float lx, ly, lz;  // the lo parts of StagedCoordinate<float> (core/grid.h)
  uint32_t unused;
};
template <>
struct alignas(32) StagedEntry<double> {
  double x, y, z;
  uint32_t meta, unused;
};
inline constexpr uint32_t kMaxStagedTypes = 1u << 16;

// Raised by kernels, read by the host when it synchronises (kernels never abort).
struct DeviceFlags {
  unsigned long long bad_pair;     // min over pairs with a non-finite force of min(i,j) << 32 | max(i,j); ~0 if none
  unsigned long long bad_coordinate;  // device input: min over particles with a non-finite coordinate of i << 32 | axis; ~0 if none
  unsigned long long bad_type;     // device input: min over particles with a type index out of range of i << 32 | type; ~0 if none
  unsigned long long candidates;   // record mode: pairs tested after the control-bit rule
  unsigned long long interacting;  // record mode: pairs with r < rc
  unsigned long long recorded;     // record mode: pairs found (may exceed the buffer: the host grows it and reruns)
  unsigned int impossible;         // nonzero: a particle index out of range (a bug, never bad input)
  unsigned int unused;
};

// Everything a traversal kernel reads and writes (device pointers). Jacobi: slot t of particle i
// at force[t * force_slot_stride + i * dim] (force_slot_stride = n * dim), written only by the one
// collision cell of type t that i occupies. Gauss-Seidel: force_slot_stride = 0, one launch per
// cell type. The cells a launch covers are cells[range[0]] .. cells[range[1] - 1], with the range
// in device memory (stage 3's counts); the launch is shaped for max_cells (>= range[1] - range[0]).
template <class Real, class Accum>
struct TraversalArgs {
  Grid grid;
  const CollisionCell* cells = nullptr;  // every collision cell
  const uint32_t* cell_range = nullptr;  // device: this launch's [first, end)
  uint32_t max_cells = 0;                // host: a bound on the launch's cells
  // Tile form (a block per row tile): tile_start[c] = the row tiles (of 32 occupants) of cells before c, over
  // max_cells + 1 entries (the last: every tile), from tile_starts(); max_tiles bounds them.
  const uint32_t* tile_start = nullptr;
  uint32_t max_tiles = 0;
  const StagedEntry<Real>* staged = nullptr;  // sorted order, as the cells' start counts
  const uint32_t* sorted_ids = nullptr;       // particle index of each sorted entry
  std::size_t n = 0;
  const LJParams<Real>* table = nullptr;      // num_types x num_types
  uint32_t num_types = 1;
  Real rc2 = 0;
  Real length[kMaxDim] = {0, 0, 0};      // nonzero only on a periodic axis with one cell
  Real inv_length[kMaxDim] = {0, 0, 0};
  Accum* force = nullptr;
  std::size_t force_slot_stride = 0;
  Accum* energy = nullptr;               // per particle, same slots with one component
  std::size_t energy_slot_stride = 0;
  Accum* cell_sums = nullptr;            // kCellSums per cell
  // Local and ghost particles (traverse_local): particles n_local .. n - 1 are ghosts, which get no
  // slots; each local's half of its pairs' virials, kVirialComponents a slot, at
  // virial[t * virial_slot_stride + i * kVirialComponents] (core/cell_totals.h's order).
  std::size_t n_local = 0;
  Accum* virial = nullptr;
  std::size_t virial_slot_stride = 0;
  DeviceFlags* flags = nullptr;
  uint2* pairs = nullptr;                // record mode: (i, j) of each pair with r < rc
  std::size_t pair_capacity = 0;
  int multiprocessors = 1;               // launch shape only: the device's SM count
};

// The run-time choices that pick one kernel instantiation.
struct Switches {
  int dim = 3;
  bool wrap = false;         // some periodic axis has a single cell
  bool multi_type = false;
  CutoffMode mode = CutoffMode::kTruncate;
  bool observables = false;  // energy and virial (on the GPU they come together)
};

// Stages the first *valid (device memory) of the `entries` sorted entries: one thread per entry.
// A type index >= num_types (bad device input, flagged by check_input) is staged as type 0.
template <class Real>
void stage_occupants(const Grid& grid, const uint32_t* sorted_keys, const uint32_t* sorted_ids,
                     std::size_t entries, const unsigned long long* valid, const double* positions,
                     const uint32_t* types, uint32_t num_types, const Control* control,
                     StagedEntry<Real>* staged, cudaStream_t stream);

// For the tile form (a block per row tile): tile_start[c] for c in [0, cell_bound] = the row tiles (ceil(m / 32)
// for a cell of m occupants) of the collision cells before c, cells beyond the count
// (counts->cell_range[1]) having none, so tile_start[cell_bound] is the number of tiles. `scratch`
// grows as CUB asks.
void tile_starts(const CollisionCell* cells, const uint32_t* cell_range, std::size_t cell_bound,
                 uint32_t* tile_start, DeviceBuffer<std::byte>& scratch, cudaStream_t stream);
// A bound on the tiles: sum over cells of ceil(m / 32) <= entries / 32 + cells.
inline std::size_t max_tiles(std::size_t entries, std::size_t cell_bound) { return entries / 32 + cell_bound + 1; }

namespace detail {

// Local: the evaluation has ghosts (traverse_local), which only the tile form takes.
template <int D, bool Wrap, bool MultiType, CutoffMode Mode, bool Observables, bool Local = false>
struct Traits {
  static constexpr int kDim = D;
  static constexpr bool kWrap = Wrap;
  static constexpr bool kMultiType = MultiType;
  static constexpr CutoffMode kMode = Mode;
  static constexpr bool kObservables = Observables;
  static constexpr bool kLocal = Local;
};

constexpr uint32_t kControlMask = 0xffffu;

__device__ __forceinline__ Control control_of(uint32_t meta) { return Control(meta & kControlMask); }

// Sorted entry e as staged: particle i's position relative to the centre of the entry's cell,
// formed in double (the shared core's relative_coordinate(), as the CPU stages it) and rounded to
// the pair precision, with its control bits and type. The one definition behind stage_kernel and
// the pair-list build (which stages its columns as it loads them, with no staged array).
template <class Real>
__device__ __forceinline__ StagedEntry<Real> stage_entry(const Grid& grid, uint32_t key, uint32_t i,
                                                         const double* __restrict__ positions,
                                                         const uint32_t* __restrict__ types, uint32_t num_types,
                                                         const Control* __restrict__ control) {
  int k[kMaxDim];
  cell_coords(grid, key_cell(key, grid.slab_bits), k);
  StagedCoordinate<Real> r[kMaxDim] = {};
  for (int a = 0; a < grid.dim; ++a)
    r[a] = StagedCoordinate<Real>::from(relative_coordinate(
        grid, a, positions[std::size_t(i) * grid.dim + a], cell_center(grid, a, k[a])));
  StagedEntry<Real> s{};
  s.x = r[0].hi;
  s.y = r[1].hi;
  s.z = r[2].hi;
  if constexpr (StagedCoordinate<Real>::kCompensated) {
    s.lx = r[0].lo;
    s.ly = r[1].lo;
    s.lz = r[2].lo;
  }
  const uint32_t type = types ? types[i] : 0u;
  s.meta = uint32_t(control[i]) | (type < num_types ? type : 0u) << 16;
  return s;
}
__device__ __forceinline__ uint32_t type_of(uint32_t meta) { return meta >> 16; }

// d = x_a - x_b (minimum image along axes that need it inside a cell); returns r^2.
template <class T, class Real>
__device__ __forceinline__ Real separation(const StagedEntry<Real>& a, const StagedEntry<Real>& b,
                                           const Real* length, const Real* inv_length, Real d[3]) {
  d[0] = a.x - b.x;
  d[1] = a.y - b.y;
  d[2] = T::kDim == 3 ? a.z - b.z : Real(0);
  if constexpr (StagedCoordinate<Real>::kCompensated) {
    d[0] += a.lx - b.lx;
    d[1] += a.ly - b.ly;
    if constexpr (T::kDim == 3) d[2] += a.lz - b.lz;
  }
  if constexpr (T::kWrap)
    for (int c = 0; c < T::kDim; ++c) d[c] = minimum_image(d[c], length[c], inv_length[c]);
  Real r2 = d[0] * d[0] + d[1] * d[1];
  if constexpr (T::kDim == 3) r2 += d[2] * d[2];
  return r2;
}

__device__ __forceinline__ void flag_bad_pair(DeviceFlags* flags, uint32_t i, uint32_t j) {
  const unsigned long long lo = i < j ? i : j, hi = i < j ? j : i;
  atomicMin(&flags->bad_pair, lo << 32 | hi);
}

// A warp's butterfly sum: the same tree every time, so the result is reproducible.
template <class V>
__device__ __forceinline__ V warp_sum(V v) {
  for (int offset = 16; offset > 0; offset >>= 1) v += __shfl_xor_sync(0xffffffffu, v, offset);
  return v;
}

// The collision cell holding row tile w of the launch's cells and the tile's first row: the last c
// in [cell_range[0], cell_range[1]) with tile_start[c] <= w (every collision cell has at least one
// tile, so tile_start increases strictly over the cells). Shared by the tile form and the pair
// lists' build (search/list_build.cu).
template <class Real, class Accum>
__device__ __forceinline__ uint32_t tile_cell(const TraversalArgs<Real, Accum>& args, uint32_t w, uint32_t& row) {
  uint32_t lo = args.cell_range[0], hi = args.cell_range[1];
  while (hi - lo > 1) {
    const uint32_t mid = lo + (hi - lo) / 2;
    if (args.tile_start[mid] <= w) lo = mid;
    else hi = mid;
  }
  row = (w - args.tile_start[lo]) * 32u;
  return lo;
}

template <class F>
void with_bool(bool b, F&& f) {
  if (b) f(std::true_type{});
  else f(std::false_type{});
}

// Turns the run-time choices into one Traits instantiation (Local: of the ghosts' kernels).
template <bool Local = false, class F>
void dispatch(const Switches& sw, F&& f) {
  auto with_mode = [&](auto d, auto w, auto m) {
    auto go = [&](auto cm) {
      with_bool(sw.observables, [&](auto o) {
        f(Traits<decltype(d)::value, decltype(w)::value, decltype(m)::value, decltype(cm)::value,
                 decltype(o)::value, Local>{});
      });
    };
    switch (sw.mode) {
      case CutoffMode::kTruncate: go(std::integral_constant<CutoffMode, CutoffMode::kTruncate>{}); break;
      case CutoffMode::kShift: go(std::integral_constant<CutoffMode, CutoffMode::kShift>{}); break;
      case CutoffMode::kForceShift: go(std::integral_constant<CutoffMode, CutoffMode::kForceShift>{}); break;
    }
  };
  auto with_dim = [&](auto d) {
    with_bool(sw.wrap, [&](auto w) { with_bool(sw.multi_type, [&](auto m) { with_mode(d, w, m); }); });
  };
  if (sw.dim == 2) with_dim(std::integral_constant<int, 2>{});
  else with_dim(std::integral_constant<int, 3>{});
}

}  // namespace detail
}  // namespace cellforce::cuda
