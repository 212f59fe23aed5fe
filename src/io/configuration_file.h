// Reading one configuration (box, positions, species) from a file: extended XYZ (the ASE
// convention) or H5MD. Species become type indices in the order they first appear; the caller
// maps their names to force-field types.
#pragma once

#include <string>
#include <vector>

#include "state/configuration.h"

namespace cellforce {

struct ConfigurationFile {
  Configuration config;              // box, positions (n x dim), types (indices into species)
  std::vector<std::string> species;  // species names, in order of first appearance
  std::string source;                // the file, and the frame read
};

struct ReadOptions {
  int dim = 0;            // 2 or 3; 0: from the file (H5MD) or 3 (XYZ, whose lines hold x y z)
  long frame = -1;        // frame index; negative counts from the end (-1: the last)
  std::string group;      // H5MD particles group; empty: the only one in the file
};

// Extended XYZ: line 1 the particle count, line 2 key=value pairs (Lattice="ax ay az bx by bz cx
// cy cz", orthorhombic only; Properties=species:S:1:pos:R:3, the default; pbc="T T T", the default
// when a Lattice is given, "F F F" otherwise), then one line per particle. Frames follow each
// other. In 2D (dim 2) every z must be exactly 0. Errors name the file, line and particle.
ConfigurationFile read_extxyz(const std::string& path, const ReadOptions& options = {});

// H5MD 1.x: /particles/GROUP/position/value (frames x n x dim), the box's dimension, boundary
// ("periodic" or "none" per axis) and edges (fixed, or a value per frame), and species (fixed or
// per frame; integers, named by the species' string attribute `names` where it has one, as
// cellforce's trajectories do (species k is names[k]), else by their decimal value; all "0" when
// absent).
ConfigurationFile read_h5md(const std::string& path, const ReadOptions& options = {});

// Either of the above, chosen by the file's contents (HDF5 signature or not).
ConfigurationFile read_configuration(const std::string& path, const ReadOptions& options = {});

// Writes one extended XYZ frame (17 significant digits, so that reading it back is exact).
void write_extxyz(const std::string& path, const Configuration& config,
                  const std::vector<std::string>& species);

}  // namespace cellforce
