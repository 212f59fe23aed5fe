// Input checks that run before any stage of the pipeline (or the brute force) touches the data.
#include <cmath>
#include <sstream>

#include "core/engine_options.h"  // to_string(Precision)
#include "core/error.h"
#include "core/memory.h"
#include "core/system.h"
#include "core/text.h"

namespace cellforce {

void validate_physics(const Box& box, const ForceField& ff, std::size_t n) {
  static constexpr const char* kAxis[kMaxDim] = {"x", "y", "z"};
  if (box.dim != 2 && box.dim != 3)
    throw Error("dimension is " + std::to_string(box.dim) + "; it must be 2 or 3");
  ff.validate();
  for (int a = 0; a < box.dim; ++a) {
    const double L = box.length[a];
    if (!std::isfinite(L) || (box.periodic[a] && L <= 0.0)) {
      std::ostringstream s;
      s << "box edge " << kAxis[a] << " is " << format_number(L) << "; it must be finite and > 0";
      throw Error(s.str());
    }
    if (box.periodic[a] && !(ff.cutoff <= 0.5 * L)) {
      std::ostringstream s;
      s << "cutoff " << format_number(ff.cutoff) << " exceeds half the periodic box edge " << kAxis[a]
        << " = " << format_number(L) << " (minimum image needs rc <= L/2)";
      throw Error(s.str());
    }
  }
  if (n > kMaxParticles) throw Error("too many particles: " + std::to_string(n));
}

void validate_system(const SystemView& system, const ForceField& ff) {
  static constexpr const char* kAxis[kMaxDim] = {"x", "y", "z"};
  const Box& box = system.box;
  validate_physics(box, ff, system.n);
  if (system.n > 0 && system.positions == nullptr) throw Error("positions array is null");
  for (std::size_t i = 0; i < system.n; ++i) {
    for (int a = 0; a < box.dim; ++a) {
      const double x = system.positions[i * box.dim + a];
      if (!std::isfinite(x)) {
        std::ostringstream s;
        s << "particle " << i << " has a non-finite " << kAxis[a] << " coordinate (" << format_number(x) << ")";
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

void throw_close_pair(const SystemView& system, uint32_t i, uint32_t j, double r2, const ForceField* ff,
                      Precision precision) {
  // The distance in double, from the positions wrapped exactly into the box: "the same position"
  // is said only when the two points are the same; otherwise the working-precision r^2 that made
  // the force not finite is shown beside the exact distance.
  const Box& box = system.box;
  const int dim = box.dim;
  double exact2 = 0;
  for (int a = 0; a < dim; ++a) {
    const double inv = box.periodic[a] ? 1.0 / box.length[a] : 0.0;
    const double d = separation(system.positions[std::size_t(i) * dim + a],
                                system.positions[std::size_t(j) * dim + a], box.length[a], inv);
    exact2 += d * d;
  }
  std::string s = "particles " + std::to_string(i) + " and " + std::to_string(j);
  if (exact2 == 0.0) {
    s += " are at the same position";
  } else {
    s += " are too close (r = " + format_number(std::sqrt(exact2));
    if (r2 != exact2) s += ", " + format_number(std::sqrt(r2)) + " in the working precision";
    const std::size_t ti = system.types ? system.types[i] : 0, tj = system.types ? system.types[j] : 0;
    if (!ff || ti >= ff->num_types() || tj >= ff->num_types()) {
      s += "): the Lennard-Jones force is not finite in this precision";
    } else {
      // The evaluator forms F(r) / r ~ 48 eps / sigma^2 (sigma / r)^14 near contact (in double here:
      // inf where double overflows too), and each of its factors is below it there.
      const double r = std::sqrt(exact2), sigma = ff->pair_sigma(ti, tj), eps = ff->pair_epsilon(ti, tj);
      const double force = 48.0 * eps / (sigma * sigma) * std::pow(sigma / r, 14.0);
      const std::string pair = ti == tj ? "type " + quote_excerpt(ff->types[ti].name)
                                        : "pair " + quote_excerpt(ff->types[std::min(ti, tj)].name) + "-" +
                                              quote_excerpt(ff->types[std::max(ti, tj)].name);
      const bool in_float = precision != Precision::kDouble;
      s += ", " + format_number(r / sigma) + " sigma with sigma " + format_number(sigma) + " of " + pair +
           "): the Lennard-Jones force over the distance there, F/r ~ " + format_number(force) + ", is beyond " +
           (in_float ? std::string(to_string(precision)) + " precision's float range (~3.4e38)"
                     : std::string("double's range")) +
           "; if sigma of " + pair + " is right, the particles overlap (minimise first" +
           (in_float && std::isfinite(force) ? ", or use double precision)" : ")") +
           ", else correct sigma of " + pair;
    }
  }
  bool outside = false;
  auto point = [&](uint32_t k, bool wrapped) {
    std::string p = "(";
    for (int a = 0; a < dim; ++a) {
      double x = system.positions[std::size_t(k) * dim + a];
      if (wrapped && box.periodic[a]) {
        const double w = wrap_coordinate(x, box.length[a]);
        outside = outside || w != x;
        x = w;
      }
      p += (a ? ", " : "") + format_number(x);
    }
    return p + ")";
  };
  s += "; positions in the box " + point(i, true) + " " + point(j, true);
  if (outside) s += ", given as " + point(i, false) + " " + point(j, false);
  throw Error(s);
}

}  // namespace cellforce
