#include "backend/memory_plan.h"

#include <algorithm>
#include <cstdint>

namespace cellforce::cuda {

BuildMemoryPlan plan_build_memory(const BuildMemoryInputs& in) {
  BuildMemoryPlan p;
  if (in.listed) {
    p.lean = lists_memory(in.memory, in.n, in.device_bytes) == ListMemory::kLean;
    p.lend = p.lean && in.cub_sort && in.list_words >= in.lent_need_words;
  }
  const bool keep_room = p.lean && in.was_lean && in.entries == in.last_entries && p.lend;
  p.give_up_masks = (p.lean || in.was_lean) && !keep_room;
  const std::size_t mask_words = p.give_up_masks ? 0 : in.mask_words;  // the room the build finds
  const bool masks_to_come = in.listed && !p.lean && in.cub_sort && in.masks_allowed;
  p.lend_masks = masks_to_come && mask_words >= in.lent_need_words;
  p.free_after_sort = masks_to_come && !p.lend_masks && mask_words == 0;
  p.graphed = in.graph_allowed && in.listed && !p.lean && in.cub_sort && in.n > 0;
  return p;
}


}  // namespace cellforce::cuda
