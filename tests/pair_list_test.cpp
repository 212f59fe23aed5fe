// Pair lists (ReuseOptions::list, cuda/search/pair_list.cuh): a build records every particle's partners
// within rc + skin; the evaluations the structure serves walk those lists. Checked against the
// double-precision brute force at positions moved after the build, against the brute force's
// own pair count, through an MD run, for bitwise repeatability, and for the error that names a
// coincident pair. Skips with a message where no CUDA device exists; compiled only with CUDA.
#ifdef CELLFORCE_HAVE_CUDA

#include <cuda_runtime.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <initializer_list>
#include <optional>
#include <string>
#include <tuple>

#include "backends/md_engine.h"
#include "core/error.h"
#include "backend/engine.h"        // cuda/backend/engine.h
#include "backend/force_engine.h"  // cuda/backend/force_engine.h
#include "search/list_build.h"  // cuda/search/list_build.h
#include "md/md.h"
#include "oracle.h"
#include "reference/brute_force.h"
#include "scene/scene.h"
#include "scenes.h"

namespace cftest {
namespace {

using cellforce::Configuration;
using cellforce::ForceResult;
using cellforce::GpuEngine;
using cellforce::GpuOptions;
using cellforce::ListMemory;
using cellforce::Precision;
using cellforce::Request;

#define CF_SKIP_WITHOUT_DEVICE()                       \
  do {                                                 \
    const std::string why_ = GpuEngine::unavailable(); \
    if (!why_.empty()) GTEST_SKIP() << why_;           \
  } while (0)

constexpr double kSkin = 0.3;

GpuOptions list_options(Precision p, double skin = kSkin, bool list = true) {
  GpuOptions o;
  o.precision = p;
  o.reuse.skin = skin;
  o.reuse.list = list;
  return o;
}

// Whether the scene's periodic edges leave room for lists (rc + skin <= L / 2); else the engine
// traverses the cells.
bool lists_fit(const Scene& s, double skin) {
  for (int a = 0; a < s.config.box.dim; ++a)
    if (s.config.box.periodic[a] && 2 * (s.ff.cutoff + skin) > s.config.box.length[a]) return false;
  return true;
}

// Pairs closer than r by minimum image, counted by the test itself (all pairs, double).
std::size_t pairs_within(const Configuration& c, double r) {
  std::size_t count = 0;
  for (std::size_t i = 0; i < c.size(); ++i)
    for (std::size_t j = i + 1; j < c.size(); ++j)
      if (distance2(c, i, j) < r * r) ++count;
  return count;
}

// Two engines that must build the same lists (another memory mode, another number of splits):
// the same listed pairs, and bitwise the same forces, energies and virial, evaluation by evaluation.
void expect_same_lists(GpuEngine& x, GpuEngine& y, const Configuration& c, const Scene& scene) {
  ForceResult rx, ry;
  x.evaluate(c.view(), scene.ff, Request{true, true}, rx);
  y.evaluate(c.view(), scene.ff, Request{true, true}, ry);
  if (lists_fit(scene, kSkin)) {
    EXPECT_GT(x.listed_pairs(), 0u);
  }
  EXPECT_EQ(x.listed_pairs(), y.listed_pairs());
  EXPECT_EQ(x.stats().rebuilt, y.stats().rebuilt);
  EXPECT_TRUE(bitwise_equal(rx, ry));
}

using ListParam = std::tuple<Precision, std::string>;

class PairList : public ::testing::TestWithParam<ListParam> {
 protected:
  void SetUp() override { CF_SKIP_WITHOUT_DEVICE(); }
};

// The build evaluation and one at positions moved by up to 0.1499 < skin / 2 (no rebuild: the
// list serves it). Double: per particle |dF_i| <= 1e-12 max(|F_i|, F_rms), energies, total and
// virial to 1e-12. Single and mixed: r_ij is formed in double and rounded once to float (an open
// axis), or from fixed-point positions with two roundings (periodic boxes: fixed_point_serves), so
// the median per-particle relative error stays below the cells' 1e-6 bound; total energy and
// virial to 1e-5.
TEST_P(PairList, ReusedEvaluationMatchesTheBruteForce) {
  const auto& [precision, name] = GetParam();
  const Scene s = make_scene(name);
  GpuEngine e(list_options(precision));
  const Request all{true, true};
  const Configuration m = moved(s.config, 0.1499, 11);
  for (const Configuration* c : {&s.config, &m}) {
    ForceResult got, ref;
    e.evaluate(c->view(), s.ff, all, got);
    cellforce::brute_force(c->view(), s.ff, all, ref);
    const char* which = c == &s.config ? "build" : "reused";
    if (c == &m) {
      EXPECT_FALSE(e.stats().rebuilt) << "the moves stay under skin / 2: the structure must serve";
    }
    if (lists_fit(s, kSkin)) {
      EXPECT_GT(e.listed_pairs(), 0u) << which << ": the cells served, not the list";
    }
    SCOPED_TRACE(which);
    expect_results_match(ref, got, precision);
  }
}

std::string list_param_name(const ::testing::TestParamInfo<ListParam>& p) {
  return std::string(cellforce::to_string(std::get<0>(p.param))) + "_" + std::get<1>(p.param);
}

std::vector<std::string> list_scene_names() {
  std::vector<std::string> names = all_modes_scene_names();
  for (const char* extra : {"random3d_open_far", "random3d_periodic_far_image", "clustered3d_corner",
                            "clustered3d_across_boundary", "lattice_fcc_jitter", "uneven3d"})
    names.push_back(extra);
  return names;
}

INSTANTIATE_TEST_SUITE_P(Scenes, PairList,
                         ::testing::Combine(::testing::Values(Precision::kDouble, Precision::kMixed,
                                                              Precision::kSingle),
                                            ::testing::ValuesIn(list_scene_names())),
                         list_param_name);

// The list holds every pair within rc + skin exactly once from each side: its entries are twice
// the pairs the test counts by brute force (random positions: no pair sits at rc + skin to the
// last bit), in every precision (float coordinates pass the hi-part prefilter and the compensated
// test, with the double positions deciding near the cutoff).
TEST(PairListBuild, EntriesAreTwiceThePairsWithinTheListCutoff) {
  CF_SKIP_WITHOUT_DEVICE();
  for (const char* name : {"random3d_periodic", "random2d_periodic", "random3d_open", "slab3d", "multitype3d_lb",
                           "clustered3d_corner", "uneven3d"}) {
    const Scene s = make_scene(name);
    if (!lists_fit(s, kSkin)) continue;
    const std::size_t expected = 2 * pairs_within(s.config, s.ff.cutoff + kSkin);
    for (Precision p : {Precision::kDouble, Precision::kMixed, Precision::kSingle}) {
      GpuEngine e(list_options(p));
      ForceResult r;
      e.evaluate(s.config.view(), s.ff, Request{false, false}, r);
      EXPECT_EQ(e.listed_pairs(), expected) << name << " " << cellforce::to_string(p);
    }
  }
}

// Pairs placed at the list cutoff to within 3e-8..3e-6 relative, either side, in 27 directions (each
// pair far from the others, straddling cell faces and corners): the float coordinates' prefilter,
// the compensated test and the double band between in2 and out2 keep exactly the pairs closer than
// rc + skin in double, in every precision (the brute force's count; 0 relative offset excluded).
TEST(PairListBuild, PairsAtTheListCutoffAreDecidedInDouble) {
  const Scene base = make_scene("random3d_periodic");
  const double cut = base.ff.cutoff + kSkin;
  const double offsets[] = {-3e-6, -1e-6, -3e-7, -1e-7, -3e-8, 3e-8, 1e-7, 3e-7, 1e-6, 3e-6};
  Configuration c;
  c.box.dim = 3;
  for (int a = 0; a < 3; ++a) c.box.length[a] = 30.0, c.box.periodic[a] = true;
  std::size_t k = 0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int l = 0; l < 3; ++l, ++k) {
        double u[3], norm = 0;
        for (int a = 0; a < 3; ++a) {
          u[a] = cellforce::unit_open(cellforce::splitmix64(7 * k + uint64_t(a) + 1)) - 0.5;
          norm += u[a] * u[a];
        }
        const double r = cut * (1 + offsets[k % 10]);
        // Sites 10 apart on every axis (more than 2 (rc + skin) + rc + skin: no pair meets another),
        // next to the periodic boundary on x and on the faces of the 5-wide cells on y and z.
        const double site[3] = {10.0 * i + 0.05, 10.0 * j + 5.0, 10.0 * l + 4.97};
        for (int a = 0; a < 3; ++a) c.positions.push_back(site[a]);
        for (int a = 0; a < 3; ++a)
          c.positions.push_back(cellforce::wrap_coordinate(site[a] + r * u[a] / std::sqrt(norm), 30.0));
        c.types.push_back(0);
        c.types.push_back(0);
      }
  const std::size_t expected = pairs_within(c, cut);
  ASSERT_EQ(expected, 15u) << "the pairs placed inside (negative offsets)";
  CF_SKIP_WITHOUT_DEVICE();
  for (Precision p : {Precision::kDouble, Precision::kMixed, Precision::kSingle}) {
    GpuEngine e(list_options(p));
    ForceResult r;
    e.evaluate(c.view(), base.ff, Request{false, false}, r);
    EXPECT_EQ(e.listed_pairs(), 2 * expected) << cellforce::to_string(p);
  }
}

// MD with lists: the trajectory of a build on every step to round-off (as ReuseMd), far fewer
// builds.
TEST(PairListMd, TrajectoryMatchesBuildingEveryStep) {
  CF_SKIP_WITHOUT_DEVICE();
  auto run = [](double skin, std::size_t* builds) {
    GpuEngine e(list_options(Precision::kDouble, skin));
    cellforce::MdState s;
    s.config = cellforce::make_lattice(cellforce::Lattice::kFcc, 5, 0.8442);
    const std::vector<double> masses(s.config.size(), 1.0);
    cellforce::ForceField ff = lj_field(2.5);
    ff.mode = cellforce::CutoffMode::kForceShift;
    cellforce::initialize_velocities(s, masses, 1.44, 5);
    ForceResult result;
    std::size_t listed = 0;
    auto compute = [&](cellforce::MdState& st) {
      e.evaluate(st.config.view(), ff, Request{false, false}, result);
      st.forces = result.forces;
      listed = std::max(listed, e.listed_pairs());
    };
    compute(s);
    cellforce::IntegratorSettings settings;
    settings.dt = 0.005;
    for (int k = 0; k < 200; ++k) cellforce::advance(s, masses, settings, compute);
    *builds = e.stats().builds;
    if (skin > 0) {
      EXPECT_GT(listed, 0u) << "the lists never served";
    }
    return s;
  };
  std::size_t fresh_builds = 0, list_builds = 0;
  const cellforce::MdState fresh = run(0.0, &fresh_builds);
  const cellforce::MdState listed = run(kSkin, &list_builds);
  EXPECT_EQ(fresh_builds, 201u);
  EXPECT_LT(list_builds, 40u) << "a skin of 0.3 at T = 1.44 should serve ~10+ steps";
  EXPECT_GT(list_builds, 1u) << "the run never rebuilt: the check was not exercised";
  double worst = 0;
  for (std::size_t k = 0; k < fresh.config.positions.size(); ++k) {
    const double l = fresh.config.box.length[k % 3];
    worst = std::max(worst, std::fabs(cellforce::minimum_image(fresh.config.positions[k] - listed.config.positions[k],
                                                               l, 1.0 / l)));
  }
  EXPECT_LT(worst, 1e-8);
}

// Two engines, the same calls: bitwise the same results, at the build and on the reused step.
TEST(PairListRepeat, TwoEnginesAreBitwiseEqual) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene s = make_scene("multitype3d_lb");
  const Configuration m = moved(s.config, 0.1, 3);
  for (Precision p : {Precision::kSingle, Precision::kMixed, Precision::kDouble}) {
    GpuEngine a(list_options(p)), b(list_options(p));
    for (const Configuration* c : {&s.config, &m}) {
      ForceResult ra, rb;
      a.evaluate(c->view(), s.ff, Request{true, true}, ra);
      b.evaluate(c->view(), s.ff, Request{true, true}, rb);
      EXPECT_TRUE(bitwise_equal(ra, rb)) << cellforce::to_string(p);
    }
  }
}

