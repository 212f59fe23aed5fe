// CUDA stages 1-3 against the CPU stages (themselves tested against direct tallies and
// std::stable_sort in sort_test.cpp): cell-ID, object-ID and control arrays, the valid count,
// the sorted arrays and the collision-cell list must be identical element for element, and the
// chapter's sort must give CUB's arrays. Both device sorts run through the same test bodies on the
// edge cases a sort must survive, against std::stable_sort. Skips with a message where no CUDA
// device exists.
#include <cuda_runtime.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include "check.cuh"
#include "cuda_device.h"
#include "cpu/stages.h"
#include "oracle.h"
#include "scene/lattice.h"
#include "search/stages.cuh"

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
  cuda::DeviceBuffer<cuda::PipelineCounts> d_counts(1);
  cuda::build_cell_ids(g, d_pos.data(), sys.n, d_keys.data(), d_ids.data(), d_control.data(), 0);
  cuda::count_valid(d_keys.data(), entries, d_counts.data(), scratch, 0);
  const std::size_t valid = cuda::read_counts(d_counts.data(), 0).valid;

  EXPECT_EQ(valid, host.valid);
  EXPECT_EQ(download(d_keys, entries), host.keys) << "cell-ID array";
  EXPECT_EQ(download(d_ids, entries), host.object_ids) << "object-ID array";
  EXPECT_EQ(download(d_control, sys.n), host.control) << "control bits";
  // The engine's form: the kernel zeroes every count (they held another value before),
  // counts the valid entries itself and keeps the positions it read; the same arrays.
  {
    CF_CUDA_CHECK(cudaMemset(d_counts.data(), 0x5a, sizeof(cuda::PipelineCounts)));
    cuda::DeviceBuffer<double> d_copy(std::max<std::size_t>(c.positions.size(), 1));
    cuda::build_cell_ids(g, d_pos.data(), sys.n, d_keys.data(), d_ids.data(), d_control.data(), 0, d_counts.data(),
                         d_copy.data());
    const cuda::PipelineCounts counted = cuda::read_counts(d_counts.data(), 0);
    EXPECT_EQ(counted.valid, host.valid) << "valid entries counted by the cell-ID kernel";
    EXPECT_EQ(counted.runs, 0u);
    EXPECT_EQ(counted.cell_range[0], 0u);
    EXPECT_EQ(counted.cell_range[1], 0u);
    EXPECT_EQ(download(d_copy, c.positions.size()), c.positions) << "the positions the kernel kept";
    EXPECT_EQ(download(d_keys, entries), host.keys) << "cell-ID array (engine's form)";
    EXPECT_EQ(download(d_ids, entries), host.object_ids) << "object-ID array (engine's form)";
    EXPECT_EQ(download(d_control, sys.n), host.control) << "control bits (engine's form)";
  }

  cuda::radix_sort_cub(d_keys.data(), d_ids.data(), d_keys_sorted.data(), d_ids_sorted.data(),
                       entries, g.key_bits, scratch, 0);
  CF_CUDA_CHECK(cudaDeviceSynchronize());
  cpu::SortScratch sort_scratch;
  cpu::radix_sort(host.keys, host.object_ids, g.key_bits, sort_scratch);
  EXPECT_EQ(download(d_keys_sorted, entries), host.keys) << "sorted keys";
  EXPECT_EQ(download(d_ids_sorted, entries), host.object_ids) << "sorted object IDs (stability)";

  // CUB's sort with its scratch lent from another buffer (a lean build lends the dead list's
  // array): the same result, and the lent room is what it used (its own scratch stays empty).
  {
    cuda::DeviceBuffer<std::byte> probe;  // takes exactly what the sort asks for
    cuda::radix_sort_cub(d_keys.data(), d_ids.data(), d_keys_sorted.data(), d_ids_sorted.data(), entries,
                         g.key_bits, probe, 0);
    const std::size_t bytes = probe.capacity();
    EXPECT_EQ(cuda::radix_sort_cub_bytes(entries, g.key_bits), bytes) << "what a lean build's lend decision asks";
    cuda::DeviceBuffer<std::byte> lent(bytes + 256), own;
    CF_CUDA_CHECK(cudaMemset(lent.data(), 0xa5, bytes + 256));
    cuda::DeviceBuffer<uint32_t> k2(std::max<std::size_t>(entries, 1)), i2(std::max<std::size_t>(entries, 1));
    cuda::radix_sort_cub(d_keys.data(), d_ids.data(), k2.data(), i2.data(), entries, g.key_bits, own, 0,
                         cuda::ScratchLoan{lent.data(), bytes});
    CF_CUDA_CHECK(cudaDeviceSynchronize());
    EXPECT_EQ(own.capacity(), 0u) << "the sort took its own scratch despite the loan";
    {
      std::vector<std::byte> after(bytes + 256);
      CF_CUDA_CHECK(cudaMemcpy(after.data(), lent.data(), bytes + 256, cudaMemcpyDeviceToHost));
      const auto pattern = std::byte{0xa5};
      EXPECT_TRUE(std::all_of(after.begin() + std::ptrdiff_t(bytes), after.end(),
                              [&](std::byte b) { return b == pattern; }))
          << "the sort wrote past the lent bytes";
    }
    EXPECT_EQ(download(k2, entries), host.keys) << "sorted keys, lent scratch";
    EXPECT_EQ(download(i2, entries), host.object_ids) << "sorted object IDs, lent scratch";
    // A loan too small: the sort's own scratch instead, the same result.
    if (bytes > 0) {
      cuda::radix_sort_cub(d_keys.data(), d_ids.data(), k2.data(), i2.data(), entries, g.key_bits, own, 0,
                           cuda::ScratchLoan{lent.data(), bytes - 1});
      CF_CUDA_CHECK(cudaDeviceSynchronize());
      EXPECT_GE(own.capacity(), bytes);
      EXPECT_EQ(download(k2, entries), host.keys) << "sorted keys, loan too small";
    }
  }

  // The chapter's sort on the same arrays: CUB's result element for element.
  cuda::DeviceBuffer<uint32_t> d_keys_chapter(std::max<std::size_t>(entries, 1)),
      d_ids_chapter(std::max<std::size_t>(entries, 1));
  cuda::ChapterSortScratch chapter_scratch;
  cuda::radix_sort_chapter(d_keys.data(), d_ids.data(), d_keys_chapter.data(), d_ids_chapter.data(),
                           entries, g.key_bits, chapter_scratch, 0);
  CF_CUDA_CHECK(cudaDeviceSynchronize());
  EXPECT_EQ(download(d_keys_chapter, entries), download(d_keys_sorted, entries))
      << "chapter sort keys against CUB, key bits " << g.key_bits;
  EXPECT_EQ(download(d_ids_chapter, entries), download(d_ids_sorted, entries))
      << "chapter sort object IDs against CUB, key bits " << g.key_bits;

  std::vector<CollisionCell> host_cells;
  cpu::find_collision_cells(host.keys.data(), host.valid, g.slab_bits, host_cells);
  cuda::DeviceBuffer<CollisionCell> d_cells;
  cuda::CollisionScratch collision_scratch;
  // Buffers sized by the engine's bounds: runs <= min(entries, grid cells), collision cells <=
  // min(n, grid cells).
  const std::size_t run_bound = std::min<std::size_t>(entries, g.num_cells);
  const std::size_t cell_bound = std::min<std::size_t>(sys.n, g.num_cells);
  // The engine's form: the counts zeroed by the cell-ID kernel above (`zeroed`); and the same cells
  // where the stage zeroes them itself (their old values garbage).
  cuda::find_collision_cells(d_keys_sorted.data(), g.slab_bits, entries, run_bound, cell_bound, d_counts.data(), d_cells,
                             collision_scratch, 0, true);
  const cuda::PipelineCounts counts = cuda::read_counts(d_counts.data(), 0);
  {
    cuda::DeviceBuffer<CollisionCell> again;
    CF_CUDA_CHECK(cudaMemset(&d_counts.data()->runs, 0x5a, sizeof(uint32_t) * 3));
    cuda::find_collision_cells(d_keys_sorted.data(), g.slab_bits, entries, run_bound, cell_bound, d_counts.data(), again,
                               collision_scratch, 0);
    const cuda::PipelineCounts second = cuda::read_counts(d_counts.data(), 0);
    EXPECT_EQ(second.runs, counts.runs);
    EXPECT_EQ(second.cell_range[1], counts.cell_range[1]);
    const auto a = download(again, counts.cell_range[1]), b = download(d_cells, counts.cell_range[1]);
    for (std::size_t i = 0; i < a.size(); ++i)
      ASSERT_TRUE(a[i].start == b[i].start && a[i].h == b[i].h && a[i].p == b[i].p && a[i].cell == b[i].cell)
          << "collision cell " << i << " where the stage zeroed its counts";
  }
  const std::size_t ncells = counts.cell_range[1];
  EXPECT_EQ(counts.cell_range[0], 0u);
  EXPECT_LE(counts.runs, run_bound);
  EXPECT_LE(ncells, cell_bound);
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

