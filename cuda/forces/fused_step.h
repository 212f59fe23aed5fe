// What the list force kernel needs to run the next step's velocity Verlet kick-drift after its
// forces (cuda/forces/list_forces.cu, a gated Verlet chunk in fast memory: the force and the
// kick-drift in one kernel). The arithmetic is md/verlet_step.h's, the same as the step kernels'
// (cuda/integrate/gated_steps.cu), so that a fused chunk is the stepwise run bit for bit. Plain
// C++: backend/engine.h includes it.
#pragma once

#include <cstdint>

#include "md/verlet_step.h"  // DriftBox, MdFlags

namespace cellforce::cuda {

// The next gated step's kick-drift: the step's closing half kick and the next one's opening half
// kick v += (h / m) F with the forces the kernel just summed, the drift x += dt v with the wrap and
// the check, the displacement from `built` into the gate's slot of the next step, and the new
// positions into the list's other rank-ordered array, which the next evaluation reads. The arrays
// are the gated chunk's copy of the state in the list's rank order (n x dim; mass n).
struct NextKickDrift {
  double* x = nullptr;
  double* v = nullptr;
  const double* mass = nullptr;     // n, or null: every mass is mass_value
  const double* built = nullptr;    // the positions the structure in use was built from
  const uint32_t* order = nullptr;  // n: the particle (the caller's index) of rank p, for the flags
  double h = 0;                     // half the time step
  double dt = 0;
  DriftBox box{};
  MdFlags* flags = nullptr;
  double mass_value = 0;  // every particle's mass where `mass` is null
};

}  // namespace cellforce::cuda
