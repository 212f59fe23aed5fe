// Bad input is refused with a cellforce::Error whose message names the culprit: the particle
// index, the box, the cutoff, the type. Every entry point that takes a system is checked (each
// backend of backends.h in each precision, and the brute force, which promises the same errors). Messages are
// matched loosely: a keyword and the indices as whole numbers, never a full sentence.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <string>

#include "core/error.h"
#include "core/force_field.h"
#include "core/system.h"
#include "backends.h"
#include "cpu/engine.h"
#include "oracle.h"
#include "reference/brute_force.h"
#include "scene/lattice.h"

namespace cftest {
namespace {

using cellforce::Configuration;
using cellforce::ForceField;
using cellforce::ForceResult;
using ::testing::HasSubstr;

struct EntryPoint {
  std::string name;
  bool float_pairs;  // evaluates pairs in float (can overflow where double does not)
  std::function<void(const cellforce::SystemView&, const ForceField&)> call;
  std::function<std::string()> unavailable = [] { return std::string(); };
};

EntryPoint engine_entry(std::size_t backend, cellforce::Precision p) {
  const Backend& b = backends()[backend];
  return {b.name + "_" + cellforce::to_string(p), p != cellforce::Precision::kDouble,
          [backend, p](const cellforce::SystemView& s, const ForceField& ff) {
            EngineSpec spec;
            spec.precision = p;
            auto e = backends()[backend].make(spec);
            ForceResult r;
            e->evaluate(s, ff, cellforce::Request{}, r);
          },
          b.unavailable};
}

const std::vector<EntryPoint>& entry_points() {
  static const std::vector<EntryPoint> list = [] {
    std::vector<EntryPoint> l;
    for (std::size_t b : backend_ids())
      for (auto p : {cellforce::Precision::kDouble, cellforce::Precision::kMixed,
                     cellforce::Precision::kSingle})
        l.push_back(engine_entry(b, p));
    l.push_back({"brute_force", false, [](const cellforce::SystemView& s, const ForceField& ff) {
                   ForceResult r;
                   cellforce::brute_force(s, ff, cellforce::Request{}, r);
                 }});
    return l;
  }();
  return list;
}

class BadInput : public ::testing::TestWithParam<std::size_t> {
 protected:
  void SetUp() override {
    const std::string why = entry().unavailable();
    if (!why.empty()) GTEST_SKIP() << entry().name << ": " << why;
    // fcc 3^3 at 0.8442: 108 particles, L = 5.0387, rc = 2.5 <= L/2.
    config_ = cellforce::make_lattice(cellforce::Lattice::kFcc, 3, 0.8442);
    cellforce::jitter(config_, 0.05, 4);
    ff_.cutoff = 2.5;
    ff_.types = {{"Alpha", 1.0, 1.0}, {"Bravo", 0.9, 0.8}};
    for (std::size_t i = 0; i < config_.size(); ++i) config_.types[i] = uint32_t(i % 2);
  }
  const EntryPoint& entry() const { return entry_points()[GetParam()]; }

  // The message of the cellforce::Error that the entry point throws ("" plus a test failure when
  // it throws nothing or something else).
  std::string error_of(const Configuration& c, const ForceField& ff) const {
    try {
      entry().call(c.view(), ff);
    } catch (const cellforce::Error& e) {
      return e.what();
    } catch (const std::exception& e) {
      ADD_FAILURE() << entry().name << " threw a non-cellforce exception: " << e.what();
      return {};
    }
    ADD_FAILURE() << entry().name << " accepted the bad input";
    return {};
  }
  double& coord(std::size_t i, int a) { return config_.positions[i * 3 + std::size_t(a)]; }