// The forces of a step do not depend on whether its energy and virial were asked for: the force
// kernels with and without observables give bitwise the same forces, at a build and on a reused
// step, in every precision and cutoff mode. An MD run observes only its output steps and a restart
// recomputes the forces with observables, so a bitwise restart needs this. Single-type cubes and
// squares (the in.lj case, where the fixed-point scale is the same on every axis and the force
// kernels fold it into the pair's constants) and a multi-type box: a fold in the kernels without
// observables only would break this. The full request's energy and virial, which the folded kernels
// scale back by 1 + eps, are checked against the double brute force as the list tests check them:
// not on the perfect lattice, whose forces are ~0, and on the jittered square lattice with float
// bounds of its own (2e-6 median relative force error, virial 2e-5): its spacing (1.118) sits at
// the LJ minimum (2^(1/6) = 1.122), where each pair's force cancels to a small remainder, so
// float's median error there is ~1.0-1.3e-6 and force shift's virial 1.0e-5 (measured on the GPU; a
// host emulation of the float pair gives 1.1e-6 in either form of the force), above the 1e-6 and
// 1e-5 that well-conditioned scenes meet.
TEST(PairListRequests, ForcesDoNotDependOnTheObservablesAsked) {
  CF_SKIP_WITHOUT_DEVICE();
  using cellforce::CutoffMode;
  for (const char* name : {"lattice_fcc_jitter", "lattice_bcc_perfect", "multitype3d_lb", "random2d_periodic",
                           "lattice_square2d_jitter"}) {
    for (CutoffMode mode : {CutoffMode::kTruncate, CutoffMode::kShift, CutoffMode::kForceShift}) {
      Scene s = make_scene(name);
      s.ff.mode = mode;
      ASSERT_TRUE(lists_fit(s, kSkin)) << name;
      const Configuration m = moved(s.config, 0.1, 7);
      const Configuration* configs[2] = {&s.config, &m};
      const bool oracle = std::string(name) != "lattice_bcc_perfect";
      const bool at_minimum = std::string(name) == "lattice_square2d_jitter";
      ForceResult refs[2];  // the double brute force of each configuration, for every precision
      if (oracle)
        for (int k = 0; k < 2; ++k) cellforce::brute_force(configs[k]->view(), s.ff, Request{true, true}, refs[k]);
      for (Precision p : {Precision::kSingle, Precision::kMixed, Precision::kDouble}) {
        SCOPED_TRACE(std::string(name) + " " + cellforce::to_string(mode) + " " + cellforce::to_string(p));
        GpuEngine bare(list_options(p)), full(list_options(p));
        for (int k = 0; k < 2; ++k) {
          ForceResult rb, rf;
          bare.evaluate(configs[k]->view(), s.ff, Request{false, false}, rb);
          full.evaluate(configs[k]->view(), s.ff, Request{true, true}, rf);
          EXPECT_GT(bare.listed_pairs(), 0u);
          EXPECT_EQ(bare.stats().rebuilt, full.stats().rebuilt);
          EXPECT_EQ(rb.forces, rf.forces);
          if (at_minimum && p != Precision::kDouble) {
            EXPECT_LT(median_relative_force_error(refs[k], rf), 2e-6);
            EXPECT_TRUE(total_energy_matches(refs[k], rf, 1e-5));
            EXPECT_TRUE(virial_matches(refs[k], rf, 2e-5));
          } else if (oracle) {
            expect_results_match(refs[k], rf, p);
          }
        }
      }
    }
  }
}

// The lean memory mode (the build stages occupants as it loads them and frees what is dead first,
// chosen for systems near the device's memory) makes the same list as the staged build: the same
// results, bit for bit, at a build, on a reused step, and at rebuilds (another system, then the
// first again: the lean engine frees or lends its list's array and takes the sort's arrays
// again; its count pass reads occupants staged in that array where they fit), in every precision.
TEST(PairListLean, LeanBuildIsBitwiseTheStagedOne) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene a = make_scene("multitype3d_lb"), b = make_scene("random3d_periodic");
  const Configuration am = moved(a.config, 0.14, 5);
  const std::pair<const Configuration*, const Scene*> sequence[] = {
      {&a.config, &a}, {&am, &a}, {&b.config, &b}, {&a.config, &a}};
  for (Precision p : {Precision::kSingle, Precision::kMixed, Precision::kDouble}) {
    GpuOptions lean = list_options(p), fast = list_options(p);
    lean.memory = ListMemory::kLean;
    fast.memory = ListMemory::kFast;
    SCOPED_TRACE(cellforce::to_string(p));
    GpuEngine x(lean), y(fast);
    for (const auto& [c, scene] : sequence) expect_same_lists(x, y, *c, *scene);
    // The rebuild of a after b: b's list array holds a's staged occupants, which its count pass
    // reads; the fast engine's cells have their own.
    EXPECT_GE(x.list_staged_counts(), 1u);
    EXPECT_EQ(y.list_staged_counts(), 0u);
  }
}

// ---- the build's arithmetic (cuda/search/list_build.h), on the host ---------------------------------

// A row tile's column ranges: in order, contiguous, covering [0, ncols), each starting on a whole
// 32-column tile; one range is the whole walk.
TEST(PairListRules, SplitRangesPartitionTheColumns) {
  using cellforce::cuda::split_columns;
  for (uint32_t ncols = 0; ncols <= 700; ++ncols)
    for (uint32_t splits : {1u, 2u, 3u, 4u, 8u}) {
      uint32_t next = 0;
      for (uint32_t s = 0; s < splits; ++s) {
        const auto r = split_columns(ncols, splits, s);
        ASSERT_EQ(r.begin, next) << ncols << " columns, range " << s << " of " << splits;
        ASSERT_LE(r.begin, r.end);
        ASSERT_TRUE(r.begin == ncols || r.begin % 32 == 0);
        next = r.end;
      }
      ASSERT_EQ(next, ncols) << ncols << " columns in " << splits << " ranges";
      ASSERT_EQ(split_columns(ncols, 1, 0).end, ncols);
    }
}

