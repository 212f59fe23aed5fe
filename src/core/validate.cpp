// Input checks that run before any stage of the pipeline (or the brute force) touches the data.
#include <cmath>
#include <sstream>

#include "core/error.h"
#include "core/system.h"

namespace cellforce {

void validate_system(const SystemView& system, const ForceField& ff) {
  static constexpr const char* kAxis[kMaxDim] = {"x", "y", "z"};
  const Box& box = system.box;
  if (box.dim != 2 && box.dim != 3)
    throw Error("dimension is " + std::to_string(box.dim) + "; it must be 2 or 3");
  ff.validate();
  for (int a = 0; a < box.dim; ++a) {
    const double L = box.length[a];
    if (!std::isfinite(L) || (box.periodic[a] && L <= 0.0)) {
      std::ostringstream s;
      s << "box edge " << kAxis[a] << " is " << L << "; it must be finite and > 0";
      throw Error(s.str());
    }
    if (box.periodic[a] && !(ff.cutoff <= 0.5 * L)) {
      std::ostringstream s;
      s << "cutoff " << ff.cutoff << " exceeds half the periodic box edge " << kAxis[a] << " = "
        << L << " (minimum image needs rc <= L/2)";
      throw Error(s.str());
    }
  }
  if (system.n > 0 && system.positions == nullptr) throw Error("positions array is null");
  if (system.n >= (std::size_t(1) << 31))
    throw Error("too many particles: " + std::to_string(system.n));
  for (std::size_t i = 0; i < system.n; ++i) {
    for (int a = 0; a < box.dim; ++a) {
      const double x = system.positions[i * box.dim + a];
      if (!std::isfinite(x)) {
        std::ostringstream s;
        s << "particle " << i << " has a non-finite " << kAxis[a] << " coordinate (" << x << ")";
        throw Error(s.str());
      }
    }
    if (system.types && system.types[i] >= ff.num_types()) {
      std::ostringstream s;
      s << "particle " << i << " has type index " << system.types[i] << " but there are "
        << ff.num_types() << " types";
      throw Error(s.str());
    }
  }
}

void throw_close_pair(const SystemView& system, uint32_t i, uint32_t j, double r2) {
  std::ostringstream s;
  s.precision(17);
  if (r2 == 0.0)
    s << "particles " << i << " and " << j << " are at the same position";
  else
    s << "particles " << i << " and " << j << " are too close (r = " << std::sqrt(r2)
      << "): the Lennard-Jones force is not finite in this precision";
  const int dim = system.box.dim;
  s << "; positions";
  for (uint32_t k : {i, j}) {
    s << " (";
    for (int a = 0; a < dim; ++a) s << (a ? ", " : "") << system.positions[std::size_t(k) * dim + a];
    s << ")";
  }
  throw Error(s.str());
}

}  // namespace cellforce
