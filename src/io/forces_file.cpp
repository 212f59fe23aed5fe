#include "io/forces_file.h"

#include "core/error.h"
#include "io/hdf5.h"

namespace cellforce {

void write_forces_file(const std::string& path, const ForceResult& result, std::size_t n,
                       const Attributes& attributes, const Series& series) {
  const int dim = result.dim;
  if (result.forces.size() != n * std::size_t(dim))
    throw Error(path + ": internal error: " + std::to_string(result.forces.size()) +
                " force components for " + std::to_string(n) + " particles");
  if (result.energies.size() != n)
    throw Error(path + ": internal error: per-particle energies were not computed");
  h5::write_file_atomically(path, [&](hid_t root) {
    const hsize_t hn = n, hd = hsize_t(dim);
    h5::write_doubles(root, "forces", result.forces, {hn, hd}, path);
    h5::write_doubles(root, "energies", result.energies, {hn}, path);
    h5::write_doubles(root, "energy", {result.energy}, {}, path);
    std::vector<double> w;
    for (int a = 0; a < dim; ++a)
      for (int b = 0; b < dim; ++b) w.push_back(result.virial[a][b]);
    h5::write_doubles(root, "virial", w, {hd, hd}, path);
    for (const auto& [name, values] : series)
      h5::write_doubles(root, name, values, {hsize_t(values.size())}, path);
    for (const auto& [name, value] : attributes)
      std::visit([&, &key = name](const auto& v) { h5::write_attribute(root, key, v, path); }, value);
  });
}

}  // namespace cellforce