TEST(PairListRules, SplitRule) {
  using cellforce::cuda::build_splits;
  EXPECT_EQ(build_splits(8217, 132), 4);    // 32,000 in.lj: 256,000 / 32 + 216 + 1 tiles at most
  EXPECT_EQ(build_splits(16217, 132), 2);   // 64,000
  EXPECT_EQ(build_splits(17000, 132), 1);   // ~67,000 on
  EXPECT_EQ(build_splits(1, 132), 8);
  EXPECT_EQ(build_splits(8217, 0), 1);      // no multiprocessor count: no splits wanted
}

// The block size of the force kernel with the next step's kick-drift, with the H100's in.lj
// numbers: 9 blocks of 128 or 4 of 256 a multiprocessor, 132 multiprocessors (waves of 152,064 and
// 135,168 threads).
TEST(PairListRules, FusedBlockRule) {
  using cellforce::cuda::fused_block_size;
  const int h100[2] = {9, 4};
  auto block = [&](std::size_t threads) { return fused_block_size(threads, 1, 128, h100, 132); };
  EXPECT_EQ(block(100000), 128);    // below one wave of 128: 256 would leave multiprocessors idle
  EXPECT_EQ(block(152064), 128);    // one whole wave of 128, two of 256
  EXPECT_EQ(block(152065), 256);    // two waves either way
  EXPECT_EQ(block(256000), 256);
  EXPECT_EQ(block(270336), 256);
  EXPECT_EQ(block(270337), 128);    // three waves of 256, two of 128
  EXPECT_EQ(block(304128), 128);
  EXPECT_EQ(block(304129), 256);
  EXPECT_EQ(block(1048576), 128);   // 7 waves against 8
  EXPECT_EQ(block(1064448), 128);
  EXPECT_EQ(block(1064449), 256);   // 8 waves either way
  EXPECT_EQ(block(1081344), 256);
  EXPECT_EQ(block(1081345), 128);
  EXPECT_EQ(block(4244832), 128);
  EXPECT_EQ(fused_block_size(256000, 8, 128, h100, 132), 128);  // 8 threads a particle: measured slower
  const int same_warps[2] = {10, 5}, none[2] = {9, 0};
  EXPECT_EQ(fused_block_size(256000, 1, 128, same_warps, 132), 128);  // 40 warps either way
  EXPECT_EQ(fused_block_size(256000, 1, 128, none, 132), 128);        // no block of 256 fits
  EXPECT_EQ(fused_block_size(256000, 1, 128, h100, 0), 128);          // no multiprocessor count
}

// The hi-part prefilter drops only pairs the compensated test drops: pairs of coordinates staged
// relative to a cell's centre (within c/2 + h of it), their double separation within 1e-5 of the
// list cutoff, staged as StagedCoordinate<float> (hi and lo); whenever the hi-part r^2 reaches the
// bound, the compensated r^2 (as the kernel forms it, with and without fused multiply-adds) is at
// least out2. A bound without the hi parts' rounding (out2 itself) fails this check: it has teeth.
TEST(PairListRules, PrefilterDropsOnlyWhatTheCompensatedTestDrops) {
  struct Case {
    double cell, half_width, cutoff;
  };
  for (const Case c : {Case{5.29, 2.19, 3.1}, Case{5.6, 2.19, 3.1}, Case{40.0, 2.19, 3.1}, Case{3.0, 1.0, 1.4}}) {
    cellforce::Grid g;
    g.dim = 3;
    for (int a = 0; a < 3; ++a) g.cell[a] = c.cell;
    g.half_width = c.half_width;
    const double cutoff2 = c.cutoff * c.cutoff;
    const float out2 = float(cutoff2 * (1 + 1e-5));
    const float pre2 = cellforce::cuda::prefilter_bound(g, double(out2));
    const double x = 0.5 * c.cell + c.half_width;
    cftest::Rng rng(uint64_t(c.cell * 1000));
    std::size_t violations = 0, loose = 0, near = 0;
    for (int k = 0; k < 400000; ++k) {
      double a[3], b[3], u[3], norm = 0;
      for (int i = 0; i < 3; ++i) a[i] = rng.uniform(-x, x), u[i] = rng.uniform(-1, 1), norm += u[i] * u[i];
      const double r = std::sqrt(double(out2)) * (1 + rng.uniform(-1e-5, 1e-5));
      bool inside = true;
      for (int i = 0; i < 3; ++i) b[i] = a[i] + r * u[i] / std::sqrt(norm), inside = inside && std::abs(b[i]) <= x;
      if (!inside) continue;
      ++near;
      float hd[3], fd[3];
      for (int i = 0; i < 3; ++i) {
        const auto sa = cellforce::StagedCoordinate<float>::from(a[i]), sb = cellforce::StagedCoordinate<float>::from(b[i]);
        hd[i] = sa.hi - sb.hi;
        fd[i] = hd[i] + (sa.lo - sb.lo);
      }
      const float hi2 = hd[0] * hd[0] + hd[1] * hd[1] + hd[2] * hd[2];
      const float full2 = fd[0] * fd[0] + fd[1] * fd[1] + fd[2] * fd[2];
      const float full2_fma = std::fma(fd[2], fd[2], std::fma(fd[1], fd[1], fd[0] * fd[0]));
      const float hi2_fma = std::fma(hd[2], hd[2], std::fma(hd[1], hd[1], hd[0] * hd[0]));
      for (const float h : {hi2, hi2_fma})
        for (const float f : {full2, full2_fma}) {
          if (!(h < pre2) && f < out2) ++violations;
          if (!(h < out2) && f < out2) ++loose;
        }
    }
    SCOPED_TRACE("cell " + std::to_string(c.cell));
    EXPECT_GT(near, 100000u);
    EXPECT_EQ(violations, 0u);
    EXPECT_GT(loose, 0u) << "out2 as the bound never failed: the sample does not reach the rounding";
    EXPECT_LT(double(pre2), double(out2) * (1 + 1e-4)) << "the bound is far looser than the rounding needs";
  }
}

// The force kernel's fixed-point separations (FixedParticle, float pairs in a periodic box)
// against the double minimum image of the wrapped coordinates: pairs up to rc + skin + 1 apart,
// anywhere in boxes of 5 to 490 (the 100M in.lj box), a share of them across the periodic
// boundary; the error stays within L / 2^32 (two quantisations) plus two float roundings of |d|
// (with the scale rounded to a single float, the separations along an axis were all stretched by
// the scale's rounding, up to 2^-24: up to three roundings, which this bound refuses).
TEST(PairListRules, FixedPointSeparationIsTheMinimumImage) {
  using cellforce::cuda::fixed_coordinate;
  using cellforce::cuda::fixed_scale;
  using cellforce::cuda::fixed_separation;
  for (const double length : {5.0, 33.59, 107.2, 490.3}) {
    SCOPED_TRACE("L " + std::to_string(length));
    const double inv = 1.0 / length, reach = std::min(4.0, 0.45 * length);
    const cellforce::cuda::FixedScale scale = fixed_scale(length);
    cftest::Rng rng(uint64_t(length * 100));
    std::size_t across = 0, bad = 0;
    double worst = 0;
    for (int k = 0; k < 200000; ++k) {
      const double xa = rng.uniform(0, length), d = rng.uniform(-reach, reach);
      const double xb = cellforce::wrap_coordinate(xa - d, length);
      if (std::abs(xa - xb) > 0.5 * length) ++across;
      const double exact = cellforce::minimum_image(xa - xb, length, inv);
      const float got = fixed_separation(fixed_coordinate(xa, inv), fixed_coordinate(xb, inv), scale);
      const double err = std::abs(double(got) - exact);
      const double bound = length * 0x1p-32 + std::abs(exact) * 2.01 * 0x1p-24;
      if (!(err <= bound)) ++bad;
      worst = std::max(worst, err / bound);
    }
    EXPECT_EQ(bad, 0u) << "worst error / bound " << worst;
    EXPECT_GT(across, 500u) << "too few pairs across the boundary to test the image";
  }
}

// Fixed-point gathers serve periodic boxes whose edges are at most 2^8 cutoffs (the quantisation
// then no larger than a float rounding at the cutoff); an open axis or a longer edge gathers
// doubles. The 100M in.lj box (490, rc 2.5) is within; 2D boxes look at their two axes only.
TEST(PairListRules, FixedPointServesPeriodicBoxesUpTo256Cutoffs) {
  auto grid = [](int dim, double lx, double ly, double lz) {
    cellforce::Grid g;
    g.dim = dim;
    const double l[3] = {lx, ly, lz};
    for (int a = 0; a < 3; ++a) {
      g.length[a] = l[a];
      g.inv_length[a] = l[a] > 0 ? 1.0 / l[a] : 0.0;
    }
    return g;
  };
  using cellforce::cuda::fixed_point_serves;
  EXPECT_TRUE(fixed_point_serves(grid(3, 490.3, 490.3, 490.3), 2.5));
  EXPECT_TRUE(fixed_point_serves(grid(3, 640.0, 33.6, 33.6), 2.5));
  EXPECT_FALSE(fixed_point_serves(grid(3, 640.1, 33.6, 33.6), 2.5));
  EXPECT_FALSE(fixed_point_serves(grid(3, 1290.0, 1290.0, 1290.0), 2.5));
  EXPECT_FALSE(fixed_point_serves(grid(3, 33.6, 0.0, 33.6), 2.5));  // an open axis
  EXPECT_TRUE(fixed_point_serves(grid(2, 100.0, 100.0, 0.0), 2.5));
  EXPECT_FALSE(fixed_point_serves(grid(2, 100.0, 0.0, 0.0), 2.5));
}

