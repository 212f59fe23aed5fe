// Stages 1-3 on their own: the radix sort against std::stable_sort on the edge cases a sort must
// survive, the cell-ID stage's count of valid entries, and the collision-cell scan against a
// direct count per cell.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
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
    const bool phantom = key_is_phantom(ids.keys[e], g.slab_bits);
    EXPECT_EQ(e % slots == 0, !phantom) << "phantom bit of entry " << e;
    auto& t = tally[key_cell(ids.keys[e], g.slab_bits)];
    (phantom ? t.second : t.first)++;
  }
  EXPECT_EQ(ids.valid, valid);

  cpu::SortScratch scratch;
  cpu::radix_sort(ids.keys, ids.object_ids, g.key_bits, scratch);
  std::vector<cpu::CollisionCell> cells;
  cpu::find_collision_cells(ids.keys.data(), ids.valid, g.slab_bits, cells);
  std::size_t expected_cells = 0;
  for (const auto& [cell, hp] : tally) expected_cells += hp.first >= 1 && hp.first + hp.second >= 2;
  ASSERT_EQ(cells.size(), expected_cells);
  for (const auto& cc : cells) {
    const auto& hp = tally.at(cc.cell);
    EXPECT_EQ(cc.h, hp.first) << "cell " << cc.cell;
    EXPECT_EQ(cc.p, hp.second) << "cell " << cc.cell;
    for (uint32_t e = cc.start; e < cc.start + cc.h + cc.p; ++e) {
      EXPECT_EQ(key_cell(ids.keys[e], g.slab_bits), cc.cell);
      EXPECT_EQ(key_is_phantom(ids.keys[e], g.slab_bits), e >= cc.start + cc.h) << "H entries must come first";
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
  cpu::find_collision_cells(ids.keys.data(), ids.valid, g.slab_bits, cells);
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

// The slab bits (where GridOptions::slabs asks for them: none otherwise): the sort key's
// cell part keeps its width, the slab takes 2-3 bits (fewer only where the cell part leaves less of
// the 32), and it adds no 8-bit sort pass where the last digit has 2 or more bits free; every valid
// key, whatever its slab, stays below an invalid entry masked to the key's width.
TEST(SortKey, SlabBitsFillTheSortsLastDigit) {
  using namespace cellforce;
  // Up to the grid's limit: 1,006^3 cells leave 1 bit of the 32, 1,024^3 = kMaxCells none.
  for (double edge : {10.0, 16.0, 33.6, 53.0, 67.7, 107.5, 111.5, 170.6, 270.9, 491.0, 1350.0, 4300.0, 4372.0}) {
    Box box;
    box.dim = 3;
    for (int a = 0; a < 3; ++a) {
      box.length[a] = edge;
      box.periodic[a] = true;
    }
    GridOptions options;
    options.slabs = true;
    const Grid g = plan_grid(box, 2.5, nullptr, 0, options);
    EXPECT_EQ(plan_grid(box, 2.5, nullptr, 0).slab_bits, 0) << "slabs only where asked";
    const int cell_bits = int(std::bit_width(uint64_t(2) * g.num_cells));
    SCOPED_TRACE("edge " + std::to_string(edge) + ", " + std::to_string(g.num_cells) + " cells");
    EXPECT_EQ(g.key_bits, cell_bits + g.slab_bits);
    EXPECT_LE(g.key_bits, 32);
    EXPECT_GE(g.slab_bits, std::min(2, 32 - cell_bits));
    EXPECT_LE(g.slab_bits, kMaxSlabBits);
    const int free_bits = (8 - cell_bits % 8) % 8;
    if (free_bits >= 2) {
      EXPECT_EQ((g.key_bits + 7) / 8, (cell_bits + 7) / 8) << "a sort pass more";
    }
    if (free_bits >= kMaxSlabBits) {
      EXPECT_EQ(g.slab_bits, kMaxSlabBits);
    }
    const uint32_t largest = sort_key(g, g.num_cells - 1, true, (1u << g.slab_bits) - 1);
    const uint32_t window = g.key_bits >= 32 ? 0xffffffffu : (uint32_t(1) << g.key_bits) - 1;
    EXPECT_LT(largest, kInvalidCell & window);
    EXPECT_EQ(key_cell(largest, g.slab_bits), g.num_cells - 1);
    EXPECT_TRUE(key_is_phantom(largest, g.slab_bits));
  }
}

// After the sort a cell's H entries, then its P entries, run by slab (the particle's layer inside
// its own H cell along the last axis, found here from its position), and within a slab by particle
// index: with the particles numbered at random, consecutive entries of a cell still lie in one
// layer. The layer is checked against the position independently of bin_particle().
TEST(SortKey, CellEntriesRunBySlabThenParticle) {
  using namespace cellforce;
  Configuration c = make_lattice(Lattice::kFcc, 8, 0.8442);
  jitter(c, 0.3, 5);
  // The caller's numbering at random.
  const std::size_t n = c.size();
  std::vector<std::size_t> perm(n);
  std::iota(perm.begin(), perm.end(), 0);
  std::shuffle(perm.begin(), perm.end(), std::mt19937(17));
  std::vector<double> shuffled(c.positions.size());
  for (std::size_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) shuffled[i * 3 + a] = c.positions[perm[i] * 3 + a];
  c.positions = shuffled;
  const SystemView sys = c.view();
  GridOptions options;
  options.slabs = true;
  const Grid g = plan_grid(sys.box, 2.5, sys.positions, sys.n, options);
  ASSERT_GE(g.slab_bits, 2);
  const uint32_t layers = 1u << g.slab_bits;
  auto layer_of = [&](uint32_t i) {
    const double z = wrap_coordinate(sys.positions[std::size_t(i) * 3 + 2], g.length[2]);
    const double u = z * g.inv_cell[2];  // the origin is 0 on a periodic axis
    const double f = u - std::floor(u);
    return std::min(uint32_t(f * layers), layers - 1);
  };
  cpu::CellIdArrays ids;
  cpu::build_cell_ids(g, sys, ids);
  cpu::SortScratch scratch;
  cpu::radix_sort(ids.keys, ids.object_ids, g.key_bits, scratch);
  std::vector<cpu::CollisionCell> cells;
  cpu::find_collision_cells(ids.keys.data(), ids.valid, g.slab_bits, cells);
  ASSERT_FALSE(cells.empty());
  std::size_t checked = 0, layer_changes = 0;
  for (const auto& cc : cells) {
    for (uint32_t e = cc.start; e < cc.start + cc.h + cc.p; ++e) {
      const uint32_t i = ids.object_ids[e];
      EXPECT_EQ(ids.keys[e] & (layers - 1), layer_of(i)) << "entry " << e << ", particle " << i;
      ++checked;
      if (e == cc.start || e == cc.start + cc.h) continue;  // a group's first entry
      const uint32_t prev = ids.object_ids[e - 1];
      const uint32_t lp = layer_of(prev), li = layer_of(i);
      EXPECT_LE(lp, li) << "cell " << cc.cell << ": entries " << e - 1 << ", " << e << " out of layer order";
      if (lp == li) {
        EXPECT_LT(prev, i) << "cell " << cc.cell << ": ties by particle index";
      }
      layer_changes += lp != li;
    }
  }
  EXPECT_EQ(checked, ids.valid);
  EXPECT_GT(layer_changes, cells.size()) << "the layers split the cells";
}
