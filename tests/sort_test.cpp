// Stages 1-3 on their own: the radix sort against std::stable_sort on the edge cases a sort must
// survive, the cell-ID stage's count of valid entries, and the collision-cell scan against a
// direct count per cell.
#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <numeric>
#include <random>
#include <vector>

#include "core/grid.h"
#include "cpu/stages.h"
#include "oracle.h"
#include "scene/lattice.h"

namespace {

using cellforce::cpu::radix_sort;
using cellforce::cpu::SortScratch;

// The oracle: std::stable_sort on the key masked to the window, carrying the values.
void expect_sorted_like_stable_sort(std::vector<uint32_t> keys, int key_bits) {
  std::vector<uint32_t> values(keys.size());
  std::iota(values.begin(), values.end(), 0u);
  const auto expected = cftest::stable_sorted_with_positions(keys, key_bits);
  SortScratch scratch;
  radix_sort(keys, values, key_bits, scratch);
  ASSERT_EQ(keys.size(), expected.size());
  for (std::size_t i = 0; i < keys.size(); ++i) {
    ASSERT_EQ(keys[i], expected[i].first) << "at " << i << " of " << keys.size();
    ASSERT_EQ(values[i], expected[i].second) << "at " << i << " (stability)";
  }
}

std::vector<uint32_t> random_keys(std::size_t n, uint32_t bound, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::vector<uint32_t> k(n);
  for (auto& v : k) v = uint32_t(rng() % bound);
  return k;
}

TEST(RadixSort, EmptyAndSingle) {
  expect_sorted_like_stable_sort({}, 8);
  expect_sorted_like_stable_sort({42}, 8);
}

TEST(RadixSort, AllKeysEqualKeepInputOrder) {
  expect_sorted_like_stable_sort(std::vector<uint32_t>(10007, 5u), 9);
}

TEST(RadixSort, KeysUsingEveryBit) {
  // 31-bit window (the widest a grid uses) and the full 32 bits, with 0 and all-ones present.
  auto k = random_keys(20011, 0xffffffffu, 1);
  k[17] = 0;
  k[18] = 0xffffffffu;
  k[19] = 0x7fffffffu;
  expect_sorted_like_stable_sort(k, 31);
  expect_sorted_like_stable_sort(k, 32);
}

TEST(RadixSort, SizesThatAreNotMultiplesOfTheBlock) {
  for (std::size_t n : {2u, 3u, 255u, 257u, 4095u, 4097u, 8193u, 65537u})
    expect_sorted_like_stable_sort(random_keys(n, 1000, n), 10);
}

TEST(RadixSort, OnlyTheWindowIsSorted) {
  // Bits above the window are ignored: keys that differ only there keep their input order, and
  // the invalid marker (all ones) sorts after every key that fits the window.
  std::vector<uint32_t> k = {0xffffffffu, 3u | (1u << 20), 3u, 1u, cellforce::kInvalidCell, 2u};
  expect_sorted_like_stable_sort(k, 4);
}

TEST(RadixSort, ManyDuplicatesOneBitWindow) {
  expect_sorted_like_stable_sort(random_keys(30001, 2, 7), 1);
}

// Stage 1 + 3 against a direct count: every particle has one H entry, the valid count is the
// number of entries not marked invalid, and each collision cell's (H, P) counts equal the number
// of H and P keys of that cell, for cells with H >= 1 and H + P >= 2 only.
TEST(CollisionCells, CountsMatchDirectTally) {
  using namespace cellforce;
  Configuration c = make_lattice(Lattice::kFcc, 5, 0.8442);
  jitter(c, 0.3, 11);
  const SystemView sys = c.view();
  const Grid g = plan_grid(sys.box, 2.5, sys.positions, sys.n);
  cpu::CellIdArrays ids;
  cpu::build_cell_ids(g, sys, ids);
  const std::size_t slots = std::size_t(1) << g.dim;
  ASSERT_EQ(ids.keys.size(), sys.n * slots);
  std::size_t valid = 0;
  std::map<uint32_t, std::pair<uint32_t, uint32_t>> tally;  // cell -> (H, P)
  for (std::size_t e = 0; e < ids.keys.size(); ++e) {
    if (ids.keys[e] == kInvalidCell) {
      EXPECT_NE(e % slots, 0u) << "the H entry of particle " << e / slots << " is invalid";
      continue;
    }
    ++valid;
    EXPECT_EQ(e % slots == 0, (ids.keys[e] & 1u) == 0) << "phantom bit of entry " << e;
    auto& t = tally[ids.keys[e] >> 1];
    ((ids.keys[e] & 1u) ? t.second : t.first)++;
  }
  EXPECT_EQ(ids.valid, valid);

  cpu::SortScratch scratch;
  cpu::radix_sort(ids.keys, ids.object_ids, g.key_bits, scratch);
  std::vector<cpu::CollisionCell> cells;
  cpu::find_collision_cells(ids.keys.data(), ids.valid, cells);
  std::size_t expected_cells = 0;
  for (const auto& [cell, hp] : tally) expected_cells += hp.first >= 1 && hp.first + hp.second >= 2;
  ASSERT_EQ(cells.size(), expected_cells);
  for (const auto& cc : cells) {
    const auto& hp = tally.at(cc.cell);
    EXPECT_EQ(cc.h, hp.first) << "cell " << cc.cell;
    EXPECT_EQ(cc.p, hp.second) << "cell " << cc.cell;
    for (uint32_t e = cc.start; e < cc.start + cc.h + cc.p; ++e) {
      EXPECT_EQ(ids.keys[e] >> 1, cc.cell);
      EXPECT_EQ((ids.keys[e] & 1u) != 0, e >= cc.start + cc.h) << "H entries must come first";
    }
  }
}

// The Gauss-Seidel split keeps every cell once and groups them by type in increasing order.
TEST(CollisionCells, SplitByTypeIsAStablePartition) {
  using namespace cellforce;
  Configuration c = make_lattice(Lattice::kFcc, 5, 0.8442);
  const SystemView sys = c.view();
  const Grid g = plan_grid(sys.box, 2.5, sys.positions, sys.n);
  cpu::CellIdArrays ids;
  cpu::build_cell_ids(g, sys, ids);
  cpu::SortScratch scratch;
  cpu::radix_sort(ids.keys, ids.object_ids, g.key_bits, scratch);
  std::vector<cpu::CollisionCell> cells, split;
  cpu::find_collision_cells(ids.keys.data(), ids.valid, cells);
  split = cells;
  std::vector<std::size_t> start;
  cpu::split_by_type(g, split, start);
  ASSERT_EQ(start.size(), std::size_t(g.num_types()) + 1);
  EXPECT_EQ(start.front(), 0u);
  EXPECT_EQ(start.back(), cells.size());
  for (int t = 0; t < g.num_types(); ++t) {
    std::vector<uint32_t> want;
    for (const auto& cc : cells)
      if (cell_type_of_id(g, cc.cell) == unsigned(t)) want.push_back(cc.cell);
    std::vector<uint32_t> got;
    for (std::size_t i = start[t]; i < start[t + 1]; ++i) got.push_back(split[i].cell);
    EXPECT_EQ(got, want) << "type " << t;
  }
}

}  // namespace
