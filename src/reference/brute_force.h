// The oracle: every pair under the minimum image, in double, with no grid at all. O(n^2).
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "core/system.h"

namespace cellforce {

// Same outputs and the same errors as CpuEngine::evaluate; forces on i summed over j in index
// order, energies as half of each pair energy, virial over pairs i < j.
void brute_force(const SystemView& system, const ForceField& ff, const Request& request,
                 ForceResult& result);

// All pairs i < j with minimum-image r^2 < rc^2, sorted.
std::vector<std::pair<uint32_t, uint32_t>> brute_force_pairs(const SystemView& system,
                                                             const ForceField& ff);

}  // namespace cellforce
