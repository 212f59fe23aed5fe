// The CUDA engine's plan for a build, as plain host functions: the traversal form the collision cells
// get, the lists' memory mode, which of a build's arrays share room with arrays that are dead at the
// time (the lean memory mode, the count pass's masks lending their room to the sort) and which
// builds a CUDA graph replays. The room of the pair
// list's own arrays is search/list_build.h's (plan_mask_room, plan_list_room). The engine
// (backend/structure_build.cu) applies it to the device's numbers; the unit tests
// (tests/memory_plan_test.cpp) check it without a GPU. Plain C++: built with or without CUDA.
#pragma once

#include <cstddef>

#include <cellforce/options.hpp>  // TraversalForm, ListMemory

namespace cellforce::cuda {

// traversal = auto: a block per row tile while the collision cells (bounded by min(n, grid cells))
// are at most this many per multiprocessor, else warp per cell: the tile form's lead over warp per
// cell shrinks as the cells per multiprocessor grow and is gone at about this many
// (validation/reports/performance.md records the measurement). A rule of the system and the
// device, not a timing: the choice, and so the bits, are the same on every run.
inline constexpr int kTileCellsPerMultiprocessor = 16;
inline TraversalForm resolve_traversal(TraversalForm form, std::size_t cell_bound, int multiprocessors) {
  if (form != TraversalForm::kAuto) return form;
  return cell_bound <= std::size_t(kTileCellsPerMultiprocessor) * std::size_t(multiprocessors)
             ? TraversalForm::kWarpPerTile
             : TraversalForm::kWarpPerCell;
}

// The memory mode the lists run in for `n` particles on a device of `device_bytes` (0: unknown, or
// no device): as asked, or (auto) lean where the fast layout, about kFastListBytesPerParticle with
// a 0.6 skin and the MD state (a staged array, the sorted arrays, the list, the masks, the gated
// evaluations' forces, a second rank-ordered array and the MD engine's rank-order copy of the state
// side by side, the sort's unsorted arrays and scratch in the masks' room; performance.md records
// the measured bytes per particle), would not fit in 90% of the device. Applied at every build
// (plan_build_memory), and the automatic skin follows it (core/reuse.h resolve_reuse, given the mode
// by cuda_lists_memory). The mode itself changes no result; the skin it leads to changes when the
// builds come and the order of the sums (so the bits), not which pairs are summed.
inline constexpr double kFastListBytesPerParticle = 1320.0;
inline ListMemory lists_memory(ListMemory asked, std::size_t n, std::size_t device_bytes) {
  if (asked != ListMemory::kAuto) return asked;
  return device_bytes > 0 && double(n) * kFastListBytesPerParticle > 0.9 * double(device_bytes) ? ListMemory::kLean
                                                                                                 : ListMemory::kFast;
}

// Words of a dead array (a lean build's last list, or the masks' room) lent to an unsorted array of
// `entries` cell-ID entries: whole 256-byte blocks (the cell-ID kernel stores 16 bytes at a time;
// CUB's scratch wants 256-byte alignment).
constexpr std::size_t lent_words(std::size_t entries) { return (entries + 63) / 64 * 64; }

// The room a build's unsorted keys and IDs and the sort's scratch take when lent: two lent arrays
// of `entries` and the scratch bytes in whole words.
constexpr std::size_t lent_room_words(std::size_t entries, std::size_t sort_scratch_bytes) {
  return 2 * lent_words(entries) + (sort_scratch_bytes + 3) / 4;
}

// What a build knows before it takes memory.
struct BuildMemoryInputs {
  bool listed = false;            // the evaluations walk pair lists (core/reuse.h pair_lists_serve)
  ListMemory memory = ListMemory::kAuto;  // the option
  std::size_t n = 0;
  std::size_t device_bytes = 0;   // the device's memory (0: unknown)
  bool cub_sort = true;           // CUB's radix sort (the chapter's may reuse its input arrays)
  bool was_lean = false;          // the last build ran in lean memory
  std::size_t entries = 0, last_entries = 0;  // this build's cell-ID entries and the last one's
  std::size_t list_words = 0;     // the capacity of the list's array (words)
  std::size_t mask_words = 0;     // the capacity of the masks' room (words)
  std::size_t lent_need_words = 0;  // lent_room_words of this build
  bool masks_allowed = true;      // the count pass keeps masks, and may lend their room (options)
  bool graph_allowed = true;      // a graph may replay the build's fixed part (options: Jacobi slots,
                                  // no audit, no counting of masked units, graphs not switched off)
};

// Where the build's arrays go.
struct BuildMemoryPlan {
  bool lean = false;              // lean memory: no staged occupants, the list's array lent
  bool lend = false;              // lean: the unsorted keys, IDs and scratch in the dead list's array
  bool give_up_masks = false;     // the masks' room is given up before anything else is taken
  bool lend_masks = false;        // fast: the unsorted keys, IDs and scratch in the masks' room
  bool free_after_sort = false;   // fast, no room yet: those arrays freed after the sort
  bool graphed = false;           // the build's fixed part is captured or replayed as a CUDA graph
};

// Lean where asked, or where the fast layout would not fit in 90% of the device (lists_memory). A
// lean build keeps the dead list's array and lends it to the sort's arrays where they fit in it
// (else frees it, so that they have its room). A lean build's masks' room, sized to the memory it
// left, is kept for lean builds of the same size whose arrays are lent, and given up otherwise (a
// new system, the other mode, arrays of their own). A fast build lends the masks' room (dead from
// the fill to the next count pass) to the sort's arrays where it is large enough; a system's first
// build, with no room yet, frees them after its sort so that they and the masks are never held
// together. Graphs serve fast builds with CUB's sort.
BuildMemoryPlan plan_build_memory(const BuildMemoryInputs& in);

}  // namespace cellforce::cuda