// The build's column splits (build_splits: each row tile's columns cut into 2, 4 or 8 ranges, one
// warp each, the fill placing each range after the ones before it) give the list of one split, entry
// for entry: the same listed pairs and bitwise the same forces, energies and virial (summed in list
// order) on every scene of the sequence, after moves and rebuilds, staged (fast) and lean.
TEST(PairListSplits, SplitWalksListWhatOneWalkLists) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene a = make_scene("multitype3d_lb"), b = make_scene("random3d_periodic");
  const Configuration am = moved(a.config, 0.14, 5);
  const std::pair<const Configuration*, const Scene*> sequence[] = {
      {&a.config, &a}, {&am, &a}, {&b.config, &b}, {&a.config, &a}};
  for (const bool lean : {false, true})
    for (const int splits : {2, 4, 8}) {
      SCOPED_TRACE(std::to_string(splits) + " splits" + (lean ? ", lean" : ""));
      GpuOptions one = list_options(Precision::kMixed), many = list_options(Precision::kMixed);
      one.test.list_splits = 1;
      many.test.list_splits = splits;
      one.memory = many.memory = lean ? ListMemory::kLean : ListMemory::kFast;
      GpuEngine x(one), y(many);
      for (const auto& [c, scene] : sequence) expect_same_lists(x, y, *c, *scene);
    }
}

// The fill from the count pass's masks (BuildMasks, fast memory mode: every build after the first,
// once the room its count pass asks for is there) lists what a fill that tests every pair again
// lists: the same pairs and bitwise the same results on every scene of the sequence (the rebuild
// for the denser, larger u finds the room a and b asked for too small for its later units, which
// walk again), with one and with 4 splits, in every precision; and the masks were read (the test
// would pass without them otherwise).
// Two engines in fast memory mode with `splits` column splits: x's fills read the masks, y's test
// every pair again.
std::pair<GpuOptions, GpuOptions> masked_and_walked(Precision p, int splits) {
  GpuOptions masked = list_options(p), walked = list_options(p);
  masked.memory = walked.memory = ListMemory::kFast;
  masked.test.list_splits = walked.test.list_splits = splits;
  walked.test.list_masks = false;
  return {masked, walked};
}

TEST(PairListMasks, FillFromMasksIsTheWalkedFill) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene a = make_scene("multitype3d_lb"), b = make_scene("random3d_periodic"),
              u = make_scene("random3d_uniform");
  const Configuration am = moved(a.config, 0.14, 5), bm = moved(b.config, 0.14, 7);
  const std::pair<const Configuration*, const Scene*> sequence[] = {
      {&a.config, &a}, {&am, &a}, {&b.config, &b}, {&bm, &b}, {&u.config, &u}, {&a.config, &a}, {&b.config, &b}};
  for (Precision p : {Precision::kSingle, Precision::kMixed, Precision::kDouble})
    for (const int splits : {1, 4}) {
      SCOPED_TRACE(cellforce::to_string(p) + std::string(", ") + std::to_string(splits) + " splits");
      const auto [masked, walked] = masked_and_walked(p, splits);
      GpuEngine x(masked), y(walked);
      for (const auto& [c, scene] : sequence) expect_same_lists(x, y, *c, *scene);
      EXPECT_GE(x.list_masked_fills(), 2u);  // the rebuilds of a, at least
      EXPECT_EQ(y.list_masked_fills(), 0u);
    }
}

// Lean memory keeps the count pass's masks in the room the device has left. Three lean engines on
// one sequence: `full` has room for every mask, `part` a room capped below each scene's demand
// (list_mask_words, as a nearly full device leaves: 2,048 and 8,192 words; 32,768 held a's and b's
// whole, H100), `none` no room (its fills test every pair again). The lists and results are bitwise
// the same; the capped room's rebuilds wrote some units from masks, fewer than the full room's at
// the same rebuild (list_masked_units, counted on the device). A lean engine gives the room up when
// the system changes size and asks for it again at the end of a build that kept masks
// (cuda/backend/memory_plan.cpp), so it reads masks from the second build of a system on (from the
// third of its first system, whose first build has no list array to lend the sort and keeps none);
// so each scene is rebuilt at its own size (moves past skin / 2) as well as reused (a move below
// it): `full` reads masks at the third build of a, at bf, uf and the last af.
TEST(PairListMasks, LeanFillFromMasksIsTheWalkedFill) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene a = make_scene("multitype3d_lb"), b = make_scene("random3d_periodic"),
              u = make_scene("random3d_uniform");
  const Configuration am = moved(a.config, 0.14, 5), af = moved(a.config, 0.2, 6), bf = moved(b.config, 0.2, 7),
                      uf = moved(u.config, 0.2, 8);
  const std::pair<const Configuration*, const Scene*> sequence[] = {
      {&a.config, &a}, {&am, &a}, {&af, &a}, {&a.config, &a}, {&b.config, &b}, {&bf, &b},
      {&u.config, &u}, {&uf, &u}, {&a.config, &a}, {&af, &a}};
  for (Precision p : {Precision::kSingle, Precision::kMixed, Precision::kDouble})
    for (const int splits : {1, 4})
      for (const std::size_t room : {std::size_t(2048), std::size_t(8192)}) {
        SCOPED_TRACE(cellforce::to_string(p) + std::string(", ") + std::to_string(splits) + " splits, room " +
                     std::to_string(room));
        auto [masked, walked] = masked_and_walked(p, splits);
        masked.memory = walked.memory = ListMemory::kLean;
        masked.test.list_count_masked = true;
        GpuOptions capped = masked;
        capped.test.list_mask_words = room;
        GpuEngine full(masked), part(capped), none(walked);
        std::size_t part_reads = 0;
        for (const auto& [c, scene] : sequence) {
          ForceResult rf, rp, rn;
          full.evaluate(c->view(), scene->ff, Request{true, true}, rf);
          part.evaluate(c->view(), scene->ff, Request{true, true}, rp);
          none.evaluate(c->view(), scene->ff, Request{true, true}, rn);
          EXPECT_GT(none.listed_pairs(), 0u);
          EXPECT_EQ(full.listed_pairs(), none.listed_pairs());
          EXPECT_EQ(part.listed_pairs(), none.listed_pairs());
          EXPECT_TRUE(bitwise_equal(rf, rn));
          EXPECT_TRUE(bitwise_equal(rp, rn));
          EXPECT_EQ(none.stats().list_mask_words_held, 0u);
          if (!none.stats().rebuilt || part.list_masked_units() == 0) continue;
          ++part_reads;  // this rebuild's fill wrote some units from the capped room, fewer than from a full one
          EXPECT_LT(part.list_masked_units(), full.list_masked_units());
          // What the stats say of it: every word held in full, part of them within the cap.
          EXPECT_GT(full.stats().list_mask_words, 0u);
          EXPECT_EQ(full.stats().list_mask_words_held, full.stats().list_mask_words);
          EXPECT_EQ(part.stats().list_mask_words, full.stats().list_mask_words);
          EXPECT_GT(part.stats().list_mask_words_held, 0u);
          EXPECT_LE(part.stats().list_mask_words_held, room);
          EXPECT_LT(part.stats().list_mask_words_held, part.stats().list_mask_words);
        }
        EXPECT_GE(full.list_masked_fills(), 4u);
        EXPECT_EQ(part.list_masked_fills(), 0u);
        EXPECT_GE(part.list_partly_masked_fills(), 2u);
        EXPECT_GE(part_reads, 2u);
        EXPECT_EQ(none.list_masked_fills() + none.list_partly_masked_fills() + none.list_masked_units(), 0u);
      }
}

// The same for a dense cluster: 200 particles in a cube of edge 2 in one cell, nearly every pair
// within rc + skin (2.8; the cube's diagonal is 3.5), so a row tile keeps ~32 x 100 entries in a
// batch of 4 column tiles, more than the fill's queue holds (1,024): the fill from masks takes
// those batches a tile at a time. A build, and two rebuilds (moves past skin / 2) that
// read the masks.
TEST(PairListMasks, FillFromMasksIsTheWalkedFillInADenseCluster) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene s = make_scene("clustered3d_one_cell");
  ASSERT_TRUE(lists_fit(s, kSkin));
  const Configuration far = moved(s.config, 0.2, 17);
  for (Precision p : {Precision::kSingle, Precision::kMixed, Precision::kDouble})
    for (const int splits : {1, 4}) {
      SCOPED_TRACE(cellforce::to_string(p) + std::string(", ") + std::to_string(splits) + " splits");
      const auto [masked, walked] = masked_and_walked(p, splits);
      GpuEngine x(masked), y(walked);
      for (const Configuration* c : {&s.config, &far, &s.config}) expect_same_lists(x, y, *c, s);
      EXPECT_GE(x.list_masked_fills(), 1u);
      EXPECT_GT(x.listed_pairs(), 200u * 199u * 3u / 4u);  // the cluster's pairs, counted from both sides
    }
}

