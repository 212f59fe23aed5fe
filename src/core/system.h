// What a force evaluation reads and writes, in the user's particle order.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <cellforce/options.hpp>  // Scalar

#include "core/box.h"
#include "core/cell_totals.h"  // the virial layout
#include "core/force_field.h"

namespace cellforce {

// A non-owning view of the particles.
struct SystemView {
  Box box;
  std::size_t n = 0;
  const double* positions = nullptr;  // n x box.dim, row-major, length units, any periodic image
  const uint32_t* types = nullptr;    // n indices into ForceField::types; null means all type 0
};

// The particles of a device evaluation: device pointers, the caller's order and layout as in
// SystemView (positions n x dim doubles, types n or null).
struct DeviceSystemView {
  Box box;
  std::size_t n = 0;
  const double* positions = nullptr;
  const uint32_t* types = nullptr;
};

// A caller's device arrays as it holds them (Context::compute_device): positions as n rows of
// `stride` elements (0: dim) of float64 or float32, the first dim used; types as in
// DeviceSystemView (an int32 array passes as uint32: a negative index reads as one out of range).
struct DeviceInput {
  Box box;
  std::size_t n = 0;
  const void* positions = nullptr;
  Scalar scalar = Scalar::kFloat64;
  std::size_t stride = 0;
  const uint32_t* types = nullptr;
  // Packed float64 rows: the engine computes on them as they are.
  bool packed() const { return scalar == Scalar::kFloat64 && (stride == 0 || stride == std::size_t(box.dim)); }
};

// Where a device evaluation writes: device pointers; forces (n x dim) always, the others when not
// null: per-particle energies (n), total energy (1), virial (dim x dim, row-major).
struct DeviceOutputs {
  double* forces = nullptr;
  double* energies = nullptr;
  double* energy = nullptr;
  double* virial = nullptr;
};

// Which observables to compute. Forces are always computed; energy and virial cost arithmetic
// and are left out (at compile time) when nobody reads them.
struct Request {
  bool energy = true;
  bool virial = true;
};

struct ForceResult {
  int dim = 3;
  std::vector<double> forces;    // n x dim, row-major, user order, energy/length units
  std::vector<double> energies;  // n, half of each pair energy; empty unless energy requested
  double energy = 0;             // total potential energy; 0 unless requested
  double virial[kMaxDim][kMaxDim] = {};  // sum over pairs of r_ij (x) f_ij, r_ij = x_i - x_j
                                         // (minimum image), f_ij the force on i from j; the
                                         // dim x dim block is used; 0 unless requested
  // Local evaluations (ForceEngine::evaluate_local) only: each local's half of its pairs' virials,
  // n_local x dim x dim row-major; empty unless virial requested.
  std::vector<double> virials;
};

// Stores the six virial components w = (xx, yy, zz, xy, xz, yz) as the symmetric dim x dim block
// of result.virial, zero elsewhere (2D uses xx, yy, xy). Shared by the engines' accumulation.
inline void set_virial(ForceResult& result, int dim, const double w[kVirialComponents]) {
  for (auto& row : result.virial)
    for (double& v : row) v = 0;
  for (int k = 0; k < kVirialComponents; ++k) {
    const int r = virial_row(k), c = virial_col(k);
    if (r >= dim || c >= dim) continue;
    result.virial[r][c] = result.virial[c][r] = w[k];
  }
}

// Rejects bad input before any kernel runs; throws cellforce::Error naming the particle (index),
// axis or parameter: non-finite coordinates, non-positive or non-finite box edges, cutoff not
// positive or beyond half a periodic edge, type index out of range, bad force-field values.
void validate_system(const SystemView& system, const ForceField& ff);
// The checks of validate_system that need no array: the dimension, the force field, the box edges
// and the cutoff against them, the particle count (for arrays that live on a device).
void validate_physics(const Box& box, const ForceField& ff, std::size_t n);

// The error for a pair whose force is not finite: coincident (r2 == 0) or so close that the
// Lennard-Jones force overflows in the precision used. Names both particles and their positions,
// and, given the force field, the pair's sigma, the distance in sigmas and the force's size against
// the precision's range, so that a sigma far from the particles' spacing (a unit slip) is named as
// the cause rather than the particles.
[[noreturn]] void throw_close_pair(const SystemView& system, uint32_t i, uint32_t j, double r2,
                                   const ForceField* ff = nullptr, Precision precision = Precision::kDouble);

}  // namespace cellforce
