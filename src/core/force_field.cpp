#include "core/force_field.h"

#include <cmath>
#include <sstream>

#include "core/error.h"
#include "core/text.h"

namespace cellforce {
namespace {

const PairOverride* find_override(const ForceField& ff, std::size_t a, std::size_t b) {
  for (const auto& o : ff.overrides)
    if ((o.a == a && o.b == b) || (o.a == b && o.b == a)) return &o;
  return nullptr;
}

void check_lj_value(double v, const std::string& what) {
  if (!std::isfinite(v) || v < 0.0) {
    std::ostringstream s;
    s << what << " is " << format_number(v) << "; it must be finite and >= 0";
    throw Error(s.str());
  }
}

}  // namespace

double ForceField::pair_sigma(std::size_t a, std::size_t b) const {
  if (const auto* o = find_override(*this, a, b)) return o->sigma;
  const double sa = types[a].sigma, sb = types[b].sigma;
  return mixing == Mixing::kLorentzBerthelot ? 0.5 * (sa + sb) : std::sqrt(sa * sb);
}

double ForceField::pair_epsilon(std::size_t a, std::size_t b) const {
  if (const auto* o = find_override(*this, a, b)) return o->epsilon;
  return std::sqrt(types[a].epsilon * types[b].epsilon);
}

void ForceField::validate() const {
  if (!std::isfinite(cutoff) || cutoff <= 0.0) {
    std::ostringstream s;
    s << "cutoff is " << format_number(cutoff) << "; it must be finite and > 0";
    throw Error(s.str());
  }
  if (types.empty()) throw Error("the force field has no particle types");
  for (const auto& t : types) {
    // Names travel into files (H5MD species, HDF5 attributes) as C strings: no NUL or other
    // control character may cut them short.
    if (t.name.empty()) throw Error("a particle type has an empty name");
    for (const char c : t.name)
      if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f)
        throw Error("type name " + quote_excerpt(t.name) + " holds a control character; names must be printable");
    check_lj_value(t.sigma, "sigma of type " + quote_excerpt(t.name));
    check_lj_value(t.epsilon, "epsilon of type " + quote_excerpt(t.name));
  }
  for (const auto& o : overrides) {
    if (o.a >= types.size() || o.b >= types.size()) {
      std::ostringstream s;
      s << "pair override (" << o.a << ", " << o.b << ") names a type index beyond the "
        << types.size() << " types";
      throw Error(s.str());
    }
    const std::string pair = "pair " + quote_excerpt(types[o.a].name) + "-" + quote_excerpt(types[o.b].name);
    check_lj_value(o.sigma, "sigma of " + pair);
    check_lj_value(o.epsilon, "epsilon of " + pair);
  }
}

void check_precision_range(const ForceField& ff, Precision precision) {
  if (precision == Precision::kDouble) return;
  const char* const name = precision == Precision::kSingle ? "single" : "mixed";
  auto inside = [](double v) { return v == 0.0 || (std::fabs(v) >= kFloatRangeLow && std::fabs(v) <= kFloatRangeHigh); };
  const double rc2 = ff.cutoff * ff.cutoff;
  const std::size_t nt = ff.num_types();
  for (std::size_t a = 0; a < nt; ++a)
    for (std::size_t b = a; b < nt; ++b) {
      const double sigma = ff.pair_sigma(a, b), epsilon = ff.pair_epsilon(a, b);
      const LJParams<double> p = make_lj_params<double>(sigma, epsilon, ff.cutoff, ff.mode);
      if (p.f12 == 0.0 && p.e12 == 0.0) continue;  // a pair that does not interact
      // Length: the unit lambda (~sigma) and the cutoff in it; energy: epsilon and the force
      // constants epsilon / lambda^2.
      const bool length_ok = inside(p.inv_s2) && inside(rc2 * p.inv_s2);
      // U(rc) and F(rc) only shift what they are subtracted from: below float's range they are
      // nothing to it; only overflow matters.
      const bool energy_ok = inside(p.e12) && inside(p.e6) && inside(p.f12) && inside(p.f6) &&
                             std::fabs(p.u_rc) <= kFloatRangeHigh && std::fabs(p.f_rc) <= kFloatRangeHigh;
      if (length_ok && energy_ok) continue;
      const std::string pair = a == b ? "type " + quote_excerpt(ff.types[a].name)
                                      : "pair " + quote_excerpt(ff.types[a].name) + "-" + quote_excerpt(ff.types[b].name);
      std::ostringstream s;
      s << "the Lennard-Jones parameters of " << pair << " (sigma " << format_number(sigma) << ", epsilon "
        << format_number(epsilon) << ", cutoff " << format_number(ff.cutoff) << ") are outside what " << name
        << " precision can evaluate: ";
      if (!inside(p.inv_s2))
        s << "sigma is too " << (p.inv_s2 > 1.0 ? "small" : "large") << " for float's range";
      else if (!length_ok)
        s << "the cutoff is " << format_number(ff.cutoff / sigma) << " sigma, too far from sigma for float's range";
      else
        s << "epsilon / sigma^2 (" << format_number(epsilon / (sigma * sigma)) << ") or epsilon leaves float's range";
      s << "; express lengths and energies in units nearer sigma and epsilon, or use double precision";
      throw Error(s.str());
    }
  // The pairs first: a sigma out of range is the cause to name; then the cutoff for pairs that
  // do not interact.
  if (!inside(rc2)) {
    std::ostringstream s;
    s << "cutoff " << format_number(ff.cutoff) << " is outside what " << name
      << " precision can evaluate (its square must lie within " << format_number(kFloatRangeLow) << " to "
      << format_number(kFloatRangeHigh) << "); express lengths in a unit nearer the particles' size, or use "
      << "double precision";
    throw Error(s.str());
  }
}

template <class Real>
std::vector<LJParams<Real>> make_pair_table(const ForceField& ff) {
  const std::size_t nt = ff.num_types();
  std::vector<LJParams<Real>> table(nt * nt);
  for (std::size_t a = 0; a < nt; ++a)
    for (std::size_t b = 0; b < nt; ++b)
      table[a * nt + b] =
          make_lj_params<Real>(ff.pair_sigma(a, b), ff.pair_epsilon(a, b), ff.cutoff, ff.mode);
  return table;
}

template std::vector<LJParams<float>> make_pair_table<float>(const ForceField&);
template std::vector<LJParams<double>> make_pair_table<double>(const ForceField&);

const char* to_string(CutoffMode mode) {
  switch (mode) {
    case CutoffMode::kTruncate: return "truncate";
    case CutoffMode::kShift: return "shift";
    case CutoffMode::kForceShift: return "force-shift";
  }
  return "?";
}

const char* to_string(Mixing mixing) {
  return mixing == Mixing::kLorentzBerthelot ? "lorentz-berthelot" : "geometric";
}

}  // namespace cellforce
