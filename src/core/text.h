// How error messages show what the user gave: numbers with every digit that tells them apart
// (5.0000001 is not printed as 5), and text from a file or the command line as a short, escaped
// excerpt (a UTF-8 byte-order mark, a NUL or a control character is shown as an escape, and a
// 10 MB line is not echoed whole).
#pragma once

#include <charconv>
#include <cstddef>
#include <string>
#include <string_view>

namespace cellforce {

// The shortest decimal text that reads back as exactly `x` (std::to_chars): 5.0000001, 2.5, 1e+300,
// inf, nan.
inline std::string format_number(double x) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof buffer, x);
  return std::string(buffer, result.ptr);
}

// `text` between single quotes, at most `max_bytes` of it (then "... (N bytes)"), with bytes that
// are not printable ASCII written as escapes: \t \n \r \0, \xHH for other control bytes and DEL,
// and the byte-order mark EF BB BF as \uFEFF. Other UTF-8 bytes (names in other scripts) are
// kept as they are.
inline std::string quote_excerpt(std::string_view text, std::size_t max_bytes = 60) {
  std::string out = "'";
  std::size_t shown = text.size() > max_bytes ? max_bytes : text.size();
  // Cut before a UTF-8 continuation byte, never inside a character.
  while (shown > 0 && shown < text.size() && (static_cast<unsigned char>(text[shown]) & 0xC0) == 0x80) --shown;
  for (std::size_t k = 0; k < shown; ++k) {
    const auto c = static_cast<unsigned char>(text[k]);
    if (text.substr(k, 3) == "\xEF\xBB\xBF") {
      out += "\\uFEFF";
      k += 2;
    } else if (c == '\t') {
      out += "\\t";
    } else if (c == '\n') {
      out += "\\n";
    } else if (c == '\r') {
      out += "\\r";
    } else if (c == 0) {
      out += "\\0";
    } else if (c < 0x20 || c == 0x7F) {
      static constexpr char kHex[] = "0123456789ABCDEF";
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 15];
    } else if (c == '\'' || c == '\\') {
      out += '\\';
      out += char(c);
    } else {
      out += char(c);
    }
  }
  out += "'";
  if (shown < text.size()) out += "... (" + std::to_string(text.size()) + " bytes)";
  return out;
}

}  // namespace cellforce
