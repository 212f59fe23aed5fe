// Reading numbers that a user typed (command-line values, extended XYZ columns, option strings):
// the whole text or nothing, integers in decimal only, and a value too large for its type told
// apart from text that is no number at all, so that a message can name the real cause.
#pragma once

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <string>
#include <string_view>
#include <type_traits>

#include "core/text.h"

namespace cellforce {

enum class NumberText {
  kOk,
  kInvalid,     // not a number of the kind asked for
  kOutOfRange,  // a number, but beyond what the type holds
};

// A real number as C++ and Python read it: a leading '+' allowed, "nan" and "inf" included. A
// magnitude beyond the largest double (1e400) is out of range; one below the smallest (1e-400)
// reads as the nearest value, 0 or a subnormal, as strtod and Python give it.
inline NumberText read_real(std::string_view text, double& value) {
  const char* begin = text.data();
  const char* end = text.data() + text.size();
  if (begin != end && *begin == '+' && end - begin > 1 && begin[1] != '-') ++begin;
  if (begin == end) return NumberText::kInvalid;
  double v = 0;
  const auto [ptr, ec] = std::from_chars(begin, end, v);
  if (ptr != end) return NumberText::kInvalid;
  if (ec == std::errc::result_out_of_range) {
    // from_chars leaves no value; strtod ("C" locale: the program never sets another) tells an
    // overflow (HUGE_VAL) from an underflow (the nearest representable value).
    const std::string copy(begin, end);
    errno = 0;
    v = std::strtod(copy.c_str(), nullptr);
    if (std::isinf(v)) return NumberText::kOutOfRange;
  } else if (ec != std::errc()) {
    return NumberText::kInvalid;
  }
  value = v;
  return NumberText::kOk;
}

// An integer in decimal digits with an optional sign ("010" is ten, "0x10" and "1e3" are not
// integers); a value beyond Int's range is out of range (a '-' before an unsigned type's digits
// included), never wrapped or clamped.
template <class Int>
NumberText read_decimal(std::string_view text, Int& value) {
  static_assert(std::is_integral_v<Int> && !std::is_same_v<Int, bool>);
  std::size_t at = 0;
  const bool negative = !text.empty() && text[0] == '-';
  if (!text.empty() && (text[0] == '+' || text[0] == '-')) at = 1;
  if (at == text.size()) return NumberText::kInvalid;
  for (std::size_t k = at; k < text.size(); ++k)
    if (text[k] < '0' || text[k] > '9') return NumberText::kInvalid;
  if (negative && std::is_unsigned_v<Int>) {
    const bool zero = text.find_first_not_of('0', 1) == std::string_view::npos;
    if (!zero) return NumberText::kOutOfRange;
    value = 0;
    return NumberText::kOk;
  }
  Int v = 0;
  // from_chars takes a '-' but no '+'.
  const char* begin = text.data() + (text[0] == '+' ? 1 : 0);
  const auto [ptr, ec] = std::from_chars(begin, text.data() + text.size(), v, 10);
  if (ec == std::errc::result_out_of_range) return NumberText::kOutOfRange;
  if (ec != std::errc() || ptr != text.data() + text.size()) return NumberText::kInvalid;
  value = v;
  return NumberText::kOk;
}

// Why `text` was refused, as a message's ending: "'abc' is not a number", "'1e400' is out of range
// (beyond +-1.7976931348623157e+308)", "'0x10' is not a decimal integer", "'99999999999999999999'
// is out of range (-9223372036854775808 .. 9223372036854775807)".
inline std::string real_problem(std::string_view text, NumberText result) {
  if (result == NumberText::kOutOfRange)
    return quote_excerpt(text) + " is out of range (beyond +-" + format_number(std::numeric_limits<double>::max()) + ")";
  return quote_excerpt(text) + " is not a number";
}
template <class Int>
std::string integer_problem(std::string_view text, NumberText result) {
  if (result == NumberText::kOutOfRange)
    return quote_excerpt(text) + " is out of range (" + std::to_string(std::numeric_limits<Int>::min()) + " .. " +
           std::to_string(std::numeric_limits<Int>::max()) + ")";
  return quote_excerpt(text) + " is not a decimal integer";
}

}  // namespace cellforce
