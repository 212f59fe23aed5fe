// One FIRE step's arithmetic per particle (md/minimize.h describes the algorithm), written once for
// minimize_fire on host arrays and for the CUDA engine's FIRE kernels
// (cuda/integrate/fire_kernels.cu): given the same forces and the same scalars (dt, alpha, the sums
// v^2 and F^2), both move every particle by the same bits. A product that an add follows goes
// through mul_rn, so that nvcc does not fuse it into an FMA that the host does not compute.
#pragma once

#include <cmath>

#include "core/hd.h"

namespace cellforce {

// An uphill step's step back: x -= half_dt v, then v = 0 (one particle, dim coordinates).
CF_HD void fire_step_back(double* x, double* v, double half_dt, int dim) {
  for (int a = 0; a < dim; ++a) {
    x[a] = x[a] - mul_rn(half_dt, v[a]);
    v[a] = 0.0;
  }
}

// The kick of the semi-implicit Euler step: v += (dt / m) F.
CF_HD void fire_kick(double* v, const double* f, double dt, double mass, int dim) {
  const double h = dt / mass;
  for (int a = 0; a < dim; ++a) v[a] = v[a] + mul_rn(h, f[a]);
}

// The mixing factor alpha |v| / |F| from v2 = sum v^2 and f2 = sum F^2 over every coordinate,
// into `mix`; false (no mixing) when there is no force or v2 is not finite.
CF_HD bool fire_mix_factor(double alpha, double v2, double f2, double& mix) {
  if (!(f2 > 0 && v2 - v2 == 0.0)) return false;  // v2 - v2 == 0: finite (as box.h tests it)
  mix = alpha * std::sqrt(v2) / std::sqrt(f2);
  return true;
}

// The velocity mixing: v = (1 - alpha) v + mix F.
CF_HD void fire_mix(double* v, const double* f, double alpha, double mix, int dim) {
  for (int a = 0; a < dim; ++a) v[a] = mul_rn(1 - alpha, v[a]) + mul_rn(mix, f[a]);
}

// The displacement cap: a velocity that would carry the particle further than max_displacement in
// dt is scaled down to that length. |v| as largest component x norm of the scaled vector, so that
// no square overflows.
CF_HD void fire_cap(double* v, double dt, double max_displacement, int dim) {
  double largest = 0;
  for (int a = 0; a < dim; ++a) {
    const double c = std::fabs(v[a]);
    largest = largest < c ? c : largest;  // std::max's choice: a NaN component is passed over
  }
  if (!(largest > 0)) return;
  double u2 = 0;
  for (int a = 0; a < dim; ++a) {
    const double u = v[a] / largest;
    u2 = u2 + mul_rn(u, u);
  }
  const double step_length = dt * largest * std::sqrt(u2);
  if (step_length > max_displacement) {
    const double scale = max_displacement / step_length;
    for (int a = 0; a < dim; ++a) v[a] *= scale;
  }
}

// The drift: x += dt v.
CF_HD void fire_drift(double* x, const double* v, double dt, int dim) {
  for (int a = 0; a < dim; ++a) x[a] = x[a] + mul_rn(dt, v[a]);
}

}  // namespace cellforce
