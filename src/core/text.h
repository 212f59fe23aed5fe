// How error messages show what the user gave: numbers with every digit that tells them apart
// (5.0000001 is not printed as 5), and text from a file or the command line as a short, escaped
// excerpt (a UTF-8 byte-order mark, a NUL or a control character is shown as an escape, and a
// 10 MB line is not echoed whole).
#pragma once

#include <charconv>
#include <cstdio>
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

// `x` to six significant digits (printf's %.6g: 0.001, 2.5e+07, inf), for messages that quote
// a derived quantity rather than an input the user wrote.
inline std::string format_6g(double x) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.6g", x);
  return buffer;
}

// The length of the well-formed UTF-8 character (2 to 4 bytes: no overlong form, no surrogate,
// nothing beyond U+10FFFF) that starts at text[k], or 0 when the bytes there are not one.
inline std::size_t utf8_character(std::string_view text, std::size_t k) {
  const auto byte = [&](std::size_t j) { return k + j < text.size() ? static_cast<unsigned char>(text[k + j]) : 0u; };
  const unsigned c = byte(0);
  const auto continuation = [&](std::size_t j) { return (byte(j) & 0xC0) == 0x80; };
  if (c >= 0xC2 && c <= 0xDF) return continuation(1) ? 2 : 0;
  if (c >= 0xE0 && c <= 0xEF) {
    const unsigned lo = c == 0xE0 ? 0xA0 : 0x80, hi = c == 0xED ? 0x9F : 0xBF;
    return byte(1) >= lo && byte(1) <= hi && continuation(2) ? 3 : 0;
  }
  if (c >= 0xF0 && c <= 0xF4) {
    const unsigned lo = c == 0xF0 ? 0x90 : 0x80, hi = c == 0xF4 ? 0x8F : 0xBF;
    return byte(1) >= lo && byte(1) <= hi && continuation(2) && continuation(3) ? 4 : 0;
  }
  return 0;
}

// `text` between single quotes, at most `max_bytes` of it (then "... (N bytes)"), with bytes that
// are not printable ASCII written as escapes: \t \n \r \0, \xHH for other control bytes, DEL
// and bytes that are no well-formed UTF-8 (a binary or compressed file's), and the byte-order mark
// EF BB BF as \uFEFF. Well-formed UTF-8 characters (names in other scripts) are kept as they are.
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
    } else if (c < 0x20 || c == 0x7F || (c >= 0x80 && utf8_character(text.substr(0, shown), k) == 0)) {
      static constexpr char kHex[] = "0123456789ABCDEF";
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 15];
    } else if (c >= 0x80) {
      const std::size_t length = utf8_character(text, k);
      out.append(text.substr(k, length));
      k += length - 1;
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

// A file name in a message: as given when it is short and plain (printable ASCII or well-formed
// UTF-8, at most `max_bytes`), else as quote_excerpt shows it (a 100 KB name is cut, a control
// byte escaped).
inline std::string display_path(std::string_view path, std::size_t max_bytes = 200) {
  bool plain = path.size() <= max_bytes;
  for (std::size_t k = 0; plain && k < path.size(); ++k) {
    const auto c = static_cast<unsigned char>(path[k]);
    if (c >= 0x80) {
      const std::size_t length = utf8_character(path, k);
      plain = length > 0 && path.substr(k, 3) != "\xEF\xBB\xBF";
      k += length > 0 ? length - 1 : 0;
    } else {
      plain = c >= 0x20 && c != 0x7F;
    }
  }
  return plain ? std::string(path) : quote_excerpt(path, max_bytes);
}

// What a file's first bytes say when they are the signature of a compressed format: a hint for a
// message about a file that could not be read as text ("" otherwise).
inline std::string compressed_hint(std::string_view head) {
  struct Signature {
    std::string_view bytes, format, tool;
  };
  static constexpr Signature kSignatures[] = {{"\x1F\x8B", "gzip", "gunzip"},
                                              {"BZh", "bzip2", "bunzip2"},
                                              {"\xFD" "7zXZ", "xz", "unxz"},
                                              {"\x28\xB5\x2F\xFD", "zstd", "unzstd"},
                                              {"PK\x03\x04", "zip", "unzip"}};
  for (const Signature& s : kSignatures)
    if (head.substr(0, s.bytes.size()) == s.bytes)
      return " (the file starts with the " + std::string(s.format) + " signature: compressed? decompress it first, e.g. with " +
             std::string(s.tool) + ")";
  return {};
}

}  // namespace cellforce
