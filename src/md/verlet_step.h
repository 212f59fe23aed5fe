// One coordinate of a velocity Verlet or Langevin BAOAB step (md/md.h states the algorithms),
// written once for every place that integrates: the host loop (md/md.cpp advance), the CUDA
// engine's step kernels (cuda/integrate/) and the list force kernel that runs the next step's
// kick-drift after its forces (cuda/forces/list_forces.cu). Each function rounds every value the
// same way on the host and the device (a product that an add follows goes through mul_rn, so that
// nvcc does not fuse it into an FMA the host does not compute), so that every backend and every
// schedule of the same steps gives the same bits.
//
// The device half (below) reports a drift that fails its check: a kernel cannot throw, so it
// raises the smallest failing particle into MdFlags, which the host reads once per chunk of steps.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>

#include "core/box.h"  // kMaxDim, wrap_coordinate
#include "core/hd.h"   // CF_HD, mul_rn

namespace cellforce {

// v += (h / m) F for one velocity component, with hm = h / m.
CF_HD double kicked(double v, double hm, double f) { return v + mul_rn(hm, f); }

// `kicks` half kicks v += (h / m) F of velocity component va under force component fa, rounded one
// after the other (two: a step's closing half kick and the next step's opening one, as two
// separate kicks would). Returns the new component.
CF_HD double kick_value(double va, double fa, double m, double h, int kicks) {
  const double hm = h / m;
  for (int s = 0; s < kicks; ++s) va = kicked(va, hm, fa);
  return va;
}

// One axis as a drift sees it: the box edge, the largest displacement one drift may make
// (md/md.h drift_limit), 1 / length on a periodic axis (0 on an open one), and whether it wraps.
struct DriftAxis {
  double length, most, inv_length;
  bool periodic;
};

// A drift x += h v of coordinate xa: `bad` where the displacement is not finite or beyond
// axis.most; with `wrap` (a step's last drift) also where the new position is not finite, and
// otherwise the new position is wrapped into [0, L) on a periodic axis. Returns the new coordinate.
CF_HD double drift_value(double xa, double va, double h, const DriftAxis& axis, bool wrap, bool& bad) {
  const double dx = mul_rn(h, va);
  bad = !(std::fabs(dx) <= axis.most);  // also catches NaN
  xa += dx;
  if (wrap) {
    if (!std::isfinite(xa)) bad = true;
    else if (axis.periodic) xa = wrap_coordinate(xa, axis.length);
  }
  return xa;
}

// BAOAB's O step for one velocity component: v = c1 v + sigma xi, with sigma = c2 sqrt(kT / m)
// (thermostat_sigma) and xi the step's standard normal number for the coordinate
// (core/random.h counter_normal, keyed by step and the particle's stable index).
CF_HD double thermostat_sigma(double c2, double kT, double m) { return c2 * std::sqrt(kT / m); }
CF_HD double thermostat_value(double v, double c1, double sigma, double xi) { return c1 * v + sigma * xi; }

// What the device's step kernels raise: the smallest index (the caller's) of a particle whose drift
// failed (drift_value's `bad`), ~0 when none; and, for the message, the smallest drift_key() of
// those drifts: the same particle (below 2^32) with its axis and displacement.
struct MdFlags {
  unsigned long long diverged;
  unsigned long long drift;
};

// A failed drift as one 64-bit key that a minimum orders by particle, then axis: the particle
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

// The box as the device's drifts see it (a kernel parameter).
struct DriftBox {
  int dim;
  double length[kMaxDim];
  double most[kMaxDim];        // drift_limit per axis
  double inv_length[kMaxDim];  // 1 / length on periodic axes, 0 on open ones (minimum image)
  bool periodic[kMaxDim];
};

#if defined(__CUDACC__)
// Axis a of a DriftBox, picked by comparisons: a kernel parameter indexed at run time is copied to
// local memory first, one copy per thread (performance.md records what that cost the step kernels).
__device__ __forceinline__ DriftAxis drift_axis(const DriftBox& b, int a) {
  static_assert(kMaxDim == 3, "three axes to pick from");
  return a == 0   ? DriftAxis{b.length[0], b.most[0], b.inv_length[0], b.periodic[0]}
         : a == 1 ? DriftAxis{b.length[1], b.most[1], b.inv_length[1], b.periodic[1]}
                  : DriftAxis{b.length[2], b.most[2], b.inv_length[2], b.periodic[2]};
}

// A particle whose drift h * va along `axis` failed its check raises its index (the caller's) and
// the drift's key (drift_key), for the host's message.
__device__ __forceinline__ void flag_diverged(bool bad, std::size_t i, int axis, double h, double va,
                                              MdFlags* flags) {
  if (!bad) return;
  atomicMin(&flags->diverged, static_cast<unsigned long long>(i));
  const double dx = mul_rn(h, va);  // drift_value's displacement
  atomicMin(&flags->drift, drift_key(i, axis, static_cast<unsigned long long>(__double_as_longlong(dx))));
}
#endif

}  // namespace cellforce
