#include "io/checkpoint.h"

#include <cstdio>
#include <cstdlib>

#include "core/error.h"
#include "io/hdf5.h"

namespace cellforce {

void write_checkpoint(const std::string& path, const MdState& state, const CheckpointInfo& info) {
  const int dim = state.config.box.dim;
  const hsize_t n = state.config.size(), hd = hsize_t(dim);
  h5::write_file_atomically(path, [&](hid_t root) {
    h5::write_doubles(root, "positions", state.config.positions, {n, hd}, path);
    h5::write_doubles(root, "velocities", state.velocities, {n, hd}, path);
    std::vector<int64_t> types(state.config.types.begin(), state.config.types.end());
    h5::write_ints(root, "types", types, {n}, path);
    std::vector<double> box(state.config.box.length, state.config.box.length + dim);
    h5::write_attribute(root, "box", box, path);
    h5::write_attribute(root, "step", int64_t(state.step), path);
    h5::write_attribute(root, "time", state.time, path);
    h5::write_attribute(root, "dimension", int64_t(dim), path);
    // Stored as text: HDF5 has no unsigned 64-bit attribute type in this layer.
    h5::write_attribute(root, "seed", std::to_string(info.seed), path);
    h5::write_attribute(root, "scene_fingerprint", std::to_string(info.scene_fingerprint), path);
    h5::write_attribute(root, "scene", info.scene, path);
    h5::write_attribute(root, "backend", info.backend, path);
    h5::write_attribute(root, "precision", info.precision, path);
    if (!info.neighbor.build_positions.empty()) {
      h5::write_doubles(root, "neighbor_build_positions", info.neighbor.build_positions, {n, hd}, path);
      h5::write_attribute(root, "neighbor_served", int64_t(info.neighbor.served), path);
      char skin[40];  // as text, exactly: there is no double-attribute reader in this layer
      std::snprintf(skin, sizeof skin, "%.17g", info.skin);
      h5::write_attribute(root, "neighbor_skin", std::string(skin), path);
      if (info.neighbor_list) h5::write_attribute(root, "neighbor_list", int64_t(*info.neighbor_list ? 1 : 0), path);
    }
  });
}

CheckpointInfo read_checkpoint(const std::string& path, MdState& state, const CheckpointInfo& expected) {
  // state.time is left to the caller: step x dt, as the integrator computes it.
  h5::File f = h5::File::open_read(path);
  const hid_t root = f.id();
  const int dim = state.config.box.dim;
  const std::size_t n = state.config.size();
  const int64_t file_dim = h5::read_int_attribute(root, "dimension", path);
  if (file_dim != dim)
    throw Error(path + ": checkpoint of a " + std::to_string(file_dim) + "D run, the scene is " + std::to_string(dim) + "D");
  const std::string print = h5::read_string_attribute(root, "scene_fingerprint", path).at(0);
  if (print != std::to_string(expected.scene_fingerprint))
    throw Error(path + ": written for another system (" + h5::read_string_attribute(root, "scene", path).at(0) +
                ", or its particles, types, interactions, initial state or integrator have changed since) than " +
                expected.scene);
  if (h5::read_string_attribute(root, "seed", path).at(0) != std::to_string(expected.seed))
    throw Error(path + ": written with seed " + h5::read_string_attribute(root, "seed", path).at(0) +
                ", the run has seed " + std::to_string(expected.seed));
  const h5::Array<double> pos = h5::read_doubles(root, "positions", path);
  const h5::Array<double> vel = h5::read_doubles(root, "velocities", path);
  const h5::Array<int64_t> types = h5::read_ints(root, "types", path);
  const std::vector<hsize_t> shape = {hsize_t(n), hsize_t(dim)};
  if (pos.shape != shape || vel.shape != shape || types.values.size() != n)
    throw Error(path + ": holds " + std::to_string(pos.shape.empty() ? 0 : pos.shape[0]) +
                " particles, the scene " + std::to_string(n));
  for (std::size_t i = 0; i < n; ++i)
    if (uint32_t(types.values[i]) != state.config.types[i])
      throw Error(path + ": particle " + std::to_string(i) + " has type " + std::to_string(types.values[i]) +
                  " in the checkpoint, " + std::to_string(state.config.types[i]) + " in the scene");
  state.config.positions = pos.values;
  state.velocities = vel.values;
  state.step = h5::read_int_attribute(root, "step", path);
  if (state.step < 0)
    throw Error(path + ": its step is " + std::to_string(state.step) +
                "; a checkpoint's step is 0 or more (the file is damaged or was not written by cellforce)");
  CheckpointInfo saved = expected;
  saved.scene = h5::read_string_attribute(root, "scene", path).at(0);
  saved.backend = h5::read_string_attribute(root, "backend", path).at(0);
  saved.precision = h5::read_string_attribute(root, "precision", path).at(0);
  saved.neighbor = {};
  saved.skin = 0;
  saved.neighbor_list.reset();
  if (h5::exists(root, "neighbor_build_positions")) {
    const h5::Array<double> built = h5::read_doubles(root, "neighbor_build_positions", path);
    if (built.shape != shape) throw Error(path + ": neighbor_build_positions has the wrong shape");
    saved.neighbor.build_positions = built.values;
    saved.neighbor.served = h5::read_int_attribute(root, "neighbor_served", path);
    saved.skin = std::strtod(h5::read_string_attribute(root, "neighbor_skin", path).at(0).c_str(), nullptr);
    if (h5::has_attribute(root, "neighbor_list")) saved.neighbor_list = h5::read_int_attribute(root, "neighbor_list", path) != 0;
  }
  f.close();
  return saved;
}

}  // namespace cellforce
