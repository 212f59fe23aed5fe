// Numbers on the command line, read by one rule for every option of every command: integers in
// decimal only ("010" is ten, not eight; "0x10" is refused), a value beyond the option's type
// refused (never clamped or wrapped), real numbers finite, "1e400" out of range rather than "not a
// number", and the option's own limit said as a rule ("must be > 0, got 0").
//
// CLI11 converts an option's text with strtoll/strtoull in base 0 (octal, hex, a clamped
// overflow) and strtold; the transform here runs first, refuses what those would misread, and
// hands CLI11 the value in a form it reads exactly (decimal digits; a hexadecimal float).
#pragma once

#include <CLI/CLI.hpp>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <limits>
#include <map>
#include <string>
#include <type_traits>
#include <vector>

#include "core/numbers.h"
#include "core/option_table.h"
#include "core/text.h"
#include "cli/options.h"

namespace cellforce::cli {

// What an option accepts beyond its type's range, written as the rule that messages state.
struct Limits {
  double min = -std::numeric_limits<double>::infinity();
  bool above_min = false;  // min itself excluded (> min rather than >= min)
  double max = std::numeric_limits<double>::infinity();

  bool admits(double v) const { return (above_min ? v > min : v >= min) && v <= max; }
  std::string rule() const {
    if (std::isfinite(min) && std::isfinite(max)) return "must be between " + show(min) + " and " + show(max);
    if (std::isfinite(min)) return std::string("must be ") + (above_min ? "> " : ">= ") + show(min);
    if (std::isfinite(max)) return "must be <= " + show(max);
    return {};
  }
  // 100000 rather than format_number's 1e+05.
  static std::string show(double v) {
    return v == std::floor(v) && std::abs(v) < 1e15 ? std::to_string(static_cast<long long>(v)) : format_number(v);
  }
};
inline const Limits kAnyValue{};
inline const Limits kPositive{0.0, true};
inline const Limits kNonNegative{0.0, false};
inline Limits between(double lo, double hi) { return Limits{lo, false, hi}; }

template <class T>
struct NumberKind {
  using type = T;
};
template <class T>
struct NumberKind<std::vector<T>> {
  using type = T;
};

// The transform of one value of type T (an integer or a real type) under `limits`.
template <class T>
CLI::Validator number(const Limits& limits = kAnyValue) {
  static_assert(std::is_arithmetic_v<T> && !std::is_same_v<T, bool>);
  return CLI::Validator(
      [limits](std::string& text) -> std::string {
        if constexpr (std::is_integral_v<T>) {
          T v{};
          if (const NumberText r = read_decimal(text, v); r != NumberText::kOk) return integer_problem<T>(text, r);
          if (!limits.admits(double(v))) return limits.rule() + ", got " + std::to_string(v);
          text = std::to_string(v);
        } else {
          double v = 0;
          if (const NumberText r = read_real(text, v); r != NumberText::kOk) return real_problem(text, r);
          if (!std::isfinite(v)) return "must be a finite number, got " + quote_excerpt(text);
          if (!limits.admits(v)) return limits.rule() + ", got " + format_number(v);
          // A hexadecimal float: CLI11's strtold reads it exactly (a decimal text would be rounded
          // twice, to long double and then to double).
          char buffer[64];
          const auto end = std::to_chars(buffer, buffer + sizeof buffer, v, std::chars_format::hex).ptr;
          const bool negative = buffer[0] == '-';
          text = std::string(negative ? "-0x" : "0x") + std::string(buffer + (negative ? 1 : 0), end);
        }
        return {};
      },
      limits.rule().empty() ? "" : limits.rule().substr(8));  // "> 0", ">= 0", "between 2 and 3"
}

// add_option for a number or a vector of numbers, read by the rule above. The type name in --help
// is INTEGER or NUMBER (CLI11's own options say INT, UINT or FLOAT: a test looks for those to find an
// option added without this).
template <class T>
CLI::Option* add_number(CLI::App* cmd, const std::string& name, T& variable, const std::string& description,
                        const Limits& limits = kAnyValue) {
  using Value = typename NumberKind<T>::type;
  return cmd->add_option(name, variable, description)
      ->transform(number<Value>(limits))
      ->type_name(std::is_integral_v<Value> ? "INTEGER" : "NUMBER");
}

// A name from `names` in any letter case (as every entry point reads names: the scene, the API's
// set_option), handed on in lower case.
template <class T>
CLI::Validator name_in(const std::map<std::string, T>& names) {
  std::string keys;
  for (const auto& entry : names) keys += (keys.empty() ? "" : ", ") + entry.first;
  return CLI::Validator(
      [names, keys](std::string& value) -> std::string {
        if (!names.count(lowercase(value))) return quote_excerpt(value) + " is not one of " + keys;
        value = lowercase(value);
        return {};
      },
      "{" + keys + "}");
}

// The same for an engine option's names (core/option_table.h), listed in order as above.
inline CLI::Validator name_in(const NameList& names) {
  std::map<std::string, const char*> map;
  for (const char* name : names) map.emplace(name, name);
  return name_in(map);
}

// An existing file that is not a folder (CLI::ExistingFile, with the name shown as display_path
// shows it: a 100 KB name is cut, control bytes escaped).
inline CLI::Validator existing_file() {
  return CLI::Validator(
      [](std::string& path) -> std::string {
        std::error_code error;
        const auto status = std::filesystem::status(path, error);
        if (!std::filesystem::exists(status)) return "no such file: " + display_path(path);
        if (std::filesystem::is_directory(status)) return display_path(path) + " is a folder, not a file";
        return {};
      },
      "FILE");
}

}  // namespace cellforce::cli