  Configuration config_;
  ForceField ff_;
};

// The valid baseline goes through every entry point (so that each error below is the named one).
TEST_P(BadInput, BaselineIsAccepted) { EXPECT_NO_THROW(entry().call(config_.view(), ff_)); }

// NaN coordinate of particle 7: the message says "particle" and 7.
TEST_P(BadInput, NaNCoordinateNamesParticle) {
  coord(7, 1) = std::numeric_limits<double>::quiet_NaN();
  const std::string msg = error_of(config_, ff_);
  EXPECT_THAT(lowercase(msg), HasSubstr("particle"));
  EXPECT_TRUE(contains_number(msg, 7)) << msg;
}

// +inf on particle 7 and -inf on particle 42: each named.
TEST_P(BadInput, InfiniteCoordinateNamesParticle) {
  coord(7, 2) = std::numeric_limits<double>::infinity();
  std::string msg = error_of(config_, ff_);
  EXPECT_THAT(lowercase(msg), HasSubstr("particle"));
  EXPECT_TRUE(contains_number(msg, 7)) << msg;
  coord(7, 2) = 1.0;
  coord(42, 0) = -std::numeric_limits<double>::infinity();
  msg = error_of(config_, ff_);
  EXPECT_TRUE(contains_number(msg, 42)) << msg;
}

// A periodic box edge of 0, -5 or NaN: the message names the box.
TEST_P(BadInput, NonPositiveBoxEdgeNamesBox) {
  for (double bad : {0.0, -5.0, std::numeric_limits<double>::quiet_NaN()}) {
    Configuration c = config_;
    c.box.length[1] = bad;
    EXPECT_THAT(lowercase(error_of(c, ff_)), HasSubstr("box")) << "edge " << bad;
  }
}

// rc = 2.6 > L/2 = 2.519 on a periodic axis: the message names the cutoff and the box.
TEST_P(BadInput, CutoffAboveHalfBoxNamesCutoffAndBox) {
  ForceField ff = ff_;
  ff.cutoff = 2.6;
  const std::string msg = lowercase(error_of(config_, ff));
  EXPECT_THAT(msg, HasSubstr("cutoff"));
  EXPECT_THAT(msg, HasSubstr("box"));
}

// The same cutoff is fine when that axis is open (the minimum image does not apply there).
TEST_P(BadInput, CutoffAboveHalfBoxIsFineOnOpenAxes) {
  ForceField ff = ff_;
  ff.cutoff = 2.6;
  Configuration c = config_;
  for (bool& p : c.box.periodic) p = false;
  EXPECT_NO_THROW(entry().call(c.view(), ff));
}

// Cutoff 0, -1 or NaN: the message names the cutoff.
TEST_P(BadInput, NonPositiveCutoffNamesCutoff) {
  for (double bad : {0.0, -1.0, std::numeric_limits<double>::quiet_NaN()}) {
    ForceField ff = ff_;
    ff.cutoff = bad;
    EXPECT_THAT(lowercase(error_of(config_, ff)), HasSubstr("cutoff")) << "cutoff " << bad;
  }
}

// Negative sigma of type "Bravo": the message names the type and sigma.
TEST_P(BadInput, NegativeSigmaNamesType) {
  ForceField ff = ff_;
  ff.types[1].sigma = -0.9;
  const std::string msg = error_of(config_, ff);
  EXPECT_THAT(msg, HasSubstr("Bravo"));
  EXPECT_THAT(lowercase(msg), HasSubstr("sigma"));
}

// Negative epsilon of type "Bravo": the message names the type and epsilon.
TEST_P(BadInput, NegativeEpsilonNamesType) {
  ForceField ff = ff_;
  ff.types[1].epsilon = -0.8;
  const std::string msg = error_of(config_, ff);
  EXPECT_THAT(msg, HasSubstr("Bravo"));
  EXPECT_THAT(lowercase(msg), HasSubstr("epsilon"));
}

// A negative override sigma is refused and the message says sigma.
TEST_P(BadInput, NegativeOverrideSigmaIsRefused) {
  ForceField ff = ff_;
  ff.overrides = {{0, 1, -1.0, 1.0}};
  EXPECT_THAT(lowercase(error_of(config_, ff)), HasSubstr("sigma"));
}

// An override naming a type that does not exist (index 5 of 2) is refused.
TEST_P(BadInput, OverrideTypeOutOfRangeIsRefused) {
  ForceField ff = ff_;
  ff.overrides = {{0, 5, 1.0, 1.0}};
  EXPECT_FALSE(error_of(config_, ff).empty());
}

// Particle 5 has type index 2 with 2 types: the message names the particle (5) and says "type".
TEST_P(BadInput, TypeIndexOutOfRangeNamesParticle) {
  config_.types[5] = 2;
  const std::string msg = error_of(config_, ff_);
  EXPECT_TRUE(contains_number(msg, 5)) << msg;
  EXPECT_THAT(lowercase(msg), HasSubstr("type"));
}

// Particles 3 and 11 at the same position: the message names both indices.
TEST_P(BadInput, CoincidentParticlesNameBoth) {
  for (int a = 0; a < 3; ++a) coord(11, a) = coord(3, a);
  const std::string msg = error_of(config_, ff_);
  EXPECT_TRUE(contains_number(msg, 3)) << msg;
  EXPECT_TRUE(contains_number(msg, 11)) << msg;
}

// Particle 11 at particle 3's position plus a box vector (dyadic coordinates, L = 8: exact, so
// the minimum-image distance is exactly 0): both named.
TEST_P(BadInput, CoincidentThroughPeriodicImageNameBoth) {
  cellforce::Box box = config_.box;
  box.length[0] = box.length[1] = box.length[2] = 8.0;
  RandomSpec spec;
  spec.min_distance = 1.0;
  Configuration c = random_configuration(box, 20, 9, spec);
  for (double& x : c.positions) x = std::floor(x * 64.0) / 64.0;  // dyadic: differences exact
  c.positions[11 * 3 + 0] = c.positions[3 * 3 + 0] + 8.0;
  c.positions[11 * 3 + 1] = c.positions[3 * 3 + 1];
  c.positions[11 * 3 + 2] = c.positions[3 * 3 + 2] - 16.0;
  const std::string msg = error_of(c, ff_);
  EXPECT_TRUE(contains_number(msg, 3)) << msg;
  EXPECT_TRUE(contains_number(msg, 11)) << msg;
}

// Float pairs only: particles 3 and 11 at 1e-3 sigma, where the float force overflows to inf
// (F ~ 48 sigma^12 / r^13 = 5e40): the error names both (engine.h: "overflowing pair").
TEST_P(BadInput, OverflowingFloatPairNamesBoth) {
  if (!entry().float_pairs) GTEST_SKIP() << entry().name << " evaluates pairs in double";
  for (int a = 0; a < 3; ++a) coord(11, a) = coord(3, a) + (a == 0 ? 1e-3 : 0.0);
  const std::string msg = error_of(config_, ff_);
  EXPECT_TRUE(contains_number(msg, 3)) << msg;
  EXPECT_TRUE(contains_number(msg, 11)) << msg;
}

INSTANTIATE_TEST_SUITE_P(EntryPoints, BadInput,
                         ::testing::Range(std::size_t(0), entry_points().size()),
                         [](const ::testing::TestParamInfo<std::size_t>& p) {
                           return entry_points()[p.param].name;
                         });

// ForceField::validate itself names the type with the negative sigma or epsilon, and the cutoff.
TEST(ForceFieldValidate, NamesTheOffendingParameter) {
  ForceField ff;
  ff.types = {{"Alpha", 1.0, 1.0}, {"Bravo", -1.0, 1.0}};
  try {
    ff.validate();
    ADD_FAILURE() << "negative sigma accepted";
  } catch (const cellforce::Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("Bravo"));
  }
  ff.types[1] = {"Bravo", 1.0, -2.0};
  try {
    ff.validate();
    ADD_FAILURE() << "negative epsilon accepted";
  } catch (const cellforce::Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("Bravo"));
  }
  ff.types[1] = {"Bravo", 1.0, 1.0};
  ff.cutoff = -2.5;
  try {
    ff.validate();
    ADD_FAILURE() << "negative cutoff accepted";
  } catch (const cellforce::Error& e) {
    EXPECT_THAT(lowercase(e.what()), HasSubstr("cutoff"));
  }
}

// validate_system names particle 7's NaN directly too.
TEST(ValidateSystem, NamesParticle) {
  Configuration c = cellforce::make_lattice(cellforce::Lattice::kFcc, 3, 0.8442);
  c.positions[7 * 3] = std::numeric_limits<double>::quiet_NaN();
  try {
    cellforce::validate_system(c.view(), ForceField{});
    ADD_FAILURE() << "NaN accepted";
  } catch (const cellforce::Error& e) {
    EXPECT_TRUE(contains_number(e.what(), 7)) << e.what();
  }
}

// contains_number itself: whole numbers only.
TEST(OracleHelpers, ContainsNumberMatchesWholeNumbers) {
  EXPECT_TRUE(contains_number("particle 7 has", 7));
  EXPECT_TRUE(contains_number("particles 3 and 11.", 11));
  EXPECT_TRUE(contains_number("(3, 11)", 3));
  EXPECT_FALSE(contains_number("particle 17", 7));
  EXPECT_FALSE(contains_number("x = 0.7", 7));
  EXPECT_FALSE(contains_number("x = 7.5", 7));
  EXPECT_FALSE(contains_number("particle 71", 7));
}

}  // namespace
}  // namespace cftest
