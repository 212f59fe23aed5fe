// The stages of the CPU pipeline and the arrays that flow between them, in the order of
// GPU Gems 3 ch. 32, section 32.2: cell IDs (32.2.2) -> sort (32.2.3-32.2.4) -> collision cells
// (32.2.5) -> traversal (the narrow phase) -> accumulation of the Jacobi slots.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "core/grid.h"
#include "core/system.h"

namespace cellforce::cpu {

// Stage 1 output. Entry e = i * 2^d + t belongs to particle i: t = 0 is its H cell, t > 0 a P
// cell (see bin_particle). Keys are sort_key()'s ((cell ID << 1 | phantom) << slab bits | slab), so
// that a sort by key puts every cell's H entries before its P entries, each group by slab;
// kInvalidCell marks an unused entry.
struct CellIdArrays {
  std::vector<uint32_t> keys;        // n * 2^d; after the sort: sorted_keys
  std::vector<uint32_t> object_ids;  // n * 2^d particle index (user order); after the sort: in cell order
  std::vector<Control> control;      // n, user order: home type and touched types
  std::size_t valid = 0;             // entries that are not kInvalidCell (a reduction)
};

void build_cell_ids(const Grid& grid, const SystemView& system, CellIdArrays& out);

// Stage 2: stable LSD radix sort of (keys, values) on the low key_bits bits, in the chapter's three
// phases per digit: tabulate digit counts per thread block of the input, prefix-sum them in
// (digit, block) order, reorder each block stably. Scratch buffers are grown as needed.
struct SortScratch {
  std::vector<uint32_t> keys, values;
  std::vector<std::size_t> counts;
};
void radix_sort(std::vector<uint32_t>& keys, std::vector<uint32_t>& values, int key_bits,
                SortScratch& scratch);

using cellforce::CollisionCell;

// Scans the first `valid` sorted keys (sort_key(), the grid's slab_bits) for transitions and lists
// the collision cells in cell order.
void find_collision_cells(const uint32_t* sorted_keys, std::size_t valid, int slab_bits,
                          std::vector<CollisionCell>& cells);

// Reorders `cells` so that cells of type 0 come first, then type 1, ... (stable), and writes the
// start of each type's run to type_start[0 .. 2^d] (for the Gauss-Seidel passes).
void split_by_type(const Grid& grid, std::vector<CollisionCell>& cells,
                   std::vector<std::size_t>& type_start);

}  // namespace cellforce::cpu
