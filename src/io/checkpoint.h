// Checkpoints: the state of a run (positions, velocities, step, time) in an HDF5 file, written
// under a temporary name and renamed when complete. Restarting from one reproduces the
// uninterrupted run bit for bit on the same backend: the integrators' random numbers depend only
// on (seed, step, particle, axis), and the forces are recomputed from the stored positions (with
// a skin, by the cell structure rebuilt from the positions it was built from, so that the force
// sums keep their order).
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include <cellforce/cellforce.hpp>  // NeighborState

#include "state/md_state.h"

namespace cellforce {

struct CheckpointInfo {
  uint64_t seed = 0;
  uint64_t scene_fingerprint = 0;  // of the scene's physics (scene_fingerprint): a restart needs the same
  std::string scene;               // where the scene came from (for messages)
  std::string backend, precision;  // what wrote it: a restart on others continues, but not bit for bit
  // With a skin ([neighbor]): the neighbour structure in use at the checkpoint (Context::
  // neighbor_state), for the restart to rebuild it (read back only when the file has it and was
  // written with the same skin).
  double skin = 0;
  NeighborState neighbor;
  // Whether that structure's evaluations walked pair lists (another summation order than the cells):
  // a restart rebuilds it only for the same choice. Absent in files written before skin auto.
  std::optional<bool> neighbor_list;
};

void write_checkpoint(const std::string& path, const MdState& state, const CheckpointInfo& info);

// Reads a checkpoint into `state` (whose configuration must already hold the scene's particles:
// the particle count, dimension and types must match, and the scene fingerprint and seed).
// Returns what the file says of itself. Throws cellforce::Error naming the file and what differs.
CheckpointInfo read_checkpoint(const std::string& path, MdState& state, const CheckpointInfo& expected);

}  // namespace cellforce
