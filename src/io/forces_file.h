// The output of `cellforce forces`: one HDF5 file with the forces, per-particle energies, total
// energy and virial of one configuration, plus attributes that say how they were computed.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "core/system.h"

namespace cellforce {

using AttributeValue = std::variant<std::string, double, int64_t, std::vector<double>>;
using Attributes = std::vector<std::pair<std::string, AttributeValue>>;

// Writes /forces (n x dim, float64, the user's particle order), /energies (n), /energy (scalar),
// /virial (dim x dim) and the attributes on the root group. The file is written under a temporary
// name and renamed when complete, so that a failed run never leaves a file that looks finished.
void write_forces_file(const std::string& path, const ForceResult& result, std::size_t n,
                       const Attributes& attributes);

}  // namespace cellforce
