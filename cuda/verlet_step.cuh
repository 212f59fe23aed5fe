// The device arithmetic of a velocity Verlet kick-drift (verlet_step.h): the MD engine's kernels
// (cuda/md_engine.cu) and the gated force kernel that runs the next step's kick-drift (change 59,
// cuda/pair_list.cu) round every value the same way, so that a gated run is the stepwise run bit
// for bit.
#pragma once

#include <cmath>
#include <cstddef>

#include "core/box.h"  // wrap_coordinate
#include "core/hd.h"   // mul_rn
#include "verlet_step.h"

namespace cellforce::cuda {

// v += (h / m) F, per coordinate (rounded product, then sum: the same bits in every kernel that kicks).
__device__ __forceinline__ double kicked(double v, double hm, double f) { return v + mul_rn(hm, f); }

// `kicks` half kicks v += (h / m) F of one velocity component va under its force component fa (two:
// a step's closing one, deferred, and the next step's opening one, rounded one after the other as
// two launches of one would). Returns the new component.
__device__ __forceinline__ double kick_value(double va, double fa, double m, double h, int kicks) {
  const double hm = h / m;
  for (int s = 0; s < kicks; ++s) va = kicked(va, hm, fa);
  return va;
}

// Axis a of a DriftBox, picked by comparisons: a kernel parameter indexed at run time is copied to
// local memory first (each thread's own copy: Nsight Compute found the gated kick-drift's local
// loads and stores at 1 useful byte of 32 a sector; without them the kernel went from 111 to 70.5
// us at 1M particles on an H200, performance.md change 20).
struct DriftAxis {
  double length, most, inv_length;
  bool periodic;
};
__device__ __forceinline__ DriftAxis drift_axis(const DriftBox& b, int a) {
  static_assert(kMaxDim == 3, "three axes to pick from");
  return a == 0   ? DriftAxis{b.length[0], b.most[0], b.inv_length[0], b.periodic[0]}
         : a == 1 ? DriftAxis{b.length[1], b.most[1], b.inv_length[1], b.periodic[1]}
                  : DriftAxis{b.length[2], b.most[2], b.inv_length[2], b.periodic[2]};
}

// A drift x += h v of one coordinate xa on `axis`, the displacement checked as the host's drift()
// checks it (`bad` where it fails); with `wrap` (a step's last drift) the new position is wrapped
// into [0, L) on a periodic axis. Returns the new coordinate.
__device__ __forceinline__ double drift_value(double xa, double va, double h, const DriftAxis& axis, bool wrap,
                                              bool& bad) {
  const double dx = mul_rn(h, va);
  bad = !(fabs(dx) <= axis.most);  // also catches NaN
  xa += dx;
  if (wrap) {
    if (!isfinite(xa)) bad = true;
    else if (axis.periodic) xa = wrap_coordinate(xa, axis.length);
  }
  return xa;
}

// A particle whose drift h * va along `axis` failed the check raises its index (the caller's) and
// the drift's key (drift_key), for the message.
__device__ __forceinline__ void flag_diverged(bool bad, std::size_t i, int axis, double h, double va,
                                              MdFlags* flags) {
  if (!bad) return;
  atomicMin(&flags->diverged, static_cast<unsigned long long>(i));
  const double dx = mul_rn(h, va);  // drift_value's displacement
  atomicMin(&flags->drift, drift_key(i, axis, static_cast<unsigned long long>(__double_as_longlong(dx))));
}

}  // namespace cellforce::cuda