// The same in two dimensions (4 cell types): a build, a reused step, and a rebuild that reads the
// masks.
TEST(PairListMasks, FillFromMasksIsTheWalkedFillIn2D) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene s = make_scene("random2d_periodic");
  const Configuration m = moved(s.config, 0.14, 9), far = moved(s.config, 0.2, 13);
  for (Precision p : {Precision::kSingle, Precision::kMixed, Precision::kDouble})
    for (const int splits : {1, 2}) {
      SCOPED_TRACE(cellforce::to_string(p) + std::string(", ") + std::to_string(splits) + " splits");
      const auto [masked, walked] = masked_and_walked(p, splits);
      GpuEngine x(masked), y(walked);
      for (const Configuration* c : {&s.config, &m, &far, &s.config}) expect_same_lists(x, y, *c, s);
      EXPECT_GE(x.list_masked_fills(), 1u);
    }
}

// The force kernel's threads per particle (1 from ~135,000 particles on an H100, which reads its
// list a 16-byte chunk at a time; 2, 4 or 8 below, entry by entry): each against the double
// brute force at the build and at a reused step, as the PairList scenes are checked.
TEST(PairListThreads, EveryThreadCountMatchesTheBruteForce) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene s = make_scene("multitype3d_lb");
  const Configuration m = moved(s.config, 0.1499, 11);
  const Request all{true, true};
  for (Precision p : {Precision::kSingle, Precision::kMixed, Precision::kDouble})
    for (const int threads : {1, 2, 4, 8}) {
      SCOPED_TRACE(cellforce::to_string(p) + std::string(", ") + std::to_string(threads) + " threads");
      GpuOptions o = list_options(p);
      o.test.list_threads = threads;
      GpuEngine e(o);
      for (const Configuration* c : {&s.config, &m}) {
        ForceResult got, ref;
        e.evaluate(c->view(), s.ff, all, got);
        cellforce::brute_force(c->view(), s.ff, all, ref);
        ASSERT_GT(e.listed_pairs(), 0u);
        expect_results_match(ref, got, p);
      }
    }
}

// An engine whose options `set` gives each of `values` is refused when it is made, naming `option`
// and the value (before the device is looked for: no GPU needed).
template <class Set>
void expect_refused(const char* option, std::initializer_list<int> values, Set&& set) {
  for (const int value : values) {
    GpuOptions o = list_options(Precision::kMixed);
    set(o, value);
    try {
      GpuEngine e(o);
      FAIL() << option << " = " << value << " was accepted";
    } catch (const cellforce::Error& err) {
      const std::string text = err.what();
      EXPECT_NE(text.find(option), std::string::npos) << text;
      EXPECT_TRUE(contains_number(text, std::size_t(value))) << text;
    }
  }
}

// A thread count the force kernel has no form for is refused.
TEST(PairListThreads, AThreadCountWithNoKernelIsRefused) {
  expect_refused("list_threads", {0, 3, 16}, [](GpuOptions& o, int v) { o.test.list_threads = v; });
}

// A block size the force kernel that runs the next step's kick-drift has no form for is refused.
TEST(PairListThreads, ABlockSizeWithNoKernelIsRefused) {
  expect_refused("list_block", {0, 64, 192, 512}, [](GpuOptions& o, int v) { o.test.list_block = v; });
}

// The audit of a structure the lists serve audits the lists: with the check off, after moves below
// and well beyond skin / 2, the missed pairs are those within rc now that were not within rc + skin
// at the build (counted here pair by pair), and none repeat.
TEST(PairListAudit, CountsThePairsTheListsLack) {
  CF_SKIP_WITHOUT_DEVICE();
  std::size_t total_missed = 0;
  for (const char* name : {"random3d_periodic", "random2d_periodic", "uneven3d"}) {
    const Scene s = make_scene(name);
    if (!lists_fit(s, kSkin)) continue;
    for (const double factor : {0.45, 4.0}) {
      SCOPED_TRACE(std::string(name) + " moved " + std::to_string(factor) + " x skin/2");
      GpuOptions o = list_options(Precision::kDouble);
      o.reuse.check = false;
      o.reuse.audit = true;
      GpuEngine e(o);
      ForceResult r;
      e.evaluate(s.config.view(), s.ff, Request{false, false}, r);
      const Configuration now = moved(s.config, factor * 0.5 * kSkin, 13);
      e.evaluate(now.view(), s.ff, Request{false, false}, r);
      ASSERT_FALSE(e.stats().rebuilt);
      ASSERT_TRUE(e.stats().listed);
      std::size_t expected = 0;
      const double cut = s.ff.cutoff + kSkin;
      for (const auto& [i, j] : cellforce::pairs_within(now.view(), s.ff.cutoff))
        if (!(distance2(s.config, i, j) < cut * cut)) ++expected;
      EXPECT_EQ(e.stats().missed_pairs, expected);
      EXPECT_EQ(e.stats().repeated_pairs, 0u);
      total_missed += expected;
    }
  }
  EXPECT_GT(total_missed, 0u) << "no move left a pair out: the count is not exercised";
}

// A restored structure (a bitwise restart: rebuilt from the positions it was built from) lists the
// pairs of those positions, not of the positions it is next evaluated at: the same results, bit for
// bit, as the engine that built it, on every evaluation it serves.
TEST(PairListRestore, RestoredStructureServesAsTheOriginal) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene s = make_scene("random3d_periodic");
  const Configuration x1 = moved(s.config, 0.07, 21), x2 = moved(s.config, 0.14, 22);
  for (Precision p : {Precision::kMixed, Precision::kDouble}) {
    GpuEngine original(list_options(p)), restored(list_options(p));
    ForceResult a, b;
    original.evaluate(s.config.view(), s.ff, Request{true, true}, a);
    restored.restore_reuse(s.config.view(), s.ff, 1);
    for (const Configuration* c : {&x1, &x2}) {
      original.evaluate(c->view(), s.ff, Request{true, true}, a);
      restored.evaluate(c->view(), s.ff, Request{true, true}, b);
      EXPECT_FALSE(restored.stats().rebuilt);
      EXPECT_GT(restored.listed_pairs(), 0u);
      EXPECT_TRUE(bitwise_equal(a, b)) << cellforce::to_string(p);
    }
  }
}

// An empty system after a listed one: energy and virial zero, nothing stale.
TEST(PairListEmpty, EmptySystemAfterAListedOneIsZero) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene s = make_scene("random3d_periodic");
  Configuration empty = s.config;
  empty.positions.clear();
  empty.types.clear();
  GpuEngine e(list_options(Precision::kMixed));
  ForceResult r;
  e.evaluate(s.config.view(), s.ff, Request{true, true}, r);
  ASSERT_NE(r.energy, 0.0);
  for (const Configuration* c : {&empty, &empty}) {
    e.evaluate(c->view(), s.ff, Request{true, true}, r);
    EXPECT_EQ(r.energy, 0.0);
    EXPECT_TRUE(r.forces.empty());
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) EXPECT_EQ(r.virial[a][b], 0.0);
  }
}

// A pair that becomes coincident on a reused step is named (both particles), as the cells name it.
TEST(PairListErrors, CoincidentPairOnAReusedStepIsNamed) {
  CF_SKIP_WITHOUT_DEVICE();
  Scene s = make_scene("random3d_periodic");
  const std::size_t i = 3, j = 7;
  // j 0.25 from i along x: built with that, then moved onto i (0.25 < skin / 2 = 0.3).
  for (int a = 0; a < 3; ++a) s.config.positions[j * 3 + a] = s.config.positions[i * 3 + a];
  s.config.positions[j * 3] += 0.25;
  GpuEngine e(list_options(Precision::kMixed, 0.6));
  ForceResult r;
  try {
    e.evaluate(s.config.view(), s.ff, Request{true, true}, r);
  } catch (const cellforce::Error&) {
    // 0.25 sigma may already overflow float: then the build names the pair, which is fine too.
  }
  Configuration m = s.config;
  m.positions[j * 3] -= 0.25;
  try {
    e.evaluate(m.view(), s.ff, Request{true, true}, r);
    FAIL() << "a coincident pair gave no error";
  } catch (const cellforce::Error& err) {
    const std::string text = err.what();
    EXPECT_TRUE(contains_number(text, i) && contains_number(text, j)) << text;
  }
}

