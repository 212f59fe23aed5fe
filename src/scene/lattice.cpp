#include "scene/lattice.h"

#include <cmath>
#include <array>
#include <random>

#include "core/error.h"

namespace cellforce {

Configuration make_lattice(Lattice lattice, int cells, double density) {
  if (cells < 1) throw Error("lattice needs at least one unit cell per axis, got " + std::to_string(cells));
  if (!(density > 0) || !std::isfinite(density))
    throw Error("lattice density must be finite and > 0, got " + std::to_string(density));
  struct Basis {
    int dim;
    std::vector<std::array<double, 3>> sites;
  };
  Basis basis{3, {}};
  switch (lattice) {
    case Lattice::kSimpleCubic: basis = {3, {{0, 0, 0}}}; break;
    case Lattice::kBcc: basis = {3, {{0, 0, 0}, {0.5, 0.5, 0.5}}}; break;
    case Lattice::kFcc: basis = {3, {{0, 0, 0}, {0.5, 0.5, 0}, {0.5, 0, 0.5}, {0, 0.5, 0.5}}}; break;
    case Lattice::kSquare: basis = {2, {{0, 0, 0}}}; break;
  }
  const int dim = basis.dim;
  const double per_cell = double(basis.sites.size());
  const double a = std::pow(per_cell / density, 1.0 / dim);  // lattice constant
  Configuration c;
  c.box.dim = dim;
  for (int ax = 0; ax < kMaxDim; ++ax) {
    c.box.length[ax] = ax < dim ? a * cells : 0.0;
    c.box.periodic[ax] = ax < dim;
  }
  const int nz = dim == 3 ? cells : 1;
  for (int iz = 0; iz < nz; ++iz)
    for (int iy = 0; iy < cells; ++iy)
      for (int ix = 0; ix < cells; ++ix)
        for (const auto& s : basis.sites) {
          const double p[3] = {(ix + s[0]) * a, (iy + s[1]) * a, (iz + s[2]) * a};
          for (int ax = 0; ax < dim; ++ax) c.positions.push_back(p[ax]);
          c.types.push_back(0);
        }
  return c;
}

void jitter(Configuration& config, double amplitude, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-amplitude, amplitude);
  for (double& x : config.positions) x += u(rng);
}

Configuration make_random(const Box& box, std::size_t n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  Configuration c;
  c.box = box;
  c.positions.resize(n * box.dim);
  c.types.assign(n, 0);
  for (std::size_t i = 0; i < n; ++i)
    for (int a = 0; a < box.dim; ++a)
      c.positions[i * box.dim + a] = std::uniform_real_distribution<double>(0.0, box.length[a])(rng);
  return c;
}

}  // namespace cellforce
