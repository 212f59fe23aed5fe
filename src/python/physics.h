// The physics a ForceKernel or a Simulation is given, into its Context, read one way for both:
// the box (2 or 3 edges), which axes wrap (any sequence of truth values: a list, NumPy's bools,
// ASE's atoms.pbc; None: all), the cutoff and its mode, the mixing rule, the types ({name: (sigma,
// epsilon)}, indexed in the dict's order; None: one type 'A' (1, 1)) and explicit pairs ({(a, b):
// (sigma, epsilon)}). TypeError or ValueError name the argument; the library's refusals are its
// errors (ValueError through the module's translator).
#pragma once

#include <nanobind/nanobind.h>

#include <cellforce/cellforce.hpp>

#include <string>
#include <vector>

namespace cellforce::python {

// The dimension a box gives (2 or 3), or a ValueError naming `box`.
int box_dim(const std::vector<double>& box);

struct Physics {
  std::vector<std::string> names;  // the types in index order
  std::vector<bool> periodic;      // one per axis
};
Physics set_physics(cellforce::Context& ctx, const std::vector<double>& box, nanobind::handle periodic,
                    double cutoff, const std::string& mode, const std::string& mixing, nanobind::handle types,
                    nanobind::handle pairs);

}  // namespace cellforce::python
