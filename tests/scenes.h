// Named test scenes (configuration + force field), built deterministically on demand so that a
// test parameter is only a name. Each group below lists the scenes a family of tests runs over.
#pragma once

#include <string>
#include <vector>

#include "core/force_field.h"
#include "scene/lattice.h"

namespace cftest {

struct Scene {
  std::string name;
  cellforce::Configuration config;
  cellforce::ForceField ff;
};

// Throws std::invalid_argument for an unknown name.
Scene make_scene(const std::string& name);

// Every scene: used by the pair-coverage tests.
std::vector<std::string> all_scene_names();
// Scenes whose forces are compared with the brute force in every cutoff mode.
std::vector<std::string> all_modes_scene_names();
// Scenes for the single/mixed precision accuracy tests (random liquids; one far from the origin).
std::vector<std::string> precision_scene_names();

// Positions drawn from the values that stress binning on each axis: cell faces of the planned
// grid, faces +- 1e-12, faces +- h, faces +- h(1 +- 1e-9), cell centres, and on periodic axes 0,
// -0.0, L, nextafter(L, 0), -1e-8, -1e-300; no two closer than min_distance.
cellforce::Configuration faces_configuration(const cellforce::Box& box, double cutoff,
                                             std::size_t n, uint64_t seed, double min_distance);

}  // namespace cftest
