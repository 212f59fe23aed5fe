// Box geometry shared by the CPU path, the GPU kernels and the tests: per-axis periodicity, wrap
// into [0, L) and minimum image. Open axes carry an inverse length of zero so that the same
// branch-free expression leaves them untouched.
#pragma once

#include <cmath>

#include "core/hd.h"

namespace cellforce {

inline constexpr int kMaxDim = 3;

// What the user describes: dimension, edge lengths, and which axes wrap. On an open axis the
// length is only informative (particles may lie anywhere); the grid then covers their bounding box.
struct Box {
  int dim = 3;
  double length[kMaxDim] = {1.0, 1.0, 1.0};
  bool periodic[kMaxDim] = {true, true, true};

  bool any_periodic() const {
    for (int a = 0; a < dim; ++a)
      if (periodic[a]) return true;
    return false;
  }
  double volume() const {
    double v = 1.0;
    for (int a = 0; a < dim; ++a) v *= length[a];
    return v;
  }
};

// Wrap x into [0, L), exactly for any finite x: the remainder fmod(x, L) is always representable,
// so a coordinate far outside the box (an unwrapped trajectory; x = 1e16 in a box of 10) lands on
// the point that the value given is modulo L, not one an inexact quotient x / L picks. Only adding
// L to a negative remainder rounds, once; rounding can turn a tiny negative remainder into exactly
// L (x = -1e-8 in float), which is mapped to 0, the same point modulo L. Not-finite x stays so.
template <class Real>
CF_HD Real wrap_coordinate(Real x, Real length) {
  if (x >= Real(0) && x < length) return x;  // inside already: the common case costs one test
  if (!(x - x == Real(0))) return x;          // inf or nan: left for the caller's checks to name
  Real w = std::fmod(x, length);
  if (w < Real(0)) w += length;
  return w >= length ? Real(0) : w + Real(0);  // + 0: x = -k L gives fmod -0, returned as +0
}

// Minimum image of a separation along one axis; inv_length == 0 marks an open axis (no change).
// Exact only while dx / L is well below 2^52 / L; separation() holds for any coordinates.
template <class Real>
CF_HD Real minimum_image(Real dx, Real length, Real inv_length) {
  return dx - mul_rn(length, std::rint(dx * inv_length));
}

// Minimum-image separation xi - xj along one axis (inv_length == 0: open, the plain difference).
// Each coordinate is wrapped exactly first, so coordinates far outside the box (x = 1e16 in a box
// of 10) give the separation of the points they are modulo L, not a difference that has lost
// their digits.
template <class Real>
CF_HD Real separation(Real xi, Real xj, Real length, Real inv_length) {
  if (inv_length == Real(0)) return xi - xj;
  return minimum_image(wrap_coordinate(xi, length) - wrap_coordinate(xj, length), length, inv_length);
}

// One axis's share of a particle's squared displacement from `then` to `now` (a rounded square:
// no FMA with the sum over axes). Summed over axes in order, from 0, it gives the reuse check's
// number with the same bits on the host, in the device's reduction and in the step gate.
CF_HD double displacement_term(double now, double then, double length, double inv_length) {
  const double d = separation(now, then, length, inv_length);
  return mul_rn(d, d);
}

}  // namespace cellforce
