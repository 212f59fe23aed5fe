// Stage 3, collision cells (GPU Gems 3 ch. 32, section 32.2.5): a scan of the sorted keys for the
// transitions between cells. A cell with at least one H occupant and at least two occupants is a
// collision cell; since H keys sort before P keys, its H entries come first.
#include <algorithm>

#include "cpu/stages.h"

namespace cellforce::cpu {

void find_collision_cells(const uint32_t* sorted_keys, std::size_t valid, int slab_bits,
                          std::vector<CollisionCell>& cells) {
  cells.clear();
  std::size_t begin = 0;
  while (begin < valid) {
    const uint32_t cell = key_cell(sorted_keys[begin], slab_bits);
    std::size_t end = begin, h = 0;
    while (end < valid && key_cell(sorted_keys[end], slab_bits) == cell) {
      h += !key_is_phantom(sorted_keys[end], slab_bits);
      ++end;
    }
    const std::size_t total = end - begin;
    if (h >= 1 && total >= 2)
      cells.push_back({uint32_t(begin), uint32_t(h), uint32_t(total - h), cell});
    begin = end;
  }
}

void split_by_type(const Grid& grid, std::vector<CollisionCell>& cells,
                   std::vector<std::size_t>& type_start) {
  const int types = grid.num_types();
  std::stable_sort(cells.begin(), cells.end(), [&](const CollisionCell& a, const CollisionCell& b) {
    return cell_type_of_id(grid, a.cell) < cell_type_of_id(grid, b.cell);
  });
  type_start.assign(std::size_t(types) + 1, 0);
  for (const auto& c : cells) ++type_start[cell_type_of_id(grid, c.cell) + 1];
  for (int t = 0; t < types; ++t) type_start[t + 1] += type_start[t];
}

}  // namespace cellforce::cpu
