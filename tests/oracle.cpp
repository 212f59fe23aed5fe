#include "oracle.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <numeric>
#include <sstream>
#include <stdexcept>
#include <unordered_map>

namespace cftest {

std::vector<std::pair<uint32_t, uint32_t>> stable_sorted_with_positions(
    const std::vector<uint32_t>& keys, int key_bits) {
  const uint32_t window = key_bits >= 32 ? 0xffffffffu : (uint32_t(1) << key_bits) - 1;
  std::vector<std::pair<uint32_t, uint32_t>> sorted;
  for (std::size_t i = 0; i < keys.size(); ++i) sorted.emplace_back(keys[i], uint32_t(i));
  std::stable_sort(sorted.begin(), sorted.end(),
                   [&](const auto& a, const auto& b) { return (a.first & window) < (b.first & window); });
  return sorted;
}


cellforce::Box make_box(int dim, std::array<double, 3> lengths, std::array<bool, 3> periodic) {
  cellforce::Box b;
  b.dim = dim;
  for (int a = 0; a < 3; ++a) {
    b.length[a] = lengths[std::size_t(a)];
    b.periodic[a] = periodic[std::size_t(a)];
  }
  return b;
}

cellforce::Box cube(int dim, double l, bool periodic) {
  return make_box(dim, {l, l, l}, {periodic, periodic, periodic});
}


using cellforce::Box;
using cellforce::Configuration;
using cellforce::ForceResult;

// ---- Rng -----------------------------------------------------------------------------------------
uint64_t Rng::next() {
  uint64_t z = (state_ += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}
double Rng::uniform() { return double(next() >> 11) * 0x1.0p-53; }
double Rng::uniform(double lo, double hi) {
  const double x = lo + (hi - lo) * uniform();
  return x < hi ? x : lo;  // rounding can reach hi
}
std::size_t Rng::below(std::size_t n) { return std::size_t(next() % n); }

// ---- configurations ------------------------------------------------------------------------------
namespace {
double min_image_d2(const Box& box, const double* a, const double* b) {
  double r2 = 0;
  for (int k = 0; k < box.dim; ++k) {
    double d = a[k] - b[k];
    if (box.periodic[k]) d -= box.length[k] * std::rint(d / box.length[k]);
    r2 += d * d;
  }
  return r2;
}
}  // namespace

namespace {
// Bins of edge >= min_distance, so that a new particle need only be checked against the particles
// of its own and the neighbouring bins (periodic axes wrap). Gives the same accept/reject
// decisions as checking every particle, in O(1) per trial.
class Bins {
 public:
  Bins(const Box& box, const double* lo, const double* hi, double width) : box_(box) {
    for (int k = 0; k < 3; ++k) {
      if (k >= box.dim) {
        n_[k] = 1;
        continue;
      }
      periodic_[k] = box.periodic[k];
      origin_[k] = periodic_[k] ? 0.0 : lo[k];
      const double extent = periodic_[k] ? box.length[k] : hi[k] - lo[k];
      n_[k] = std::max<long>(1, std::min<long>(long(extent / width), 1L << 20));
      width_[k] = extent > 0 ? extent / double(n_[k]) : 1.0;
    }
  }
  template <class F>
  bool all_neighbours(const double* x, F&& ok) const {
    long c[3];
    coords(x, c);
    long lo[3], hi[3];
    for (int k = 0; k < 3; ++k) {
      if (n_[k] <= 3 && (periodic_[k] || k >= box_.dim)) {
        lo[k] = 0;
        hi[k] = n_[k] - 1;
      } else {
        lo[k] = c[k] - 1;
        hi[k] = c[k] + 1;
      }
    }
    for (long a = lo[0]; a <= hi[0]; ++a)
      for (long b = lo[1]; b <= hi[1]; ++b)
        for (long d = lo[2]; d <= hi[2]; ++d) {
          auto it = map_.find(key(a, b, d));
          if (it == map_.end()) continue;
          for (std::size_t j : it->second)
            if (!ok(j)) return false;
        }
    return true;
  }
  void insert(const double* x, std::size_t j) {
    long c[3];
    coords(x, c);
    map_[key(c[0], c[1], c[2])].push_back(j);
  }

 private:
  void coords(const double* x, long c[3]) const {
    for (int k = 0; k < 3; ++k) {
      if (k >= box_.dim) {
        c[k] = 0;
        continue;
      }
      double u = x[k] - origin_[k];
      if (periodic_[k]) u -= box_.length[k] * std::floor(u / box_.length[k]);
      c[k] = long(std::floor(u / width_[k]));
      if (periodic_[k]) c[k] = std::min(std::max(c[k], 0L), n_[k] - 1);
    }
  }
  uint64_t key(long a, long b, long d) const {
    auto wrap = [&](long v, int k) {
      if (periodic_[k] || k >= box_.dim) return ((v % n_[k]) + n_[k]) % n_[k];
      return v;
    };
    const uint64_t ua = uint64_t(wrap(a, 0) + (1L << 20)), ub = uint64_t(wrap(b, 1) + (1L << 20)),
                   ud = uint64_t(wrap(d, 2) + (1L << 20));
    return ua | ub << 21 | ud << 42;
  }
  const Box& box_;
  bool periodic_[3] = {false, false, false};
  double origin_[3] = {0, 0, 0}, width_[3] = {1, 1, 1};
  long n_[3] = {1, 1, 1};
  std::unordered_map<uint64_t, std::vector<std::size_t>> map_;
};
}  // namespace

Configuration random_configuration(const Box& box, std::size_t n, uint64_t seed,
                                   const RandomSpec& spec) {
  Rng rng(seed);
  Configuration c;
  c.box = box;
  const int d = box.dim;
  c.positions.reserve(n * std::size_t(d));
  c.types.reserve(n);
  double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  for (int k = 0; k < d; ++k) {
    lo[k] = spec.lo ? (*spec.lo)[std::size_t(k)] : 0.0;
    hi[k] = spec.hi ? (*spec.hi)[std::size_t(k)] : box.length[k];
  }
  const double dmin2 = spec.min_distance * spec.min_distance;
  Bins bins(box, lo, hi, std::max(spec.min_distance, 1e-9));
  const std::size_t max_attempts = 2000 * (n + 1);
  std::size_t attempts = 0;
  double x[3] = {0, 0, 0};
  while (c.types.size() < n) {
    if (++attempts > max_attempts)
      throw std::runtime_error("random_configuration: cannot place " + std::to_string(n) +
                               " particles with min_distance " + std::to_string(spec.min_distance));
    for (int k = 0; k < d; ++k) x[k] = rng.uniform(lo[k], hi[k]);
    if (dmin2 > 0 && !bins.all_neighbours(x, [&](std::size_t j) {
          return min_image_d2(box, x, &c.positions[j * std::size_t(d)]) >= dmin2;
        }))
      continue;
    if (dmin2 > 0) bins.insert(x, c.types.size());
    for (int k = 0; k < d; ++k) c.positions.push_back(x[k]);
    c.types.push_back(spec.num_types > 1 ? uint32_t(rng.below(spec.num_types)) : 0u);
  }
  return c;
}

double distance2(const Configuration& c, std::size_t i, std::size_t j) {
  const std::size_t d = std::size_t(c.box.dim);
  return min_image_d2(c.box, &c.positions[i * d], &c.positions[j * d]);
}

Configuration permuted(const Configuration& c, const std::vector<std::size_t>& perm) {
  Configuration p;
  p.box = c.box;
  const std::size_t d = std::size_t(c.box.dim);
  p.positions.resize(c.positions.size());
  p.types.resize(c.types.size());
  for (std::size_t i = 0; i < perm.size(); ++i) {
    for (std::size_t k = 0; k < d; ++k) p.positions[i * d + k] = c.positions[perm[i] * d + k];
    p.types[i] = c.types[perm[i]];
  }
  return p;
}

std::vector<std::size_t> random_permutation(std::size_t n, uint64_t seed) {
  std::vector<std::size_t> perm(n);
  std::iota(perm.begin(), perm.end(), std::size_t(0));
  Rng rng(seed);
  for (std::size_t i = n; i > 1; --i) std::swap(perm[i - 1], perm[rng.below(i)]);
  return perm;
}

// ---- results -------------------------------------------------------------------------------------
namespace {
std::size_t particles(const ForceResult& r) {
  return r.dim > 0 ? r.forces.size() / std::size_t(r.dim) : 0;
}
::testing::AssertionResult same_shape(const ForceResult& ref, const ForceResult& got) {
  if (ref.dim != got.dim)
    return ::testing::AssertionFailure() << "dim differs: ref " << ref.dim << ", got " << got.dim;
  if (ref.forces.size() != got.forces.size())
    return ::testing::AssertionFailure() << "forces.size() differs: ref " << ref.forces.size()
                                         << ", got " << got.forces.size();
  return ::testing::AssertionSuccess();
}
}  // namespace

double force_norm(const ForceResult& r, std::size_t i) {
  double s = 0;
  for (int k = 0; k < r.dim; ++k) {
    const double f = r.forces[i * std::size_t(r.dim) + std::size_t(k)];
    s += f * f;
  }
  return std::sqrt(s);
}

double force_rms(const ForceResult& r) {
  const std::size_t n = particles(r);
  if (n == 0) return 0;
  double s = 0;
  for (double f : r.forces) s += f * f;
  return std::sqrt(s / double(n));
}

::testing::AssertionResult forces_match(const ForceResult& ref, const ForceResult& got,
                                        double tol) {
  if (auto shape = same_shape(ref, got); !shape) return shape;
  const std::size_t n = particles(ref), d = std::size_t(ref.dim);
  const double rms = force_rms(ref);
  std::size_t failures = 0, worst = 0;
  double worst_ratio = 0;
  for (std::size_t i = 0; i < n; ++i) {
    double e2 = 0;
    for (std::size_t k = 0; k < d; ++k) {
      const double e = got.forces[i * d + k] - ref.forces[i * d + k];
      e2 += e * e;
    }
    const double err = std::sqrt(e2);
    const double scale = std::max(force_norm(ref, i), rms);
    const double ratio = scale > 0 ? err / scale : (err > 0 ? INFINITY : 0.0);
    if (!(ratio <= tol)) ++failures;  // NaN fails
    if (!(ratio <= worst_ratio)) {
      worst_ratio = ratio;
      worst = i;
    }
  }
  if (failures == 0) return ::testing::AssertionSuccess();
  auto out = ::testing::AssertionFailure();
  out << failures << " of " << n << " particles exceed |dF| <= " << tol
                            << " * max(|F_ref|, F_rms=" << rms << "); worst particle " << worst
                            << ": |dF|/scale = " << worst_ratio << ", F_ref = (";
  for (std::size_t k = 0; k < d; ++k) out << (k ? ", " : "") << ref.forces[worst * d + k];
  out << "), F_got = (";
  for (std::size_t k = 0; k < d; ++k) out << (k ? ", " : "") << got.forces[worst * d + k];
  return out << ")";
}

::testing::AssertionResult energies_match(const ForceResult& ref, const ForceResult& got,
                                          double tol) {
  if (ref.energies.size() != got.energies.size())
    return ::testing::AssertionFailure() << "energies.size() differs: ref " << ref.energies.size()
                                         << ", got " << got.energies.size();
  const std::size_t n = ref.energies.size();
  double s = 0;
  for (double e : ref.energies) s += e * e;
  const double rms = n ? std::sqrt(s / double(n)) : 0.0;
  std::size_t failures = 0, worst = 0;
  double worst_ratio = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double err = std::fabs(got.energies[i] - ref.energies[i]);
    const double scale = std::max(std::fabs(ref.energies[i]), rms);
    const double ratio = scale > 0 ? err / scale : (err > 0 ? INFINITY : 0.0);
    if (!(ratio <= tol)) ++failures;
    if (!(ratio <= worst_ratio)) {
      worst_ratio = ratio;
      worst = i;
    }
  }
  if (failures == 0) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure()
         << failures << " of " << n << " particles exceed |de| <= " << tol
         << " * max(|e_ref|, e_rms=" << rms << "); worst particle " << worst << ": e_ref = "
         << ref.energies[worst] << ", e_got = " << got.energies[worst]
         << ", ratio = " << worst_ratio;
}

::testing::AssertionResult total_energy_matches(const ForceResult& ref, const ForceResult& got,
                                                double tol) {
  double scale = std::fabs(ref.energy);
  double sum_abs = 0;
  for (double e : ref.energies) sum_abs += std::fabs(e);
  scale = std::max(scale, sum_abs);
  const double err = std::fabs(got.energy - ref.energy);
  if (err <= tol * scale) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure()
         << "total energy: ref " << ref.energy << ", got " << got.energy << ", |dE| = " << err
         << " > " << tol << " * " << scale;
}

::testing::AssertionResult virial_matches(const ForceResult& ref, const ForceResult& got,
                                          double tol) {
  const int d = ref.dim;
  double scale = 0;
  for (int a = 0; a < d; ++a)
    for (int b = 0; b < d; ++b) scale = std::max(scale, std::fabs(ref.virial[a][b]));
  for (int a = 0; a < d; ++a)
    for (int b = 0; b < d; ++b) {
      const double err = std::fabs(got.virial[a][b] - ref.virial[a][b]);
      if (!(err <= tol * scale))
        return ::testing::AssertionFailure()
               << "virial[" << a << "][" << b << "]: ref " << ref.virial[a][b] << ", got "
               << got.virial[a][b] << ", |dW| = " << err << " > " << tol << " * " << scale;
    }
  return ::testing::AssertionSuccess();
}

::testing::AssertionResult bitwise_equal(const ForceResult& a, const ForceResult& b) {
  if (a.dim != b.dim) return ::testing::AssertionFailure() << "dim differs";
  if (a.forces.size() != b.forces.size() ||
      (!a.forces.empty() &&
       std::memcmp(a.forces.data(), b.forces.data(), a.forces.size() * sizeof(double)) != 0)) {
    auto out = ::testing::AssertionFailure() << "forces differ bitwise";
    for (std::size_t k = 0; k < std::min(a.forces.size(), b.forces.size()); ++k)
      if (std::memcmp(&a.forces[k], &b.forces[k], sizeof(double)) != 0) {
        out << "; first at component " << k << ": " << a.forces[k] << " vs " << b.forces[k];
        break;
      }
    return out;
  }
  if (a.energies.size() != b.energies.size() ||
      (!a.energies.empty() && std::memcmp(a.energies.data(), b.energies.data(),
                                          a.energies.size() * sizeof(double)) != 0))
    return ::testing::AssertionFailure() << "per-particle energies differ bitwise";
  if (std::memcmp(&a.energy, &b.energy, sizeof(double)) != 0)
    return ::testing::AssertionFailure() << "total energy differs bitwise: " << a.energy << " vs "
                                         << b.energy;
  if (std::memcmp(a.virial, b.virial, sizeof(a.virial)) != 0)
    return ::testing::AssertionFailure() << "virial differs bitwise";
  return ::testing::AssertionSuccess();
}

void expect_results_match(const ForceResult& ref, const ForceResult& got, cellforce::Precision precision) {
  if (precision == cellforce::Precision::kDouble) {
    EXPECT_TRUE(forces_match(ref, got, 1e-12));
    EXPECT_TRUE(energies_match(ref, got, 1e-12));
    EXPECT_TRUE(total_energy_matches(ref, got, 1e-12));
    EXPECT_TRUE(virial_matches(ref, got, 1e-12));
  } else {
    EXPECT_LT(median_relative_force_error(ref, got), 1e-6);
    EXPECT_TRUE(total_energy_matches(ref, got, 1e-5));
    EXPECT_TRUE(virial_matches(ref, got, 1e-5));
  }
}

double median_relative_force_error(const ForceResult& ref, const ForceResult& got) {
  const std::size_t n = particles(ref), d = std::size_t(ref.dim);
  std::vector<double> rel;
  rel.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    const double f = force_norm(ref, i);
    if (f == 0) continue;
    double e2 = 0;
    for (std::size_t k = 0; k < d; ++k) {
      const double e = got.forces[i * d + k] - ref.forces[i * d + k];
      e2 += e * e;
    }
    rel.push_back(std::sqrt(e2) / f);
  }
  if (rel.empty()) return 0;
  for (double r : rel)
    if (std::isnan(r)) return NAN;
  auto mid = rel.begin() + std::ptrdiff_t(rel.size() / 2);
  std::nth_element(rel.begin(), mid, rel.end());
  return *mid;
}

