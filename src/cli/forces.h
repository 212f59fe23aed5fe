// `cellforce forces`: forces, per-particle energies, total energy and virial of one configuration
// read from a file (extended XYZ or H5MD), written to HDF5. The command that the OpenMM parity
// scripts in validation/ drive.
#pragma once

#include <string>
#include <vector>

#include "scene/engine_context.h"
#include "core/force_field.h"
#include "core/option_table.h"
#include "io/configuration_file.h"

namespace cellforce {

struct ForcesArgs {
  std::string input;               // extended XYZ or H5MD
  std::string out;                 // HDF5 file to write
  double cutoff = 2.5;
  CutoffMode mode = CutoffMode::kTruncate;
  std::vector<std::string> types;  // NAME:SIGMA:EPSILON, one per species
  std::vector<std::string> pairs;  // A:B:SIGMA:EPSILON, explicit pair values
  Mixing mixing = Mixing::kLorentzBerthelot;
  OptionList engine = command_engine_defaults();  // backend auto, precision double unless asked otherwise
  ReadOptions read;                // dimension, frame, H5MD group
  int repeats = 1;                 // evaluations timed; the file holds the last one's results
  bool quiet = false;              // no summary on stdout
  bool overwrite = false;          // an existing --out file may be replaced (refused otherwise)
};

// The force field that --cutoff, --cutoff-mode, --type, --pair and --mixing describe, and each
// species' type index in it. Without --type a file of one species gets sigma = epsilon = 1.
// Throws cellforce::Error naming the spec, the type or a particle whose species has no --type.
ForceField make_force_field(const ForcesArgs& args, const ConfigurationFile& input,
                            std::vector<uint32_t>& type_of_species);

// Runs the command; returns the process exit code (0) or throws cellforce::Error.
int run_forces(const ForcesArgs& args);

}  // namespace cellforce
