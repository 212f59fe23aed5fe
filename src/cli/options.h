// Names of the run-time choices, shared by the CLI and the benchmark programs.
#pragma once

#include <algorithm>
#include <cctype>
#include <map>
#include <string>
#include <vector>

#include "core/force_field.h"
#include "cpu/engine.h"
#include "scene/lattice.h"

namespace cellforce::cli {

inline const std::map<std::string, CutoffMode> kCutoffModes = {
    {"truncate", CutoffMode::kTruncate},
    {"shift", CutoffMode::kShift},
    {"force-shift", CutoffMode::kForceShift}};
inline const std::map<std::string, Mixing> kMixings = {
    {"lorentz-berthelot", Mixing::kLorentzBerthelot}, {"geometric", Mixing::kGeometric}};
inline const std::map<std::string, Precision> kPrecisions = {
    {"single", Precision::kSingle}, {"mixed", Precision::kMixed}, {"double", Precision::kDouble}};
inline const std::map<std::string, Accumulation> kAccumulations = {
    {"jacobi", Accumulation::kJacobi}, {"gauss-seidel", Accumulation::kGaussSeidel}};
inline const std::map<std::string, CellRule> kCellRules = {{"tight", CellRule::kTight},
                                                           {"chapter", CellRule::kChapter}};
inline const std::map<std::string, Lattice> kLattices = {{"sc", Lattice::kSimpleCubic},
                                                         {"bcc", Lattice::kBcc},
                                                         {"fcc", Lattice::kFcc},
                                                         {"square", Lattice::kSquare},
                                                         {"hexagonal", Lattice::kHexagonal}};

inline std::string lowercase(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return s;
}

// Median of a sample (the middle two averaged for an even count); v must not be empty.
inline double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t m = v.size() / 2;
  return v.size() % 2 ? v[m] : 0.5 * (v[m - 1] + v[m]);
}

}  // namespace cellforce::cli
