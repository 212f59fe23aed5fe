// Reuse of the neighbour structure (core/reuse.h): the options, the grid condition the skin adds,
// the rebuild policy, the audit's own pair search and coverage count (against the brute force and
// against what the traversal actually visits), and MD with a skin against MD without one. The
// stiff cases (a particle beyond skin / 2, the missed-pair counter) are case 11 of
// stability_test.cpp.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "backends.h"
#include "core/error.h"
#include "core/grid.h"
#include "core/reuse.h"
#include "cpu/engine.h"
#include "md/md.h"
#include "oracle.h"
#include "reference/brute_force.h"
#include "scene/lattice.h"
#include "scenes.h"

namespace cftest {
namespace {

using cellforce::Configuration;
using cellforce::CpuEngine;
using cellforce::CpuOptions;
using cellforce::ForceField;
using cellforce::ForceResult;
using cellforce::Grid;
using cellforce::Request;
using cellforce::ReuseOptions;

std::string error_of(const ReuseOptions& reuse) {
  try {
    CpuOptions o;
    o.reuse = reuse;
    CpuEngine e(o);
  } catch (const cellforce::Error& err) {
    return err.what();
  }
  return {};
}

TEST(ReuseOptions, BadValuesAreRejectedNamingTheParameter) {
  for (double skin : {-0.1, std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()}) {
    ReuseOptions r;
    r.skin = skin;
    EXPECT_NE(error_of(r).find("skin"), std::string::npos) << "skin " << skin << ": " << error_of(r);
  }
  ReuseOptions r;
  r.every = -1;
  EXPECT_NE(error_of(r).find("every"), std::string::npos) << error_of(r);
  r.every = 0;
  r.skin = 0.3;
  EXPECT_EQ(error_of(r), "");
}

// skin = auto (resolve_reuse): pair lists with a skin of 0.24 rc for an MD engine on CUDA with
// Jacobi accumulation where rc + skin fits in half of every periodic edge (the bound inclusive, as
// the engine's own test of it); none for force calls, the CPU, Gauss-Seidel or a smaller box. The
// caller's check, every and audit pass through; a skin given by the caller comes back as it is.
TEST(ReuseOptions, AutoIsARuleOfTheBackendAndTheBox) {
  constexpr cellforce::ListMemory kFast = cellforce::ListMemory::kFast;
  using cellforce::Accumulation;
  using cellforce::Backend;
  using cellforce::resolve_reuse;
  const double rc = 2.5, skin = 0.24 * rc;  // 0.6
  cellforce::Box box;
  box.dim = 3;
  for (int a = 0; a < 3; ++a) box.length[a] = 20.0, box.periodic[a] = true;
  ReuseOptions automatic;
  automatic.automatic = true;
  automatic.check = false;
  automatic.every = 7;
  automatic.audit = true;
  const ReuseOptions lists = resolve_reuse(automatic, Backend::kCuda, Accumulation::kJacobi, true, box, rc, kFast);
  EXPECT_DOUBLE_EQ(lists.skin, skin);
  EXPECT_TRUE(lists.list);
  EXPECT_FALSE(lists.check);
  EXPECT_EQ(lists.every, 7);
  EXPECT_TRUE(lists.audit);
  EXPECT_EQ(cellforce::describe_reuse(automatic, lists, Backend::kCuda, Accumulation::kJacobi, true, box, rc, kFast),
            "skin 0.6 (auto: 0.24 rc), pair lists, rebuilt every 7 (not checked)");
  // Lists in lean memory: 0.18 rc; the same rule as to the box.
  const ReuseOptions lean =
      resolve_reuse(automatic, Backend::kCuda, Accumulation::kJacobi, true, box, rc, cellforce::ListMemory::kLean);
  EXPECT_DOUBLE_EQ(lean.skin, 0.18 * rc);
  EXPECT_TRUE(lean.list);
  EXPECT_EQ(cellforce::describe_reuse(automatic, lean, Backend::kCuda, Accumulation::kJacobi, true, box, rc,
                                      cellforce::ListMemory::kLean),
            "skin 0.45 (auto: 0.18 rc, lean memory), pair lists, rebuilt every 7 (not checked)");
  cellforce::Box narrow = box;  // 0.6 does not fit its y edge, 0.45 does
  narrow.length[1] = 2.0 * (rc + 0.5);
  EXPECT_FALSE(resolve_reuse(automatic, Backend::kCuda, Accumulation::kJacobi, true, narrow, rc, kFast).list);
  EXPECT_TRUE(resolve_reuse(automatic, Backend::kCuda, Accumulation::kJacobi, true, narrow, rc,
                            cellforce::ListMemory::kLean).list);
  auto none = [&](Backend b, Accumulation acc, bool md, const cellforce::Box& bx, const char* why) {
    const ReuseOptions r = resolve_reuse(automatic, b, acc, md, bx, rc, kFast);
    EXPECT_EQ(r.skin, 0.0) << why;
    EXPECT_FALSE(r.list) << why;
    EXPECT_EQ(r.every, 7) << why;
    EXPECT_NE(cellforce::describe_reuse(automatic, r, b, acc, md, bx, rc, kFast).find(why), std::string::npos)
        << cellforce::describe_reuse(automatic, r, b, acc, md, bx, rc, kFast);
  };
  none(Backend::kCpu, Accumulation::kJacobi, true, box, "no skin on the cpu");
  // Force calls (md false) take the rule of steps: on CUDA the device decides their rebuilds.
  const ReuseOptions calls = resolve_reuse(automatic, Backend::kCuda, Accumulation::kJacobi, false, box, rc, kFast);
  EXPECT_DOUBLE_EQ(calls.skin, skin);
  EXPECT_TRUE(calls.list);
  none(Backend::kCpu, Accumulation::kJacobi, false, box, "no skin on the cpu");
  none(Backend::kCuda, Accumulation::kGaussSeidel, true, box, "pair lists need jacobi");
  cellforce::Box small = box;
  small.length[1] = std::nextafter(2.0 * (rc + skin), 0.0);
  none(Backend::kCuda, Accumulation::kJacobi, true, small, "rc + skin exceeds half the box");
  small.length[1] = 2.0 * (rc + skin);  // equality fits: 2 (rc + skin) <= L
  EXPECT_TRUE(resolve_reuse(automatic, Backend::kCuda, Accumulation::kJacobi, true, small, rc, kFast).list);
  small.periodic[1] = false;  // an open axis sets no bound
  small.length[1] = 0.0;
  EXPECT_TRUE(resolve_reuse(automatic, Backend::kCuda, Accumulation::kJacobi, true, small, rc, kFast).list);
  ReuseOptions given;
  given.skin = 0.3;
  const ReuseOptions same = resolve_reuse(given, Backend::kCuda, Accumulation::kJacobi, true, box, rc, kFast);
  EXPECT_EQ(same.skin, 0.3);
  EXPECT_FALSE(same.list);
  EXPECT_EQ(cellforce::describe_reuse(given, same, Backend::kCuda, Accumulation::kJacobi, true, box, rc, kFast),
            "skin 0.3, cells reused");
  given.list = true;  // asked for: served on CUDA with Jacobi where rc + skin fits, else the cells
  EXPECT_EQ(cellforce::describe_reuse(given, given, Backend::kCuda, Accumulation::kJacobi, false, box, rc, kFast),
            "skin 0.3, pair lists");
  EXPECT_EQ(cellforce::describe_reuse(given, given, Backend::kCpu, Accumulation::kJacobi, false, box, rc, kFast),
            "skin 0.3, cells reused");
  EXPECT_EQ(cellforce::describe_reuse(given, given, Backend::kCuda, Accumulation::kGaussSeidel, false, box, rc, kFast),
            "skin 0.3, cells reused");
  EXPECT_TRUE(cellforce::pair_lists_serve(given, Accumulation::kJacobi, box, rc));
  small.periodic[1] = true;
  small.length[1] = std::nextafter(2.0 * (rc + 0.3), 0.0);
  EXPECT_FALSE(cellforce::pair_lists_serve(given, Accumulation::kJacobi, small, rc));
}

// The condition a skin adds (grid.h): on a periodic axis of two or more cells, c/2 + h + skin/2 <
// L/2, so that a particle moved by skin / 2 is still staged as the image next to its cell. In a
// box of 6.2 with rc 1 and skin 0.8 two cells would break it: the planner takes one, check_grid
// refuses two, and the planned grid is exact after moves up to skin / 2.
TEST(ReuseGrid, SkinConditionIsPlannedAndChecked) {
  const cellforce::Box box = cube(3, 6.2);
  const double rc = 1.0, skin = 0.8;
  const Grid without = cellforce::plan_grid(box, rc, nullptr, 0, {}, 0.0);
  EXPECT_EQ(without.n[0], 2u) << "without a skin the box takes two cells per axis";
  const Grid with = cellforce::plan_grid(box, rc, nullptr, 0, {}, skin);
  EXPECT_EQ(with.n[0], 1u) << "two cells of 3.1 with h = " << with.half_width << " and skin 0.8 break the condition";
  EXPECT_NO_THROW(cellforce::check_grid(with, box, rc, cellforce::CellRule::kTight, skin));
  const uint32_t two[3] = {2, 2, 2};
  const Grid broken = cellforce::make_grid_unchecked(box, two, with.half_width, nullptr, 0);
  try {
    cellforce::check_grid(broken, box, rc, cellforce::CellRule::kTight, skin);
    ADD_FAILURE() << "check_grid accepted two cells per axis with skin " << skin;
  } catch (const cellforce::Error& e) {
    EXPECT_NE(std::string(e.what()).find("skin"), std::string::npos) << e.what();
  }
  // rc + skin > L/2 is legal when rc <= L/2 (one cell per axis, minimum image in the pair).
  EXPECT_NO_THROW(cellforce::check_grid(cellforce::plan_grid(box, 3.0, nullptr, 0, {}, 0.5), box, 3.0,
                                        cellforce::CellRule::kTight, 0.5));

  RandomSpec spec;
  spec.min_distance = 0.85;
  const Configuration c = random_configuration(box, 120, 21, spec);
  const ForceField ff = lj_field(rc);
  CpuOptions o;
  o.reuse.skin = skin;
  o.reuse.audit = true;
  CpuEngine e(o);
  ForceResult r;
  e.evaluate(c.view(), ff, Request{}, r);
  const Configuration m = moved(c, 0.499 * skin, 22);
  e.evaluate(m.view(), ff, Request{}, r);
  EXPECT_FALSE(e.stats().rebuilt);
  ForceResult ref;
  cellforce::brute_force(m.view(), ff, Request{}, ref);
  EXPECT_TRUE(forces_match(ref, r, 1e-12));
  EXPECT_TRUE(pair_sets_equal(cellforce::brute_force_pairs(m.view(), ff), e.visited_pairs(m.view(), ff)));
}

// `every` = N: a structure serves N evaluations (its build's included), whatever the displacement;
// a change of box, particle count or cutoff rebuilds at once.
TEST(ReusePolicy, EveryAndChangesOfTheSystem) {
  const Scene s = make_scene("random3d_periodic");
  CpuOptions o;
  o.reuse.skin = 0.3;
  o.reuse.check = false;
  o.reuse.every = 3;
  CpuEngine e(o);
  ForceResult r;
  std::vector<std::size_t> builds;
  for (int k = 0; k < 7; ++k) {
    e.evaluate(s.config.view(), s.ff, Request{}, r);
    builds.push_back(e.stats().builds);
  }
  EXPECT_EQ(builds, (std::vector<std::size_t>{1, 1, 1, 2, 2, 2, 3}));

  ForceField longer = s.ff;
  longer.cutoff = 2.6;
  e.evaluate(s.config.view(), longer, Request{}, r);
  EXPECT_TRUE(e.stats().rebuilt) << "a new cutoff must rebuild";
  Configuration bigger = s.config;
  bigger.box.length[0] *= 1.01;
  e.evaluate(bigger.view(), longer, Request{}, r);
  EXPECT_TRUE(e.stats().rebuilt) << "a new box must rebuild";
  Configuration fewer = bigger;
  fewer.positions.resize(fewer.positions.size() - 3);
  fewer.types.pop_back();
  e.evaluate(fewer.view(), longer, Request{}, r);
  EXPECT_TRUE(e.stats().rebuilt) << "a new particle count must rebuild";
  ForceResult ref;
  cellforce::brute_force(fewer.view(), longer, Request{}, ref);
  EXPECT_TRUE(forces_match(ref, r, 1e-12));

  CpuOptions off;  // skin 0: every evaluation builds
  CpuEngine plain(off);
  for (int k = 0; k < 3; ++k) plain.evaluate(s.config.view(), s.ff, Request{}, r);
  EXPECT_TRUE(plain.stats().rebuilt);
  EXPECT_EQ(plain.stats().builds, 3u);
}

// The audit's own search (pairs_within) is the brute force's pair set on every test scene.
TEST(ReuseAudit, PairsWithinEqualsBruteForce) {
  for (const std::string& name : all_scene_names()) {
    const Scene s = make_scene(name);
    EXPECT_TRUE(pair_sets_equal(cellforce::brute_force_pairs(s.config.view(), s.ff),
                                cellforce::pairs_within(s.config.view(), s.ff.cutoff)))
        << name;
  }
}

// A particle far out in an open box (a dilute scene, or one that escaped) does not blow up the
// audit's cell counts: they are capped before any integer conversion.
TEST(ReuseAudit, PairsWithinSurvivesAFarParticle) {
  Configuration c;
  c.box = cube(3, 10, false);
  c.positions = {0, 0, 0, 0.5, 0, 0, 4194304.5, 1e12, -3e15, 4194305.0, 1e12, -3e15};
  c.types = {0, 0, 0, 0};
  EXPECT_TRUE(pair_sets_equal(cellforce::brute_force_pairs(c.view(), lj_field(2.5)),
                              cellforce::pairs_within(c.view(), 2.5)));
}

// The list audit: lists of the pairs within rc + skin at the build (each pair in both lists), then
// every particle moved by up to `factor` x skin / 2: missed = pairs within rc now that were not within
// rc + skin then (counted here from the two configurations, pair by pair); none below skin / 2. A
// list holding a partner twice, or only one side of a pair, is counted as repeated or missed.
TEST(ReuseAudit, ListAuditCountsThePairsTheListsLack) {
  const double skin = 0.3;
  std::size_t total_missed = 0;
  for (const std::string name : {"random3d_periodic", "random2d_periodic", "random3d_open", "uneven3d"}) {
    const Scene s = make_scene(name);
    const std::size_t n = s.config.size();
    std::vector<std::vector<uint32_t>> partners(n);
    for (const auto& [i, j] : cellforce::pairs_within(s.config.view(), s.ff.cutoff + skin)) {
      partners[i].push_back(j);
      partners[j].push_back(i);
    }
    for (double factor : {0.45, 4.0}) {
      SCOPED_TRACE(name + " moved " + std::to_string(factor) + " x skin/2");
      const Configuration now = moved(s.config, factor * 0.5 * skin, 11);  // |move| < factor x skin / 2
      const auto pairs = cellforce::pairs_within(now.view(), s.ff.cutoff);
      std::size_t expected = 0;
      for (const auto& [i, j] : pairs)
        if (!(distance2(s.config, i, j) < (s.ff.cutoff + skin) * (s.ff.cutoff + skin))) ++expected;
      const cellforce::ReuseAudit a = cellforce::audit_lists(partners, pairs);
      EXPECT_EQ(a.missed, expected);
      EXPECT_EQ(a.repeated, 0u);
      if (factor < 1) {
        EXPECT_EQ(a.missed, 0u);
      }
      total_missed += a.missed;
    }
    const auto pairs = cellforce::pairs_within(s.config.view(), s.ff.cutoff);
    ASSERT_FALSE(pairs.empty());
    const auto [i, j] = pairs.front();
    std::vector<std::vector<uint32_t>> twice = partners, one_side = partners;
    twice[i].push_back(j);
    std::erase(one_side[j], i);
    EXPECT_EQ(cellforce::audit_lists(twice, pairs).repeated, 1u);
    EXPECT_EQ(cellforce::audit_lists(twice, pairs).missed, 0u);
    EXPECT_EQ(cellforce::audit_lists(one_side, pairs).missed, 1u);
  }
  EXPECT_GT(total_missed, 0u) << "the moves beyond skin / 2 never left a pair out: the count is not exercised";
}

// The audit's counts equal what the reused traversal really does: missed = brute-force pairs it
// does not find (not visited, or visited as another image of a particle that moved too far),
// repeated = pairs it finds more than once, for moves below and well beyond skin / 2 with the
// check off.
TEST(ReuseAudit, CountsEqualWhatTheTraversalVisits) {
  std::size_t total_missed = 0;
  for (const std::string name : {"random3d_periodic", "random2d_periodic", "random3d_open", "slab3d",
                                  "two_cells3d", "uneven3d", "half_box3d"}) {
    const Scene s = make_scene(name);
    for (double factor : {0.45, 1.5, 4.0}) {
      const double skin = 0.3;
      CpuOptions o;
      o.reuse.skin = skin;
      o.reuse.check = false;
      o.reuse.audit = true;
      CpuEngine e(o);
      ForceResult r;
      e.evaluate(s.config.view(), s.ff, Request{}, r);
      const Configuration m = moved(s.config, factor * skin, 31);
      const auto got = e.visited_pairs(m.view(), s.ff);
      const auto want = cellforce::brute_force_pairs(m.view(), s.ff);
      const auto& st = e.stats();
      ASSERT_FALSE(st.rebuilt) << name;
      EXPECT_EQ(st.missed_pairs, missing(want, got).size()) << name << ", moves up to " << factor << " skin";
      EXPECT_EQ(st.repeated_pairs, duplicates(got).size()) << name << ", moves up to " << factor << " skin";
      if (factor < 0.5) {
        EXPECT_EQ(st.missed_pairs + st.repeated_pairs, 0u) << name;
      }
      total_missed += st.missed_pairs;
    }
  }
  EXPECT_GT(total_missed, 0u) << "no move beyond skin / 2 missed a pair: the audit was not tested";
}

// =====================================================================================================
// MD with a skin: the same trajectory as with a build on every step (to round-off, which chaos
// amplifies over the run), far fewer builds, and the audit finds nothing missed on any step.
// =====================================================================================================
class ReuseMd : public ::testing::TestWithParam<std::size_t> {
 protected:
  void SetUp() override {
    const std::string why = backends()[GetParam()].unavailable();
    if (!why.empty()) GTEST_SKIP() << backends()[GetParam()].name << ": " << why;
  }
};

struct MdRun {
  cellforce::MdState state;
  std::size_t builds = 0, missed = 0, repeated = 0;
  double max_displacement = 0;
};

MdRun run_md(std::size_t backend, double skin, int steps) {
  EngineSpec spec;
  spec.reuse.skin = skin;
  spec.reuse.audit = skin > 0;
  auto e = backends()[backend].make(spec);
  MdRun run;
  cellforce::MdState& s = run.state;
  s.config = cellforce::make_lattice(cellforce::Lattice::kFcc, 5, 0.8442);
  const std::vector<double> masses(s.config.size(), 1.0);
  ForceField ff = lj_field(2.5);
  ff.mode = cellforce::CutoffMode::kForceShift;
  cellforce::initialize_velocities(s, masses, 1.44, 5);
  ForceResult result;
  auto compute = [&](cellforce::MdState& st) {
    e->evaluate(st.config.view(), ff, Request{false, false}, result);
    st.forces = result.forces;
    run.missed += e->stats().missed_pairs;
    run.repeated += e->stats().repeated_pairs;
    if (!e->stats().rebuilt)  // (a rebuild reports the displacement that asked for it)
      run.max_displacement = std::max(run.max_displacement, e->stats().max_displacement);
  };
  compute(s);
  cellforce::IntegratorSettings settings;
  settings.dt = 0.005;
  for (int k = 0; k < steps; ++k) cellforce::advance(s, masses, settings, compute);
  run.builds = e->stats().builds;
  return run;
}

TEST_P(ReuseMd, TrajectoryMatchesBuildingEveryStep) {
  const int steps = 200;
  const MdRun fresh = run_md(GetParam(), 0.0, steps);
  const MdRun reused = run_md(GetParam(), 0.3, steps);
  EXPECT_EQ(fresh.builds, std::size_t(steps) + 1);
  EXPECT_LT(reused.builds, std::size_t(steps) / 5) << "a skin of 0.3 at T = 1.44 should serve ~10+ steps";
  EXPECT_GT(reused.builds, 1u) << "the run never rebuilt: the check was not exercised";
  EXPECT_LE(reused.max_displacement, 0.15) << "a structure served past skin / 2";
  EXPECT_EQ(reused.missed, 0u);
  EXPECT_EQ(reused.repeated, 0u);
  // Positions after 200 steps (t = 1): the two runs differ only in the order of the force sums,
  // ~1e-16 relative per step, grown by the Lyapunov instability to well below 1e-8.
  double worst = 0;
  const auto& a = fresh.state.config.positions;
  const auto& b = reused.state.config.positions;
  for (std::size_t k = 0; k < a.size(); ++k) {
    const double l = fresh.state.config.box.length[k % 3];
    worst = std::max(worst, std::fabs(cellforce::minimum_image(a[k] - b[k], l, 1.0 / l)));
  }
  EXPECT_LT(worst, 1e-8);
}

std::string backend_name(const ::testing::TestParamInfo<std::size_t>& p) { return backends()[p.param].name; }
INSTANTIATE_TEST_SUITE_P(Backends, ReuseMd, ::testing::ValuesIn(backend_ids()), backend_name);

}  // namespace
}  // namespace cftest
