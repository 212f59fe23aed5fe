// Stage 4, traversal = narrow phase, and stage 5, accumulation, on the GPU: the kernels' argument
// blocks and launchers. Everything a scene may leave out (2D vs 3D, wrap inside a one-cell
// periodic axis, multiple types, cutoff mode, energy and virial) is a template switch, chosen once
// per evaluation by the launcher (traversal_impl.cuh); traversal_{single,mixed,double}.cu
// instantiate one precision each so that the builds run side by side.
#pragma once

#include <cuda_runtime.h>

#include <cstddef>
#include <cstdint>

#include "core/engine_options.h"  // TraversalForm
#include "search/cells.cuh"

namespace cellforce::cuda {

// Device input (compute_device): raises flags->bad_coordinate for the first particle with a
// coordinate that is not finite and flags->bad_type for the first with a type index >= num_types
// (types may be null: all type 0).
void check_input(const double* positions, const uint32_t* types, std::size_t n, int dim,
                 uint32_t num_types, DeviceFlags* flags, cudaStream_t stream);

// Runs the traversal over args.cells in the given form.
template <class Real, class Accum>
void traverse(TraversalForm form, const Switches& sw, const TraversalArgs<Real, Accum>& args,
              cudaStream_t stream);

// The tile form's traversal with ghosts: particles args.n_local .. args.n - 1 are ghosts, which get
// no slots and no pair of two of which is tested; each local's forces, and with sw.observables its
// half of each pair's energy and virial (args.virial), go to its slots; candidate and interacting
// pairs are counted in args.flags; no cell sums. Needs args.tile_start (tile_starts) and max_tiles.
template <class Real, class Accum>
void traverse_local(const Switches& sw, const TraversalArgs<Real, Accum>& args, cudaStream_t stream);

// The same candidate loop in double, recording each pair with r < rc in args.pairs and counting
// candidates and interacting pairs in args.flags, instead of evaluating LJ.
void record_pairs(TraversalForm form, int dim, bool wrap, const TraversalArgs<double, double>& args,
                  cudaStream_t stream);

// Stage 5: sums each particle's `copies` slots in slot order into forces (n x dim doubles) and,
// when energy_slots is non-null, energies (n doubles).
template <class Accum>
void sum_slots(const Accum* force_slots, const Accum* energy_slots, int dim, std::size_t n,
               int copies, double* forces, double* energies, cudaStream_t stream);

// With ghosts: each local's `copies` virial slots (kVirialComponents each, stride n_local x
// kVirialComponents) summed in slot order into virials (n_local x kVirialComponents doubles).
template <class Accum>
void sum_virial_slots(const Accum* virial_slots, std::size_t n_local, int copies, double* virials,
                      cudaStream_t stream);

// Sums the per-cell energy and virial over cells [0, *count) (count in device memory) in a fixed
// order into totals[kCellSums].
// skip: as ListArgs::skip (device memory or null: nonzero, nothing is written).
template <class Accum>
void sum_cells(const Accum* cell_sums, const uint32_t* count, double* totals, cudaStream_t stream,
               const unsigned long long* skip = nullptr);

// The totals of sum_cells to a device energy (1 double) and row-major dim x dim virial, either
// of which may be null; the virial's unused entries (dim < 3) are not written.
void write_totals(const double* totals, int dim, double* energy, double* virial, cudaStream_t stream);

}  // namespace cellforce::cuda