// A gated MD run (many steps in one call: the step gate, its drifts placing the positions in rank
// order and its evaluations leaving the forces in rank order; the chunk on a rank-order copy of the
// state, Verlet's next kick-drift in the force kernel) ends bitwise where the step-by-step run ends
// (one step a call: never gated), and so does the gated run of a lean engine, whose gated
// evaluations store the forces in the caller's order instead; Verlet and Langevin, 2,048 particles
// of the in.lj fluid, 300 steps with ~20 rebuilds; in mixed precision (fixed-point gathers) with 8
// threads a particle (the rule's choice at this size) and 1 (the large systems' force kernel), and
// in double precision (double gathers) with 2; all masses 1 (passed as one number), and in mixed
// precision also with masses that differ, in 2D and with two types. The 2D form:
// systems/lj_2d.toml's liquid (1,152 particles); the two-type form: the Kob-Andersen mixture of
// systems/kob_andersen.toml (2,048 particles, 80:20). The fused force kernel in blocks of 256 (the
// rule gives 128 at these sizes) is forced in mixed precision with 1 thread a particle, in single
// with 2 and varied masses, in 2D (its last block part full) and in double; the runs report the
// blocks they ran (MdCounters::list_block: 0 where none ran the kick-drift).
constexpr const char* kGated2d = R"(
[system]
dimension = 2
periodic = [true, true]
[particles]
source = "lattice"
lattice = "hexagonal"
cells = [32, 18]
density = 0.7
[[types]]
name = "A"
[interactions]
cutoff = 2.5
mode = "truncate"
)";
constexpr const char* kGatedTwoTypes = R"(
[system]
dimension = 3
[particles]
source = "lattice"
lattice = "fcc"
cells = [8, 8, 8]
density = 1.2
composition = { A = 0.8, B = 0.2 }
[[types]]
name = "A"
sigma = 1.0
epsilon = 1.0
[[types]]
name = "B"
sigma = 0.88
epsilon = 0.5
[interactions]
cutoff = 2.5
mode = "shift"
[[interactions.pairs]]
types = ["A", "B"]
sigma = 0.8
epsilon = 1.5
)";

// The in.lj fluid at 2,048 particles (8 x 8 x 8 fcc cells, edge 13.4 > 2 (rc + 0.3)).
cellforce::Scene small_fluid() {
  cellforce::Scene fluid = cellforce::default_scene();
  fluid.particles.cells = {8, 8, 8};
  return fluid;
}

// A start of `scene`'s configuration with unit masses and velocities at T 1.44 (seed 7, no drift).
cellforce::MdState unit_mass_start(const cellforce::Scene& scene, std::vector<double>& masses) {
  cellforce::MdState start;
  start.config = cellforce::build_configuration(scene);
  masses.assign(start.config.size(), 1.0);
  cellforce::initialize_velocities(start, masses, 1.44, 7, true);
  return start;
}

// The MD tests' integrator: Verlet, or Langevin at kT 1.44 with seed 99 (friction the default).
cellforce::IntegratorSettings md_settings(bool langevin) {
  cellforce::IntegratorSettings settings;
  settings.langevin = langevin;
  settings.kT = 1.44;
  settings.seed = 99;
  return settings;
}

// A CUDA engine with pair lists at skin 0.3 (not the automatic choice), fast or lean memory.
cellforce::EngineChoice list_choice(Precision p, ListMemory memory) {
  cellforce::EngineChoice choice;
  choice.backend = cellforce::Backend::kCuda;
  choice.precision = p;
  choice.reuse.automatic = false;
  choice.reuse.skin = 0.3;
  choice.reuse.list = true;
  choice.memory = memory;
  return choice;
}

// An MD engine's positions, velocities and forces, one after the other: what two runs compare bitwise.
std::vector<double> end_state(cellforce::MdEngine& md) {
  cellforce::MdState end;
  md.get_state(end);
  std::vector<double> all = end.config.positions;
  all.insert(all.end(), end.velocities.begin(), end.velocities.end());
  all.insert(all.end(), end.forces.begin(), end.forces.end());
  return all;
}

TEST(PairListMd, GatedRunsEqualTheStepwiseRunLeanOrNot) {
  CF_SKIP_WITHOUT_DEVICE();
  const cellforce::Scene fluid = small_fluid();
  struct Form {
    Precision precision;
    std::optional<int> threads;
    const char* name;
    bool varied_masses = false;    // 1, 1.5 and 2 in turn (one mass for all: a number)
    const char* scene = nullptr;  // a scene file's text instead of the in.lj fluid
    std::optional<int> block = std::nullopt;  // the fused force kernel's threads a block instead of the rule
  };
  for (const Form form : {Form{Precision::kMixed, std::nullopt, "mixed, the rule's threads"},
                          Form{Precision::kMixed, 1, "mixed, 1 thread a particle"},
                          Form{Precision::kDouble, 2, "double, 2 threads a particle"},
                          Form{Precision::kMixed, std::nullopt, "mixed, masses 1, 1.5 and 2", true},
                          Form{Precision::kMixed, std::nullopt, "mixed, 2D", false, kGated2d},
                          Form{Precision::kMixed, std::nullopt, "mixed, two types", false, kGatedTwoTypes},
                          Form{Precision::kMixed, 1, "mixed, 1 thread a particle, blocks of 256", false, nullptr, 256},
                          Form{Precision::kSingle, 2, "single, 2 threads a particle, blocks of 256", true, nullptr, 256},
                          Form{Precision::kMixed, 1, "mixed, 2D, blocks of 256 (the last one part full)", false, kGated2d, 256},
                          Form{Precision::kDouble, 1, "double, 1 thread a particle, blocks of 256", false, nullptr, 256}}) {
    SCOPED_TRACE(form.name);
    const cellforce::Scene scene = form.scene ? cellforce::parse_scene(form.scene, form.name) : fluid;
    cellforce::MdState start;
    start.config = cellforce::build_configuration(scene);
    const std::size_t n = start.config.size();
    std::vector<double> masses(n, 1.0);
    if (form.varied_masses)
      for (std::size_t i = 0; i < n; ++i) masses[i] = 1.0 + 0.5 * double(i % 3);
    cellforce::initialize_velocities(start, masses, 1.44, 7, true);
    for (const bool langevin : {false, true}) {
      SCOPED_TRACE(langevin ? "Langevin" : "Verlet");
      const cellforce::IntegratorSettings settings = md_settings(langevin);
      auto run = [&](bool lean, bool one_call, cellforce::MdCounters* counters) {
        cellforce::EngineChoice choice = list_choice(form.precision, lean ? ListMemory::kLean : ListMemory::kFast);
        choice.test.list_threads = form.threads;
        choice.test.list_block = form.block;
        auto md = cellforce::make_cuda_md_engine(choice);
        md->set_state(start, masses, scene.force_field);
        if (one_call) {
          md->advance(300, settings, false);
        } else {
          for (int k = 0; k < 300; ++k) md->advance(1, settings, false);
        }
        *counters = md->counters();
        return end_state(*md);
      };
      cellforce::MdCounters fast, lean, stepwise;
      const std::vector<double> a = run(false, true, &fast), b = run(true, true, &lean),
                                c = run(false, false, &stepwise);
      EXPECT_TRUE(a == c) << "the gated run differs from the step-by-step run";
      EXPECT_TRUE(b == c) << "the lean gated run differs from the step-by-step run";
      EXPECT_EQ(fast.builds, stepwise.builds);
      EXPECT_EQ(lean.builds, stepwise.builds);
      EXPECT_GE(stepwise.builds, 5) << "too few rebuilds to exercise the gate's closing";
      EXPECT_EQ(stepwise.gated_steps, 0);
      EXPECT_GT(fast.gated_steps, 200) << "the gate served few steps";
      EXPECT_GT(lean.gated_steps, 200);
      // The fused force kernel's blocks: the form's, or the rule's 128 at this size;
      // none where no kernel runs the next step's kick-drift (Langevin, lean memory, step by step).
      EXPECT_EQ(fast.list_block, langevin ? 0 : form.block.value_or(128));
      EXPECT_EQ(lean.list_block, 0);
      EXPECT_EQ(stepwise.list_block, 0);
    }
  }
}

