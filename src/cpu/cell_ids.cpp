// Stage 1, cell IDs (GPU Gems 3 ch. 32, section 32.2.2): each particle writes its H cell and up to
// 2^d - 1 P cells (those its box of half-width h reaches) into a cell-ID array of n x 2^d entries,
// with the object-ID array alongside, and its control bits. Invalid entries are marked and the
// valid ones counted by a reduction.
#include <omp.h>

#include "cpu/stages.h"

namespace cellforce::cpu {

void build_cell_ids(const Grid& grid, const SystemView& system, CellIdArrays& out) {
  const int dim = grid.dim;
  const std::size_t slots = std::size_t(1) << dim;
  const std::size_t n = system.n;
  out.keys.resize(n * slots);
  out.object_ids.resize(n * slots);
  out.control.resize(n);
  std::size_t valid = 0;
#pragma omp parallel for schedule(static) reduction(+ : valid)
  for (std::size_t i = 0; i < n; ++i) {
    double x[kMaxDim] = {0, 0, 0};
    for (int a = 0; a < dim; ++a) x[a] = system.positions[i * dim + a];
    uint32_t ids[kMaxCellTypes];
    uint32_t slab = 0;
    out.control[i] = bin_particle(grid, x, ids, &slab);
    for (std::size_t t = 0; t < slots; ++t) {
      const bool ok = ids[t] != kInvalidCell;
      out.keys[i * slots + t] = ok ? sort_key(grid, ids[t], t != 0, slab) : kInvalidCell;
      out.object_ids[i * slots + t] = uint32_t(i);
      valid += ok;
    }
  }
  out.valid = valid;
}

}  // namespace cellforce::cpu
