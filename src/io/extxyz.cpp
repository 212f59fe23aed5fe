// Extended XYZ, as ASE writes it: a count line, a line of key=value pairs (values in double quotes
// when they hold spaces), and one line per particle whose columns the Properties key describes.
#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <unordered_map>

#include "core/error.h"
#include "core/numbers.h"
#include "core/text.h"
#include "io/configuration_file.h"
#include "io/text_file.h"

namespace cellforce {
namespace {

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return s;
}

std::vector<std::string> split_ws(const std::string& line) {
  std::vector<std::string> out;
  std::istringstream in(line);
  for (std::string t; in >> t;) out.push_back(t);
  return out;
}

// The key=value pairs of the comment line, as ASE writes and reads them: values bare, in double
// or single quotes (a backslash escapes the next character), or in [] or {} brackets (commas
// read as spaces); keys lower-cased; a bare key reads as "T".
std::map<std::string, std::string> parse_header(const std::string& line, const std::string& where) {
  std::map<std::string, std::string> kv;
  std::size_t k = 0;
  const std::size_t n = line.size();
  auto skip_ws = [&] { while (k < n && std::isspace(static_cast<unsigned char>(line[k]))) ++k; };
  auto token = [&](bool stop_at_equals) {
    std::string t;
    if (k < n && (line[k] == '"' || line[k] == '\'')) {
      const char quote = line[k++];
      for (; k < n && line[k] != quote; ++k) {
        if (line[k] == '\\' && k + 1 < n) ++k;
        t += line[k];
      }
      if (k >= n) throw Error(where + ": unterminated " + std::string(1, quote) + " quote in the comment line");
      ++k;
      return t;
    }
    if (!stop_at_equals && k < n && (line[k] == '[' || line[k] == '{')) {
      const char close = line[k] == '[' ? ']' : '}';
      const std::size_t end = line.find(close, k + 1);
      if (end == std::string::npos)
        throw Error(where + ": unterminated " + quote_excerpt(std::string_view(&line[k], 1)) + " in the comment line");
      t = line.substr(k + 1, end - k - 1);
      std::replace(t.begin(), t.end(), ',', ' ');
      k = end + 1;
      return t;
    }
    while (k < n && !std::isspace(static_cast<unsigned char>(line[k])) && !(stop_at_equals && line[k] == '='))
      t += line[k++];
    return t;
  };
  for (skip_ws(); k < n; skip_ws()) {
    const std::string key = token(true);
    skip_ws();
    if (k < n && line[k] == '=') {
      ++k;
      skip_ws();
      kv[lower(key)] = token(false);
    } else {
      kv.insert_or_assign(lower(key), std::string(1, 'T'));  // (= "T" trips GCC 12's -Wrestrict)
    }
  }
  return kv;
}

bool parse_flag(const std::string& s, bool& value) {
  const std::string l = lower(s);
  if (l == "t" || l == "true" || l == "1") return value = true, true;
  if (l == "f" || l == "false" || l == "0") return value = false, true;
  return false;
}

struct Columns {
  std::size_t total = 0;
  std::size_t species = 0;
  std::size_t pos = 0;
};

Columns parse_properties(const std::string& spec, const std::string& where) {
  std::vector<std::string> parts;
  std::stringstream in(spec);
  for (std::string p; std::getline(in, p, ':');) parts.push_back(p);
  if (parts.size() % 3 != 0)
    throw Error(where + ": Properties=" + quote_excerpt(spec) + " is not a list of name:type:count");
  Columns c;
  bool have_species = false, have_pos = false;
  std::set<std::string> names;
  for (std::size_t k = 0; k < parts.size(); k += 3) {
    const std::string name = lower(parts[k]);
    // Two columns of one name leave it unclear which one is meant (ASE keeps a dictionary).
    if (!names.insert(name).second)
      throw Error(where + ": Properties: " + quote_excerpt(parts[k]) + " is described twice in " + quote_excerpt(spec));
    const std::string type = lower(parts[k + 1]);
    int count = 0;
    auto [ptr, ec] = std::from_chars(parts[k + 2].data(), parts[k + 2].data() + parts[k + 2].size(), count);
    if (ec != std::errc() || ptr != parts[k + 2].data() + parts[k + 2].size() || count < 1)
      throw Error(where + ": Properties: " + quote_excerpt(parts[k + 2]) + " is not a column count");
    if (name == "species") {
      if (type != "s" || count != 1) throw Error(where + ": Properties: species must be species:S:1");
      c.species = c.total;
      have_species = true;
    } else if (name == "pos") {
      if (type != "r" || count != 3) throw Error(where + ": Properties: pos must be pos:R:3");
      c.pos = c.total;
      have_pos = true;
    }
    c.total += std::size_t(count);
  }
  if (!have_species || !have_pos)
    throw Error(where + ": Properties=" + quote_excerpt(spec) + " needs species:S:1 and pos:R:3");
  return c;
}

// Where each frame starts (its count line, 0-based), checking only the counts.
std::vector<std::size_t> frame_starts(const std::vector<std::string>& lines, const std::string& path) {
  std::vector<std::size_t> starts;
  std::size_t at = 0;
  while (at < lines.size()) {
    if (split_ws(lines[at]).empty()) {  // blank lines after the last frame
      ++at;
      continue;
    }
    const std::vector<std::string> t = split_ws(lines[at]);
    long long count = -1;
    auto [ptr, ec] = std::from_chars(t[0].data(), t[0].data() + t[0].size(), count);
    if (t.size() != 1 || ec != std::errc() || ptr != t[0].data() + t[0].size() || count < 0)
      throw Error(path + ":" + std::to_string(at + 1) + ": expected a particle count, found " + quote_excerpt(lines[at]) +
                  (lines[at].rfind("\xEF\xBB\xBF", 0) == 0 ? " (the file starts with a UTF-8 byte-order mark; save it without one)" : "") +
                  (at == 0 ? compressed_hint(lines[at]) : ""));
    if (at + 2 + std::size_t(count) > lines.size())
      throw Error(path + ":" + std::to_string(at + 1) + ": the frame declares " + std::to_string(count) +
                  " particles but the file ends after " +
                  std::to_string(lines.size() - std::min(lines.size(), at + 2)));
    starts.push_back(at);
    at += 2 + std::size_t(count);
  }
  return starts;
}

}  // namespace

