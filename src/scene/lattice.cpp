#include "scene/lattice.h"

#include <cmath>
#include <array>
#include <random>

#include "core/error.h"

namespace cellforce {

namespace {

struct Basis {
  int dim;
  std::array<double, 3> cell;  // unit-cell edges in units of the lattice constant
  std::vector<std::array<double, 3>> sites;  // fractional coordinates
};

Basis basis_of(Lattice lattice) {
  switch (lattice) {
    case Lattice::kSimpleCubic: return {3, {1, 1, 1}, {{0, 0, 0}}};
    case Lattice::kBcc: return {3, {1, 1, 1}, {{0, 0, 0}, {0.5, 0.5, 0.5}}};
    case Lattice::kFcc: return {3, {1, 1, 1}, {{0, 0, 0}, {0.5, 0.5, 0}, {0.5, 0, 0.5}, {0, 0.5, 0.5}}};
    case Lattice::kSquare: return {2, {1, 1, 0}, {{0, 0, 0}}};
    case Lattice::kHexagonal: return {2, {1, std::sqrt(3.0), 0}, {{0, 0, 0}, {0.5, 0.5, 0}}};
  }
  throw Error("unknown lattice");
}

}  // namespace

int lattice_dimension(Lattice lattice) { return basis_of(lattice).dim; }

double lattice_site_count(Lattice lattice, std::array<int, 3> cells) {
  const Basis b = basis_of(lattice);
  double n = double(b.sites.size());
  for (int ax = 0; ax < b.dim; ++ax) n *= double(cells[std::size_t(ax)]);
  return n;
}

double lattice_constant_for(Lattice lattice, double density) {
  if (!(density > 0) || !std::isfinite(density))
    throw Error("lattice density must be finite and > 0, got " + std::to_string(density));
  const Basis b = basis_of(lattice);
  double cell_volume = 1.0;  // in units of a^dim
  for (int ax = 0; ax < b.dim; ++ax) cell_volume *= b.cell[std::size_t(ax)];
  return std::pow(double(b.sites.size()) / (density * cell_volume), 1.0 / b.dim);
}

Configuration make_lattice_cells(Lattice lattice, std::array<int, 3> cells, double a) {
  const Basis b = basis_of(lattice);
  const int dim = b.dim;
  for (int ax = 0; ax < dim; ++ax)
    if (cells[std::size_t(ax)] < 1)
      throw Error("lattice needs at least one unit cell per axis, got " + std::to_string(cells[std::size_t(ax)]));
  if (!(a > 0) || !std::isfinite(a)) throw Error("lattice constant must be finite and > 0, got " + std::to_string(a));
  Configuration c;
  c.box.dim = dim;
  for (int ax = 0; ax < kMaxDim; ++ax) {
    c.box.length[ax] = ax < dim ? a * b.cell[std::size_t(ax)] * cells[std::size_t(ax)] : 0.0;
    c.box.periodic[ax] = ax < dim;
  }
  const int nz = dim == 3 ? cells[2] : 1;
  for (int iz = 0; iz < nz; ++iz)
    for (int iy = 0; iy < cells[1]; ++iy)
      for (int ix = 0; ix < cells[0]; ++ix)
        for (const auto& site : b.sites) {
          const int index[3] = {ix, iy, iz};
          for (int ax = 0; ax < dim; ++ax)
            c.positions.push_back((index[ax] + site[std::size_t(ax)]) * a * b.cell[std::size_t(ax)]);
          c.types.push_back(0);
        }
  return c;
}

Configuration make_lattice(Lattice lattice, int cells, double density) {
  if (cells < 1) throw Error("lattice needs at least one unit cell per axis, got " + std::to_string(cells));
  return make_lattice_cells(lattice, {cells, cells, cells}, lattice_constant_for(lattice, density));
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

namespace cellforce {

Configuration make_random_spaced(const Box& box, std::size_t n, double min_distance, uint64_t seed) {
  if (!(min_distance >= 0) || !std::isfinite(min_distance))
    throw Error("random placement: min_distance must be finite and >= 0");
  if (min_distance == 0) return make_random(box, n, seed);
  const int dim = box.dim;
  // A grid of cells no smaller than min_distance: a new particle is checked against the 3^dim
  // neighbouring cells only.
  // Cells no smaller than min_distance, and about as many as particles (a large, dilute box must
  // not allocate a huge grid).
  double volume = 1.0;
  for (int a = 0; a < dim; ++a) {
    if (!(box.length[a] > 0) || !std::isfinite(box.length[a]))
      throw Error("random placement: box edge " + std::string(1, "xyz"[a]) + " must be finite and > 0");
    volume *= box.length[a];
  }
  const double edge = std::max(min_distance, std::pow(volume / double(std::max<std::size_t>(n, 1)), 1.0 / dim));
  int cells[3] = {1, 1, 1};
  for (int a = 0; a < dim; ++a) cells[a] = std::max(1, int(std::min(1024.0, box.length[a] / edge)));
  const std::size_t ncells = std::size_t(cells[0]) * std::size_t(cells[1]) * std::size_t(cells[2]);
  std::vector<std::vector<uint32_t>> grid(ncells);
  auto cell_of = [&](const double* x, int* c) {
    for (int a = 0; a < 3; ++a)
      c[a] = a < dim ? std::min(cells[a] - 1, std::max(0, int(x[a] / box.length[a] * cells[a]))) : 0;
  };
  std::mt19937_64 rng(seed);
  Configuration c;
  c.box = box;
  c.positions.reserve(n * std::size_t(dim));
  const double d2 = min_distance * min_distance;
  for (std::size_t i = 0; i < n; ++i) {
    bool placed = false;
    for (int attempt = 0; attempt < 10000 && !placed; ++attempt) {
      double x[3] = {0, 0, 0};
      for (int a = 0; a < dim; ++a) x[a] = std::uniform_real_distribution<double>(0.0, box.length[a])(rng);
      int home[3];
      cell_of(x, home);
      bool clear = true;
      for (int dz = (dim == 3 ? -1 : 0); dz <= (dim == 3 ? 1 : 0) && clear; ++dz)
        for (int dy = -1; dy <= 1 && clear; ++dy)
          for (int dx = -1; dx <= 1 && clear; ++dx) {
            int nb[3] = {home[0] + dx, home[1] + dy, home[2] + dz};
            bool skip = false;
            for (int a = 0; a < dim; ++a) {
              if (nb[a] < 0 || nb[a] >= cells[a]) {
                if (!box.periodic[a]) skip = true;
                nb[a] = (nb[a] + cells[a]) % cells[a];
              }
            }
            if (skip) continue;
            for (uint32_t j : grid[(std::size_t(nb[2]) * cells[1] + std::size_t(nb[1])) * cells[0] + std::size_t(nb[0])]) {
              double r2 = 0;
              for (int a = 0; a < dim; ++a) {
                double dxa = x[a] - c.positions[j * std::size_t(dim) + std::size_t(a)];
                if (box.periodic[a]) dxa -= box.length[a] * std::rint(dxa / box.length[a]);
                r2 += dxa * dxa;
              }
              if (r2 < d2) {
                clear = false;
                break;
              }
            }
          }
      if (!clear) continue;
      for (int a = 0; a < dim; ++a) c.positions.push_back(x[a]);
      grid[(std::size_t(home[2]) * cells[1] + std::size_t(home[1])) * cells[0] + std::size_t(home[0])].push_back(uint32_t(i));
      placed = true;
    }
    if (!placed)
      throw Error("random placement: particle " + std::to_string(i) + " of " + std::to_string(n) +
                  " found no place at least " + std::to_string(min_distance) +
                  " from the others in 10,000 tries; lower the count or min_distance, or enlarge the box");
  }
  c.types.assign(n, 0);
  return c;
}

}  // namespace cellforce