// The gate's notice (cuda/integrate/gate_readback.cuh): the first kernel of a gated chunk that finds
// the gate shut posts the closed step and the gate's values into mapped host memory, and the host
// queues the rebuild as soon as it sees them, before the chunk's end. Runs of the in.lj fluid
// (mixed precision; fast and lean memory, Verlet and Langevin) whose host reads the notice first
// (the default), the copy alone (gate_notice = false) or both (gate_notice_check: the notice must be
// there exactly where the copy says the gate closed, with its values, else the run throws; the first
// post is the only one, so it is the one checked) give bitwise the same state and count the same
// closings; the default reads most of them early.
TEST(PairListMd, GateNoticeIsTheGatesOwnCopy) {
  CF_SKIP_WITHOUT_DEVICE();
  const cellforce::Scene fluid = small_fluid();
  std::vector<double> masses;
  const cellforce::MdState start = unit_mass_start(fluid, masses);
  int64_t closings = 0, early = 0;
  for (const ListMemory memory : {ListMemory::kFast, ListMemory::kLean}) {
    for (const bool langevin : {false, true}) {
      SCOPED_TRACE(std::string(memory == ListMemory::kLean ? "lean, " : "fast, ") + (langevin ? "Langevin" : "Verlet"));
      auto run = [&](std::optional<bool> notice, std::optional<bool> check, cellforce::MdCounters* counters) {
        cellforce::EngineChoice choice = list_choice(Precision::kMixed, memory);
        choice.test.gate_notice = notice;
        choice.test.gate_notice_check = check;
        auto md = cellforce::make_cuda_md_engine(choice);
        md->set_state(start, masses, fluid.force_field);
        md->advance(300, md_settings(langevin), false);
        *counters = md->counters();
        return end_state(*md);
      };
      cellforce::MdCounters first, copy, checked;
      const std::vector<double> a = run(std::nullopt, std::nullopt, &first), b = run(false, std::nullopt, &copy),
                                c = run(std::nullopt, true, &checked);
      EXPECT_TRUE(a == b) << "reading the notice first changed the run";
      EXPECT_TRUE(c == b) << "the checked run differs";
      EXPECT_GE(checked.gate_closings, 5) << "too few closings to check the notice";
      EXPECT_LE(checked.gate_closings, checked.builds);
      EXPECT_EQ(first.gate_closings, checked.gate_closings);
      EXPECT_EQ(copy.gate_closings, checked.gate_closings);
      EXPECT_EQ(first.builds, copy.builds);
      closings += first.gate_closings;
      early += first.gate_closings_early;
      std::printf("gate notice, %s memory, %s: %lld of %lld closings read early\n",
                  memory == ListMemory::kLean ? "lean" : "fast", langevin ? "Langevin" : "Verlet",
                  (long long)first.gate_closings_early, (long long)first.gate_closings);
    }
  }
  // Whether the host sees a notice before the chunk's end is a matter of timing (the chunk's tail
  // after the closing: its shut steps, the write-back, the copy). Fewer than a quarter means the
  // notices come late or not at all.
  EXPECT_GT(early, closings / 4) << "the host read few closings from the notice";
}

// The build's fixed part replayed as a CUDA graph (cuda/backend/build_graph.cuh) is the part
// queued operation by operation: two engines, x with graphs and y without, on a sequence of
// rebuilds (every other configuration moved by up to 0.2 > skin / 2) of one system, the same
// particles in a box 5% larger, the same with a 5% shorter cutoff (the same n, another grid: the
// key must change), a system of another size, and the first again, list the same pairs and give
// bitwise the same results, in every precision, with the rule's column splits and with one (the
// count pass's units partitioned: the path of systems above ~67,000 particles). x captured a graph
// for each system and replayed it at the later builds of that system, whose stage times its events
// still measure, and never at the first build of another; its audit (build_graph_audit) finds
// nothing of the part queued again by a replayed build.
TEST(PairListGraph, ReplayedBuildsAreTheQueuedOnes) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene a = make_scene("multitype3d_lb"), b = make_scene("random3d_periodic");
  ASSERT_NE(a.config.size(), b.config.size());
  Scene wide = a, short_cut = a;
  for (double& x : wide.config.positions) x *= 1.05;
  for (int k = 0; k < wide.config.box.dim; ++k) wide.config.box.length[k] *= 1.05;
  short_cut.ff.cutoff *= 0.95;
  const Configuration am = moved(a.config, 0.2, 6), am2 = moved(a.config, 0.2, 9), bm = moved(b.config, 0.2, 7),
                      wm = moved(wide.config, 0.2, 8), sm = moved(short_cut.config, 0.2, 10);
  struct Build {
    const Configuration* config;
    const Scene* scene;
    bool new_key;  // the first build of another system, grid or cutoff: no graph may serve it
  };
  const Build sequence[] = {
      {&a.config, &a, true},  {&am, &a, false},  {&a.config, &a, false}, {&am2, &a, false}, {&a.config, &a, false},
      {&am, &a, false},
      {&wide.config, &wide, true}, {&wm, &wide, false}, {&wide.config, &wide, false}, {&wm, &wide, false},
      {&short_cut.config, &short_cut, true}, {&sm, &short_cut, false}, {&short_cut.config, &short_cut, false},
      {&sm, &short_cut, false},
      {&b.config, &b, true}, {&bm, &b, false}, {&b.config, &b, false}, {&bm, &b, false}, {&b.config, &b, false},
      {&a.config, &a, true}, {&am, &a, false}, {&a.config, &a, false}, {&am2, &a, false}};
  for (Precision p : {Precision::kSingle, Precision::kMixed, Precision::kDouble})
    for (const std::optional<int> splits : {std::optional<int>{}, std::optional<int>{1}}) {
      SCOPED_TRACE(cellforce::to_string(p) + std::string(splits ? ", one split" : ", the rule's splits"));
      GpuOptions graphed = list_options(p), queued = list_options(p);
      graphed.memory = queued.memory = ListMemory::kFast;
      graphed.test.list_splits = queued.test.list_splits = splits;
      graphed.test.build_graph_audit = true;
      queued.test.build_graph = false;
      GpuEngine x(graphed), y(queued);
      std::size_t replayed = 0;
      for (const Build& build : sequence) {
        const std::size_t before = x.build_replays();
        expect_same_lists(x, y, *build.config, *build.scene);
        EXPECT_TRUE(x.stats().rebuilt);
        if (x.build_replays() == before) continue;
        EXPECT_FALSE(build.new_key) << "a graph served the first build of another system";
        ++replayed;
        const cellforce::PipelineStats& st = x.stats();  // the graph's event nodes time the stages
        EXPECT_GT(st.t_cell_ids, 0.0);
        EXPECT_GT(st.t_count, 0.0);
        EXPECT_GT(st.t_sort, 0.0);
        EXPECT_GT(st.t_collision_cells, 0.0);
      }
      EXPECT_GE(x.build_captures(), 5u);  // a, wide, short_cut, b, a again
      EXPECT_GE(replayed, 8u);
      EXPECT_EQ(y.build_captures() + y.build_replays(), 0u);
    }
}

// The same through a resident MD run (the gated chunks' builds, evaluate_resident): 300 steps of
// the in.lj fluid (2,048 particles), Verlet and Langevin, with and without graphs: bitwise the same
// positions, velocities and forces, and the graphed run replayed most of its builds (audited: none
// queued anything of its graph's part again).
TEST(PairListGraph, ReplayedRunIsTheQueuedRun) {
  CF_SKIP_WITHOUT_DEVICE();
  const cellforce::Scene scene = small_fluid();
  std::vector<double> masses;
  const cellforce::MdState start = unit_mass_start(scene, masses);
  for (const bool langevin : {false, true}) {
    SCOPED_TRACE(langevin ? "Langevin" : "Verlet");
    const cellforce::IntegratorSettings settings = md_settings(langevin);
    auto run = [&](bool graph, std::size_t* replays, int64_t* builds) {
      cellforce::EngineChoice choice = list_choice(Precision::kMixed, ListMemory::kFast);
      choice.test.build_graph = graph;
      choice.test.build_graph_audit = graph;  // a replayed build queues nothing of its graph's part
      auto md = cellforce::make_cuda_md_engine(choice);
      const GpuEngine& gpu = dynamic_cast<cellforce::CudaForceEngine&>(md->forces()).engine();
      md->set_state(start, masses, scene.force_field);
      md->advance(300, settings, false);
      *replays = gpu.build_replays();
      *builds = md->counters().builds;
      EXPECT_EQ(md->counters().graph_builds, int64_t(*replays));  // MdCounters counts them too
      return end_state(*md);
    };
    std::size_t with = 0, without = 0;
    int64_t builds_with = 0, builds_without = 0;
    const std::vector<double> g = run(true, &with, &builds_with), q = run(false, &without, &builds_without);
    EXPECT_TRUE(g == q) << "the run with graphs differs from the run without";
    EXPECT_EQ(builds_with, builds_without);
    EXPECT_GE(builds_with, 8) << "too few rebuilds to replay a graph";
    EXPECT_GE(int64_t(with), builds_with - 4) << "builds after the first few should replay the graph";
    EXPECT_EQ(without, 0u);
  }
}