// ---- pair sets ------------------------------------------------------------------------------------
std::vector<Pair> normalized(std::vector<Pair> pairs) {
  for (auto& p : pairs)
    if (p.first > p.second) std::swap(p.first, p.second);
  std::sort(pairs.begin(), pairs.end());
  return pairs;
}

std::vector<Pair> duplicates(std::vector<Pair> pairs) {
  pairs = normalized(std::move(pairs));
  std::vector<Pair> dup;
  for (std::size_t k = 1; k < pairs.size(); ++k)
    if (pairs[k] == pairs[k - 1]) dup.push_back(pairs[k]);
  return dup;
}

std::vector<Pair> missing(std::vector<Pair> expected, std::vector<Pair> got) {
  expected = normalized(std::move(expected));
  got = normalized(std::move(got));
  expected.erase(std::unique(expected.begin(), expected.end()), expected.end());
  got.erase(std::unique(got.begin(), got.end()), got.end());
  std::vector<Pair> out;
  std::set_difference(expected.begin(), expected.end(), got.begin(), got.end(),
                      std::back_inserter(out));
  return out;
}

std::string to_string(const std::vector<Pair>& pairs, std::size_t max_items) {
  std::ostringstream s;
  s << "[";
  for (std::size_t k = 0; k < pairs.size() && k < max_items; ++k)
    s << (k ? " " : "") << "(" << pairs[k].first << "," << pairs[k].second << ")";
  if (pairs.size() > max_items) s << " ... " << pairs.size() - max_items << " more";
  return s.str() + "]";
}

