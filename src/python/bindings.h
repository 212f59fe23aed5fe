// The Python module's classes, each bound into the module by its own file.
#pragma once

#include <nanobind/nanobind.h>

namespace cellforce::python {

void bind_force_kernel(nanobind::module_& m);  // ForceKernel, Result (force_kernel.cpp)
void bind_simulation(nanobind::module_& m);    // SimulationCore (simulation.cpp; cellforce/simulation.py)

}  // namespace cellforce::python
