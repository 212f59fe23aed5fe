#include "physics.h"

#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>

#include <algorithm>
#include <utility>

namespace cellforce::python {

namespace nb = nanobind;

int box_dim(const std::vector<double>& box) {
  if (box.size() != 2 && box.size() != 3)
    throw nb::value_error(("box: " + std::to_string(box.size()) + " edge lengths; expected 2 or 3").c_str());
  return int(box.size());
}

Physics set_physics(cellforce::Context& ctx, const std::vector<double>& box, nb::handle periodic, double cutoff,
                    const std::string& mode, const std::string& mixing, nb::handle types, nb::handle pairs) {
  const std::size_t dim = std::size_t(box_dim(box));
  Physics physics;
  physics.periodic.assign(dim, true);
  if (!periodic.is_none()) {
    std::vector<bool> given;
    try {
      for (nb::handle axis : nb::iter(periodic)) given.push_back(PyObject_IsTrue(axis.ptr()) == 1);
    } catch (const nb::python_error&) {
      throw nb::type_error("periodic: expected a sequence of truth values, one per axis");
    }
    if (given.size() != dim)
      throw nb::value_error(("periodic: " + std::to_string(given.size()) + " values for a box of " +
                             std::to_string(dim) + " axes")
                                .c_str());
    physics.periodic = given;
  }
  bool p[3] = {true, true, true};
  for (std::size_t a = 0; a < dim; ++a) p[a] = physics.periodic[a];
  ctx.set_box(box.data(), p);
  ctx.set_option("cutoff-mode", mode);
  ctx.set_cutoff(cutoff);
  ctx.set_option("mixing", mixing);
  // Types in the order given (a dict keeps it): a type's index is its place in that order.
  if (types.is_none()) {
    physics.names.push_back("A");
    ctx.add_type("A", 1.0, 1.0);
  } else {
    if (!nb::isinstance<nb::dict>(types)) throw nb::type_error("types: expected {name: (sigma, epsilon)}");
    const nb::dict given = nb::borrow<nb::dict>(types);
    if (given.size() == 0) throw nb::value_error("types: no particle type given");
    for (const auto& [key, value] : given) {
      std::string name;
      std::pair<double, double> se;
      if (!nb::try_cast(key, name) || !nb::try_cast(value, se))
        throw nb::type_error("types: expected {name: (sigma, epsilon)}");
      ctx.add_type(name, se.first, se.second);
      physics.names.push_back(std::move(name));
    }
  }
  if (!pairs.is_none() && !nb::isinstance<nb::dict>(pairs))
    throw nb::type_error("pairs: expected {(name, name): (sigma, epsilon)}");
  auto index_of = [&](const std::string& name) {
    const auto it = std::find(physics.names.begin(), physics.names.end(), name);
    if (it == physics.names.end()) throw nb::value_error(("pairs: unknown type '" + name + "'").c_str());
    return uint32_t(it - physics.names.begin());
  };
  if (!pairs.is_none())
    for (const auto& [key, value] : nb::borrow<nb::dict>(pairs)) {
      std::pair<std::string, std::string> ab;
      std::pair<double, double> se;
      if (!nb::try_cast(key, ab) || !nb::try_cast(value, se))
        throw nb::type_error("pairs: expected {(name, name): (sigma, epsilon)}");
      ctx.set_pair(index_of(ab.first), index_of(ab.second), se.first, se.second);
    }
  return physics;
}

}  // namespace cellforce::python
