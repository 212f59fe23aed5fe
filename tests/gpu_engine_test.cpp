// Properties of the CUDA engine that the shared test bodies (pipeline_test.cpp, which run it as
// the gpuwarp, gputhread and gputile backends against the brute force) do not state: the GPU
// equals the CPU engine of the same precision, every traversal form tests exactly the CPU's
// candidate pairs, and
// scenes that stress the cooperative kernel (many 32-occupant tiles, a pair buffer that must grow)
// stay exact. Skips with a message where no CUDA device exists; compiled only with CUDA.
#ifdef CELLFORCE_HAVE_CUDA

#include <gtest/gtest.h>

#include <memory>
#include <string>
#include <tuple>

#include "cpu/engine.h"
#include "backend/engine.h"  // cuda/backend/engine.h
#include "oracle.h"
#include "reference/brute_force.h"
#include "scene/lattice.h"
#include "scenes.h"

namespace cftest {
namespace {

using cellforce::Accumulation;
using cellforce::CpuEngine;
using cellforce::CpuOptions;
using cellforce::ForceResult;
using cellforce::GpuEngine;
using cellforce::GpuOptions;
using cellforce::Precision;
using cellforce::Request;
using cellforce::TraversalForm;

const char* name_of(TraversalForm f) {
  switch (f) {
    case TraversalForm::kWarpPerCell: return "warp";
    case TraversalForm::kThreadPerCell: return "thread";
    case TraversalForm::kWarpPerTile: return "tile";
    case TraversalForm::kAuto: return "auto";
  }
  return "?";
}
const char* name_of(Precision p) { return cellforce::to_string(p); }
const char* name_of(Accumulation a) { return a == Accumulation::kJacobi ? "jacobi" : "gaussseidel"; }

#define CF_SKIP_WITHOUT_DEVICE()                                          \
  do {                                                                    \
    const std::string why_ = GpuEngine::unavailable();                    \
    if (!why_.empty()) GTEST_SKIP() << why_;                              \
  } while (0)

GpuOptions gpu_options(TraversalForm form, Precision p, Accumulation acc) {
  GpuOptions o;
  o.traversal = form;
  o.precision = p;
  o.accumulation = acc;
  return o;
}

ForceResult run_gpu(const GpuOptions& o, const Scene& s) {
  GpuEngine e(o);
  ForceResult r;
  e.evaluate(s.config.view(), s.ff, Request{true, true}, r);
  return r;
}

ForceResult run_cpu(Precision p, Accumulation acc, const Scene& s) {
  CpuOptions o;
  o.precision = p;
  o.accumulation = acc;
  CpuEngine e(o);
  ForceResult r;
  e.evaluate(s.config.view(), s.ff, Request{true, true}, r);
  return r;
}

// ---- GPU equals CPU --------------------------------------------------------------------------------
using VsCpuParam = std::tuple<TraversalForm, Precision, Accumulation, std::string>;

class GpuVsCpu : public ::testing::TestWithParam<VsCpuParam> {
 protected:
  void SetUp() override { CF_SKIP_WITHOUT_DEVICE(); }
};

// Double: per particle |dF_i| <= 1e-12 max(|F_i|, F_rms), energies, total and virial to 1e-12.
// Single and mixed: both engines round the same staged float coordinates but sum in different
// orders (and nvcc fuses multiply-adds), so the agreement is that of float arithmetic: median
// per-particle relative difference below 1e-6, total energy and virial to 1e-5.
TEST_P(GpuVsCpu, SameResultsAsCpuOfSamePrecision) {
  const auto& [form, precision, acc, scene_name] = GetParam();
  const Scene s = make_scene(scene_name);
  const ForceResult cpu = run_cpu(precision, acc, s);
  const ForceResult gpu = run_gpu(gpu_options(form, precision, acc), s);
  ASSERT_EQ(gpu.forces.size(), cpu.forces.size());
  expect_results_match(cpu, gpu, precision);
}

INSTANTIATE_TEST_SUITE_P(
    Scenes, GpuVsCpu,
    ::testing::Combine(::testing::Values(TraversalForm::kWarpPerCell, TraversalForm::kThreadPerCell, TraversalForm::kWarpPerTile),
                       ::testing::Values(Precision::kDouble, Precision::kMixed, Precision::kSingle),
                       ::testing::Values(Accumulation::kJacobi, Accumulation::kGaussSeidel),
                       ::testing::Values("random3d_periodic", "random2d_periodic", "slab3d",
                                         "multitype3d_lb", "clustered3d_one_cell", "half_box3d",
                                         "lattice_fcc_jitter", "random3d_open_far")),
    [](const ::testing::TestParamInfo<VsCpuParam>& p) {
      return std::string(name_of(std::get<0>(p.param))) + "_" + name_of(std::get<1>(p.param)) +
             "_" + name_of(std::get<2>(p.param)) + "_" + std::get<3>(p.param);
    });

// ---- the stream it is given ------------------------------------------------------------------------
// An engine given a stream (GpuOptions::stream, as the Context gives its one stream to every engine
// it makes) queues its work there and leaves the stream to its owner: a second engine on the same
// stream after the first is gone runs (a destroyed stream would fail it), and both give bitwise the
// forces of an engine with a stream of its own.
TEST(GpuStream, EnginesRunOnTheStreamTheyAreGivenAndLeaveItToItsOwner) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene s = make_scene("lattice_fcc_jitter");
  const std::shared_ptr<void> stream = GpuEngine::make_stream(0);
  ASSERT_NE(stream.get(), nullptr);
  GpuOptions given = gpu_options(TraversalForm::kAuto, Precision::kMixed, Accumulation::kJacobi);
  given.stream = stream.get();
  ForceResult first;
  {
    GpuEngine e(given);
    EXPECT_EQ(e.stream(), stream.get());
    e.evaluate(s.config.view(), s.ff, Request{true, true}, first);
  }
  const ForceResult second = run_gpu(given, s);
  const ForceResult own = run_gpu(gpu_options(TraversalForm::kAuto, Precision::kMixed, Accumulation::kJacobi), s);
  EXPECT_EQ(first.forces, own.forces);
  EXPECT_EQ(second.forces, own.forces);
  EXPECT_EQ(second.energy, own.energy);
  GpuEngine mine(gpu_options(TraversalForm::kAuto, Precision::kMixed, Accumulation::kJacobi));
  EXPECT_NE(mine.stream(), stream.get());  // without one, an engine makes its own
}

// ---- the same candidates as the CPU ----------------------------------------------------------------
class GpuCandidates : public ::testing::TestWithParam<std::tuple<TraversalForm, std::string>> {
 protected:
  void SetUp() override { CF_SKIP_WITHOUT_DEVICE(); }
};

// The control-bit rule and the H x all loop are the CPU's: the number of candidate pairs tested,
// the number within the cutoff and the largest occupancy equal the CPU engine's exactly.
TEST_P(GpuCandidates, CountsEqualCpu) {
  const auto& [form, scene_name] = GetParam();
  const Scene s = make_scene(scene_name);
  CpuEngine cpu;
  ForceResult r;
  cpu.evaluate(s.config.view(), s.ff, Request{false, false}, r);
  GpuOptions o;
  o.traversal = form;
  GpuEngine gpu(o);
  const std::vector<Pair> pairs = gpu.visited_pairs(s.config.view(), s.ff);
  EXPECT_EQ(gpu.stats().candidate_pairs, cpu.stats().candidate_pairs);
  EXPECT_EQ(gpu.stats().interacting_pairs, cpu.stats().interacting_pairs);
  EXPECT_EQ(pairs.size(), cpu.stats().interacting_pairs);
  EXPECT_EQ(gpu.stats().max_occupancy, cpu.stats().max_occupancy);
  EXPECT_EQ(gpu.stats().collision_cells, cpu.stats().collision_cells);
  EXPECT_EQ(gpu.stats().valid_entries, cpu.stats().valid_entries);
  // Counting without storing gives the same counts.
  GpuEngine counter(o);
  counter.count_pairs(s.config.view(), s.ff);
  EXPECT_EQ(counter.stats().candidate_pairs, cpu.stats().candidate_pairs);
  EXPECT_EQ(counter.stats().interacting_pairs, cpu.stats().interacting_pairs);
}

INSTANTIATE_TEST_SUITE_P(
    Scenes, GpuCandidates,
    ::testing::Combine(::testing::Values(TraversalForm::kWarpPerCell, TraversalForm::kThreadPerCell, TraversalForm::kWarpPerTile),
                       ::testing::ValuesIn(all_scene_names())),
    [](const ::testing::TestParamInfo<std::tuple<TraversalForm, std::string>>& p) {
      return std::string(name_of(std::get<0>(p.param))) + "_" + std::get<1>(p.param);
    });

// ---- a dense cluster: one cell of 32 tiles, a pair buffer that must grow ------------------------
class GpuDenseCluster : public ::testing::TestWithParam<TraversalForm> {
 protected:
  void SetUp() override { CF_SKIP_WITHOUT_DEVICE(); }
};

// 1000 particles (no two closer than 0.6) in an 8^3 cube of an open 100^3 box: the grid covers the
// cube with one cell (two need an extent of 2 (rc + h) = 8.54), so one collision cell holds all
// 1000 (32 tiles of 32 in the warp form), with ~60,000 pairs, far more than the pair recorder's
// first buffer (8 per entry). Pairs equal the brute force's exactly; double forces, energies and
// virial to 1e-12 of the brute force.
TEST_P(GpuDenseCluster, ExactAgainstBruteForce) {
  const cellforce::Box box = make_box(3, {100, 100, 100}, {false, false, false});
  RandomSpec spec;
  spec.min_distance = 0.6;
  spec.lo = std::array<double, 3>{40, 40, 40};
  spec.hi = std::array<double, 3>{48, 48, 48};
  Scene s{"dense", random_configuration(box, 1000, 77, spec), {}};
  s.ff.cutoff = 2.5;
  s.ff.types = {{"A", 1.0, 1.0}};
  GpuOptions o;
  o.traversal = GetParam();
  GpuEngine gpu(o);
  const auto view = s.config.view();
  EXPECT_TRUE(pair_sets_equal(cellforce::brute_force_pairs(view, s.ff), gpu.visited_pairs(view, s.ff)));
  EXPECT_EQ(gpu.stats().max_occupancy, 1000u);
  EXPECT_EQ(gpu.stats().collision_cells, 1u);
  ForceResult ref, got;
  cellforce::brute_force(view, s.ff, Request{true, true}, ref);
  gpu.evaluate(view, s.ff, Request{true, true}, got);
  EXPECT_TRUE(forces_match(ref, got, 1e-12));
  EXPECT_TRUE(energies_match(ref, got, 1e-12));
  EXPECT_TRUE(total_energy_matches(ref, got, 1e-12));
  EXPECT_TRUE(virial_matches(ref, got, 1e-12));
}

INSTANTIATE_TEST_SUITE_P(Forms, GpuDenseCluster,
                         ::testing::Values(TraversalForm::kWarpPerCell, TraversalForm::kThreadPerCell, TraversalForm::kWarpPerTile),
                         [](const ::testing::TestParamInfo<TraversalForm>& p) {
                           return std::string(name_of(p.param));
                         });

// ---- the tile form on liquid cells ------------------------------------------------------------------
// A jittered fcc liquid (10,976 particles, 4 x 4 x 4 cells of ~171 home and ~600 phantom
// occupants): row tiles straddle the H/P boundary, H-row tiles walk every column tile, P-row tiles
// the H ones, and the block's four warps share each tile's columns. Forces, per-particle energies,
// energy and virial equal the brute force to 1e-12 (double), Jacobi and Gauss-Seidel; the pairs
// found are the brute force's, each once; auto chooses this form here.
TEST(GpuTileForm, LiquidCellsMatchTheBruteForce) {
  CF_SKIP_WITHOUT_DEVICE();
  cellforce::Configuration c = cellforce::make_lattice(cellforce::Lattice::kFcc, 14, 0.8442);
  cellforce::jitter(c, 0.2, 17);
  cellforce::ForceField ff;
  ff.cutoff = 2.5;
  ff.types = {{"A", 1.0, 1.0}};
  const auto view = c.view();
  ForceResult ref;
  cellforce::brute_force(view, ff, Request{true, true}, ref);
  for (Accumulation acc : {Accumulation::kJacobi, Accumulation::kGaussSeidel}) {
    SCOPED_TRACE(name_of(acc));
    GpuOptions o;
    o.traversal = TraversalForm::kWarpPerTile;
    o.accumulation = acc;
    GpuEngine gpu(o);
    ForceResult got;
    gpu.evaluate(view, ff, Request{true, true}, got);
    EXPECT_GT(gpu.stats().valid_entries / gpu.stats().collision_cells, 600u);  // cells of many tiles
    EXPECT_TRUE(forces_match(ref, got, 1e-12));
    EXPECT_TRUE(energies_match(ref, got, 1e-12));
    EXPECT_TRUE(total_energy_matches(ref, got, 1e-12));
    EXPECT_TRUE(virial_matches(ref, got, 1e-12));
    EXPECT_TRUE(pair_sets_equal(cellforce::brute_force_pairs(view, ff), gpu.visited_pairs(view, ff)));
  }
  GpuEngine automatic;  // the default: auto
  EXPECT_EQ(automatic.traversal(), TraversalForm::kAuto);  // nothing built yet
  ForceResult got;
  automatic.evaluate(view, ff, Request{false, false}, got);
  EXPECT_EQ(automatic.traversal(), TraversalForm::kWarpPerTile);  // 64 cells: few per SM
}

// ---- the engine object ------------------------------------------------------------------------------
// One engine, scenes of different sizes and dimensions in turn: buffers grow and shrink in use
// without stale data (each result equals a fresh engine's bitwise).
TEST(GpuEngineReuse, AlternatingScenesMatchFreshEngines) {
  CF_SKIP_WITHOUT_DEVICE();
  GpuEngine shared;
  for (const char* name : {"clustered3d_one_cell", "random2d_periodic", "random3d_periodic",
                           "two_cells2d", "multitype3d_lb", "random2d_periodic"}) {
    const Scene s = make_scene(name);
    ForceResult a, b;
    shared.evaluate(s.config.view(), s.ff, Request{true, true}, a);
    GpuEngine fresh;
    fresh.evaluate(s.config.view(), s.ff, Request{true, true}, b);
    EXPECT_TRUE(bitwise_equal(a, b)) << name;
  }
}

// Energy alone and virial alone (one switch on the GPU computes both): each requested observable
// equals the brute force to 1e-12, the other is zero, and the forces are bitwise those of a
// forces-only request.
TEST(GpuEngineRequests, EnergyOnlyAndVirialOnly) {
  CF_SKIP_WITHOUT_DEVICE();
  const Scene s = make_scene("multitype3d_lb");
  const auto view = s.config.view();
  ForceResult ref, bare, energy_only, virial_only;
  cellforce::brute_force(view, s.ff, Request{true, true}, ref);
  GpuEngine e;
  e.evaluate(view, s.ff, Request{false, false}, bare);
  e.evaluate(view, s.ff, Request{true, false}, energy_only);
  e.evaluate(view, s.ff, Request{false, true}, virial_only);
  EXPECT_TRUE(total_energy_matches(ref, energy_only, 1e-12));
  EXPECT_TRUE(energies_match(ref, energy_only, 1e-12));
  EXPECT_TRUE(virial_matches(ref, virial_only, 1e-12));
  EXPECT_EQ(virial_only.energy, 0.0);
  EXPECT_TRUE(virial_only.energies.empty());
  for (const auto& row : energy_only.virial)
    for (double v : row) EXPECT_EQ(v, 0.0);
  EXPECT_EQ(bare.forces, energy_only.forces);
  EXPECT_EQ(bare.forces, virial_only.forces);
}

// An empty system gives empty forces and zero energy, not a launch error.
TEST(GpuEngineReuse, EmptySystem) {
  CF_SKIP_WITHOUT_DEVICE();
  cellforce::Configuration c;
  c.box = cube(3, 10.0);
  cellforce::ForceField ff;
  ff.cutoff = 2.5;
  ff.types = {{"A", 1.0, 1.0}};
  GpuEngine e;
  ForceResult r;
  e.evaluate(c.view(), ff, Request{true, true}, r);
  EXPECT_TRUE(r.forces.empty());
  EXPECT_EQ(r.energy, 0.0);
}

}  // namespace
}  // namespace cftest

#endif  // CELLFORCE_HAVE_CUDA