// ---- both device sorts on the edge cases a sort must survive ----------------------------------

enum class DeviceSort { kCub, kChapter };

std::string sort_name(const ::testing::TestParamInfo<DeviceSort>& info) {
  return info.param == DeviceSort::kCub ? "Cub" : "Chapter";
}

// One device sort, its scratch kept across calls as the pipeline keeps it.
class GpuSort : public cftest::NeedsCudaDevice, public ::testing::WithParamInterface<DeviceSort> {
 protected:
  void sort(const uint32_t* keys_in, const uint32_t* values_in, uint32_t* keys_out,
            uint32_t* values_out, std::size_t entries, int key_bits) {
    if (GetParam() == DeviceSort::kCub)
      cuda::radix_sort_cub(keys_in, values_in, keys_out, values_out, entries, key_bits, cub_, 0);
    else
      cuda::radix_sort_chapter(keys_in, values_in, keys_out, values_out, entries, key_bits,
                               chapter_, 0);
  }

  // Sorts `keys` with values = input positions: the result must be std::stable_sort's on the
  // window [0, key_bits) (keys and positions, so stability is checked), and the inputs must be
  // left as they were.
  ::testing::AssertionResult sorts_like_stable_sort(const std::vector<uint32_t>& keys,
                                                    int key_bits) {
    std::vector<uint32_t> values(keys.size());
    std::iota(values.begin(), values.end(), 0u);
    const auto expected = cftest::stable_sorted_with_positions(keys, key_bits);
    cuda::DeviceBuffer<uint32_t> ki, vi, ko(std::max<std::size_t>(keys.size(), 1)),
        vo(std::max<std::size_t>(keys.size(), 1));
    upload(ki, keys);
    upload(vi, values);
    sort(ki.data(), vi.data(), ko.data(), vo.data(), keys.size(), key_bits);
    CF_CUDA_CHECK(cudaDeviceSynchronize());
    const auto k = download(ko, keys.size()), v = download(vo, keys.size());
    const std::string where =
        "n " + std::to_string(keys.size()) + ", key bits " + std::to_string(key_bits);
    for (std::size_t i = 0; i < keys.size(); ++i)
      if (k[i] != expected[i].first || v[i] != expected[i].second)
        return ::testing::AssertionFailure()
               << where << ", at " << i << ": got (key " << k[i] << ", position " << v[i]
               << "), std::stable_sort (key " << expected[i].first << ", position "
               << expected[i].second << ")";
    if (download(ki, keys.size()) != keys || download(vi, keys.size()) != values)
      return ::testing::AssertionFailure() << where << ": the input arrays were modified";
    return ::testing::AssertionSuccess();
  }

