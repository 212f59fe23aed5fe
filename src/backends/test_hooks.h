// Settings that only tests set. Each forces a choice the engines otherwise make by a rule, or
// switches a mechanism off (or adds a check) to show that it changes no result. The API, scene
// files and the CLI never set them: the engines' options hold them in one member, `test`.
#pragma once

#include <cstddef>
#include <optional>

#include "core/grid.h"

namespace cellforce {

struct EngineTestHooks {
  std::optional<Grid> grid_override;  // this grid, unchecked (both backends)

  // CUDA pair lists (cuda/search/list_build.h states the rules these replace).
  std::optional<int> list_splits;   // the build's column splits per row tile
  std::optional<int> list_threads;  // the force kernel's threads per particle: 1, 2, 4 or 8
  std::optional<int> list_block;    // threads a block (128 or 256) of the force kernel that runs the
                                    // next step's kick-drift
  std::optional<bool> list_masks;   // false: the fill tests every pair again instead of reading the
                                    // count pass's masks
  std::optional<bool> list_lend_masks;         // false: fast memory's unsorted keys, IDs and sort
                                               // scratch keep arrays of their own
  std::optional<std::size_t> list_mask_words;  // the masks' room holds at most this many words
  std::optional<bool> list_count_masked;       // true: count the units each fill writes from masks
                                               // (a wait for the fill)

  // CUDA builds and MD chunks.
  std::optional<bool> build_graph;        // false: the build's fixed part never runs as a CUDA graph
  std::optional<bool> build_graph_audit;  // true: a replayed build's bookkeeping runs under a stream
                                          // capture that must record nothing
  std::optional<bool> gate_notice;        // false: a gated chunk's host waits for the gate's copy at
                                          // its end, not for a shut kernel's notice
  std::optional<bool> device_decides;     // false: compute_device's rebuild is decided on the host at
                                          // every call (a wait), never by the device's call graph
  std::optional<bool> gate_notice_check;  // true: it waits for the copy, and the notice must be there
                                          // exactly where the gate closed, with the copy's values
};

}  // namespace cellforce
