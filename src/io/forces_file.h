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
// One-dimensional float64 datasets written beside the results (e.g. per-repeat timings, which
// can outgrow HDF5's 64 KiB limit on an attribute).
using Series = std::vector<std::pair<std::string, std::vector<double>>>;

// Writes /forces (n x dim, float64, the user's particle order), /energies (n), /energy (scalar),
// /virial (dim x dim), the series, and the attributes on the root group. The file is written
// under a fresh temporary name beside `path` and renamed when complete, so that a failed run
// never leaves a file that looks finished, and an existing file at `path` is replaced only by a
// complete one.
void write_forces_file(const std::string& path, const ForceResult& result, std::size_t n,
                       const Attributes& attributes, const Series& series = {});

}  // namespace cellforce
