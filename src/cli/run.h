// `cellforce run [SCENE]`: molecular dynamics of a scene (systems/*.toml, or the built-in LAMMPS
// in.lj fluid): thermodynamics on the screen and in CSV, a progress bar on a terminal (plain
// lines otherwise), and a performance summary at the end. [run] steps is the run's total length:
// a restart from a checkpoint at step s runs the steps from s to it.
#pragma once

#include <cstdint>
#include <string>

namespace cellforce {

struct RunArgs {
  std::string scene;          // empty: the built-in default scene
  int64_t steps = -1;         // >= 0: overrides the scene's [run] steps
  std::string backend;        // non-empty: overrides [run] backend
  std::string precision;      // non-empty: overrides [run] precision
  std::string traversal;      // non-empty: the CUDA traversal form (auto, warp, thread, tile)
  std::string thermo_file;    // non-empty: overrides [output] thermo_file
  std::string restart;        // non-empty: continue from this checkpoint (same scene)
  std::string trajectory;     // non-empty: overrides [output] trajectory
  int64_t trajectory_every = 0;  // > 0: overrides [output] trajectory_every
  double skin = -1;           // not < 0: overrides [neighbor] skin (NaN reaches validate_reuse)
  bool skin_auto = false;     // --skin auto: overrides [neighbor] skin with the engine's rule
  bool quiet = false;         // no thermo lines or progress on the screen (summary only)
  bool overwrite = false;     // a fresh run may replace the outputs of an earlier one
};

// Returns the exit code (0) or throws cellforce::Error.
int run_md(const RunArgs& args);

}  // namespace cellforce