  cuda::DeviceBuffer<std::byte> cub_;
  cuda::ChapterSortScratch chapter_;
};

std::vector<uint32_t> random_keys(std::size_t n, uint64_t bound, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::vector<uint32_t> k(n);
  for (auto& x : k) x = uint32_t(bound ? rng() % bound : rng());  // bound 0: all 32 bits
  return k;
}

TEST_P(GpuSort, EmptyAndSingle) {
  EXPECT_TRUE(sorts_like_stable_sort({}, 8));
  EXPECT_TRUE(sorts_like_stable_sort({42}, 8));
  EXPECT_TRUE(sorts_like_stable_sort({0xffffffffu}, 32));
  EXPECT_TRUE(sorts_like_stable_sort({3}, 1));
}

TEST_P(GpuSort, AllKeysEqual) {
  EXPECT_TRUE(sorts_like_stable_sort(std::vector<uint32_t>(10007, 5u), 9));
  EXPECT_TRUE(sorts_like_stable_sort(std::vector<uint32_t>(5000, 0xffffffffu), 17));
  EXPECT_TRUE(sorts_like_stable_sort(std::vector<uint32_t>(4096, 0u), 32));
}

// 31- and 32-bit windows over keys using every bit, 0 and all ones included.
TEST_P(GpuSort, KeysUsingEveryBit) {
  for (std::size_t n : {20011u, 262147u}) {
    std::vector<uint32_t> wide = random_keys(n, 0, n);
    wide[3] = 0;
    wide[4] = 0xffffffffu;
    wide[n - 1] = 0x80000000u;
    EXPECT_TRUE(sorts_like_stable_sort(wide, 31));
    EXPECT_TRUE(sorts_like_stable_sort(wide, 32));
  }
}

// Windows giving one to four passes of 8 bits or fewer, odd and even counts; the bits above the
// window are random and must be carried, not compared (small windows: many equal keys).
TEST_P(GpuSort, EveryPassCount) {
  std::vector<uint32_t> keys = random_keys(70001, 0, 4);
  keys[10] = 0xffffffffu;
  keys[70000] = 0xffffffffu;
  for (int bits : {1, 7, 8, 9, 16, 17, 24, 25, 31, 32})
    EXPECT_TRUE(sorts_like_stable_sort(keys, bits));
}

