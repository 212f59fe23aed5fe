// Grid planning: picks cell counts that satisfy the conditions of spatial-subdivision.md, and
// refuses grids that do not.
#include "core/grid.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <sstream>

#include "core/engine_options.h"
#include "core/error.h"

namespace cellforce {
namespace {

constexpr const char* kAxisName[kMaxDim] = {"x", "y", "z"};

// The product of the per-axis cell counts, in double: three counts of up to 2^32 overflow a
// 64-bit integer (2^30 cells per axis wrapped to a grid of 0 cells: no pairs, no error), while
// the double product is exact up to 2^53 and only compared with the limit beyond that.
double cell_count(const uint32_t n[kMaxDim]) { return double(n[0]) * double(n[1]) * double(n[2]); }

// Lower corner and extent of the particles along an open axis.
void bounding_interval(const double* positions, std::size_t n, int dim, int a, double& lo,
                       double& extent) {
  double mn = std::numeric_limits<double>::infinity();
  double mx = -mn;
  for (std::size_t i = 0; i < n; ++i) {
    mn = std::min(mn, positions[i * dim + a]);
    mx = std::max(mx, positions[i * dim + a]);
  }
  if (n == 0) mn = mx = 0.0;
  lo = mn;
  extent = mx - mn;
}

// Fills the derived fields (inverse edges, half-width in cell units, cell count, key width).
void finish(Grid& g, bool slabs) {
  for (int a = 0; a < kMaxDim; ++a) {
    g.inv_cell[a] = 1.0 / g.cell[a];
    g.half_width_cells[a] = a < g.dim ? g.half_width * g.inv_cell[a] : 0.0;
  }
  if (cell_count(g.n) > double(kMaxCells)) {
    std::ostringstream s;
    s << "grid of " << g.n[0] << " x " << g.n[1] << " x " << g.n[2] << " cells exceeds the limit of " << kMaxCells;
    throw Error(s.str());
  }
  const uint64_t cells = uint64_t(g.n[0]) * g.n[1] * g.n[2];  // <= 2^30: exact
  g.num_cells = uint32_t(cells);
  // Valid keys' (cell << 1 | phantom) parts are < 2 * num_cells; an invalid entry masked to
  // key_bits is 2^key_bits - 1, which stays above every valid key (whatever its slab) so that
  // invalid entries sort last. The slab takes the bits left free in the sort's last 8-bit digit
  // (CUB's radix sort takes 8 bits a pass), up to kMaxSlabBits; where fewer than 2 are free it takes
  // 2 and the sort one more pass (performance.md records what that costs), within the key's 32 bits
  // (1 above 2^29 cells, 0 at 2^30).
  const int cell_bits = int(std::bit_width(uint64_t(2) * cells));
  const int free_bits = (8 - cell_bits % 8) % 8;
  g.slab_bits = slabs ? std::min({kMaxSlabBits, std::max(free_bits, 2), 32 - cell_bits}) : 0;
  g.key_bits = cell_bits + g.slab_bits;
}

void set_axis_geometry(Grid& g, const Box& box, int a, uint32_t n, double lo, double extent,
                       double min_edge) {
  g.n[a] = n;
  if (box.periodic[a]) {
    g.origin[a] = 0.0;
    g.cell[a] = box.length[a] / n;
    g.length[a] = box.length[a];
    g.inv_length[a] = 1.0 / box.length[a];
  } else {
    g.origin[a] = lo;
    g.cell[a] = std::max(extent / n, min_edge);
    g.length[a] = 0.0;
    g.inv_length[a] = 0.0;
  }
}

// The spacing of doubles at x (x >= 0): what a coordinate staged at distance x from its cell's centre
// rounds by.
double ulp(double x) { return std::nextafter(x, INFINITY) - x; }

// Whether a particle of a periodic axis's cell c, its box of half-width h, moved by up to skin/2
// since the build, stays within half a box edge of the cell centre (staged as the right image).
bool holds_moved_box(double cell, double half_width, double skin, double length) {
  return skin <= 0.0 || 0.5 * cell + half_width + 0.5 * skin < 0.5 * length;
}

}  // namespace

double min_cell_edge(CellRule rule, double cutoff, double half_width) {
  return rule == CellRule::kTight ? cutoff + half_width : 3.0 * half_width;
}

Grid plan_grid(const Box& box, double physical_cutoff, const double* positions,
               std::size_t n_particles, const GridOptions& options, double skin) {
  const double cutoff = physical_cutoff + skin;  // what the structure must hold
  Grid g;
  g.dim = box.dim;
  g.half_width = options.half_width_factor * cutoff;
  const double min_edge = std::max(min_cell_edge(options.rule, cutoff, g.half_width),
                                   2.0 * g.half_width);
  double lo[kMaxDim] = {0, 0, 0}, extent[kMaxDim] = {0, 0, 0};
  uint32_t n[kMaxDim] = {1, 1, 1};
  for (int a = 0; a < box.dim; ++a) {
    if (box.periodic[a]) {
      extent[a] = box.length[a];
      double count = std::floor(box.length[a] / min_edge);
      count = std::min(count, double(kMaxCells));
      uint64_t m = count < 1 ? 1 : uint64_t(count);
      while (m > 1 && box.length[a] / double(m) < min_edge) --m;  // rounding at the boundary
      if (m % 2 == 1) m = m - 1;  // the parity pattern must tile the box
      if (m == 2 && !holds_moved_box(box.length[a] / 2.0, g.half_width, skin, box.length[a])) m = 1;
      n[a] = uint32_t(std::max<uint64_t>(m, 1));
    } else {
      bounding_interval(positions, n_particles, box.dim, a, lo[a], extent[a]);
      const double count = std::min(std::floor(extent[a] / min_edge), double(kMaxCells));
      n[a] = uint32_t(std::max(count, 1.0));
    }
  }
  // Coarsen the axis with the most cells until the grid fits the key (a dilute scene in a huge
  // open box); a larger cell keeps every condition.
  while (cell_count(n) > double(kMaxCells)) {
    int a = int(std::max_element(n, n + box.dim) - n);
    uint32_t m = n[a] / 2;
    if (box.periodic[a] && m > 1 && m % 2 == 1) --m;
    n[a] = std::max<uint32_t>(m, 1);
  }
  for (int a = 0; a < box.dim; ++a) set_axis_geometry(g, box, a, n[a], lo[a], extent[a], min_edge);
  finish(g, options.slabs);
  return g;
}

Grid make_grid_unchecked(const Box& box, const uint32_t cells[kMaxDim], double half_width,
                         const double* positions, std::size_t n_particles) {
  Grid g;
  g.dim = box.dim;
  g.half_width = half_width;
  for (int a = 0; a < box.dim; ++a) {
    double lo = 0, extent = 0;
    if (!box.periodic[a]) bounding_interval(positions, n_particles, box.dim, a, lo, extent);
    set_axis_geometry(g, box, a, std::max<uint32_t>(cells[a], 1), lo, extent, 0.0);
    if (!box.periodic[a] && g.cell[a] <= 0) g.cell[a] = 1.0;  // all particles at one coordinate
  }
  finish(g, false);
  return g;
}

void check_staging(const Grid& g, double physical_cutoff, Precision precision, double skin, CellRule rule) {
  double largest = 0;  // the largest |x - centre| a staged coordinate can have
  int axis = 0;
  for (int a = 0; a < g.dim; ++a)
    if (0.5 * g.cell[a] + g.half_width > largest) largest = 0.5 * g.cell[a] + g.half_width, axis = a;
  const double resolution =
      precision == Precision::kDouble
          ? std::ldexp(physical_cutoff, -40)
          : double(std::nextafter(float(physical_cutoff), INFINITY) - float(physical_cutoff));
  if (ulp(largest) <= resolution) return;

  // Which of the two lengths in c/2 + h is too large: the reach rc + skin itself (cells of the finest
  // edge it allows already round too much: a skin far beyond the cutoff), or the cell edge, which
  // the grid's limit on its cell count widened (a cutoff tiny against the box, or particles far apart
  // on an open axis).
  const double reach = physical_cutoff + skin;
  const double width = g.half_width / reach;  // h / (rc + skin), from the grid options
  const double finest_per_reach = std::max(min_cell_edge(rule, 1.0, width), 2.0 * width);
  const double finest = finest_per_reach * reach;                    // the smallest cell edge allowed
  const double finest_largest = (0.5 * finest_per_reach + width) * reach;  // c/2 + h in such cells
  const std::string resolves = std::string(to_string(precision)) + " pairs resolve at the cutoff";
  std::ostringstream s;
  s.precision(3);
  if (!(ulp(finest_largest) <= resolution)) {  // also a reach so large that the cells overflow
    // The largest reach whose finest cells stage within the resolution: |x - centre| below the
    // power of two where a double's ulp exceeds it.
    const double below = std::ldexp(1.0, std::ilogb(resolution) + 53);
    const double most_skin = below / (0.5 * finest_per_reach + width) - physical_cutoff;
    double widest_edge = 0;
    for (int a = 0; a < g.dim; ++a) widest_edge = std::max(widest_edge, g.length[a]);
    s << "skin " << skin << " is too large: the neighbour structure holds the pairs within rc + skin = " << reach
      << ", in cells at least " << finest << " wide, and positions staged relative to a cell's centre would round "
      << "each r_ij component by up to " << ulp(finest_largest) << ", more than " << resolves << " "
      << physical_cutoff << " (" << resolution << "); a skin here must be below " << most_skin;
    if (widest_edge > 0)
      s << ", and beyond the box (largest periodic edge " << widest_edge << ") it adds nothing: a structure for "
        << "rc + skin >= half the edge already holds every pair along that axis";
    throw Error(s.str());
  }
  // The cells the reach needs along each axis: the box edge on a periodic axis, the particles' span
  // (at most n x c) on an open one.
  double need[kMaxDim] = {1, 1, 1}, extent[kMaxDim] = {0, 0, 0};
  int most = 0;
  for (int a = 0; a < g.dim; ++a) {
    extent[a] = g.inv_length[a] != 0.0 ? g.length[a] : g.cell[a] * g.n[a];
    need[a] = std::max(1.0, std::floor(extent[a] / finest));
    if (need[a] > need[most]) most = a;
  }
  const bool open = g.inv_length[most] == 0.0;
  s << "the cutoff " << physical_cutoff << (skin > 0 ? " (plus skin " : "");
  if (skin > 0) s << skin << ")";
  s << " is too small for the " << (open ? "particles' span" : "box") << ": along " << kAxisName[most] << ", "
    << (open ? "their span " : "its edge ") << extent[most] << (open ? " (an open axis)" : "")
    << " would take " << need[most] << " cells at least " << finest << " wide (" << need[0] * need[1] * need[2]
    << " in all), more than the grid's limit of " << kMaxCells << " cells; coarsened to " << g.n[0] << " x " << g.n[1]
    << " x " << g.n[2] << " cells " << g.cell[axis] << " wide along " << kAxisName[axis]
    << ", positions staged relative to their cell's centre would round each r_ij component by up to " << ulp(largest)
    << ", more than " << resolves << " (" << resolution << "); use a larger cutoff or "
    << (open ? "bring the particles far from the others closer on the open axis" : "a smaller periodic box")
    << (precision == Precision::kDouble ? ", or mixed or single precision" : "");
  throw Error(s.str());
}

void check_grid(const Grid& g, const Box& box, double physical_cutoff, CellRule rule, double skin) {
  const double cutoff = physical_cutoff + skin;  // what the structure must hold
  auto fail = [&](int a, const std::string& what) {
    std::ostringstream s;
    s << "grid violates " << what << " on axis " << kAxisName[a] << " (box edge " << box.length[a]
      << ", cutoff " << physical_cutoff;
    if (skin > 0) s << ", skin " << skin;
    s << ", cells " << g.n[a] << ", cell edge " << g.cell[a] << ", half-width " << g.half_width << ")";
    throw Error(s.str());
  };
  const double kCoverage = cutoff * 0.70710678118654752440;
  if (g.half_width < kCoverage)
    fail(0, skin > 0 ? "coverage (half-width h must be >= (rc + skin)/sqrt(2))"
                     : "coverage (half-width h must be >= rc/sqrt(2))");
  for (int a = 0; a < g.dim; ++a) {
    if (box.periodic[a] && 2.0 * physical_cutoff > box.length[a])
      fail(a, "minimum image (cutoff must be <= half the periodic box edge)");
    if (box.periodic[a] && g.n[a] > 1 && !holds_moved_box(g.cell[a], g.half_width, skin, box.length[a]))
      fail(a, "reuse (c/2 + h + skin/2 must be < L/2 on a periodic axis of two or more cells)");
    if (box.periodic[a] && g.n[a] > 1 && g.n[a] % 2 == 1)
      fail(a, "the parity tiling (cell count on a periodic axis must be even or 1)");
    if (g.n[a] == 1) continue;
    if (2.0 * g.half_width > g.cell[a])
      fail(a, "at most two cells per axis (2h must be <= cell edge)");
    if (g.cell[a] < min_cell_edge(rule, cutoff, g.half_width))
      fail(a, rule == CellRule::kTight
                  ? (skin > 0 ? "the control-bit rule (cell edge must be >= rc + skin + h)"
                              : "the control-bit rule (cell edge must be >= rc + h)")
                  : "the chapter's rule (cell edge must be >= 3h)");
  }
}

}  // namespace cellforce
