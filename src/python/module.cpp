// The Python module `cellforce` (its compiled part, `cellforce._cellforce`): the public C++ API
// (include/cellforce/cellforce.hpp) with arrays in and out where the caller holds them. Each class
// is bound by its own file (bindings.h); here the module and the translation of the library's
// errors.
#include <nanobind/nanobind.h>

#include <cellforce/cellforce.hpp>

#include "arrays.h"
#include "bindings.h"

namespace nb = nanobind;

NB_MODULE(_cellforce, m) {
  m.doc() = "cellforce's compiled part: the C++ API (include/cellforce/cellforce.hpp) for Python";
  m.attr("__version__") = CELLFORCE_VERSION_STRING;
  m.attr("built_with_cuda") = cellforce::python::built_with_cuda();
  // The library's errors name the particle or parameter at fault: bad input is a ValueError, a
  // device that cannot be used a RuntimeError.
  nb::register_exception_translator([](const std::exception_ptr& p, void*) {
    try {
      std::rethrow_exception(p);
    } catch (const cellforce::DeviceError& e) {
      PyErr_SetString(PyExc_RuntimeError, e.what());
    } catch (const cellforce::Error& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    }
  });
  cellforce::python::bind_force_kernel(m);
  cellforce::python::bind_simulation(m);
}
