// Names of the physics' and the lattices' choices as the CLI's flags read them (the engine options'
// names: core/option_table.h), and helpers shared by the CLI and the benchmark programs.
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
inline const std::map<std::string, Lattice> kLattices = name_map(kLatticeNames);

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
