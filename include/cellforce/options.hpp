// The physics and arithmetic choices shared by the public API and the engine underneath it: one
// definition of each enumeration.
#pragma once

#include <cstdint>

#include <cellforce/version.h>

namespace cellforce {
inline namespace CELLFORCE_ABI_NAMESPACE {  // v<MAJOR>: version.h

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

// Settings of the CUDA engine (options `traversal`, `sort`, `memory`); the CPU engine has none of
// these stages' variants and ignores them. None changes which pairs are summed.

// How the CUDA traversal maps collision cells onto threads.
enum class TraversalForm : uint8_t {
  kWarpPerCell,    // cooperative: a warp shares one cell, occupants staged 32 at a time in shared
                   // memory, partial sums added in a fixed order (the chapter's future work)
  kThreadPerCell,  // the chapter's: one thread walks one collision cell
  kWarpPerTile,    // a block per tile of 32 occupants of a cell, its warps sharing the columns,
                   // each pair from both sides (no writes but its own rows): parallel work for
                   // small systems
  kAuto,           // chosen by the engine at each build from the cells and the device
};

// The CUDA pipeline's stage 2; both are stable and sort only the bits the grid needs.
enum class SortMethod : uint8_t {
  kCub,      // CUB's device radix sort
  kChapter,  // the chapter's three-phase radix sort (tabulate, prefix sums, stable reorder)
};

// The CUDA pair lists' memory mode. Lean: no staged array of the cells' own, the sort's arrays in
// the dead list's room, the count pass's masks only in the memory the device has left (~700 bytes a
// particle against fast's ~1,300, up to ~930 with every mask; builds up to ~2x slower where the
// masks find no room); auto: lean where fast would not fit in 90% of the device.
enum class ListMemory : uint8_t { kAuto, kFast, kLean };

// Element types of a caller's arrays (cellforce.hpp Positions and Types; C: cf_compute_layout).
enum class Scalar : uint8_t { kFloat64, kFloat32 };
enum class Index : uint8_t { kUInt32, kInt32 };

}  // namespace CELLFORCE_ABI_NAMESPACE
}  // namespace cellforce
