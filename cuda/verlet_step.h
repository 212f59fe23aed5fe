// A velocity Verlet step's kick-drift on the device, as the MD engine's kernels run it
// (cuda/md_engine.cu) and as a gated evaluation's force kernel runs the next step's (change 59:
// cuda/pair_list.cu, the force and the kick-drift in one kernel). The device arithmetic is in
// verlet_step.cuh; this header holds what the host passes. Plain C++: engine.h includes it.
#pragma once

#include <cstddef>
#include <cstdint>

#include "core/box.h"  // kMaxDim
#include "core/hd.h"   // CF_HD

namespace cellforce::cuda {

// What the integration kernels raise: the smallest index (the caller's) of a particle whose drift
// diverged (a displacement not finite or beyond md/md.h's drift_limit, or a position no longer
// finite), ~0 when none; and, for the message, the smallest drift_key() of those drifts: the same
// particle (below 2^32) with its axis and displacement.
struct MdFlags {
  unsigned long long diverged;
  unsigned long long drift;
};

// A failed drift as one 64-bit key that an atomicMin orders by particle, then axis: the particle
// (saturated at 2^32 - 1) in bits 32-63, the axis in bits 30-31, and the displacement's sign,
// exponent and 18 leading mantissa bits (its double's top 30 bits: 6 digits, enough for a message;
// infinities and quiet NaNs kept) in bits 0-29.
CF_HD constexpr unsigned long long drift_key(unsigned long long particle, int axis,
                                              unsigned long long displacement_bits) {
  return (particle < 0xffffffffull ? particle : 0xffffffffull) << 32 | (unsigned long long)(axis & 3) << 30 |
         displacement_bits >> 34;
}
CF_HD constexpr unsigned long long drift_key_particle(unsigned long long key) { return key >> 32; }
CF_HD constexpr int drift_key_axis(unsigned long long key) { return int((key >> 30) & 3); }
CF_HD constexpr unsigned long long drift_key_displacement_bits(unsigned long long key) {
  return (key & 0x3fffffffull) << 34;
}

// The box as a drift sees it.
struct DriftBox {
  int dim;
  double length[kMaxDim];
  double most[kMaxDim];        // largest displacement allowed per axis (md/md.h's drift_limit)
  double inv_length[kMaxDim];  // 1 / length on periodic axes, 0 on open ones (minimum image)
  bool periodic[kMaxDim];
};

// The next gated step's Verlet kick-drift, for the force kernel of this step's gated evaluation to
// run after its forces (change 59): the previous step's closing half kick and the next one's
// opening half kick v += (h / m) F with the forces it just summed, the drift x += dt v with the
// wrap and the check, the displacement from `built` into the gate's slot of the next step, and the
// new positions into the list's other rank-ordered array, which the next evaluation reads. The
// arrays are the gated chunk's copy of the state in the list's rank order (change 58; n x dim,
// mass n).
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
  double mass_value = 0;  // every particle's mass where `mass` is null (change 60)
};

}  // namespace cellforce::cuda