// Sizes around the warp, the block and the chapter sort's 4096-key tile, and a large odd one.
TEST_P(GpuSort, SizesNotMultiplesOfTheTile) {
  for (std::size_t n : {2u, 31u, 32u, 33u, 255u, 256u, 257u, 4095u, 4096u, 4097u, 8193u, 65537u,
                        1000003u})
    EXPECT_TRUE(sorts_like_stable_sort(random_keys(n, 1000, n), 10));
  EXPECT_TRUE(sorts_like_stable_sort(random_keys(1000003, 1u << 17, 6), 17));
}

// Keys as stage 1 writes them (below 2^key_bits - 1, and kInvalidCell): every
// invalid entry sorts after every valid one, in input order.
TEST_P(GpuSort, InvalidEntriesSortLast) {
  constexpr int kBits = 13;
  std::mt19937_64 rng(8);
  std::vector<uint32_t> keys(300007);
  std::size_t invalid = 0;
  for (auto& k : keys) {
    k = rng() % 4 == 0 ? 0xffffffffu : uint32_t(rng() % ((1u << kBits) - 1));
    invalid += k == 0xffffffffu;
  }
  ASSERT_TRUE(sorts_like_stable_sort(keys, kBits));
  // The oracle agrees; say it directly too.
  std::vector<uint32_t> values(keys.size());
  std::iota(values.begin(), values.end(), 0u);
  cuda::DeviceBuffer<uint32_t> ki, vi, ko(keys.size()), vo(keys.size());
  upload(ki, keys);
  upload(vi, values);
  sort(ki.data(), vi.data(), ko.data(), vo.data(), keys.size(), kBits);
  CF_CUDA_CHECK(cudaDeviceSynchronize());
  const auto k = download(ko, keys.size()), v = download(vo, keys.size());
  const std::size_t first_invalid = keys.size() - invalid;
  for (std::size_t i = 0; i < keys.size(); ++i) {
    ASSERT_EQ(k[i] == 0xffffffffu, i >= first_invalid) << "at " << i;
    if (i > first_invalid) ASSERT_LT(v[i - 1], v[i]) << "invalid entries out of order at " << i;
  }
}

// Few distinct keys spread over 28 bits (four passes): equal keys must keep their input order
// through every pass, not only the last.
TEST_P(GpuSort, StableThroughEveryPass) {
  const uint32_t distinct[] = {0x0000001u, 0x0000080u, 0x0004000u, 0x0200000u, 0x8000000u,
                               0x8000001u, 0x0204080u, 0xfffffffu, 0x0000000u, 0x5555555u,
                               0xaaaaaaau, 0x0010000u, 0x0001000u, 0x0100001u, 0x7ffffffu,
                               0x0000fffu};
  std::mt19937_64 rng(9);
  std::vector<uint32_t> keys(300007);
  for (auto& k : keys) k = distinct[rng() % 16];
  EXPECT_TRUE(sorts_like_stable_sort(keys, 28));
}

// One scratch through growing, shrinking and differently wide sorts: nothing left from an earlier
// call may leak into a later one.
TEST_P(GpuSort, ScratchReusedAcrossCalls) {
  EXPECT_TRUE(sorts_like_stable_sort(random_keys(1000003, 1u << 17, 10), 17));
  EXPECT_TRUE(sorts_like_stable_sort(random_keys(257, 0, 11), 32));
  EXPECT_TRUE(sorts_like_stable_sort(random_keys(70001, 0, 12), 9));
  EXPECT_TRUE(sorts_like_stable_sort(random_keys(1, 0, 13), 3));
  EXPECT_TRUE(sorts_like_stable_sort(random_keys(1000003, 0, 14), 31));
}

TEST_P(GpuSort, MoreThanInt32MaxEntriesThrows) {
  EXPECT_THROW(sort(nullptr, nullptr, nullptr, nullptr, std::size_t(INT32_MAX) + 1, 8), Error);
}

INSTANTIATE_TEST_SUITE_P(DeviceSorts, GpuSort,
                         ::testing::Values(DeviceSort::kCub, DeviceSort::kChapter), sort_name);

TEST_F(GpuStages, ChapterSortRejectsKeyBitsOutside1To32) {
  cuda::ChapterSortScratch scratch;
  for (int bits : {0, -1, 33})
    EXPECT_THROW(cuda::radix_sort_chapter(nullptr, nullptr, nullptr, nullptr, 10, bits, scratch, 0),
                 Error)
        << "key bits " << bits;
}

}  // namespace
