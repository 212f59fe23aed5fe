// Names of the run-time choices, shared by the CLI and the benchmark programs.
#pragma once

#include <algorithm>
#include <cctype>
#include <map>
#include <string>
#include <vector>

#include "core/force_field.h"
#include "core/names.h"
#include "scene/lattice.h"

namespace cellforce::cli {

inline const std::map<std::string, CutoffMode> kCutoffModes = name_map(kCutoffModeNames);
inline const std::map<std::string, Mixing> kMixings = name_map(kMixingNames);
inline const std::map<std::string, Precision> kPrecisions = name_map(kPrecisionNames);
inline const std::map<std::string, Accumulation> kAccumulations = name_map(kAccumulationNames);
inline const std::map<std::string, CellRule> kCellRules = name_map(kCellRuleNames);
inline const std::map<std::string, Backend> kBackends = name_map(kBackendNames);
inline const std::map<std::string, TraversalForm> kTraversals = name_map(kTraversalNames);
inline const std::map<std::string, SortMethod> kSorts = name_map(kSortNames);
inline const std::map<std::string, ListMemory> kListMemories = name_map(kListMemoryNames);
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
