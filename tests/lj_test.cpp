// The Lennard-Jones evaluator (core/lj.h) against the analytic potential, its cutoff contract, and
// the force-field mixing rules (core/force_field.h). Reduced units (sigma = epsilon = 1) unless a
// test says otherwise.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "core/error.h"
#include "core/force_field.h"
#include "core/lj.h"

namespace cftest {
namespace {

using cellforce::CutoffMode;
using cellforce::ForceField;
using cellforce::LJParams;

struct PairValue {
  bool interacts = false;
  double force = 0;   // F_c(r) (positive = repulsive), from force_over_r * r
  double energy = 0;  // U_c(r)
};

template <CutoffMode Mode>
PairValue eval(double r, double sigma, double epsilon, double rc) {
  const LJParams<double> p = cellforce::make_lj_params<double>(sigma, epsilon, rc, Mode);
  PairValue v;
  double fr = 0, u = 0;
  v.interacts = cellforce::lj_pair<Mode, true>(r * r, rc * rc, p, fr, u);
  v.force = fr * r;
  v.energy = u;
  return v;
}

PairValue eval(CutoffMode mode, double r, double sigma = 1, double epsilon = 1, double rc = 2.5) {
  switch (mode) {
    case CutoffMode::kTruncate: return eval<CutoffMode::kTruncate>(r, sigma, epsilon, rc);
    case CutoffMode::kShift: return eval<CutoffMode::kShift>(r, sigma, epsilon, rc);
    case CutoffMode::kForceShift: return eval<CutoffMode::kForceShift>(r, sigma, epsilon, rc);
  }
  return {};
}

// Analytic U and F = -dU/dr (plain double formulas, written independently of lj.h).
double u_lj(double r, double s = 1, double e = 1) {
  const double x = std::pow(s / r, 6);
  return 4 * e * (x * x - x);
}
double f_lj(double r, double s = 1, double e = 1) {
  const double x = std::pow(s / r, 6);
  return 24 * e * (2 * x * x - x) / r;
}

const CutoffMode kModes[] = {CutoffMode::kTruncate, CutoffMode::kShift, CutoffMode::kForceShift};
const double kSigmaEps[][2] = {{1.0, 1.0}, {0.88, 0.5}, {1.3, 2.7}, {3.4, 0.0104}};

// U(sigma) = 0 in truncate mode: |U| <= 1e-14 * 4 eps (the two terms, each 4 eps, cancel).
TEST(LennardJones, EnergyZeroAtSigma) {
  for (const auto& se : kSigmaEps) {
    const PairValue v = eval(CutoffMode::kTruncate, se[0], se[0], se[1], 2.5 * se[0]);
    ASSERT_TRUE(v.interacts);
    EXPECT_NEAR(v.energy, 0.0, 1e-14 * 4 * se[1]) << "sigma " << se[0];
  }
}

// F(2^(1/6) sigma) = 0: |F| <= 1e-13 * 24 eps / sigma (the scale of each term there).
TEST(LennardJones, ForceZeroAtMinimum) {
  for (const auto& se : kSigmaEps) {
    const double rmin = std::pow(2.0, 1.0 / 6.0) * se[0];
    const PairValue v = eval(CutoffMode::kTruncate, rmin, se[0], se[1], 2.5 * se[0]);
    EXPECT_NEAR(v.force, 0.0, 1e-13 * 24 * se[1] / se[0]) << "sigma " << se[0];
  }
}

// U(2^(1/6) sigma) = -epsilon to 1e-14 relative, and it is a minimum: U(rmin (1 +- 1e-3)) > U_min.
TEST(LennardJones, EnergyMinimumIsMinusEpsilon) {
  for (const auto& se : kSigmaEps) {
    const double rmin = std::pow(2.0, 1.0 / 6.0) * se[0];
    const double rc = 2.5 * se[0];
    const double umin = eval(CutoffMode::kTruncate, rmin, se[0], se[1], rc).energy;
    EXPECT_NEAR(umin, -se[1], 1e-14 * se[1]) << "sigma " << se[0];
    EXPECT_GT(eval(CutoffMode::kTruncate, rmin * (1 + 1e-3), se[0], se[1], rc).energy, umin);
    EXPECT_GT(eval(CutoffMode::kTruncate, rmin * (1 - 1e-3), se[0], se[1], rc).energy, umin);
  }
}

// r = 0.5 sigma, truncate, reduced units: U = 4 (2^12 - 2^6) = 16128 and |F| = 24 (2 * 2^12 -
// 2^6) / 0.5 = 390144. Every intermediate is dyadic, so the values are exact (asserted to 1e-15).
TEST(LennardJones, HalfSigmaValues) {
  const PairValue v = eval(CutoffMode::kTruncate, 0.5);
  ASSERT_TRUE(v.interacts);
  EXPECT_NEAR(v.energy, 16128.0, 16128.0 * 1e-15);
  EXPECT_NEAR(v.force, 390144.0, 390144.0 * 1e-15);
}

// The evaluator agrees with the analytic formulas over r in [0.8, 2.49] sigma, for several
// sigma/epsilon: |dU| <= 1e-13 * max(|U|, eps), |dF| <= 1e-13 * max(|F|, eps/sigma).
TEST(LennardJones, MatchesAnalyticFormula) {
  for (const auto& se : kSigmaEps)
    for (double x = 0.8; x < 2.49; x += 0.0173) {
      const double r = x * se[0];
      const PairValue v = eval(CutoffMode::kTruncate, r, se[0], se[1], 2.5 * se[0]);
      ASSERT_TRUE(v.interacts);
      const double u = u_lj(r, se[0], se[1]), f = f_lj(r, se[0], se[1]);
      EXPECT_NEAR(v.energy, u, 1e-13 * std::max(std::fabs(u), se[1])) << "r " << r;
      EXPECT_NEAR(v.force, f, 1e-13 * std::max(std::fabs(f), se[1] / se[0])) << "r " << r;
    }
}

// Strict cutoff: at r2 == rc2 exactly and beyond, lj_pair returns false and leaves both outputs
// untouched (sentinels compared exactly); one ulp below rc2 it interacts.
TEST(LennardJones, NothingAtOrBeyondCutoff) {
  for (CutoffMode mode : kModes) {
    const double rc = 2.5;
    const double rc2 = rc * rc;
    const auto p = cellforce::make_lj_params<double>(1.0, 1.0, rc, mode);
    for (double r2 : {rc2, std::nextafter(rc2, INFINITY), 1.0001 * rc2, 4 * rc2,
                      std::numeric_limits<double>::infinity()}) {
      double fr = -12345.0, u = -6789.0;
      bool hit = true;
      switch (mode) {
        case CutoffMode::kTruncate: hit = cellforce::lj_pair<CutoffMode::kTruncate, true>(r2, rc2, p, fr, u); break;
        case CutoffMode::kShift: hit = cellforce::lj_pair<CutoffMode::kShift, true>(r2, rc2, p, fr, u); break;
        case CutoffMode::kForceShift: hit = cellforce::lj_pair<CutoffMode::kForceShift, true>(r2, rc2, p, fr, u); break;
      }
      EXPECT_FALSE(hit) << cellforce::to_string(mode) << " r2 " << r2;
      EXPECT_EQ(fr, -12345.0);
      EXPECT_EQ(u, -6789.0);
    }
    double fr = 0, u = 0;
    const double below = std::nextafter(rc2, 0.0);
    bool hit = false;
    switch (mode) {
      case CutoffMode::kTruncate: hit = cellforce::lj_pair<CutoffMode::kTruncate, true>(below, rc2, p, fr, u); break;
      case CutoffMode::kShift: hit = cellforce::lj_pair<CutoffMode::kShift, true>(below, rc2, p, fr, u); break;
      case CutoffMode::kForceShift: hit = cellforce::lj_pair<CutoffMode::kForceShift, true>(below, rc2, p, fr, u); break;
    }
    EXPECT_TRUE(hit) << cellforce::to_string(mode);
  }
}

// Truncate jumps at rc: at r = rc (1 - 1e-9), U = U(rc) (-0.0163) and F = F(rc) to 1e-6
// relative (they move by ~7e-9 relative over that step), not 0.
TEST(LennardJones, TruncateIsDiscontinuousAtCutoff) {
  const double rc = 2.5, r = rc * (1 - 1e-9);
  EXPECT_NEAR(eval(CutoffMode::kTruncate, r).energy, u_lj(rc), 1e-6 * std::fabs(u_lj(rc)));
  EXPECT_NEAR(eval(CutoffMode::kTruncate, r).force, f_lj(rc), 1e-6 * std::fabs(f_lj(rc)));
}

// Shift: U_c(r) = U(r) - U(rc), so U_c(rc (1 - 1e-9)) -> 0: |U_c| <= 1e-6 |U(rc)| (it is
// F(rc) * 2.5e-9 ~ 4e-11, i.e. 2.4e-9 |U(rc)|); the force is the truncated force, bitwise, at
// every r; the energy formula holds to 1e-13 * max(1, |U|).
TEST(LennardJones, ShiftMakesEnergyVanishAtCutoff) {
  const double rc = 2.5;
  EXPECT_LE(std::fabs(eval(CutoffMode::kShift, rc * (1 - 1e-9)).energy), 1e-6 * std::fabs(u_lj(rc)));
  for (double r = 0.8; r < 2.5; r += 0.1) {
    EXPECT_EQ(eval(CutoffMode::kShift, r).force, eval(CutoffMode::kTruncate, r).force) << r;
    EXPECT_NEAR(eval(CutoffMode::kShift, r).energy, u_lj(r) - u_lj(rc),
                1e-13 * std::max(1.0, std::fabs(u_lj(r))))
        << r;
  }
}

// Force shift: F_c(r) = F(r) - F(rc) and U_c(r) = U(r) - U(rc) + (r - rc) F(rc): both -> 0 at rc
// (at r = rc (1 - 1e-9): |F_c| <= 1e-6 |F(rc)|, expected F'(rc) 2.5e-9 = 1.7e-8 |F(rc)|;
// |U_c| <= 1e-6 |U(rc)|, expected ~1e-17), and the formulas hold to 1e-13 * max(1, |value|)
// inside.
TEST(LennardJones, ForceShiftMakesEnergyAndForceVanishAtCutoff) {
  const double rc = 2.5;
  const PairValue edge = eval(CutoffMode::kForceShift, rc * (1 - 1e-9));
  EXPECT_LE(std::fabs(edge.force), 1e-6 * std::fabs(f_lj(rc)));
  EXPECT_LE(std::fabs(edge.energy), 1e-6 * std::fabs(u_lj(rc)));
  for (double r = 0.8; r < 2.5; r += 0.1) {
    const PairValue v = eval(CutoffMode::kForceShift, r);
    EXPECT_NEAR(v.force, f_lj(r) - f_lj(rc), 1e-13 * std::max(1.0, std::fabs(f_lj(r)))) << r;
    EXPECT_NEAR(v.energy, u_lj(r) - u_lj(rc) + (r - rc) * f_lj(rc),
                1e-13 * std::max(1.0, std::fabs(u_lj(r))))
        << r;
  }
}

// F_c = -dU_c/dr in every mode: central difference with step 1e-6 at r in [0.9, 2.45]:
// |F + dU/dr| <= 1e-6 * max(|F|, eps/sigma) (round-off ~1e-10 / step, truncation ~1e-12 U''').
TEST(LennardJones, ForceIsMinusEnergyDerivative) {
  const double step = 1e-6;
  for (CutoffMode mode : kModes)
    for (const auto& se : kSigmaEps)
      for (double x = 0.9; x < 2.45; x += 0.0371) {
        const double r = x * se[0], rc = 2.5 * se[0];
        const double du = (eval(mode, r + step * se[0], se[0], se[1], rc).energy -
                           eval(mode, r - step * se[0], se[0], se[1], rc).energy) /
                          (2 * step * se[0]);
        const double f = eval(mode, r, se[0], se[1], rc).force;
        EXPECT_NEAR(f, -du, 1e-6 * std::max(std::fabs(f), se[1] / se[0]))
            << cellforce::to_string(mode) << " sigma " << se[0] << " r " << r;
      }
}

// Energy = false leaves the energy output untouched and gives the same force bitwise.
TEST(LennardJones, EnergyFlagOnlyControlsEnergy) {
  for (CutoffMode mode : kModes) {
    const auto p = cellforce::make_lj_params<double>(1.0, 1.0, 2.5, mode);
    for (double r = 0.7; r < 2.5; r += 0.13) {
      double f1 = 0, u1 = 0, f2 = 0, u2 = 4242.0;
      bool h1 = false, h2 = false;
      switch (mode) {
        case CutoffMode::kTruncate:
          h1 = cellforce::lj_pair<CutoffMode::kTruncate, true>(r * r, 6.25, p, f1, u1);
          h2 = cellforce::lj_pair<CutoffMode::kTruncate, false>(r * r, 6.25, p, f2, u2);
          break;
        case CutoffMode::kShift:
          h1 = cellforce::lj_pair<CutoffMode::kShift, true>(r * r, 6.25, p, f1, u1);
          h2 = cellforce::lj_pair<CutoffMode::kShift, false>(r * r, 6.25, p, f2, u2);
          break;
        case CutoffMode::kForceShift:
          h1 = cellforce::lj_pair<CutoffMode::kForceShift, true>(r * r, 6.25, p, f1, u1);
          h2 = cellforce::lj_pair<CutoffMode::kForceShift, false>(r * r, 6.25, p, f2, u2);
          break;
      }
      EXPECT_TRUE(h1 && h2);
      EXPECT_EQ(f1, f2);
      EXPECT_EQ(u2, 4242.0);
    }
  }
}

// make_lj_params, in the pair's length unit lambda = 2^floor(log2 sigma): inv_s2 = 1 / lambda^2
// exactly, e12 = 4 eps (sigma / lambda)^12, e6 = 4 eps (sigma / lambda)^6, f12 = 12 e12 / lambda^2,
// f6 = 6 e6 / lambda^2 (4e-15 relative, a few ulp of pow); u_rc only for shift and force shift,
// f_rc only for force shift (exact zeros otherwise); rc stored. sigma = 1.3 has lambda = 1; 3.4e-10
// (argon's, in metres) has lambda = 2^-32.
TEST(LennardJones, ParamsPerMode) {
  for (const double s : {1.3, 3.4e-10}) {
  const double e = 0.7, rc = 3.1 / 1.3 * s;
  const double lambda = s == 1.3 ? 1.0 : 0x1p-32;
  ASSERT_GE(s / lambda, 1.0);
  ASSERT_LT(s / lambda, 2.0);
  for (CutoffMode mode : kModes) {
    const auto p = cellforce::make_lj_params<double>(s, e, rc, mode);
    EXPECT_EQ(p.inv_s2, 1.0 / (lambda * lambda));
    const double x = s / lambda;
    EXPECT_NEAR(p.e12, 4 * e * std::pow(x, 12), 4e-15 * p.e12);
    EXPECT_NEAR(p.e6, 4 * e * std::pow(x, 6), 4e-15 * p.e6);
    EXPECT_NEAR(p.f12, 48 * e * std::pow(x, 12) / (lambda * lambda), 4e-15 * p.f12);
    EXPECT_NEAR(p.f6, 24 * e * std::pow(x, 6) / (lambda * lambda), 4e-15 * p.f6);
    EXPECT_EQ(p.rc, rc);
    const double u_rc = mode == CutoffMode::kTruncate ? 0.0 : u_lj(rc, s, e);
    const double f_rc = mode == CutoffMode::kForceShift ? f_lj(rc, s, e) : 0.0;
    EXPECT_NEAR(p.u_rc, u_rc, 1e-14 * std::fabs(u_rc));  // exact 0 where not used
    EXPECT_NEAR(p.f_rc, f_rc, 1e-14 * std::fabs(f_rc));
  }
  }
}

// ---- mixing rules ------------------------------------------------------------------------------------

ForceField three_types(cellforce::Mixing mixing) {
  ForceField ff;
  ff.cutoff = 2.5;
  ff.mixing = mixing;
  ff.types = {{"A", 1.0, 1.0}, {"B", 0.8, 0.5}, {"C", 1.2, 2.0}};
  return ff;
}

// Lorentz-Berthelot: sigma_ij = (sigma_i + sigma_j) / 2, eps_ij = sqrt(eps_i eps_j), symmetric
// (1e-15 relative).
TEST(Mixing, LorentzBerthelot) {
  const ForceField ff = three_types(cellforce::Mixing::kLorentzBerthelot);
  for (std::size_t a = 0; a < 3; ++a)
    for (std::size_t b = 0; b < 3; ++b) {
      const double s = (ff.types[a].sigma + ff.types[b].sigma) / 2;
      const double e = std::sqrt(ff.types[a].epsilon * ff.types[b].epsilon);
      EXPECT_NEAR(ff.pair_sigma(a, b), s, 1e-15 * s) << a << b;
      EXPECT_NEAR(ff.pair_epsilon(a, b), e, 1e-15 * e) << a << b;
    }
  EXPECT_NEAR(ff.pair_sigma(0, 1), 0.9, 1e-15);
  EXPECT_NEAR(ff.pair_epsilon(0, 1), std::sqrt(0.5), 1e-15);
}

// Geometric: sigma_ij = sqrt(sigma_i sigma_j), eps_ij = sqrt(eps_i eps_j) (1e-15 relative).
TEST(Mixing, Geometric) {
  const ForceField ff = three_types(cellforce::Mixing::kGeometric);
  for (std::size_t a = 0; a < 3; ++a)
    for (std::size_t b = 0; b < 3; ++b) {
      const double s = std::sqrt(ff.types[a].sigma * ff.types[b].sigma);
      const double e = std::sqrt(ff.types[a].epsilon * ff.types[b].epsilon);
      EXPECT_NEAR(ff.pair_sigma(a, b), s, 1e-15 * s) << a << b;
      EXPECT_NEAR(ff.pair_epsilon(a, b), e, 1e-15 * e) << a << b;
    }
  EXPECT_NEAR(ff.pair_sigma(1, 2), std::sqrt(0.96), 1e-15);
}

// An override replaces the mixed value for its pair in both orders (exact), diagonal overrides
// too, and leaves the other pairs mixed.
TEST(Mixing, OverridesReplaceMixedValues) {
  ForceField ff = three_types(cellforce::Mixing::kLorentzBerthelot);
  ff.overrides = {{1, 0, 0.8, 1.5}, {2, 2, 1.05, 0.3}};
  EXPECT_EQ(ff.pair_sigma(0, 1), 0.8);
  EXPECT_EQ(ff.pair_sigma(1, 0), 0.8);
  EXPECT_EQ(ff.pair_epsilon(0, 1), 1.5);
  EXPECT_EQ(ff.pair_epsilon(1, 0), 1.5);
  EXPECT_EQ(ff.pair_sigma(2, 2), 1.05);
  EXPECT_EQ(ff.pair_epsilon(2, 2), 0.3);
  EXPECT_NEAR(ff.pair_sigma(0, 2), 1.1, 1e-15);
  EXPECT_NEAR(ff.pair_epsilon(1, 2), 1.0, 1e-15);
  EXPECT_NO_THROW(ff.validate());
}

// make_pair_table: num_types^2 entries, row-major, symmetric (bitwise), entry (a, b) equal to
// make_lj_params(pair_sigma, pair_epsilon, cutoff, mode) to 1e-14 relative in double (sigma^12
// turns an ulp of sigma into 12) and to 1 ulp of float (1.2e-7) in float.
TEST(Mixing, PairTableMatchesPairParameters) {
  for (auto mixing : {cellforce::Mixing::kLorentzBerthelot, cellforce::Mixing::kGeometric})
    for (CutoffMode mode : kModes) {
      ForceField ff = three_types(mixing);
      ff.mode = mode;
      ff.overrides = {{0, 2, 0.95, 1.7}};
      const auto table = cellforce::make_pair_table<double>(ff);
      const auto table_f = cellforce::make_pair_table<float>(ff);
      ASSERT_EQ(table.size(), 9u);
      ASSERT_EQ(table_f.size(), 9u);
      auto near = [](double got, double want, double rel) {
        return std::fabs(got - want) <= rel * std::fabs(want);
      };
      for (std::size_t a = 0; a < 3; ++a)
        for (std::size_t b = 0; b < 3; ++b) {
          const auto want = cellforce::make_lj_params<double>(ff.pair_sigma(a, b),
                                                              ff.pair_epsilon(a, b), ff.cutoff, mode);
          const auto& got = table[a * 3 + b];
          const auto& mirror = table[b * 3 + a];
          EXPECT_EQ(got.inv_s2, want.inv_s2) << a << b;
          EXPECT_TRUE(near(got.f12, want.f12, 1e-14)) << a << b;
          EXPECT_TRUE(near(got.f6, want.f6, 1e-14)) << a << b;
          EXPECT_TRUE(near(got.e12, want.e12, 1e-14)) << a << b;
          EXPECT_TRUE(near(got.e6, want.e6, 1e-14)) << a << b;
          EXPECT_TRUE(near(got.u_rc, want.u_rc, 1e-14)) << a << b;
          EXPECT_TRUE(near(got.f_rc, want.f_rc, 1e-14)) << a << b;
          EXPECT_EQ(got.rc, want.rc);
          EXPECT_EQ(got.f12, mirror.f12);
          EXPECT_EQ(got.f6, mirror.f6);
          EXPECT_EQ(got.e12, mirror.e12);
          EXPECT_EQ(got.e6, mirror.e6);
          EXPECT_EQ(got.u_rc, mirror.u_rc);
          EXPECT_EQ(got.f_rc, mirror.f_rc);
          const auto& gf = table_f[a * 3 + b];
          const double ulp = 1.2e-7 + 1e-14;  // float epsilon, plus the double tolerance
          EXPECT_EQ(double(gf.inv_s2), want.inv_s2) << a << b;
          EXPECT_TRUE(near(gf.f12, want.f12, ulp)) << a << b;
          EXPECT_TRUE(near(gf.f6, want.f6, ulp)) << a << b;
          EXPECT_TRUE(near(gf.e12, want.e12, ulp)) << a << b;
          EXPECT_TRUE(near(gf.e6, want.e6, ulp)) << a << b;
          EXPECT_TRUE(near(gf.u_rc, want.u_rc, ulp)) << a << b;
          EXPECT_TRUE(near(gf.f_rc, want.f_rc, ulp)) << a << b;
        }
    }
}

// A default force field is valid; the names of the enums are distinct and non-empty.
TEST(ForceFieldBasics, DefaultIsValidAndNamesExist) {
  EXPECT_NO_THROW(ForceField{}.validate());
  EXPECT_STRNE(cellforce::to_string(CutoffMode::kTruncate), cellforce::to_string(CutoffMode::kShift));
  EXPECT_STRNE(cellforce::to_string(CutoffMode::kShift), cellforce::to_string(CutoffMode::kForceShift));
  EXPECT_STRNE(cellforce::to_string(cellforce::Mixing::kLorentzBerthelot),
               cellforce::to_string(cellforce::Mixing::kGeometric));
}

}  // namespace
}  // namespace cftest
