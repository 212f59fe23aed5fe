// Writing a trajectory as an H5MD 1.1 file (https://nongnu.org/h5md/), one frame at a time, so
// that h5py, MDAnalysis's H5MD reader and cellforce's own read_h5md read it:
//
//   /h5md                      version = int32 [1, 1]; author (name), creator (name, version)
//   /particles/all/box         dimension = int32 D; boundary = "periodic" / "none" per axis
//     edges/value              float64 [frames][D]; step, time: hard links to position's
//   /particles/all/position    value float64 [frames][n][D]; step int64 [frames]; time float64
//   /particles/all/velocity    (optional) value as position's; step, time: hard links to position's
//   /particles/all/force       (optional) likewise
//   /particles/all/species     int32 [n]; attribute names: species k is names[k]
//   /observables/NAME          value float64 [frames]; step, time: hard links to position's
//
// Every frame writes the box although it is fixed: MDAnalysis reads edges only as a
// time-dependent element (edges/value), not as the fixed dataset that H5MD also allows. No `unit`
// attributes: the values are in reduced Lennard-Jones units, which H5MD's units module (SI
// symbols only) cannot name.
//
// The per-particle datasets are stored one frame per chunk (split over particles where a frame
// exceeds 1 MiB, the size of HDF5's default chunk cache), shuffled and deflated at level 1 (about
// 10-15% smaller for liquid coordinates; lattices and open systems compress far better). Each
// write_frame ends with a flush, so a run that dies afterwards leaves a readable file holding every
// frame written so far. While the writer holds the file open, HDF5's file locking keeps other
// processes from opening it unless they set HDF5_USE_FILE_LOCKING=FALSE.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "core/box.h"
#include "io/hdf5.h"

namespace cellforce {

struct H5mdOptions {
  bool velocities = false;  // write /particles/all/velocity
  bool forces = false;      // write /particles/all/force
  // Scalar observables stored per frame as /observables/NAME, e.g. "potential_energy",
  // "kinetic_energy", "total_energy", "temperature", "pressure"; write_frame takes their values
  // in this order. Names: non-empty, unique, without '/'.
  std::vector<std::string> observables;
  std::string creator_version;       // /h5md/creator version ("unknown" when empty)
  std::string author = "cellforce";  // /h5md/author name
  // Continue an existing trajectory written by H5mdWriter (a restarted run) rather than create
  // (or overwrite) the file. Its particle count, dimension, boundaries, species, species names,
  // velocity and force elements and observables must equal this run's. A last frame that some
  // datasets hold and others do not (a run killed inside write_frame) is dropped.
  bool append = false;
};

class H5mdWriter {
 public:
  // The particles' species (n values, each an index into species_names) fix n; the box fixes D
  // (2 or 3), the boundaries and the edges written with every frame. Errors name the file.
  H5mdWriter(const std::string& path, const Box& box, const std::vector<uint32_t>& species,
             const std::vector<std::string>& species_names, const H5mdOptions& options);
  // Closes the file; errors are swallowed here, call close() to see them.
  ~H5mdWriter();
  H5mdWriter(const H5mdWriter&) = delete;
  H5mdWriter& operator=(const H5mdWriter&) = delete;

  // Appends one frame and flushes it to disk. positions, velocities, forces: n x D values each,
  // row-major, in the user's particle order; velocities (forces) may be null only when the
  // options leave them out. observable_values: one per options.observables name, in that order.
  // step must exceed the last stored step (a restarted run must not repeat frames: see
  // truncate_after) and time must not decrease. Input errors are refused before the file changes.
  // When writing fails, every dataset is shrunk back to its previous length; should HDF5 be unable
  // to (it can be, after a failed write to disk), later frames are refused, and reopening the file
  // with append cuts it back to its complete frames.
  void write_frame(int64_t step, double time, const double* positions, const double* velocities,
                   const double* forces, const std::vector<double>& observable_values);

  // Drops the frames whose step exceeds `step` (a run restarted from a checkpoint older than the
  // trajectory's end); the file's allocated size does not shrink.
  void truncate_after(int64_t step);

  // Flushes and closes; errors surface here. Later write_frame calls are refused.
  void close();

  std::size_t frames() const { return frames_; }
  std::size_t particles() const { return n_; }
  // The last stored frame's step; empty when the trajectory holds no frame.
  std::optional<int64_t> last_step() const;
  // Incomplete frames that opening with append dropped (held by some datasets only).
  std::size_t dropped_incomplete_frames() const { return dropped_incomplete_; }
  const std::string& path() const { return path_; }

  // Refuses, as the constructor would, what cannot be written (a box of another dimension, a
  // species without a name, names too long for an HDF5 attribute, bad observable names), without
  // touching the file: a run checks this before it writes any of its outputs. Errors name `path`.
  static void check(const std::string& path, const Box& box, const std::vector<uint32_t>& species,
                    const std::vector<std::string>& species_names, const H5mdOptions& options);

  // The particles group's name: /particles/all.
  static constexpr const char* kGroup = "all";

  // The steps of the frames a trajectory written by this class holds, read without changing the
  // file (a restart checks them before it truncates anything). Errors name the file.
  static std::vector<int64_t> stored_steps(const std::string& path);

 private:
  void create(const Box& box, const std::vector<uint32_t>& species,
              const std::vector<std::string>& species_names, const H5mdOptions& options);
  void open_existing(const Box& box, const std::vector<uint32_t>& species,
                     const std::vector<std::string>& species_names, const H5mdOptions& options);
  // Every dataset that grows by one row per frame (step and time once: they are shared).
  std::vector<hid_t> growing() const;
  // More bytes than one frame can add to the file (reserved before it is written).
  std::uint64_t frame_bytes_bound() const;
  // Throws when the file is closed or a failed write could not be undone.
  void require_writable() const;

  std::string path_;
  std::optional<h5::File> file_;
  std::size_t n_ = 0;
  int dim_ = 3;
  std::vector<double> edges_;  // D values, written with every frame
  bool velocities_ = false, forces_ = false;
  std::vector<std::string> observables_;
  h5::Handle step_, time_, position_, velocity_, force_, edges_value_;
  std::vector<h5::Handle> observable_values_;  // in observables_ order
  std::size_t frames_ = 0;
  int64_t last_step_ = 0;  // meaningful when frames_ > 0
  double last_time_ = 0;
  std::size_t dropped_incomplete_ = 0;
  std::string broken_;  // non-empty: why frames are refused (a failed write not undone)
};

}  // namespace cellforce
