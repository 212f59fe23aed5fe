// The Lennard-Jones pair evaluator: the one place where the LJ maths and its cutoff contract live.
// Loops that apply it (CPU traversal, CUDA kernels, brute force) know nothing about LJ.
//
// Cutoff contract: a pair interacts only when r^2 < rc^2 (strict, as OpenMM); a pair at exactly
// r = rc contributes nothing. With F(r) = -dU/dr and U(r) = 4 eps [(sigma/r)^12 - (sigma/r)^6]:
//   truncate:    U_c(r) = U(r)                              F_c(r) = F(r)
//   shift:       U_c(r) = U(r) - U(rc)                      F_c(r) = F(r)
//   force shift: U_c(r) = U(r) - U(rc) + (r - rc) F(rc)     F_c(r) = F(r) - F(rc)
// so that shift makes U continuous at rc and force shift makes both U and F continuous there.
#pragma once

#include <cmath>
#include <cstdint>

#include <cellforce/options.hpp>  // CutoffMode (its contract is the one above)

#include "core/hd.h"

namespace cellforce {

// Per type pair: c12 = 4 eps sigma^12, c6 = 4 eps sigma^6, and the constants that the cutoff mode
// needs (zero where it needs none).
template <class Real>
struct LJParams {
  Real c12 = 0;
  Real c6 = 0;
  Real u_rc = 0;  // U(rc), subtracted by shift and force shift
  Real f_rc = 0;  // F(rc), subtracted by force shift
  Real rc = 0;    // the cutoff, used by force shift's energy
};

// Builds the parameters of one pair in double and rounds them once to Real.
template <class Real>
LJParams<Real> make_lj_params(double sigma, double epsilon, double cutoff, CutoffMode mode) {
  const double s6 = std::pow(sigma, 6.0);
  const double c12 = 4.0 * epsilon * s6 * s6;
  const double c6 = 4.0 * epsilon * s6;
  const double ir6 = 1.0 / std::pow(cutoff, 6.0);
  const double u_rc = (c12 * ir6 - c6) * ir6;
  const double f_rc = (12.0 * c12 * ir6 - 6.0 * c6) * ir6 / cutoff;
  LJParams<Real> p;
  p.c12 = Real(c12);
  p.c6 = Real(c6);
  p.u_rc = mode == CutoffMode::kTruncate ? Real(0) : Real(u_rc);
  p.f_rc = mode == CutoffMode::kForceShift ? Real(f_rc) : Real(0);
  p.rc = Real(cutoff);
  return p;
}

// 1 / x. On the device in float: the reciprocal estimate refined by one Newton step, which is
// what nvcc emits for 1 / x when x is normal and below 2^126, and there it is the correctly
// rounded quotient, bitwise 1 / x; nvcc adds a range test and a branch to a slow path for the
// rest: ~9 of the ~50 instructions of a pair in the list force kernel, and a branch that keeps
// the kernel's cutoff test from being a select. At 2^126 it is 2^-126, still 1 / x. Beyond that
// range it is not 1 / x: NaN for x = 0 or subnormal (coincident particles: 1 / x is inf or beyond
// float's range, and the pair's force is not finite either way, so it is flagged as before), 0
// above 2^126 and NaN at inf (never inside a cutoff: every caller tests or selects the cutoff).
// The host, and double, divide.
template <class Real>
CF_HD Real reciprocal(Real x) {
#if defined(__CUDA_ARCH__)
  if constexpr (sizeof(Real) == sizeof(float)) {
    float r;
    asm("rcp.approx.ftz.f32 %0, %1;" : "=f"(r) : "f"(x));
    const float e = __fmaf_rn(x, r, -1.0f);
    return __fmaf_rn(r, -e, r);
  }
#endif
  return Real(1) / x;
}

// The pair terms at squared distance r2 > 0, with no cutoff test: force_over_r = F_c(r) / r, so
// that the force on i is force_over_r * (x_i - x_j), and, when Energy, the pair energy U_c(r).
// Mode and Energy are compile-time so that the unused arithmetic is not there at all.
// F(r) / r = (12 c12 r^-12 - 6 c6 r^-6) r^-2 is formed as r^-8 (12 c12 r^-6 - 6 c6): with 12 c12
// and 6 c6 constant over a loop's pairs, that is a multiply-add and two multiplies after r^-6, three
// instructions fewer a pair than forming c12 r^-12 and c6 r^-6 first (change 44). The energy, when
// asked, is (c12 r^-6 - c6) r^-6 beside it, so that the force is the same expression (the same
// bits) whether or not the energy is asked for.
template <CutoffMode Mode, bool Energy, class Real>
CF_HD void lj_terms(Real r2, const LJParams<Real>& p, Real& force_over_r, Real& energy) {
  const Real ir2 = reciprocal(r2);
  const Real ir6 = ir2 * ir2 * ir2;
  Real fr = (ir6 * ir2) * (Real(12) * p.c12 * ir6 - Real(6) * p.c6);
  if constexpr (Energy) energy = (p.c12 * ir6 - p.c6) * ir6;
  if constexpr (Mode == CutoffMode::kForceShift) {
    const Real r = std::sqrt(r2);
    fr -= p.f_rc / r;
    if constexpr (Energy) energy = energy - p.u_rc + (r - p.rc) * p.f_rc;
  } else if constexpr (Mode == CutoffMode::kShift) {
    if constexpr (Energy) energy -= p.u_rc;
  }
  force_over_r = fr;
}

// Evaluates one pair under the cutoff contract. Returns false (and leaves the outputs alone) when
// r2 >= rc2; otherwise sets the outputs as lj_terms does.
template <CutoffMode Mode, bool Energy, class Real>
CF_HD bool lj_pair(Real r2, Real rc2, const LJParams<Real>& p, Real& force_over_r, Real& energy) {
  if (!(r2 < rc2)) return false;
  lj_terms<Mode, Energy>(r2, p, force_over_r, energy);
  return true;
}

}  // namespace cellforce
