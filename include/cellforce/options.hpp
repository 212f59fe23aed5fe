// The physics and arithmetic choices shared by the public API and the engine underneath it: one
// definition of each enumeration.
#pragma once

#include <cstdint>

namespace cellforce {

// Arithmetic of the pair interactions / accumulation of their results.
enum class Precision : uint8_t {
  kSingle,  // float pairs, float sums
  kMixed,   // float pairs, double sums
  kDouble,  // double pairs, double sums
};

// What happens at the cutoff rc (pairs with r >= rc never interact):
//   kTruncate:   U(r) = U_LJ(r)
//   kShift:      U(r) = U_LJ(r) - U_LJ(rc)                          (energy continuous)
//   kForceShift: U(r) = U_LJ(r) - U_LJ(rc) + (r - rc) F_LJ(rc)      (force continuous)
enum class CutoffMode : uint8_t { kTruncate, kShift, kForceShift };

// How the Lennard-Jones parameters of a pair of types are made from those of the types (an
// explicit pair value replaces the rule for its pair).
enum class Mixing : uint8_t {
  kLorentzBerthelot,  // sigma_ij = (sigma_i + sigma_j) / 2, eps_ij = sqrt(eps_i eps_j)
  kGeometric,         // sigma_ij = sqrt(sigma_i sigma_j),   eps_ij = sqrt(eps_i eps_j)
};

// Where the engine runs.
enum class Backend : uint8_t {
  kAuto,  // a CUDA device when one can be used, else the CPU
  kCpu,   // OpenMP threads on the host
  kCuda,  // a CUDA device
};

}  // namespace cellforce
