#include "scenes.h"

#include <cmath>
#include <functional>
#include <map>
#include <stdexcept>

#include "core/grid.h"
#include "oracle.h"

namespace cftest {

using cellforce::Box;
using cellforce::Configuration;
using cellforce::ForceField;

namespace {

ForceField lj(double cutoff = 2.5, double sigma = 1.0) {
  ForceField ff;
  ff.cutoff = cutoff;
  ff.types = {cellforce::ParticleType{"A", sigma, 1.0}};
  return ff;
}

ForceField three_types(cellforce::Mixing mixing) {
  ForceField ff;
  ff.cutoff = 2.5;
  ff.mixing = mixing;
  ff.types = {{"A", 1.0, 1.0}, {"B", 0.88, 0.5}, {"C", 1.1, 0.8}};
  return ff;
}

Scene random_scene(const std::string& name, const Box& box, std::size_t n, uint64_t seed,
                   ForceField ff, RandomSpec spec) {
  return Scene{name, random_configuration(box, n, seed, spec), std::move(ff)};
}

RandomSpec min_dist(double d, uint32_t types = 1) {
  RandomSpec s;
  s.min_distance = d;
  s.num_types = types;
  return s;
}

RandomSpec region(double d, std::array<double, 3> lo, std::array<double, 3> hi) {
  RandomSpec s;
  s.min_distance = d;
  s.lo = lo;
  s.hi = hi;
  return s;
}

using Builder = std::function<Scene(const std::string&)>;

const std::map<std::string, Builder>& registry() {
  static const std::map<std::string, Builder> r = {
      // ---- random liquids ------------------------------------------------------------------
      {"random3d_periodic",
       [](const std::string& n) { return random_scene(n, cube(3, 11), 1000, 11, lj(), min_dist(0.85)); }},
      {"random2d_periodic",
       [](const std::string& n) { return random_scene(n, cube(2, 30), 600, 12, lj(), min_dist(0.85)); }},
      {"random3d_open",
       [](const std::string& n) {
         return random_scene(n, cube(3, 11, false), 800, 13, lj(), min_dist(0.85));
       }},
      {"random2d_open",
       [](const std::string& n) {
         return random_scene(n, cube(2, 28, false), 500, 14, lj(), min_dist(0.85));
       }},
      {"slab3d",  // periodic x, y; open z
       [](const std::string& n) {
         return random_scene(n, make_box(3, {11, 11, 9}, {true, true, false}), 700, 15, lj(),
                             min_dist(0.85));
       }},
      {"slab2d",  // periodic x; open y
       [](const std::string& n) {
         return random_scene(n, make_box(2, {30, 20, 1}, {true, false, false}), 400, 16, lj(),
                             min_dist(0.85));
       }},
      {"random3d_uniform",  // the library's own generator: no minimum distance
       [](const std::string& n) {
         return Scene{n, cellforce::make_random(cube(3, 12), 1500, 17), lj(2.5, 0.05)};
       }},
      // ---- several types -------------------------------------------------------------------
      {"multitype3d_lb",
       [](const std::string& n) {
         return random_scene(n, cube(3, 11), 900, 21,
                             three_types(cellforce::Mixing::kLorentzBerthelot), min_dist(0.9, 3));
       }},
      {"multitype3d_geometric_override",
       [](const std::string& n) {
         ForceField ff = three_types(cellforce::Mixing::kGeometric);
         ff.overrides = {{0, 1, 0.8, 1.5}, {2, 2, 1.05, 0.3}};
         return random_scene(n, cube(3, 11), 900, 22, ff, min_dist(0.9, 3));
       }},
      {"multitype2d_lb_override",
       [](const std::string& n) {
         ForceField ff;
         ff.cutoff = 2.5;
         ff.types = {{"A", 1.0, 1.0}, {"B", 0.88, 0.5}};
         ff.overrides = {{1, 0, 0.8, 1.5}};
         return random_scene(n, cube(2, 30), 600, 23, ff, min_dist(0.9, 2));
       }},
      // ---- lattices ------------------------------------------------------------------------
      {"lattice_fcc_jitter",
       [](const std::string& n) {
         Configuration c = cellforce::make_lattice(cellforce::Lattice::kFcc, 5, 0.8442);
         cellforce::jitter(c, 0.05, 31);
         return Scene{n, c, lj()};
       }},
      {"lattice_bcc_perfect",
       [](const std::string& n) {
         return Scene{n, cellforce::make_lattice(cellforce::Lattice::kBcc, 6, 0.7), lj()};
       }},
      {"lattice_sc_perfect",  // 10^3 at density 1 (spacing 1, L = 10): two cells per axis
       [](const std::string& n) {
         return Scene{n, cellforce::make_lattice(cellforce::Lattice::kSimpleCubic, 10, 1.0),
                      lj(2.5)};
       }},
      {"lattice_square2d_jitter",
       [](const std::string& n) {
         Configuration c = cellforce::make_lattice(cellforce::Lattice::kSquare, 24, 0.8);
         cellforce::jitter(c, 0.05, 32);
         return Scene{n, c, lj()};
       }},
      // ---- clustered: occupancy far above the mean ---------------------------------------------
      {"clustered3d_one_cell",  // 200 particles in [1,3]^3 of a 40^3 box: one cell (edge 5)
       [](const std::string& n) {
         return random_scene(n, cube(3, 40), 200, 41, lj(2.5, 0.25),
                             region(0.25, {1, 1, 1}, {3, 3, 3}));
       }},
      {"clustered3d_corner",  // the same cluster around the corner shared by 8 cells
       [](const std::string& n) {
         return random_scene(n, cube(3, 40), 200, 42, lj(2.5, 0.25),
                             region(0.25, {4, 4, 4}, {6, 6, 6}));
       }},
      {"clustered3d_across_boundary",  // the cluster straddles the periodic boundary
       [](const std::string& n) {
         Configuration c = random_configuration(cube(3, 40), 200, 43,
                                                region(0.25, {-1, -1, -1}, {1, 1, 1}));
         return Scene{n, c, lj(2.5, 0.25)};
       }},
      {"clustered3d_open",
       [](const std::string& n) {
         return random_scene(n, cube(3, 40, false), 200, 44, lj(2.5, 0.25),
                             region(0.25, {1, 1, 1}, {3, 3, 3}));
       }},
      {"clustered2d_one_cell",
       [](const std::string& n) {
         return random_scene(n, cube(2, 40), 200, 45, lj(2.5, 0.1),
                             region(0.1, {1, 1, 0}, {3, 3, 0}));
       }},
      // ---- particles on faces and box edges ----------------------------------------------------
      {"faces3d_periodic",
       [](const std::string& n) { return Scene{n, faces_configuration(cube(3, 20), 2.5, 400, 51, 0.3), lj(2.5, 0.25)}; }},
      {"faces2d_periodic",
       [](const std::string& n) { return Scene{n, faces_configuration(cube(2, 20), 2.5, 150, 52, 0.3), lj(2.5, 0.25)}; }},
      {"faces3d_open",
       [](const std::string& n) {
         return Scene{n, faces_configuration(cube(3, 20, false), 2.5, 400, 53, 0.3), lj(2.5, 0.25)};
       }},
      {"faces2d_open",
       [](const std::string& n) {
         return Scene{n, faces_configuration(cube(2, 20, false), 2.5, 150, 54, 0.3), lj(2.5, 0.25)};
       }},
      {"faces3d_slab",
       [](const std::string& n) {
         return Scene{n,
                      faces_configuration(make_box(3, {20, 20, 20}, {true, true, false}), 2.5, 400,
                                          55, 0.3),
                      lj(2.5, 0.25)};
       }},
      // ---- small periodic boxes: rc = L/2 (one cell), two cells per axis, uneven axes ------------
      {"half_box3d",  // rc = L/2 exactly: one cell per axis
       [](const std::string& n) { return random_scene(n, cube(3, 5), 100, 61, lj(2.5), min_dist(0.85)); }},
      {"half_box2d",
       [](const std::string& n) { return random_scene(n, cube(2, 5), 18, 62, lj(2.5), min_dist(0.85)); }},
      {"half_box3d_mixed",  // rc = L_x / 2 on x only: one cell on x, two on y and z
       [](const std::string& n) {
         return random_scene(n, make_box(3, {5, 11, 11}, {true, true, true}), 400, 63, lj(2.5),
                             min_dist(0.85));
       }},
      {"half_box3d_slab",  // rc = L/2 on the periodic axes, open z
       [](const std::string& n) {
         return random_scene(n, make_box(3, {5, 5, 12}, {true, true, false}), 200, 64, lj(2.5),
                             min_dist(0.85));
       }},
      {"lattice_fcc_half_box",  // fcc 3^3 at 0.8442 (L = 5.0387), rc = L/2 exactly
       [](const std::string& n) {
         Configuration c = cellforce::make_lattice(cellforce::Lattice::kFcc, 3, 0.8442);
         cellforce::jitter(c, 0.05, 65);
         return Scene{n, c, lj(c.box.length[0] / 2)};
       }},
      {"two_cells3d",  // L = 9: two cells per axis, both neighbours of a cell are the same cell
       [](const std::string& n) { return random_scene(n, cube(3, 9), 450, 66, lj(2.5), min_dist(0.85)); }},
      {"two_cells2d",
       [](const std::string& n) { return random_scene(n, cube(2, 9), 60, 67, lj(2.5), min_dist(0.85)); }},
      {"uneven3d",  // different cell counts per axis
       [](const std::string& n) {
         return random_scene(n, make_box(3, {9, 13, 21}, {true, true, true}), 1200, 68, lj(2.5),
                             min_dist(0.85));
       }},
      // ---- far from the origin: what float coordinates lose ------------------------------------
      {"random3d_open_far",  // the random3d_open liquid translated by 1e4 sigma
       [](const std::string& n) {
         Scene s = random_scene(n, cube(3, 11, false), 800, 13, lj(), min_dist(0.85));
         for (double& x : s.config.positions) x += 1e4;
         return s;
       }},
      {"random3d_periodic_far_image",  // random3d_periodic, each particle moved by 1000 box edges
       [](const std::string& n) {
         Scene s = random_scene(n, cube(3, 11), 1000, 11, lj(), min_dist(0.85));
         for (double& x : s.config.positions) x += 1000 * 11.0;
         return s;
       }},
  };
  return r;
}

}  // namespace

Scene make_scene(const std::string& name) {
  const auto& r = registry();
  auto it = r.find(name);
  if (it == r.end()) throw std::invalid_argument("unknown scene " + name);
  return it->second(name);
}

std::vector<std::string> all_scene_names() {
  std::vector<std::string> names;
  for (const auto& [name, builder] : registry()) names.push_back(name);
  return names;
}

std::vector<std::string> all_modes_scene_names() {
  return {"random3d_periodic", "random2d_periodic",    "random3d_open",
          "random2d_open",     "slab3d",               "slab2d",
          "multitype3d_lb",    "multitype3d_geometric_override",
          "multitype2d_lb_override", "half_box3d", "half_box3d_mixed", "clustered3d_one_cell"};
}

std::vector<std::string> precision_scene_names() {
  return {"random3d_periodic", "random2d_periodic", "random3d_open", "slab3d", "multitype3d_lb",
          "random3d_open_far", "random3d_periodic_far_image"};
}

Configuration faces_configuration(const Box& box, double cutoff, std::size_t n, uint64_t seed,
                                  double min_distance) {
  const int d = box.dim;
  Configuration c;
  c.box = box;
  // On open axes two corners pin the bounding box to [0, L], so the grid's faces are known.
  bool any_open = false;
  for (int a = 0; a < d; ++a) any_open |= !box.periodic[a];
  if (any_open) {
    for (int a = 0; a < d; ++a) c.positions.push_back(0.0);
    for (int a = 0; a < d; ++a) c.positions.push_back(box.length[a]);
    c.types = {0, 0};
  }
  const std::vector<double> corners = c.positions;
  const cellforce::Grid g =
      cellforce::plan_grid(box, cutoff, corners.empty() ? nullptr : corners.data(),
                           corners.size() / std::size_t(d));
  std::vector<std::vector<double>> values(static_cast<std::size_t>(d));
  for (int a = 0; a < d; ++a) {
    auto& v = values[std::size_t(a)];
    const double l = box.length[a], cell = g.cell[a], h = g.half_width, o = g.origin[a];
    if (box.periodic[a]) v = {0.0, -0.0, l, std::nextafter(l, 0.0), -1e-8, -1e-300};
    else v = {0.0, l, std::nextafter(l, 0.0)};
    for (uint32_t k = 0; k <= g.n[a]; ++k) {
      const double f = o + k * cell;
      for (double x : {f, f + 1e-12, f - 1e-12, f + h, f - h, f + h * (1 + 1e-9),
                       f + h * (1 - 1e-9), f - h * (1 + 1e-9), f - h * (1 - 1e-9),
                       f + 0.5 * cell})
        if (box.periodic[a] || (x >= 0 && x <= l)) v.push_back(x);
    }
  }
  Rng rng(seed);
  const std::size_t max_attempts = 200 * n;
  double x[3] = {0, 0, 0};
  for (std::size_t attempt = 0; attempt < max_attempts && c.types.size() < n; ++attempt) {
    for (int a = 0; a < d; ++a) {
      const auto& v = values[std::size_t(a)];
      x[a] = v[rng.below(v.size())];
    }
    bool ok = true;
    for (std::size_t j = 0; j < c.types.size() && ok; ++j) {
      double r2 = 0;
      for (int a = 0; a < d; ++a) {
        double dx = x[a] - c.positions[j * std::size_t(d) + std::size_t(a)];
        if (box.periodic[a]) dx -= box.length[a] * std::rint(dx / box.length[a]);
        r2 += dx * dx;
      }
      ok = r2 >= min_distance * min_distance;
    }
    if (!ok) continue;
    for (int a = 0; a < d; ++a) c.positions.push_back(x[a]);
    c.types.push_back(0);
  }
  return c;
}

}  // namespace cftest
