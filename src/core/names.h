// The names of the run-time choices as users write them (scene files, CLI options, the API's
// set_option), one table per enumeration: every parser and every message reads these (the options
// that take them: core/option_table.h).
#pragma once

#include <cstddef>
#include <map>
#include <optional>
#include <string>
#include <string_view>

#include <cellforce/options.hpp>

#include "core/engine_options.h"
#include "core/grid.h"

namespace cellforce {

template <class E>
struct Named {
  const char* name;
  E value;
};

inline constexpr Named<Backend> kBackendNames[] = {
    {"auto", Backend::kAuto}, {"cpu", Backend::kCpu}, {"cuda", Backend::kCuda}};
inline constexpr Named<Precision> kPrecisionNames[] = {
    {"single", Precision::kSingle}, {"mixed", Precision::kMixed}, {"double", Precision::kDouble}};
inline constexpr Named<CutoffMode> kCutoffModeNames[] = {
    {"truncate", CutoffMode::kTruncate}, {"shift", CutoffMode::kShift}, {"force-shift", CutoffMode::kForceShift}};
inline constexpr Named<Mixing> kMixingNames[] = {
    {"lorentz-berthelot", Mixing::kLorentzBerthelot}, {"geometric", Mixing::kGeometric}};
inline constexpr Named<Accumulation> kAccumulationNames[] = {
    {"jacobi", Accumulation::kJacobi}, {"gauss-seidel", Accumulation::kGaussSeidel}};
inline constexpr Named<CellRule> kCellRuleNames[] = {{"tight", CellRule::kTight}, {"chapter", CellRule::kChapter}};
inline constexpr Named<TraversalForm> kTraversalNames[] = {
    {"warp", TraversalForm::kWarpPerCell}, {"thread", TraversalForm::kThreadPerCell}, {"tile", TraversalForm::kWarpPerTile},
    {"auto", TraversalForm::kAuto}};
inline constexpr Named<SortMethod> kSortNames[] = {{"cub", SortMethod::kCub}, {"chapter", SortMethod::kChapter}};
inline constexpr Named<ListMemory> kListMemoryNames[] = {
    {"auto", ListMemory::kAuto}, {"fast", ListMemory::kFast}, {"lean", ListMemory::kLean}};
inline constexpr Named<bool> kBooleanNames[] = {{"true", true}, {"false", false}};

// Whether `a` and `b` are the same name in any letter case (ASCII): every entry point (the CLI,
// scene files, the API's set_option) reads names so, "CUDA" as "cuda".
inline bool same_name(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (std::size_t k = 0; k < a.size(); ++k) {
    const auto lower = [](char c) { return c >= 'A' && c <= 'Z' ? char(c - 'A' + 'a') : c; };
    if (lower(a[k]) != lower(b[k])) return false;
  }
  return true;
}

// The value named `name` (in any letter case), or nothing.
template <class E, std::size_t N>
std::optional<E> parse_name(std::string_view name, const Named<E> (&table)[N]) {
  for (const Named<E>& entry : table)
    if (same_name(name, entry.name)) return entry.value;
  return std::nullopt;
}

// The name of a value (the table's first for it).
template <class E, std::size_t N>
const char* name_of(E value, const Named<E> (&table)[N]) {
  for (const Named<E>& entry : table)
    if (entry.value == value) return entry.name;
  return "?";
}

// "a, b or c": the names of a table, for messages.
template <class E, std::size_t N>
std::string name_list(const Named<E> (&table)[N]) {
  std::string out;
  for (std::size_t k = 0; k < N; ++k)
    out += std::string(k == 0 ? "" : k + 1 == N ? " or " : ", ") + table[k].name;
  return out;
}

// The table as a map from name to value (for CLI11's transformers and the scene reader).
template <class E, std::size_t N>
std::map<std::string, E> name_map(const Named<E> (&table)[N]) {
  std::map<std::string, E> out;
  for (const Named<E>& entry : table) out.emplace(entry.name, entry.value);
  return out;
}

}  // namespace cellforce