ConfigurationFile read_extxyz(const std::string& file, const ReadOptions& options) {
  const std::string path = display_path(file);  // as messages show it
  std::ifstream in(file);
  if (!in) throw Error(path + ": cannot open the file");
  std::vector<std::string> lines;
  for (std::string l; std::getline(in, l);) {
    if (!l.empty() && l.back() == '\r') l.pop_back();
    lines.push_back(l);
  }
  const int dim = options.dim == 0 ? 3 : options.dim;
  if (dim != 2 && dim != 3) throw Error(path + ": dimension must be 2 or 3, got " + std::to_string(dim));

  const std::vector<std::size_t> starts = frame_starts(lines, path);
  if (starts.empty()) throw Error(path + ": no frame in the file");
  const long frames = long(starts.size());
  const long frame = options.frame < 0 ? frames + options.frame : options.frame;
  if (frame < 0 || frame >= frames)
    throw Error(path + ": frame " + std::to_string(options.frame) + " requested, the file holds " +
                std::to_string(frames));
  const std::size_t head = starts[std::size_t(frame)];
  const std::size_t n = std::size_t(std::stoll(split_ws(lines[head])[0]));
  const std::string where2 = path + ":" + std::to_string(head + 2);
  const auto kv = parse_header(lines[head + 1], where2);

  const auto prop = kv.find("properties");
  const Columns cols = parse_properties(prop == kv.end() ? "species:S:1:pos:R:3" : prop->second, where2);

  ConfigurationFile out;
  out.source = path + (frames > 1 ? " (frame " + std::to_string(frame) + ")" : "");
  Box& box = out.config.box;
  box.dim = dim;
  bool have_lattice = false;
  double lattice[9] = {};
  if (auto it = kv.find("lattice"); it != kv.end()) {
    const std::vector<std::string> t = split_ws(it->second);
    if (t.size() != 9) throw Error(where2 + ": Lattice needs 9 numbers, found " + std::to_string(t.size()));
    for (int k = 0; k < 9; ++k)
      if (const NumberText r = read_real(t[std::size_t(k)], lattice[k]); r == NumberText::kOutOfRange)
        throw Error(where2 + ": Lattice: " + real_problem(t[std::size_t(k)], r));
      else if (r != NumberText::kOk || !std::isfinite(lattice[k]))
        throw Error(where2 + ": Lattice: " + quote_excerpt(t[std::size_t(k)]) + " is not a finite number");
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        if (r != c && lattice[3 * r + c] != 0.0)
          throw Error(where2 + ": Lattice is not orthorhombic (vector " + std::to_string(r + 1) +
                      " has an off-diagonal component); cellforce supports rectangular boxes only");
    have_lattice = true;
  }
  bool pbc[3] = {have_lattice, have_lattice, have_lattice};
  if (auto it = kv.find("pbc"); it != kv.end()) {
    const std::vector<std::string> t = split_ws(it->second);
    if (t.size() != 3 || !parse_flag(t[0], pbc[0]) || !parse_flag(t[1], pbc[1]) || !parse_flag(t[2], pbc[2]))
      throw Error(where2 + ": pbc=" + quote_excerpt(it->second) + " must be three of T/F");
  }
  for (int a = 0; a < dim; ++a) {
    box.periodic[a] = pbc[a];
    if (pbc[a] && !have_lattice)
      throw Error(where2 + ": pbc makes axis " + std::string(1, "xyz"[a]) + " periodic but no Lattice gives its length");
    if (pbc[a] && !(lattice[4 * a] > 0))
      throw Error(where2 + ": the periodic axis " + std::string(1, "xyz"[a]) + " has Lattice length " +
                  format_number(lattice[4 * a]) + "; it must be > 0");
  }
  for (int a = dim; a < kMaxDim; ++a) {
    box.periodic[a] = false;
    box.length[a] = 0.0;
  }

  std::unordered_map<std::string, uint32_t> index;
  out.config.positions.resize(n * std::size_t(dim));
  out.config.types.resize(n);
  double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t line = head + 2 + i;
    const std::string where = path + ":" + std::to_string(line + 1) + ": particle " + std::to_string(i);
    const std::vector<std::string> t = split_ws(lines[line]);
    if (t.size() != cols.total)
      throw Error(where + ": " + std::to_string(t.size()) + " columns, Properties describes " +
                  std::to_string(cols.total));
    double x[3];
    for (int a = 0; a < 3; ++a) {
      if (const NumberText r = read_real(t[cols.pos + std::size_t(a)], x[a]); r != NumberText::kOk)
        throw Error(where + ": coordinate " + std::string(1, "xyz"[a]) + ": " + real_problem(t[cols.pos + std::size_t(a)], r));
      if (!std::isfinite(x[a]))
        throw Error(where + ": coordinate " + std::string(1, "xyz"[a]) + " is " + format_number(x[a]) +
                    "; coordinates must be finite");
    }
    if (dim == 2 && x[2] != 0.0)
      throw Error(where + ": z = " + format_number(x[2]) + ", but a 2D configuration needs z = 0 exactly");
    for (int a = 0; a < dim; ++a) {
      out.config.positions[i * std::size_t(dim) + std::size_t(a)] = x[a];
      lo[a] = std::min(lo[a], x[a]);
      hi[a] = std::max(hi[a], x[a]);
    }
    const std::string& s = t[cols.species];
    auto [it, added] = index.try_emplace(s, uint32_t(out.species.size()));
    if (added) out.species.push_back(s);
    out.config.types[i] = it->second;
  }
  // An open axis's length only informs (the grid covers the particles wherever they are).
  for (int a = 0; a < dim; ++a)
    box.length[a] = have_lattice && lattice[4 * a] > 0 ? lattice[4 * a]
                                                       : std::max(1.0, n ? hi[a] - lo[a] : 1.0);
  return out;
}

