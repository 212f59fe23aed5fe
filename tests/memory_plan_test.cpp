// The CUDA engine's build plan, memory policy and launch rules (cuda/backend/memory_plan.h,
// cuda/search/list_build.h) as host arithmetic: these run without a GPU, on every machine. The
// expected values are worked out by hand from the rules the headers state.
#include <gtest/gtest.h>

#include <cstddef>

#include "backend/memory_plan.h"
#include "search/list_build.h"

namespace cellforce::cuda {
namespace {

constexpr std::size_t kGiB = std::size_t(1) << 30;
constexpr std::size_t kMiB = std::size_t(1) << 20;

// A fast build of a listed system on an 80 GB device, its masks' room ample.
BuildMemoryInputs listed_fast(std::size_t n) {
  BuildMemoryInputs in;
  in.listed = true;
  in.n = n;
  in.device_bytes = 80 * kGiB;
  in.entries = in.last_entries = n << 3;
  in.lent_need_words = lent_room_words(in.entries, 1000);
  in.mask_words = 10 * in.lent_need_words;
  return in;
}

// traversal = auto: the tile form up to kTileCellsPerMultiprocessor collision cells per SM, warp
// per cell beyond; an explicit form is kept whatever the size.
TEST(MemoryPlan, AutoTraversalRule) {
  const std::size_t limit = std::size_t(kTileCellsPerMultiprocessor) * 132;
  EXPECT_EQ(resolve_traversal(TraversalForm::kAuto, 216, 132), TraversalForm::kWarpPerTile);
  EXPECT_EQ(resolve_traversal(TraversalForm::kAuto, limit, 132), TraversalForm::kWarpPerTile);
  EXPECT_EQ(resolve_traversal(TraversalForm::kAuto, limit + 1, 132), TraversalForm::kWarpPerCell);
  EXPECT_EQ(resolve_traversal(TraversalForm::kAuto, 13824, 132), TraversalForm::kWarpPerCell);
  for (TraversalForm f : {TraversalForm::kWarpPerCell, TraversalForm::kThreadPerCell, TraversalForm::kWarpPerTile})
    for (std::size_t cells : {std::size_t(1), limit + 1})
      EXPECT_EQ(resolve_traversal(f, cells, 132), f);
}

// The lists' memory mode (lists_memory): as asked, or (auto) lean exactly where n x 1,320 bytes
// exceeds 90% of the device's memory; fast where the device's memory is unknown (0).
TEST(MemoryPlan, ListsMemoryIsARuleOfTheSystemAndTheDevice) {
  const std::size_t h100 = 85'017'493'504;  // an H100 80GB's total as cudaMemGetInfo gives it
  const std::size_t limit = std::size_t(0.9 * double(h100) / 1320.0);  // the largest fast system (57.97M)
  EXPECT_GT(limit, 56'000'000u);  // performance.md's largest fast run: 55,990,084 particles at 1,290 B/particle
  EXPECT_EQ(lists_memory(ListMemory::kAuto, 16'777'216, h100), ListMemory::kFast);
  EXPECT_EQ(lists_memory(ListMemory::kAuto, limit, h100), ListMemory::kFast);
  EXPECT_EQ(lists_memory(ListMemory::kAuto, limit + 1, h100), ListMemory::kLean);
  EXPECT_EQ(lists_memory(ListMemory::kAuto, 100'000'000, h100), ListMemory::kLean);
  EXPECT_EQ(lists_memory(ListMemory::kAuto, 100'000'000, 0), ListMemory::kFast);
  EXPECT_EQ(lists_memory(ListMemory::kLean, 1'000, h100), ListMemory::kLean);
  EXPECT_EQ(lists_memory(ListMemory::kFast, 100'000'000, h100), ListMemory::kFast);
}

TEST(MemoryPlan, LentWordsAreWhole256ByteBlocks) {
  EXPECT_EQ(lent_words(0), 0u);
  EXPECT_EQ(lent_words(1), 64u);
  EXPECT_EQ(lent_words(64), 64u);
  EXPECT_EQ(lent_words(65), 128u);
  // Two arrays of 100 entries (128 words each) and 1,001 bytes of scratch (251 words).
  EXPECT_EQ(lent_room_words(100, 1001), 2u * 128u + 251u);
}

TEST(MemoryPlan, LeanWhereTheFastLayoutWouldNotFit) {
  BuildMemoryInputs in = listed_fast(1'000'000);
  EXPECT_FALSE(plan_build_memory(in).lean);  // 1.32 GB of 80 GB
  // 90% of the device: n x 1320 bytes > 0.9 x device_bytes.
  in.device_bytes = std::size_t(1'000'000 * kFastListBytesPerParticle / 0.9) - 1000;
  EXPECT_TRUE(plan_build_memory(in).lean);
  in.device_bytes = std::size_t(1'000'000 * kFastListBytesPerParticle / 0.9) + 1000;
  EXPECT_FALSE(plan_build_memory(in).lean);
  in.memory = ListMemory::kLean;  // asked for
  EXPECT_TRUE(plan_build_memory(in).lean);
  in.listed = false;  // no lists: neither mode applies
  EXPECT_FALSE(plan_build_memory(in).lean);
}

TEST(MemoryPlan, LeanLendsTheDeadListWhereTheSortsArraysFit) {
  BuildMemoryInputs in = listed_fast(1000);
  in.memory = ListMemory::kLean;
  in.list_words = in.lent_need_words;
  BuildMemoryPlan p = plan_build_memory(in);
  EXPECT_TRUE(p.lean);
  EXPECT_TRUE(p.lend);
  EXPECT_FALSE(p.graphed);  // graphs serve fast builds only
  in.list_words = in.lent_need_words - 1;
  EXPECT_FALSE(plan_build_memory(in).lend);
  in.list_words = in.lent_need_words;
  in.cub_sort = false;  // the chapter's sort may reuse its input arrays
  EXPECT_FALSE(plan_build_memory(in).lend);
}

TEST(MemoryPlan, LeanKeepsItsMasksRoomOnlyForTheSameSystemLent) {
  BuildMemoryInputs in = listed_fast(1000);
  in.memory = ListMemory::kLean;
  in.list_words = in.lent_need_words;
  in.was_lean = true;
  EXPECT_FALSE(plan_build_memory(in).give_up_masks);  // same entries, lent: kept
  in.last_entries = in.entries + 8;  // another system
  EXPECT_TRUE(plan_build_memory(in).give_up_masks);
  in.last_entries = in.entries;
  in.list_words = 0;  // nothing lent
  EXPECT_TRUE(plan_build_memory(in).give_up_masks);
  in.list_words = in.lent_need_words;
  in.was_lean = false;  // the first lean build after fast mode's room
  EXPECT_TRUE(plan_build_memory(in).give_up_masks);
}

TEST(MemoryPlan, FastLendsTheMasksRoomOrFreesAfterTheSort) {
  BuildMemoryInputs in = listed_fast(1000);
  BuildMemoryPlan p = plan_build_memory(in);
  EXPECT_FALSE(p.lean);
  EXPECT_FALSE(p.give_up_masks);
  EXPECT_TRUE(p.lend_masks);
  EXPECT_FALSE(p.free_after_sort);
  EXPECT_TRUE(p.graphed);
  in.mask_words = in.lent_need_words - 1;  // a room too small (tests' capped rooms): arrays of their own
  p = plan_build_memory(in);
  EXPECT_FALSE(p.lend_masks);
  EXPECT_FALSE(p.free_after_sort);
  in.mask_words = 0;  // a system's first build: no room yet
  p = plan_build_memory(in);
  EXPECT_FALSE(p.lend_masks);
  EXPECT_TRUE(p.free_after_sort);
  // Fast after lean: the lean room is given up first, so the build finds none.
  in.mask_words = 10 * in.lent_need_words;
  in.was_lean = true;
  p = plan_build_memory(in);
  EXPECT_TRUE(p.give_up_masks);
  EXPECT_FALSE(p.lend_masks);
  EXPECT_TRUE(p.free_after_sort);
  in.was_lean = false;
  in.masks_allowed = false;  // no masks: nothing to lend, nothing to free
  p = plan_build_memory(in);
  EXPECT_FALSE(p.lend_masks);
  EXPECT_FALSE(p.free_after_sort);
}

TEST(MemoryPlan, GraphsServeFastListedBuildsWithCubOnly) {
  BuildMemoryInputs in = listed_fast(1000);
  EXPECT_TRUE(plan_build_memory(in).graphed);
  in.graph_allowed = false;
  EXPECT_FALSE(plan_build_memory(in).graphed);
  in.graph_allowed = true;
  in.cub_sort = false;
  EXPECT_FALSE(plan_build_memory(in).graphed);
  in.cub_sort = true;
  in.n = 0;
  EXPECT_FALSE(plan_build_memory(in).graphed);
  in.n = 1000;
  in.listed = false;
  EXPECT_FALSE(plan_build_memory(in).graphed);
}

TEST(MemoryPlan, MaskRoomFast) {
  // 10 GiB free: 1,000,000 words and 1/8 more fit with 640 MiB to spare.
  MaskRoom r = plan_mask_room(1'000'000, false, 10 * kGiB, 0, 0);
  EXPECT_EQ(r.words, 1'125'000u);
  EXPECT_FALSE(r.refused);
  EXPECT_FALSE(r.settled);
  // 512 MiB spare at least: 1,125,000 words (4.5 MB) do not fit in 515 MiB.
  r = plan_mask_room(1'000'000, false, 515 * kMiB, 0, 0);
  EXPECT_EQ(r.words, 0u);
  EXPECT_TRUE(r.refused);
  r = plan_mask_room(1'000'000, false, 10 * kGiB, 500'000, 0);  // a test's cap
  EXPECT_EQ(r.words, 500'000u);
  EXPECT_TRUE(r.refused);
}

TEST(MemoryPlan, MaskRoomLeanHoldsWhatTheFreeMemoryLeaves) {
  // 4 GiB free: the spare is 2 GiB (more than 1/8 of it) and 1 GiB later: 1 GiB = 2^28 words left.
  const std::size_t words = std::size_t(1) << 29;
  MaskRoom r = plan_mask_room(words, true, 4 * kGiB, 0, kGiB);
  EXPECT_EQ(r.words, std::size_t(1) << 28);
  EXPECT_TRUE(r.settled);
  EXPECT_TRUE(r.refused);
  // Less than 1/16 of the demand: none.
  r = plan_mask_room(words, true, 3 * kGiB + 64 * kMiB, 0, kGiB);
  EXPECT_EQ(r.words, 0u);
  // All of it, with 1/8 more, where the free memory holds it.
  r = plan_mask_room(1000, true, 64 * kGiB, 0, 0);
  EXPECT_EQ(r.words, 1125u);
  EXPECT_FALSE(r.settled);
  EXPECT_FALSE(r.refused);
}

TEST(MemoryPlan, ListRoom) {
  // Held by the array it has: nothing to reserve, the free memory not needed.
  ListRoom r = plan_list_room(4000, 1900, 10, 4096, 0, false);
  EXPECT_FALSE(r.declined);
  EXPECT_EQ(r.reserve, 0u);
  // More than twice the pairs and 64 slots a particle: the cells serve.
  r = plan_list_room(4000, 1000, 10, 4096, 0, false);
  EXPECT_TRUE(r.declined);
  // A new array with 1/16 headroom (fast), 1/64 (lean), where twice the spare is left.
  r = plan_list_room(1'600'000, 800'000, 1000, 0, 10 * kGiB, false);
  EXPECT_EQ(r.reserve, 1'700'000u);
  r = plan_list_room(1'600'000, 800'000, 1000, 0, 10 * kGiB, true);
  EXPECT_EQ(r.reserve, 1'625'000u);
  // 1 GiB + 4 MiB free: the list (6.4 MB) fits with 512 MiB spare, but not with twice that and
  // headroom: exactly its size.
  r = plan_list_room(1'600'000, 800'000, 1000, 0, kGiB + 4 * kMiB, false);
  EXPECT_EQ(r.reserve, 1'600'000u);
  // Without 512 MiB to spare after it: declined.
  r = plan_list_room(1'600'000, 800'000, 1000, 0, 512 * kMiB + 6'000'000, false);
  EXPECT_TRUE(r.declined);
}

TEST(ListRules, ThreadsPerParticleFillHalfTheDevice) {
  // 132 multiprocessors: 135,168 threads wanted.
  EXPECT_EQ(list_threads_per_particle(32'000, 132), 8);    // 32,000 x 4 < 135,168
  EXPECT_EQ(list_threads_per_particle(33'792, 132), 4);    // 33,792 x 4 = 135,168
  EXPECT_EQ(list_threads_per_particle(67'584, 132), 2);
  EXPECT_EQ(list_threads_per_particle(135'168, 132), 1);
  EXPECT_EQ(list_threads_per_particle(1, 0), 8);            // an unknown device counts as one
  EXPECT_EQ(list_threads_per_particle(1024, 0), 1);
}

}  // namespace
}  // namespace cellforce::cuda
