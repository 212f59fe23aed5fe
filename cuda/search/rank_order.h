// Where a gated MD step's last drift puts each particle for its evaluation's list kernels: the
// pair list's rank order, written as the evaluation's gather would write it (the same values:
// search/rank_order.cuh place_ranked), so that the gated evaluation needs no gather kernel; and
// where those evaluations leave the forces.
// Plain C++: backend/engine.h includes it.
#pragma once

#include <cstdint>

#include "core/grid.h"

namespace cellforce::cuda {

struct DeviceFlags;

struct RankOrder {
  const uint32_t* rank = nullptr;   // n: the rank of particle i in the list in use
  const uint32_t* order = nullptr;  // n: the particle of rank p (rank's inverse)
  void* particles = nullptr;        // n: FixedParticle (fixed) or RankedParticle, as list_forces reads them
  bool fixed = false;
  Grid grid{};                      // the structure's: the wrap and the fixed-point scale
  const uint32_t* types = nullptr;  // n or null (all type 0)
  uint32_t num_types = 1;
  DeviceFlags* flags = nullptr;     // a coordinate that is not finite is flagged here
  // n x dim or null: where the gated evaluations leave the forces, rank p's at p * dim (the force
  // kernel's stores coalesced whatever the caller's numbering; the next step's kick, on the chunk's
  // rank-order copy of the state, reads rank p's; a Verlet chunk's fused evaluations store none).
  // Null (lean memory): they go to the user-order forces.
  double* forces = nullptr;
};

}  // namespace cellforce::cuda
