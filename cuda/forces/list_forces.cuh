// The evaluations a pair list serves (search/pair_list.cuh): the list force kernel, and in a gated
// Verlet chunk the next step's kick-drift after the forces (forces/fused_step.h).
#pragma once

#include <cuda_runtime.h>

#include "forces/fused_step.h"
#include "search/pair_list.cuh"
#include "search/step_gate.h"

namespace cellforce::cuda {

// Gathers the positions into rank order (FixedParticle for float pairs where fixed_point_serves,
// else RankedParticle) and evaluates every listed pair with r < rc: forces (and
// energies) to the user-order outputs, energy and virial per block into list.block_sums, whose
// count list.blocks holds (for sum_cells). With a gate (search/step_gate.h) the force kernel
// returns at once when it is shut for gate.step, else raises the gate's served displacement.
// With a gate the evaluation is a gated MD step's, whose drift placed the positions in the gathered
// array already (rank_order): the gather is left out. With `by_rank` (forces only), the forces go to
// list.ranked_forces in rank order (rank p's at p * dim) instead of args.forces in user order: the
// force kernel's stores coalesced whatever the caller's numbering.
// With `then` (a gate, forces only, the next array reserved: rank_order's `fused`), the force kernel
// runs the next gated step's kick-drift with the forces it summed (NextKickDrift, on the
// chunk's rank-order state; the gate's test is then the next step's first kernel's,
// step_gate_shut, which closes the gate) and stores no forces: it places the new positions in the
// next array, which then becomes the one the evaluations read.
template <class Real, class Accum>
void list_forces(const Switches& sw, const ListArgs<Real, Accum>& args, PairList& list, cudaStream_t stream,
                 const GateView& gate = {}, bool by_rank = false, const NextKickDrift* then = nullptr);

}  // namespace cellforce::cuda
