// The MD state on the host: a configuration with its velocities, forces, step and time. What the
// host integrators (md/md.h) advance, the MD engines take in and give back, checkpoints store
// (io/checkpoint.h) and the commands build from a scene.
#pragma once

#include <cstdint>
#include <vector>

#include "state/configuration.h"

namespace cellforce {

struct MdState {
  Configuration config;             // box, positions (n x dim, wrapped on periodic axes), types
  std::vector<double> velocities;   // n x dim
  std::vector<double> forces;       // n x dim, at the current positions
  int64_t step = 0;
  double time = 0.0;
};

}  // namespace cellforce
