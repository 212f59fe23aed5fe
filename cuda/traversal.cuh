// Stage 4, traversal = narrow phase, and stage 5, accumulation, on the GPU: the kernels' argument
// blocks and launchers. Everything a scene may leave out (2D vs 3D, wrap inside a one-cell
// periodic axis, multiple types, cutoff mode, energy and virial) is a template switch, chosen once
// per evaluation by the launcher (traversal_impl.cuh); traversal_{single,mixed,double}.cu
// instantiate one precision each so that the builds run side by side.
#pragma once

#include <cuda_runtime.h>

#include <cstddef>
#include <cstdint>

#include "core/grid.h"
#include "core/cell_totals.h"
#include "core/lj.h"
#include "device_buffer.cuh"
#include "engine.h"

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

// Device input (compute_device): raises flags->bad_coordinate for the first particle with a
// coordinate that is not finite and flags->bad_type for the first with a type index >= num_types
// (types may be null: all type 0).
void check_input(const double* positions, const uint32_t* types, std::size_t n, int dim,
                 uint32_t num_types, DeviceFlags* flags, cudaStream_t stream);

// For the tile form (a block per row tile): tile_start[c] for c in [0, cell_bound] = the row tiles (ceil(m / 32)
// for a cell of m occupants) of the collision cells before c, cells beyond the count
// (counts->cell_range[1]) having none, so tile_start[cell_bound] is the number of tiles. `scratch`
// grows as CUB asks.
void tile_starts(const CollisionCell* cells, const uint32_t* cell_range, std::size_t cell_bound,
                 uint32_t* tile_start, DeviceBuffer<std::byte>& scratch, cudaStream_t stream);
// A bound on the tiles: sum over cells of ceil(m / 32) <= entries / 32 + cells.
inline std::size_t max_tiles(std::size_t entries, std::size_t cell_bound) { return entries / 32 + cell_bound + 1; }

// Runs the traversal over args.cells in the given form.
template <class Real, class Accum>
void traverse(TraversalForm form, const Switches& sw, const TraversalArgs<Real, Accum>& args,
              cudaStream_t stream);

// The same candidate loop in double, recording each pair with r < rc in args.pairs and counting
// candidates and interacting pairs in args.flags, instead of evaluating LJ.
void record_pairs(TraversalForm form, int dim, bool wrap, const TraversalArgs<double, double>& args,
                  cudaStream_t stream);

// Stage 5: sums each particle's `copies` slots in slot order into forces (n x dim doubles) and,
// when energy_slots is non-null, energies (n doubles).
template <class Accum>
void sum_slots(const Accum* force_slots, const Accum* energy_slots, int dim, std::size_t n,
               int copies, double* forces, double* energies, cudaStream_t stream);

// Sums the per-cell energy and virial over cells [0, *count) (count in device memory) in a fixed
// order into totals[kCellSums].
template <class Accum>
void sum_cells(const Accum* cell_sums, const uint32_t* count, double* totals, cudaStream_t stream);

// The totals of sum_cells to a device energy (1 double) and row-major dim x dim virial, either
// of which may be null; the virial's unused entries (dim < 3) are not written.
void write_totals(const double* totals, int dim, double* energy, double* virial, cudaStream_t stream);

}  // namespace cellforce::cuda
