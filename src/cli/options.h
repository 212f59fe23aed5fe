// Names of the run-time choices, shared by the CLI and the benchmark programs.
#pragma once

#include <map>
#include <string>

#include "core/force_field.h"
#include "cpu/engine.h"
#include "scene/lattice.h"

namespace cellforce::cli {

inline const std::map<std::string, CutoffMode> kCutoffModes = {
    {"truncate", CutoffMode::kTruncate},
    {"shift", CutoffMode::kShift},
    {"force-shift", CutoffMode::kForceShift}};
inline const std::map<std::string, Precision> kPrecisions = {
    {"single", Precision::kSingle}, {"mixed", Precision::kMixed}, {"double", Precision::kDouble}};
inline const std::map<std::string, Accumulation> kAccumulations = {
    {"jacobi", Accumulation::kJacobi}, {"gauss-seidel", Accumulation::kGaussSeidel}};
inline const std::map<std::string, CellRule> kCellRules = {{"tight", CellRule::kTight},
                                                           {"chapter", CellRule::kChapter}};
inline const std::map<std::string, Lattice> kLattices = {{"sc", Lattice::kSimpleCubic},
                                                         {"bcc", Lattice::kBcc},
                                                         {"fcc", Lattice::kFcc},
                                                         {"square", Lattice::kSquare}};

}  // namespace cellforce::cli
