// Pair lists for a reused structure (ReuseOptions::list, CUDA): the traversal of a build records,
// for every particle, the partners the cell search finds within rc + skin, and the evaluations
// the structure serves walk those lists instead of the cells' candidates.
//
// Why: a collision cell's candidates fill a volume of (c + 2h)^3 ~ 32 rc^3 around each H occupant
// (c >= rc + h, h = rc / sqrt(2)), of which the cutoff sphere is 4.2 rc^3: 85-95% of the tests
// fail. The build's list holds the pairs within rc + skin only, (1 + skin/rc)^3 of the useful ones.
//
// Layout. Particles are numbered by rank: the order of their H entries in the sorted cell-ID array,
// so that ranks run cell by cell and a particle's partners have nearby ranks. The list of rank p
// is the concatenation, in cell-type order, of the partners found from its row in its cell of
// each type (the Jacobi slots' structure: one writer per particle and type, condition 1), each in
// the cell's occupant order; stored column-major, neighbors[k * n + p], so that a warp's threads
// read consecutive words. Every pair is in both partners' lists: each thread sums the whole force
// on its own particle, in its list's fixed order, with no atomics (bitwise reproducible).
//
// Exactness: the build keeps exactly the pairs with r < rc + skin in double (positions by minimum
// image; the staged coordinates decide wherever their rounding cannot matter), so a pair
// closer than rc now, with no particle moved more than skin / 2, is in the list; every
// evaluation tests r < rc again.
#pragma once

#include <cuda_runtime.h>

#include <cstddef>
#include <cstdint>

#include "step_gate.h"
#include "traversal.cuh"

namespace cellforce::cuda {

// A particle's position (wrapped into the box on periodic axes) and type, in rank order.
struct alignas(32) RankedParticle {
  double x, y, z;
  uint32_t type;
  uint32_t unused;
};

struct PairList {
  DeviceBuffer<uint32_t> order;        // n: the particle of rank p
  DeviceBuffer<uint32_t> rank;         // n: the rank of particle i
  DeviceBuffer<uint32_t> slot_counts;  // n x 2^d: partners of rank p found in its cell of type t
  DeviceBuffer<uint32_t> length;       // n: partners of rank p
  DeviceBuffer<uint32_t> neighbors;    // width x n: neighbors[k * n + p], the rank of p's k-th partner
  DeviceBuffer<RankedParticle> ranked; // n: gathered at every evaluation
  DeviceBuffer<unsigned long long> sizes;  // 2: the longest list and the sum of the lengths
  DeviceBuffer<uint32_t> selected;     // 1: CUB's count of H entries (n)
  DeviceBuffer<uint32_t> blocks;       // 1: the force kernel's blocks (their sums' count)
  DeviceBuffer<std::byte> block_sums;  // kCellSums per block of the force kernel
  DeviceBuffer<std::byte> scratch;     // CUB
  std::size_t width = 0, pairs = 0;    // of the last build (pairs: the sum of the lengths)
  int threads_per_particle = 1;        // the force kernel's: 1, 2, 4 or 8 (from n and the device)

  template <class F>
  void for_each_buffer(F&& f) {
    f(order), f(rank), f(slot_counts), f(length), f(neighbors), f(ranked), f(sizes), f(selected), f(blocks);
    f(block_sums), f(scratch);
  }
};

// What the list kernels read besides the list.
template <class Real, class Accum>
struct ListArgs {
  Grid grid;                       // its length / inv_length: minimum image on periodic axes
  std::size_t n = 0;
  const double* positions = nullptr;   // n x dim, user order
  const uint32_t* types = nullptr;     // n or null (all type 0)
  uint32_t num_types = 1;
  const LJParams<Real>* table = nullptr;
  Real rc2 = 0;
  double* forces = nullptr;            // n x dim, user order (written, not added to)
  double* energies = nullptr;          // n or null: half of each pair's energy
  DeviceFlags* flags = nullptr;
};

// Builds the list from the structure just built (cells: its cells, tile starts, sorted IDs and
// occupants staged at the positions of `list_args`) for partners closer than list_cutoff. Synchronises the stream once, to read the longest list and size the array.
// Returns false, leaving no list, when the column-major array would hold more than twice the
// pairs plus 64 per particle (a few very crowded particles): the caller then traverses the cells.
template <class Real, class Accum>
bool build_pair_list(const TraversalArgs<Real, Accum>& cells, const uint32_t* sorted_keys, std::size_t entries, double list_cutoff,
                     const ListArgs<Real, Accum>& list_args, PairList& list, cudaStream_t stream);

// Gathers the positions into rank order and evaluates every listed pair with r < rc: forces (and
// energies) to the user-order outputs, energy and virial per block into list.block_sums, whose
// count list.blocks holds (for sum_cells). With a gate (step_gate.h) both kernels return at once
// when it is shut for gate.step.
template <class Real, class Accum>
void list_forces(const Switches& sw, const ListArgs<Real, Accum>& args, PairList& list, cudaStream_t stream,
                 const GateView& gate = {});

}  // namespace cellforce::cuda
