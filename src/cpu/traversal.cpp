// Stage 4, traversal: the pair recorder used by the coverage tests; with ghosts (in.local) it skips
// the pairs of two ghosts as the force traversal does. The force traversal itself is in
// traversal_impl.h (see there for how it maps to the chapter), instantiated per precision in
// traversal_{single,mixed,double}.cpp.
#include "cpu/traversal_impl.h"

namespace cellforce::cpu {

using detail::CellStage;
using detail::for_each_candidate;
using detail::with_bool;

std::vector<std::pair<uint32_t, uint32_t>> traverse_pairs(const TraversalInput& in) {
  std::vector<std::pair<uint32_t, uint32_t>> pairs;
  const double rc2 = in.ff.cutoff * in.ff.cutoff;
  double length[kMaxDim], inv_length[kMaxDim];
  wrap_lengths(in.grid, length, inv_length);
  CellStage<double, double> s;
  auto scan = [&](auto dim, auto wrap, auto local) {
    for (const CollisionCell& cell : in.cells) {
      s.load(in, cell, decltype(dim)::value);
      const unsigned type = cell_type_of_id(in.grid, cell.cell);
      for_each_candidate<decltype(dim)::value, decltype(wrap)::value, decltype(local)::value>(
          s, cell, type, length, inv_length, in.n_local, [&](uint32_t a, uint32_t b, const double*, double r2) {
            if (r2 < rc2)
              pairs.emplace_back(std::min(s.index[a], s.index[b]), std::max(s.index[a], s.index[b]));
          });
    }
  };
  with_bool(in.grid.any_wrap_inside_cell(), [&](auto wrap) {
    with_bool(in.local, [&](auto local) {
      if (in.grid.dim == 2) scan(std::integral_constant<int, 2>{}, wrap, local);
      else scan(std::integral_constant<int, 3>{}, wrap, local);
    });
  });
  return pairs;
}

}  // namespace cellforce::cpu
