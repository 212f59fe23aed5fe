// CUDA stages 1-3 against the CPU stages (themselves tested against direct tallies and
// std::stable_sort in sort_test.cpp): cell-ID, object-ID and control arrays, the valid count,
// the sorted arrays and the collision-cell list must be identical element for element. CUB's sort is also checked on the
// edge cases a sort must survive. Skips with a message where no CUDA device exists.
#include <cuda_runtime.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <numeric>
#include <random>
#include <vector>

#include "check.cuh"
#include "cuda_device.h"
#include "cpu/stages.h"
#include "oracle.h"
#include "scene/lattice.h"
#include "stages.cuh"

namespace {

using namespace cellforce;

class GpuStages : public cftest::NeedsCudaDevice {};

using cftest::download;
using cftest::upload;

// Stages 1-3 on both backends for one configuration; every array must be identical.
void expect_stages_equal(const Configuration& c, double cutoff) {
  const SystemView sys = c.view();
  const Grid g = plan_grid(sys.box, cutoff, sys.positions, sys.n);
  cpu::CellIdArrays host;
  cpu::build_cell_ids(g, sys, host);

  const std::size_t entries = sys.n << g.dim;
  cuda::DeviceBuffer<double> d_pos;
  upload(d_pos, c.positions);
  cuda::DeviceBuffer<uint32_t> d_keys(std::max<std::size_t>(entries, 1)),
      d_ids(std::max<std::size_t>(entries, 1)), d_keys_sorted(std::max<std::size_t>(entries, 1)),
      d_ids_sorted(std::max<std::size_t>(entries, 1));
  cuda::DeviceBuffer<Control> d_control(std::max<std::size_t>(sys.n, 1));
  cuda::DeviceBuffer<std::byte> scratch;
  cuda::build_cell_ids(g, d_pos.data(), sys.n, d_keys.data(), d_ids.data(), d_control.data(), 0);
  const std::size_t valid = cuda::count_valid(d_keys.data(), entries, scratch, 0);
  CF_CUDA_CHECK(cudaDeviceSynchronize());

  EXPECT_EQ(valid, host.valid);
  EXPECT_EQ(download(d_keys, entries), host.keys) << "cell-ID array";
  EXPECT_EQ(download(d_ids, entries), host.object_ids) << "object-ID array";
  EXPECT_EQ(download(d_control, sys.n), host.control) << "control bits";

  cuda::radix_sort_cub(d_keys.data(), d_ids.data(), d_keys_sorted.data(), d_ids_sorted.data(),
                       entries, g.key_bits, scratch, 0);
  CF_CUDA_CHECK(cudaDeviceSynchronize());
  cpu::SortScratch sort_scratch;
  cpu::radix_sort(host.keys, host.object_ids, g.key_bits, sort_scratch);
  EXPECT_EQ(download(d_keys_sorted, entries), host.keys) << "sorted keys";
  EXPECT_EQ(download(d_ids_sorted, entries), host.object_ids) << "sorted object IDs (stability)";

  std::vector<CollisionCell> host_cells;
  cpu::find_collision_cells(host.keys.data(), host.valid, host_cells);
  cuda::DeviceBuffer<CollisionCell> d_cells;
  cuda::CollisionScratch collision_scratch;
  const std::size_t ncells =
      cuda::find_collision_cells(d_keys_sorted.data(), valid, d_cells, collision_scratch, 0);
  ASSERT_EQ(ncells, host_cells.size()) << "collision cells";
  const auto cells = download(d_cells, ncells);
  for (std::size_t i = 0; i < ncells; ++i) {
    const CollisionCell &a = cells[i], &b = host_cells[i];
    ASSERT_TRUE(a.start == b.start && a.h == b.h && a.p == b.p && a.cell == b.cell)
        << "collision cell " << i << ": GPU (" << a.start << ", " << a.h << ", " << a.p << ", "
        << a.cell << ") CPU (" << b.start << ", " << b.h << ", " << b.p << ", " << b.cell << ")";
  }
}

TEST_F(GpuStages, LiquidMatchesCpu) {
  Configuration c = make_lattice(Lattice::kFcc, 12, 0.8442);  // 6912 particles
  jitter(c, 0.3, 5);
  expect_stages_equal(c, 2.5);
}

TEST_F(GpuStages, TwoDimensionalAndOpenMatchCpu) {
  expect_stages_equal(cftest::random_configuration(cftest::cube(2, 40.0), 3000, 7), 2.5);
  expect_stages_equal(cftest::random_configuration(cftest::cube(3, 25.0, false), 3000, 8), 2.5);
  expect_stages_equal(
      cftest::random_configuration(cftest::make_box(3, {20, 20, 60}, {true, true, false}), 4000, 9),
      2.5);
}

TEST_F(GpuStages, ClusteredEmptyAndSingleMatchCpu) {
  cftest::RandomSpec clustered;
  clustered.lo = std::array<double, 3>{10, 10, 10};
  clustered.hi = std::array<double, 3>{11, 11, 11};
  expect_stages_equal(cftest::random_configuration(cftest::cube(3, 40.0), 2000, 10, clustered), 2.5);
  expect_stages_equal(cftest::random_configuration(cftest::cube(3, 10.0), 0, 11), 2.5);
  expect_stages_equal(cftest::random_configuration(cftest::cube(3, 10.0), 1, 12), 2.5);
}

// CUB's sort against std::stable_sort on the masked key: 0 and 1 elements, all keys equal, keys
// using every bit (31- and 32-bit windows), sizes that are not multiples of any block.
TEST_F(GpuStages, CubSortEdgeCases) {
  std::mt19937_64 rng(3);
  auto check = [&](std::vector<uint32_t> keys, int bits) {
    std::vector<uint32_t> values(keys.size());
    std::iota(values.begin(), values.end(), 0u);
    const auto expected = cftest::stable_sorted_with_positions(keys, bits);
    cuda::DeviceBuffer<uint32_t> ki, vi, ko, vo;
    upload(ki, keys);
    upload(vi, values);
    ko.reserve(std::max<std::size_t>(keys.size(), 1));
    vo.reserve(std::max<std::size_t>(keys.size(), 1));
    cuda::DeviceBuffer<std::byte> scratch;
    cuda::radix_sort_cub(ki.data(), vi.data(), ko.data(), vo.data(), keys.size(), bits, scratch, 0);
    CF_CUDA_CHECK(cudaDeviceSynchronize());
    const auto k = download(ko, keys.size()), v = download(vo, keys.size());
    for (std::size_t i = 0; i < keys.size(); ++i) {
      ASSERT_EQ(k[i], expected[i].first) << "n " << keys.size() << " bits " << bits << " at " << i;
      ASSERT_EQ(v[i], expected[i].second) << "n " << keys.size() << " bits " << bits << " at " << i;
    }
  };
  check({}, 8);
  check({42}, 8);
  check(std::vector<uint32_t>(10007, 5u), 9);
  std::vector<uint32_t> wide(20011);
  for (auto& x : wide) x = uint32_t(rng());
  wide[3] = 0;
  wide[4] = 0xffffffffu;
  check(wide, 31);
  check(wide, 32);
  for (std::size_t n : {2u, 255u, 257u, 4097u, 65537u, 1000003u}) {
    std::vector<uint32_t> k(n);
    for (auto& x : k) x = uint32_t(rng() % 1000);
    check(k, 10);
  }
}

}  // namespace