void write_extxyz(const std::string& path, const Configuration& config,
                  const std::vector<std::string>& species) {
  const int dim = config.box.dim;
  const double* L = config.box.length;
  const bool* p = config.box.periodic;
  std::string text;
  char line[512];
  std::snprintf(line, sizeof line,
                "%zu\nLattice=\"%.17g 0 0 0 %.17g 0 0 0 %.17g\" Properties=species:S:1:pos:R:3 pbc=\"%c %c %c\"\n",
                config.size(), L[0], L[1], dim == 3 ? L[2] : 1.0, p[0] ? 'T' : 'F', p[1] ? 'T' : 'F',
                dim == 3 && p[2] ? 'T' : 'F');
  text += line;
  for (std::size_t i = 0; i < config.size(); ++i) {
    const double* x = &config.positions[i * std::size_t(dim)];
    const uint32_t t = config.types.empty() ? 0 : config.types[i];
    if (t >= species.size())
      throw Error(path + ": particle " + std::to_string(i) + " has type " + std::to_string(t) + " but only " +
                  std::to_string(species.size()) + " species are named");
    std::snprintf(line, sizeof line, " %.17g %.17g %.17g\n", x[0], x[1], dim == 3 ? x[2] : 0.0);
    text += species[t];
    text += line;
  }
  // Whole or not at all, under a temporary name of its own (text_file.h).
  write_bytes_atomically(path, text.data(), text.size(), "the configuration");
}

}  // namespace cellforce
