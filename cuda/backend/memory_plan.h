// The CUDA engine's memory policy for a build, as a plain host function: which of a build's arrays
// share room with arrays that are dead at the time (the lean memory mode, the count pass's masks
// lending their room to the sort) and which builds a CUDA graph replays. The room of the pair
// list's own arrays is search/list_build.h's (plan_mask_room, plan_list_room). The engine
// (backend/structure_build.cu) applies it to the device's numbers; the unit tests
// (tests/memory_plan_test.cpp) check it without a GPU. Plain C++: built with or without CUDA.
#pragma once

#include <cstddef>

#include "core/engine_options.h"  // ListMemory, lists_memory

namespace cellforce::cuda {

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
