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

// Per type pair, in a length unit lambda of its own: lambda = 2^k, the power of two at or below the
// pair's sigma (1 <= sigma / lambda < 2), so that r^2 / lambda^2 is r^2 * inv_s2 without rounding.
// The evaluator works with q = lambda^2 / r^2 (near 1 at contact) and constants of epsilon's size
// in that unit (e12 < 2^14 eps, f12 < 48 x 2^12 eps / lambda^2), which keeps every intermediate of
// a float evaluation inside float's range for any sigma with r^2 normal (sigma^12 or r^-12 in the pair's own units would leave it: sigma = 3.4e-10 m has
// sigma^12 ~ 1e-113), and makes the float result the same as that of the system in reduced
// units, roundings and all, whatever its length scale.
//   F(r) / r = f12 q^7 - f6 q^4      f12 = 48 eps (sigma / lambda)^12 / lambda^2
//                                     f6  = 24 eps (sigma / lambda)^6  / lambda^2
//   U(r)     = e12 q^6 - e6 q^3      e12 = 4 eps (sigma / lambda)^12, e6 = 4 eps (sigma / lambda)^6
// A pair with sigma = 0 or epsilon = 0 does not interact: its constants are 0 (lambda from rc).
template <class Real>
struct LJParams {
  Real inv_s2 = 1;  // 1 / lambda^2, a power of two
  Real f12 = 0;
  Real f6 = 0;
  Real e12 = 0;
  Real e6 = 0;
  Real u_rc = 0;  // U(rc), subtracted by shift and force shift
  Real f_rc = 0;  // F(rc), subtracted by force shift
  Real rc = 0;    // the cutoff, used by force shift's energy
};

// Builds the parameters of one pair in double and rounds them once to Real. In double the
// constants are near 1 too; in float they must also be normal floats, which check_precision_range
// (core/force_field.h) checks before any evaluation.
template <class Real>
LJParams<Real> make_lj_params(double sigma, double epsilon, double cutoff, CutoffMode mode) {
  const int k = std::ilogb(sigma > 0.0 ? sigma : cutoff);  // lambda = 2^k (the cutoff's for sigma = 0)
  const bool interacts = sigma > 0.0 && epsilon > 0.0;
  const double s = std::ldexp(sigma, -k);            // sigma / lambda, in [1, 2)
  const double inv_l2 = std::ldexp(1.0, -2 * k);     // 1 / lambda^2
  const double s6 = interacts ? s * s * s * s * s * s : 0.0;
  const double e12 = 4.0 * epsilon * s6 * s6;
  const double e6 = 4.0 * epsilon * s6;
  // U(rc) and F(rc) in the caller's units; sigma / rc stays near 1 for any length scale.
  const double x6 = interacts ? std::pow(sigma / cutoff, 6.0) : 0.0;
  const double u_rc = 4.0 * epsilon * (x6 * x6 - x6);
  const double f_rc = 24.0 * epsilon * (2.0 * x6 * x6 - x6) / cutoff;
  LJParams<Real> p;
  p.inv_s2 = Real(inv_l2);
  p.f12 = Real(12.0 * e12 * inv_l2);
  p.f6 = Real(6.0 * e6 * inv_l2);
  p.e12 = Real(e12);
  p.e6 = Real(e6);
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
// `s` is r2 in the pair's length unit (r2 * p.inv_s2, exact); lj_terms forms it, and a caller
// whose separations are already in that unit passes s = r2 (with constants for it). F(r) / r =
// (f12 q^7 - f6 q^4) is formed as q^4 (f12 q^3 - f6): a multiply-add and two multiplies after
// q^3. The energy, when asked, is (e12 q^3 - e6) q^3 beside it, so that the force is the same
// expression (the same bits) whether or not the energy is asked for.
template <CutoffMode Mode, bool Energy, class Real>
CF_HD void lj_terms_at(Real r2, Real s, const LJParams<Real>& p, Real& force_over_r, Real& energy) {
  const Real q = reciprocal(s);
  const Real q3 = q * q * q;
  Real fr = (q3 * q) * (p.f12 * q3 - p.f6);
  if constexpr (Energy) energy = (p.e12 * q3 - p.e6) * q3;
  if constexpr (Mode == CutoffMode::kForceShift) {
    const Real r = std::sqrt(r2);
    fr -= p.f_rc / r;
    if constexpr (Energy) energy = energy - p.u_rc + (r - p.rc) * p.f_rc;
  } else if constexpr (Mode == CutoffMode::kShift) {
    if constexpr (Energy) energy -= p.u_rc;
  }
  force_over_r = fr;
}

template <CutoffMode Mode, bool Energy, class Real>
CF_HD void lj_terms(Real r2, const LJParams<Real>& p, Real& force_over_r, Real& energy) {
  lj_terms_at<Mode, Energy>(r2, r2 * p.inv_s2, p, force_over_r, energy);
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