// A resident evaluation with time_stages false records no stage event, so its build's
// graph holds none; its graph key is not a timed build's, so a timed build never replays it (a
// replay of an eventless graph would leave the stage events of an earlier evaluation: stage times
// out of order). One periodic system rebuilt at every evaluation (positions moved by up to 0.2 >
// skin / 2 and back): the untimed builds capture and replay a graph, the timed builds between them
// replay none and time every stage (each positive, their sum at most the total), an untimed build
// after a timed one leaves its stage times as they were (it recorded no event, in the graph or
// not), and every evaluation's forces are bitwise those of an engine without graphs.
TEST(PairListGraph, UntimedBuildsLeaveTheirEventsOut) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene s = make_scene("random3d_periodic");
  ASSERT_TRUE(lists_fit(s, kSkin));
  const cellforce::Box& box = s.config.box;
  const std::size_t n = s.config.size(), nd = n * std::size_t(box.dim);
  auto wrapped = [&](const Configuration& c) {
    std::vector<double> x = c.positions;
    for (std::size_t i = 0; i < n; ++i)
      for (int a = 0; a < box.dim; ++a) x[i * box.dim + a] = cellforce::wrap_coordinate(x[i * box.dim + a], box.length[a]);
    return x;
  };
  const std::vector<double> at[2] = {wrapped(s.config), wrapped(moved(s.config, 0.2, 12))};
  // One positions array, as an MD run has (its address is in the graph's key): each configuration
  // is copied in while both engines are idle (check_flags synchronises their streams).
  struct DeviceArrays {
    double* pos = nullptr;
    uint32_t* types = nullptr;
    ~DeviceArrays() {
      cudaFree(pos);
      cudaFree(types);
    }
  } d;
  ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d.pos), nd * sizeof(double)), cudaSuccess);
  const std::vector<uint32_t>& types = s.config.types;
  ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d.types), std::max<std::size_t>(n, 1) * sizeof(uint32_t)), cudaSuccess);
  if (!types.empty()) {
    ASSERT_EQ(cudaMemcpy(d.types, types.data(), n * sizeof(uint32_t), cudaMemcpyHostToDevice), cudaSuccess);
  }
  const uint32_t* t = types.empty() ? nullptr : d.types;
  GpuOptions graphed = list_options(Precision::kMixed), queued = list_options(Precision::kMixed);
  graphed.memory = queued.memory = ListMemory::kFast;
  graphed.test.build_graph_audit = true;
  queued.test.build_graph = false;
  GpuEngine x(graphed), y(queued);
  auto stage_times = [](const cellforce::PipelineStats& st) {
    return std::vector<double>{st.t_transfer, st.t_check, st.t_cell_ids, st.t_count, st.t_sort,
                               st.t_collision_cells, st.t_traversal, st.t_accumulate, st.t_total};
  };
  // Untimed builds 0-4 (a graph captured once the buffers have settled, replayed after), timed 5,
  // untimed 6-7, timed 8 (the evaluations alternate between the two configurations: every one rebuilds).
  const bool timed[] = {false, false, false, false, false, true, false, false, true};
  std::size_t untimed_replays = 0;
  std::vector<double> last_timed[2];  // x's and y's stage times at the last timed evaluation
  for (std::size_t e = 0; e < std::size(timed); ++e) {
    SCOPED_TRACE("evaluation " + std::to_string(e) + (timed[e] ? ", timed" : ", untimed"));
    ASSERT_EQ(cudaMemcpy(d.pos, at[e % 2].data(), nd * sizeof(double), cudaMemcpyHostToDevice), cudaSuccess);
    const std::size_t before = x.build_replays();
    x.evaluate_resident(box, n, d.pos, t, s.ff, Request{false, false}, std::nullopt, timed[e]);
    y.evaluate_resident(box, n, d.pos, t, s.ff, Request{false, false}, std::nullopt, timed[e]);
    x.check_flags(box, n, d.pos, s.ff);
    y.check_flags(box, n, d.pos, s.ff);
    std::vector<double> fx(nd), fy(nd);
    ASSERT_EQ(cudaMemcpy(fx.data(), x.device_forces(), nd * sizeof(double), cudaMemcpyDeviceToHost), cudaSuccess);
    ASSERT_EQ(cudaMemcpy(fy.data(), y.device_forces(), nd * sizeof(double), cudaMemcpyDeviceToHost), cudaSuccess);
    EXPECT_TRUE(x.stats().rebuilt);
    EXPECT_TRUE(fx == fy) << "the graphed engine's forces differ";
    GpuEngine* engines[2] = {&x, &y};
    if (!timed[e]) {
      untimed_replays += x.build_replays() - before;
      for (int k = 0; k < 2; ++k) {
        engines[k]->collect_timing();
        if (last_timed[k].empty()) {  // no evaluation was timed yet: no stage time
          EXPECT_EQ(engines[k]->stats().t_total, 0.0);
        } else {
          EXPECT_TRUE(stage_times(engines[k]->stats()) == last_timed[k]) << "an untimed evaluation recorded stage events";
        }
      }
      continue;
    }
    EXPECT_EQ(x.build_replays(), before) << "a timed build replayed an untimed build's graph";
    for (int k = 0; k < 2; ++k) {
      engines[k]->collect_timing();
      const cellforce::PipelineStats& st = engines[k]->stats();
      EXPECT_GT(st.t_cell_ids, 0.0);
      EXPECT_GE(st.t_count, 0.0);  // counted with the cell IDs: two events back to back
      EXPECT_GT(st.t_sort, 0.0);
      EXPECT_GT(st.t_collision_cells, 0.0);
      EXPECT_GT(st.t_traversal, 0.0);
      EXPECT_LE(st.t_cell_ids + st.t_count + st.t_sort + st.t_collision_cells + st.t_traversal, st.t_total);
      last_timed[k] = stage_times(st);
    }
  }
  EXPECT_GE(untimed_replays, 3u) << "the untimed builds should replay their graph";
  EXPECT_EQ(y.build_captures() + y.build_replays(), 0u);
}

// In fast memory the builds after a system's first put the unsorted keys and IDs and the
// sort's scratch in the count pass's masks' room (dead from the fill to the next count pass). An
// engine that does (x) and one that keeps them in arrays of their own (y) list the same pairs and
// give bitwise the same results over a sequence of rebuilds (positions moved by up to 0.2 > skin /
// 2 and back), in every precision; from the second build on x holds at least the keys' and IDs'
// 8 bytes an entry less (and the sort's scratch), and its builds still replay their graph.
TEST(PairListMasks, FastBuildsLendTheMasksRoomToTheSort) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene s = make_scene("random3d_periodic");
  ASSERT_TRUE(lists_fit(s, kSkin));
  const Configuration m = moved(s.config, 0.2, 13), m2 = moved(s.config, 0.2, 14);
  const Configuration* sequence[] = {&s.config, &m, &s.config, &m2, &s.config, &m, &s.config, &m2};
  const std::size_t entries = s.config.size() << s.config.box.dim;
  for (Precision p : {Precision::kSingle, Precision::kMixed, Precision::kDouble}) {
    SCOPED_TRACE(cellforce::to_string(p));
    GpuOptions lending = list_options(p), own = list_options(p);
    lending.memory = own.memory = ListMemory::kFast;
    own.test.list_lend_masks = false;
    GpuEngine x(lending), y(own);
    for (std::size_t b = 0; b < std::size(sequence); ++b) {
      SCOPED_TRACE("build " + std::to_string(b));
      expect_same_lists(x, y, *sequence[b], s);
      EXPECT_TRUE(x.stats().rebuilt);
      if (b == 0) continue;  // the first build has no masks' room yet
      EXPECT_GT(x.list_masked_fills(), 0u);
      EXPECT_LE(x.stats().buffer_bytes + 8 * entries, y.stats().buffer_bytes)
          << "the lending engine holds the keys' and IDs' arrays";
    }
    EXPECT_GE(x.build_replays(), 3u) << "lending the room should leave the build's graph to replay";
  }
}

// A gated chunk runs on a copy of the state in the list's rank order: a particle whose
// drift diverges there is named by the caller's index, not its rank. Particle 1234 of 2,048 (its
// rank is another number: the lattice's numbering is not the cells') moves twice the box edge along
// y in every step (once the edge in each of Langevin's half drifts, without friction: the speed
// stays): more than a drift may, flagged from the first step, which the gate queues (the set_state
// build serves it); it lands where it was (the wrap), so that no other particle is thrown out by an
// overlap (the flag keeps the smallest index).
TEST(PairListMd, AGatedDivergenceNamesTheCallersParticle) {
  CF_SKIP_WITHOUT_DEVICE();
  const cellforce::Scene scene = small_fluid();
  std::vector<double> masses;
  cellforce::MdState start = unit_mass_start(scene, masses);
  const std::size_t n = start.config.size(), bad = 1234;
  ASSERT_GT(n, bad);
  cellforce::IntegratorSettings settings;
  settings.kT = 1.44;
  settings.friction = 0;
  start.velocities[bad * 3 + 1] = 2 * start.config.box.length[1] / settings.dt;
  for (const bool lean : {false, true}) {
    for (const bool langevin : {false, true}) {
      SCOPED_TRACE(std::string(lean ? "lean, " : "fast, ") + (langevin ? "Langevin" : "Verlet"));
      cellforce::EngineChoice choice;
      choice.backend = cellforce::Backend::kCuda;
      choice.precision = Precision::kMixed;
      choice.reuse.automatic = false;
      choice.reuse.skin = 0.3;
      choice.reuse.list = true;
      choice.memory = lean ? cellforce::ListMemory::kLean : cellforce::ListMemory::kFast;
      auto md = cellforce::make_cuda_md_engine(choice);
      md->set_state(start, masses, scene.force_field);
      settings.langevin = langevin;
      try {
        md->advance(10, settings, false);
        ADD_FAILURE() << "the run did not diverge";
      } catch (const cellforce::Error& e) {
        EXPECT_THAT(std::string(e.what()), ::testing::HasSubstr("particle 1234 moved ")) << e.what();
        EXPECT_THAT(std::string(e.what()), ::testing::HasSubstr(" along y in one drift, more than ")) << e.what();
      }
    }
  }
}

}  // namespace
}  // namespace cftest

#endif  // CELLFORCE_HAVE_CUDA
