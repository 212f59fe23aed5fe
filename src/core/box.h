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

// Wrap x into [0, L). Rounding can turn a tiny negative x into exactly L (x = -1e-8 in float);
// that value is mapped to 0, which is the same point modulo L.
template <class Real>
CF_HD Real wrap_coordinate(Real x, Real length, Real inv_length) {
  Real w = x - mul_rn(length, std::floor(x * inv_length));
  return (w >= length || w < Real(0)) ? Real(0) : w;
}

// Minimum image of a separation along one axis; inv_length == 0 marks an open axis (no change).
template <class Real>
CF_HD Real minimum_image(Real dx, Real length, Real inv_length) {
  return dx - mul_rn(length, std::rint(dx * inv_length));
}

}  // namespace cellforce