::testing::AssertionResult pair_sets_equal(std::vector<Pair> expected, std::vector<Pair> got) {
  const auto dup = duplicates(got);
  const auto miss = missing(expected, got);
  const auto extra = missing(got, expected);
  if (dup.empty() && miss.empty() && extra.empty()) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure()
         << "pair sets differ: expected " << expected.size() << " pairs, got " << got.size()
         << "; duplicated " << dup.size() << " " << to_string(dup) << "; missing " << miss.size()
         << " " << to_string(miss) << "; extra " << extra.size() << " " << to_string(extra);
}

// ---- errors ---------------------------------------------------------------------------------------
bool contains_number(const std::string& text, uint64_t value) {
  const std::string v = std::to_string(value);
  auto digit = [&](std::size_t k) {
    return k < text.size() && std::isdigit(static_cast<unsigned char>(text[k]));
  };
  for (std::size_t pos = text.find(v); pos != std::string::npos; pos = text.find(v, pos + 1)) {
    const std::size_t end = pos + v.size();
    const bool before_ok = pos == 0 || (!digit(pos - 1) && text[pos - 1] != '.');
    const bool after_ok = !digit(end) && !(end < text.size() && text[end] == '.' && digit(end + 1));
    if (before_ok && after_ok) return true;
  }
  return false;
}

std::string lowercase(std::string s) {
  for (char& ch : s) ch = char(std::tolower(static_cast<unsigned char>(ch)));
  return s;
}

cellforce::ForceField lj_field(double cutoff, double sigma, cellforce::CutoffMode mode) {
  cellforce::ForceField ff;
  ff.cutoff = cutoff;
  ff.mode = mode;
  ff.types = {cellforce::ParticleType{"A", sigma, 1.0}};
  return ff;
}

Configuration moved(const Configuration& c, double max_step, uint64_t seed) {
  Configuration m = c;
  const std::size_t dim = std::size_t(c.box.dim);
  Rng rng(seed);
  for (std::size_t i = 0; i < c.size(); ++i) {
    double d[3] = {0, 0, 0}, norm2 = 0;
    while (norm2 < 1e-6) {
      norm2 = 0;
      for (std::size_t a = 0; a < dim; ++a) d[a] = rng.uniform(-1, 1), norm2 += d[a] * d[a];
    }
    const double length = max_step * rng.uniform() / std::sqrt(norm2);
    for (std::size_t a = 0; a < dim; ++a) m.positions[i * dim + a] += length * d[a];
  }
  return m;
}

}  // namespace cftest
