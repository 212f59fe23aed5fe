// Properties of the CPU engine itself (not shared with other backends): results independent of
// the OpenMP thread count (spatial-subdivision.md, stage 5: no two cells write one slot, every sum
// has a fixed order), and the pipeline statistics agree with independent counts.
#include <gtest/gtest.h>
#include <omp.h>

#include <string>
#include <tuple>

#include "core/grid.h"
#include "cpu/engine.h"
#include "oracle.h"
#include "reference/brute_force.h"
#include "scenes.h"

namespace cftest {
namespace {

using cellforce::Accumulation;
using cellforce::CpuEngine;
using cellforce::CpuOptions;
using cellforce::ForceResult;
using cellforce::Precision;

// Restores the OpenMP thread count a test changed.
class ThreadCountGuard {
 public:
  ThreadCountGuard() : saved_(omp_get_max_threads()) {}
  ~ThreadCountGuard() { omp_set_num_threads(saved_); }
  ThreadCountGuard(const ThreadCountGuard&) = delete;
  ThreadCountGuard& operator=(const ThreadCountGuard&) = delete;

 private:
  int saved_;
};

using ThreadParam = std::tuple<Accumulation, Precision, std::string>;

std::string thread_param_name(const ::testing::TestParamInfo<ThreadParam>& p) {
  const auto& [acc, precision, scene] = p.param;
  return std::string(acc == Accumulation::kJacobi ? "jacobi" : "gaussseidel") + "_" +
         cellforce::to_string(precision) + "_" + scene;
}

class CpuThreads : public ::testing::TestWithParam<ThreadParam> {};

// 1, 2, 3 and 5 threads give bitwise identical forces, energies, total energy and virial (memcmp).
TEST_P(CpuThreads, ResultsBitwiseIndependentOfThreadCount) {
  const auto& [acc, precision, scene_name] = GetParam();
  const Scene s = make_scene(scene_name);
  ThreadCountGuard guard;
  CpuOptions o;
  o.accumulation = acc;
  o.precision = precision;
  omp_set_num_threads(1);
  CpuEngine one(o);
  ForceResult reference;
  one.evaluate(s.config.view(), s.ff, {}, reference);
  for (int threads : {2, 3, 5}) {
    omp_set_num_threads(threads);
    CpuEngine e(o);
    ForceResult r;
    e.evaluate(s.config.view(), s.ff, {}, r);
    EXPECT_TRUE(bitwise_equal(reference, r)) << threads << " threads";
  }
}

INSTANTIATE_TEST_SUITE_P(
    Scenes, CpuThreads,
    ::testing::Combine(::testing::Values(Accumulation::kJacobi, Accumulation::kGaussSeidel),
                       ::testing::Values(Precision::kDouble, Precision::kMixed, Precision::kSingle),
                       ::testing::Values("random3d_periodic", "clustered3d_corner", "slab2d")),
    thread_param_name);

class CpuStats : public ::testing::TestWithParam<std::string> {};

// interacting_pairs equals the brute force's pair count; candidate_pairs >= interacting_pairs;
// entries = n 2^d; valid_entries equals the valid cell IDs bin_particle gives with the engine's
// grid; the grid is the planned one; max_occupancy >= the most particles homed in one cell
// (all exact counts).
TEST_P(CpuStats, CountsAgreeWithIndependentCounts) {
  const Scene s = make_scene(GetParam());
  CpuEngine e;
  ForceResult r;
  e.evaluate(s.config.view(), s.ff, {}, r);
  const cellforce::PipelineStats& st = e.stats();
  const std::size_t n = s.config.size();
  const int d = s.config.box.dim;
  EXPECT_EQ(st.interacting_pairs, cellforce::brute_force_pairs(s.config.view(), s.ff).size());
  EXPECT_GE(st.candidate_pairs, st.interacting_pairs);
  EXPECT_EQ(st.entries, n << d);
  const cellforce::Grid planned =
      cellforce::plan_grid(s.config.box, s.ff.cutoff, s.config.positions.data(), n);
  for (int a = 0; a < 3; ++a) EXPECT_EQ(st.grid.n[a], planned.n[a]) << "axis " << a;
  EXPECT_EQ(st.grid.half_width, planned.half_width);
  std::size_t valid = 0;
  std::vector<std::size_t> homed(st.grid.num_cells, 0);
  uint32_t ids[cellforce::kMaxCellTypes];
  for (std::size_t i = 0; i < n; ++i) {
    cellforce::bin_particle(st.grid, &s.config.positions[i * std::size_t(d)], ids);
    ++homed[ids[0]];
    for (int t = 0; t < (1 << d); ++t) valid += ids[t] != cellforce::kInvalidCell;
  }
  EXPECT_EQ(st.valid_entries, valid);
  std::size_t most = 0;
  for (std::size_t h : homed) most = std::max(most, h);
  EXPECT_GE(st.max_occupancy, most);
  EXPECT_GT(st.collision_cells, 0u);
}

INSTANTIATE_TEST_SUITE_P(Scenes, CpuStats,
                         ::testing::Values("random3d_periodic", "random2d_open", "slab3d",
                                           "clustered3d_one_cell", "half_box3d", "faces3d_periodic"));

}  // namespace
}  // namespace cftest
