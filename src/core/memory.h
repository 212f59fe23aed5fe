// Sizes checked before anything is allocated: a scene of 32 billion particles, or one that needs
// more memory than the machine has, is refused with the key that asked for it, the particle count
// and the bytes, instead of growing until a bare std::bad_alloc.
#pragma once

#include <cstddef>
#include <new>
#include <string>

#include "core/error.h"

namespace cellforce {

// The most particles one evaluation takes: object IDs are 32-bit and the sort key keeps a bit.
inline constexpr std::size_t kMaxParticles = (std::size_t(1) << 31) - 1;

// The bytes a run certainly holds per particle in a `dim`-dimensional scene, a lower bound:
// positions, velocities and forces in double, mass and type, and the cell structure's 2^dim
// cell-ID and object-ID entries with their sorted copies. The Jacobi slots and the backends'
// working arrays come on top, so a scene refused by this estimate cannot run.
std::size_t bytes_per_particle(int dim);

// The memory this process may use in bytes: the machine's physical memory, or its cgroup's limit
// (a container, a batch job) when that is lower; 0 where neither can be read.
std::size_t physical_memory();

// Throws cellforce::Error when `n` particles (a double: products of counts may exceed any
// integer) are more than kMaxParticles or need more than the physical memory by the estimate
// above. `what` names where the count comes from ("[particles] cells = [2000, 2000, 2000]").
void check_particle_count(double n, int dim, const std::string& what);

// Runs `allocate` and turns a std::bad_alloc it throws into a cellforce::Error that says what
// was being allocated (`what`), for the sizes the estimate lets through.
template <class F>
auto reporting_bad_alloc(const std::string& what, F&& allocate) -> decltype(allocate()) {
  try {
    return allocate();
  } catch (const std::bad_alloc&) {
    throw Error("out of memory while " + what);
  }
}

}  // namespace cellforce
