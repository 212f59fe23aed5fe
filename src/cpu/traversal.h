// Stage 4, traversal = narrow phase, and the arrays it writes (stage 5's Jacobi slots).
#pragma once

#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "core/force_field.h"
#include "core/grid.h"
#include "core/system.h"
#include "core/cell_totals.h"  // kVirialComponents
#include "cpu/engine.h"
#include "cpu/stages.h"

namespace cellforce::cpu {


// What the traversal writes, in the accumulation type.
template <class Accum>
struct Accumulators {
  // Jacobi: 2^d slots x n x dim, slot T at offset T * n * dim, particle i's slot T written by the
  // one collision cell of type T that i occupies. Gauss-Seidel: n x dim, added to pass by pass.
  std::vector<Accum> force;
  std::vector<Accum> energy;       // same layout with one component; empty unless energy
  std::vector<Accum> virial;       // local: same layout with kVirialComponents, each particle's half
                                   // of its pairs' virials; empty unless virial and local
  std::vector<Accum> cell_energy;  // per collision cell: sum of its pair energies
  std::vector<Accum> cell_virial;  // per collision cell x kVirialComponents
};

struct TraversalInput {
  const Grid& grid;
  const SystemView& system;
  const ForceField& ff;
  const uint32_t* sorted_ids;       // particle index of each sorted entry
  const Control* control;           // per particle, user order
  const std::vector<CollisionCell>& cells;
  const std::vector<std::size_t>& type_start;  // Gauss-Seidel: start of each type's cells
  // compute_local: particles n_local .. n - 1 are ghosts (pairs of two are skipped), and energy and
  // virial are summed per particle instead of per cell. Without: n_local is n.
  bool local = false;
  std::size_t n_local = 0;
};

struct TraversalReport {
  std::size_t candidates = 0;   // pairs tested after the control-bit rule
  std::size_t interacting = 0;  // pairs with r < rc
  std::size_t max_occupancy = 0;
  bool bad = false;  // a pair gave a non-finite force (coincident or overflowing)
  uint32_t bad_i = 0, bad_j = 0;
  double bad_r2 = 0;
};

template <class Real, class Accum>
TraversalReport traverse(const TraversalInput& in, const Request& request, Accumulation mode,
                         Accumulators<Accum>& out);

// The same candidate loop in double, recording each pair with r < rc as (min, max) instead of
// evaluating it (with in.local, no pair of two ghosts).
std::vector<std::pair<uint32_t, uint32_t>> traverse_pairs(const TraversalInput& in);

// Stage 5: sums the 2^d slots of each particle in slot order (Jacobi) or copies the single
// accumulator (Gauss-Seidel), and the per-cell energies and virials in cell order.
template <class Accum>
void accumulate(const Accumulators<Accum>& acc, Accumulation mode, int dim, std::size_t n,
                const Request& request, ForceResult& result);

// Stage 5 of a local traversal: the slots of particles 0 .. n_local - 1 (of n) only, summed as
// accumulate() does, into result sized for them (forces, energies, per-particle virials n_local x
// dim x dim); the totals are the sums of the locals' energies and virials in index order.
template <class Accum>
void accumulate_local(const Accumulators<Accum>& acc, Accumulation mode, int dim, std::size_t n,
                      std::size_t n_local, const Request& request, ForceResult& result);

}  // namespace cellforce::cpu
