// The engine options by name: every key that the public API's Context::set_option (and
// cf_set_option) takes, what its value is, the names of a choice's values (names.h's tables) and
// the value a new Context has. The one table behind every place an option is named: set_option
// finds its keys here (and lists them when a key is unknown), a new Context takes its defaults
// from here, the scene reader and the command line's flags check values against it where they
// enter, and the commands hand the checked (key, value) pairs to set_option (OptionList).
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "core/names.h"

namespace cellforce {

enum class OptionId : uint8_t {
  kBackend,
  kDevice,
  kPrecision,
  kMixing,
  kCutoffMode,
  kSkin,
  kNeighborCheck,
  kNeighborEvery,
  kNeighborAudit,
  kNeighborList,
  kAccumulation,
  kCellRule,
  kTraversal,
  kSort,
  kMemory,
  kThreads,
};

// What an option's value is, as text.
enum class OptionKind : uint8_t {
  kChoice,   // one of the option's names, in any letter case
  kBoolean,  // true or false, in any letter case
  kInteger,  // a decimal integer (device: an ordinal >= 0; neighbor-every: a count >= 0)
  kSkin,     // kAutoSkin, or a length >= 0
  kThreads,  // kAutoThreads, or a count >= 0 (0: as auto)
};

// The names of a table's values, in the table's order.
struct NameList {
  const char* const* names = nullptr;
  std::size_t size = 0;
  const char* const* begin() const { return names; }
  const char* const* end() const { return names + size; }
};

namespace option_detail {
template <std::size_t N>
struct Names {
  const char* names[N];
};
template <class E, std::size_t N>
constexpr Names<N> names_of(const Named<E> (&table)[N]) {
  Names<N> out{};
  for (std::size_t k = 0; k < N; ++k) out.names[k] = table[k].name;
  return out;
}
template <std::size_t N>
constexpr NameList list(const Names<N>& names) {
  return NameList{names.names, N};
}
inline constexpr auto kBackend = names_of(kBackendNames);
inline constexpr auto kPrecision = names_of(kPrecisionNames);
inline constexpr auto kMixing = names_of(kMixingNames);
inline constexpr auto kCutoffMode = names_of(kCutoffModeNames);
inline constexpr auto kBoolean = names_of(kBooleanNames);
inline constexpr auto kAccumulation = names_of(kAccumulationNames);
inline constexpr auto kCellRule = names_of(kCellRuleNames);
inline constexpr auto kTraversal = names_of(kTraversalNames);
inline constexpr auto kSort = names_of(kSortNames);
inline constexpr auto kMemory = names_of(kListMemoryNames);
}  // namespace option_detail

// The skin's value that lets the engine choose (resolve_reuse): skin, neighbour lists and their
// memory from the backend, the system and the device.
inline constexpr const char* kAutoSkin = "auto";
// The thread count's value that leaves it to OpenMP (omp_get_max_threads(); also written 0).
inline constexpr const char* kAutoThreads = "auto";

struct OptionSpec {
  OptionId id;
  const char* key;            // as set_option takes it (and the command line's --KEY)
  OptionKind kind;
  NameList names;             // kChoice and kBoolean: the values' names
  const char* default_value;  // what a new Context has
};

// In the order that the unknown-key message lists them (the documentation's order in
// include/cellforce/cellforce.hpp).
inline constexpr OptionSpec kOptions[] = {
    {OptionId::kBackend, "backend", OptionKind::kChoice, option_detail::list(option_detail::kBackend), "cpu"},
    {OptionId::kDevice, "device", OptionKind::kInteger, {}, "0"},
    {OptionId::kPrecision, "precision", OptionKind::kChoice, option_detail::list(option_detail::kPrecision), "double"},
    {OptionId::kMixing, "mixing", OptionKind::kChoice, option_detail::list(option_detail::kMixing),
     "lorentz-berthelot"},
    {OptionId::kCutoffMode, "cutoff-mode", OptionKind::kChoice, option_detail::list(option_detail::kCutoffMode),
     "truncate"},
    {OptionId::kSkin, "skin", OptionKind::kSkin, {}, kAutoSkin},
    {OptionId::kNeighborCheck, "neighbor-check", OptionKind::kBoolean, option_detail::list(option_detail::kBoolean),
     "true"},
    {OptionId::kNeighborEvery, "neighbor-every", OptionKind::kInteger, {}, "0"},
    {OptionId::kNeighborAudit, "neighbor-audit", OptionKind::kBoolean, option_detail::list(option_detail::kBoolean),
     "false"},
    {OptionId::kNeighborList, "neighbor-list", OptionKind::kBoolean, option_detail::list(option_detail::kBoolean),
     "false"},
    {OptionId::kAccumulation, "accumulation", OptionKind::kChoice, option_detail::list(option_detail::kAccumulation),
     "jacobi"},
    {OptionId::kCellRule, "cell-rule", OptionKind::kChoice, option_detail::list(option_detail::kCellRule), "tight"},
    {OptionId::kTraversal, "traversal", OptionKind::kChoice, option_detail::list(option_detail::kTraversal), "auto"},
    {OptionId::kSort, "sort", OptionKind::kChoice, option_detail::list(option_detail::kSort), "cub"},
    {OptionId::kMemory, "memory", OptionKind::kChoice, option_detail::list(option_detail::kMemory), "auto"},
    {OptionId::kThreads, "threads", OptionKind::kThreads, {}, kAutoThreads},
};

// The option of a key as set_option takes it (exact: keys are not case-folded), or null.
inline const OptionSpec* find_option(std::string_view key) {
  for (const OptionSpec& o : kOptions)
    if (key == o.key) return &o;
  return nullptr;
}

inline const OptionSpec& option_spec(OptionId id) {
  for (const OptionSpec& o : kOptions)
    if (o.id == id) return o;
  return kOptions[0];  // unreachable: every id has its row
}

inline const char* option_key(OptionId id) { return option_spec(id).key; }

// "backend, device, ...": every key, for messages.
inline std::string option_keys() {
  std::string out;
  for (const OptionSpec& o : kOptions) out += std::string(out.empty() ? "" : ", ") + o.key;
  return out;
}

// The name of a choice's or a boolean's value as the table spells it, for `value` in any letter
// case; null when it names none.
inline const char* option_name(OptionId id, std::string_view value) {
  for (const char* name : option_spec(id).names)
    if (same_name(value, name)) return name;
  return nullptr;
}

// "a, b or c": the names, for messages (as names.h's name_list).
inline std::string name_list(const NameList& names) {
  std::string out;
  for (std::size_t k = 0; k < names.size; ++k)
    out += std::string(k == 0 ? "" : k + 1 == names.size ? " or " : ", ") + names.names[k];
  return out;
}

// Engine options as the commands hold them until a Context takes them (set_option, in order):
// (option, value) pairs, each option once, in the order first given (setting one again replaces
// its value in place). The values are checked where they entered (a scene file's line, a command
// line flag) and spelled as the table spells names (lower case).
class OptionList {
 public:
  struct Entry {
    OptionId id;
    std::string value;
    const char* key() const { return option_key(id); }
    bool operator==(const Entry& other) const { return id == other.id && value == other.value; }
  };

  void set(OptionId id, std::string value) {
    for (Entry& e : entries_)
      if (e.id == id) {
        e.value = std::move(value);
        return;
      }
    entries_.push_back(Entry{id, std::move(value)});
  }
  // The value given for `id`, or null.
  const std::string* find(OptionId id) const {
    for (const Entry& e : entries_)
      if (e.id == id) return &e.value;
    return nullptr;
  }
  // The value given for `id`, else the one a new Context has.
  std::string value(OptionId id) const {
    const std::string* v = find(id);
    return v ? *v : std::string(option_spec(id).default_value);
  }
  // A boolean option's value (given, else the default).
  bool flag(OptionId id) const {
    const std::optional<bool> v = parse_name(value(id), kBooleanNames);
    return v && *v;
  }
  const std::vector<Entry>& entries() const { return entries_; }
  bool operator==(const OptionList& other) const { return entries_ == other.entries_; }

 private:
  std::vector<Entry> entries_;
};

}  // namespace cellforce
