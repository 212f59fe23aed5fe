// The grid of spatial-subdivision.md: plan_grid meets the conditions, check_grid refuses each
// broken one, bin_particle bins consistently (faces, box edges, -0.0, -1e-8), and the control-bit
// rule (skip_pair) admits each shared pair exactly once.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "core/box.h"
#include "core/error.h"
#include "core/grid.h"
#include "oracle.h"

namespace cftest {
namespace {

using cellforce::Box;
using cellforce::CellRule;
using cellforce::Control;
using cellforce::Grid;
using cellforce::kInvalidCell;
using cellforce::kMaxCellTypes;
using ::testing::HasSubstr;

constexpr double kSqrtHalf = 0.70710678118654752440;
const double kDefaultFactor = cellforce::GridOptions{}.half_width_factor;

Box periodic_box(int dim, double l) { return cftest::cube(dim, l); }

Grid unchecked(const Box& box, std::array<uint32_t, 3> cells, double h,
               const std::vector<double>& positions = {}) {
  const uint32_t n[3] = {cells[0], cells[1], cells[2]};
  return cellforce::make_grid_unchecked(box, n, h, positions.empty() ? nullptr : positions.data(),
                                        positions.size() / std::size_t(box.dim));
}

// ---- defaults and small helpers ------------------------------------------------------------------

// The default half-width factor is 1/sqrt(2) widened by 1e-6 relative (exact to 1e-15).
TEST(GridOptions, DefaultHalfWidthIsRcOverSqrt2PlusMargin) {
  EXPECT_NEAR(kDefaultFactor, kSqrtHalf * (1 + 1e-6), 1e-15);
  EXPECT_GE(kDefaultFactor, kSqrtHalf);
}

// min_cell_edge: kTight = rc + h, kChapter = 3h = 1.5 * 2h (exact arithmetic, 1e-15 relative).
TEST(MinCellEdge, TightAndChapterRules) {
  EXPECT_NEAR(cellforce::min_cell_edge(CellRule::kTight, 2.5, 1.8), 4.3, 1e-15 * 4.3);
  EXPECT_NEAR(cellforce::min_cell_edge(CellRule::kChapter, 2.5, 1.8), 5.4, 1e-15 * 5.4);
}

// cell_id and cell_coords are inverse on every cell of a 4 x 6 x 2 grid (exact).
TEST(CellIds, IdAndCoordsRoundTrip) {
  const Grid g = unchecked(periodic_box(3, 24), {4, 6, 2}, 1.0);
  ASSERT_EQ(g.num_cells, 48u);
  std::vector<bool> seen(g.num_cells, false);
  for (int z = 0; z < 2; ++z)
    for (int y = 0; y < 6; ++y)
      for (int x = 0; x < 4; ++x) {
        const int k[3] = {x, y, z};
        const uint32_t id = cellforce::cell_id(g, k);
        ASSERT_LT(id, g.num_cells);
        EXPECT_FALSE(seen[id]);
        seen[id] = true;
        int back[3];
        cellforce::cell_coords(g, id, back);
        EXPECT_EQ(back[0], x);
        EXPECT_EQ(back[1], y);
        EXPECT_EQ(back[2], z);
        EXPECT_EQ(cellforce::cell_type(k), unsigned(x & 1) | unsigned(y & 1) << 1 | unsigned(z & 1) << 2);
        EXPECT_EQ(cellforce::cell_type_of_id(g, id), cellforce::cell_type(k));
      }
}

// make_control / home_type / type_mask round-trip for every home type and mask (exact).
TEST(ControlBits, RoundTrip) {
  for (unsigned home = 0; home < 8; ++home)
    for (unsigned mask = 0; mask < 256; ++mask) {
      const Control c = cellforce::make_control(home, mask);
      EXPECT_EQ(cellforce::home_type(c), home);
      EXPECT_EQ(cellforce::type_mask(c), mask);
    }
}

// ---- plan_grid ----------------------------------------------------------------------------------

// The largest even n with L/n >= rc + h, or 1 when two cells do not fit (computed here
// independently; the default factor makes rc + h > 2h, so the tight rule is the binding one).
uint32_t expected_periodic_cells(double l, double rc, double h) {
  const double min_edge = rc + h;
  uint32_t n = uint32_t(std::floor(l / min_edge));
  while (n > 1 && l / n < min_edge) --n;
  if (n % 2 == 1) --n;
  return n < 2 ? 1u : n;
}

// Over a sweep of periodic boxes (2D and 3D, cubic and not) and cutoffs: n is the largest even
// count (or 1) with c >= rc + h; 2h <= c; h >= rc/sqrt(2); n * c == L to 1e-15 relative;
// axes beyond dim have one cell; num_cells is the product; check_grid accepts the plan.
TEST(PlanGrid, PeriodicSweepMeetsConditions) {
  int checked = 0;
  for (int dim : {2, 3})
    for (double rc : {1.0, 2.5, 3.7})
      for (double lx = 2 * rc; lx < 40 * rc; lx *= 1.173) {
        const Box box = cftest::make_box(dim, {lx, 1.31 * lx + 0.5, 2.0 * lx}, {true, true, true});
        const Grid g = cellforce::plan_grid(box, rc, nullptr, 0);
        ASSERT_EQ(g.dim, dim);
        const double h = g.half_width;
        EXPECT_NEAR(h, kDefaultFactor * rc, 1e-15 * rc);
        EXPECT_GE(h, rc * kSqrtHalf);
        uint64_t total = 1;
        for (int a = 0; a < 3; ++a) {
          total *= g.n[a];
          if (a >= dim) {
            EXPECT_EQ(g.n[a], 1u) << "axis " << a;
            continue;
          }
          const double l = box.length[a];
          EXPECT_EQ(g.n[a], expected_periodic_cells(l, rc, h)) << "L " << l << " rc " << rc;
          EXPECT_TRUE(g.n[a] == 1 || g.n[a] % 2 == 0) << "n " << g.n[a];
          EXPECT_NEAR(g.cell[a] * g.n[a], l, 1e-15 * l);
          EXPECT_EQ(g.origin[a], 0.0);
          EXPECT_NEAR(g.inv_length[a], 1.0 / l, 1e-15 / l);
          if (g.n[a] > 1) {
            EXPECT_GE(g.cell[a], rc + h) << "L " << l << " rc " << rc;
            EXPECT_LE(2 * h, g.cell[a]);
            EXPECT_LT(l / (g.n[a] + 2), rc + h) << "a finer even grid would still be exact";
          } else {
            EXPECT_LT(l / 2, rc + h) << "two cells would have fitted";
          }
        }
        EXPECT_EQ(g.num_cells, total);
        EXPECT_NO_THROW(cellforce::check_grid(g, box, rc));
        ++checked;
      }
  EXPECT_GT(checked, 100);
}

// The chapter's rule: c >= 3h on every axis with more than one cell, accepted by check_grid with
// that rule; never finer than the tight rule.
TEST(PlanGrid, ChapterRuleGivesCellsOfAtLeast3h) {
  cellforce::GridOptions opt;
  opt.rule = CellRule::kChapter;
  for (double l = 6.0; l < 100; l *= 1.21) {
    const Box box = periodic_box(3, l);
    const Grid g = cellforce::plan_grid(box, 2.5, nullptr, 0, opt);
    const Grid tight = cellforce::plan_grid(box, 2.5, nullptr, 0);
    for (int a = 0; a < 3; ++a) {
      if (g.n[a] > 1) {
        EXPECT_GE(g.cell[a], 3 * g.half_width) << "L " << l;
      }
      EXPECT_TRUE(g.n[a] == 1 || g.n[a] % 2 == 0);
      EXPECT_LE(g.n[a], tight.n[a]);
    }
    EXPECT_NO_THROW(cellforce::check_grid(g, box, 2.5, CellRule::kChapter));
  }
}

// One cell per axis when two do not fit: rc = L/2 exactly (legal), and L = 8 with rc = 2.5
// (two cells would need L >= 2 (rc + h) = 8.54).
TEST(PlanGrid, OneCellWhenBoxTooSmallForTwo) {
  for (int dim : {2, 3})
    for (auto [l, rc] : {std::pair{5.0, 2.5}, std::pair{8.0, 2.5}, std::pair{10.0, 5.0}}) {
      const Box box = periodic_box(dim, l);
      const Grid g = cellforce::plan_grid(box, rc, nullptr, 0);
      for (int a = 0; a < dim; ++a) {
        EXPECT_EQ(g.n[a], 1u) << dim << "D L " << l << " rc " << rc;
        EXPECT_NEAR(g.cell[a], l, 1e-15 * l);
        EXPECT_TRUE(g.wraps_inside_cell(a));
      }
      EXPECT_EQ(g.num_cells, 1u);
      EXPECT_NO_THROW(cellforce::check_grid(g, box, rc));
    }
}

// Two cells once L >= 2 (rc + h) (L = 9, rc = 2.5).
TEST(PlanGrid, TwoCellsOnceTheyFit) {
  const Box box = periodic_box(3, 9.0);
  const Grid g = cellforce::plan_grid(box, 2.5, nullptr, 0);
  for (int a = 0; a < 3; ++a) EXPECT_EQ(g.n[a], 2u);
  EXPECT_FALSE(g.any_wrap_inside_cell());
}

// Open axes: the cells cover the particles' bounding box (origin <= min, origin + n c >= max,
// 1e-12 relative slack), c >= rc + h where n > 1, no wrap (inv_length == 0, length == 0);
// mixed with periodic axes (slab).
TEST(PlanGrid, OpenAxesCoverBoundingBox) {
  for (auto periodic : {std::array<bool, 3>{false, false, false},
                        std::array<bool, 3>{true, true, false}}) {
    const Box box = cftest::make_box(3, {20, 20, 20}, periodic);
    Rng rng(3);
    std::vector<double> pos;
    for (int i = 0; i < 300; ++i)
      for (int a = 0; a < 3; ++a) pos.push_back(rng.uniform(-3.0, 17.0) * (a == 2 ? 2.0 : 1.0));
    const Grid g = cellforce::plan_grid(box, 2.5, pos.data(), 300);
    for (int a = 0; a < 3; ++a) {
      if (periodic[std::size_t(a)]) {
        EXPECT_NE(g.inv_length[a], 0.0);
        continue;
      }
      double mn = INFINITY, mx = -INFINITY;
      for (int i = 0; i < 300; ++i) {
        mn = std::min(mn, pos[std::size_t(3 * i + a)]);
        mx = std::max(mx, pos[std::size_t(3 * i + a)]);
      }
      EXPECT_LE(g.origin[a], mn) << "axis " << a;
      EXPECT_GE(g.origin[a] + g.n[a] * g.cell[a], mx * (1 - 1e-12)) << "axis " << a;
      EXPECT_EQ(g.inv_length[a], 0.0);
      EXPECT_EQ(g.length[a], 0.0);
      EXPECT_GT(g.n[a], 1u);
      EXPECT_GE(g.cell[a], 2.5 + g.half_width);
    }
    EXPECT_NO_THROW(cellforce::check_grid(g, box, 2.5));
  }
}

// An open axis where every particle has the same coordinate: one cell of positive, finite edge,
// and binning still gives a valid cell.
TEST(PlanGrid, OpenAxisOfZeroExtent) {
  const Box box = cftest::make_box(2, {10, 10, 1}, {false, false, false});
  const std::vector<double> pos = {1.0, 4.0, 2.0, 4.0, 7.0, 4.0};  // y == 4 for all
  const Grid g = cellforce::plan_grid(box, 1.0, pos.data(), 3);
  EXPECT_EQ(g.n[1], 1u);
  EXPECT_GT(g.cell[1], 0.0);
  EXPECT_TRUE(std::isfinite(g.inv_cell[1]));
  uint32_t ids[kMaxCellTypes];
  for (int i = 0; i < 3; ++i) {
    cellforce::bin_particle(g, &pos[std::size_t(2 * i)], ids);
    EXPECT_LT(ids[0], g.num_cells);
  }
}

// ---- check_grid: every broken condition is refused with cellforce::Error -------------------------

// Coverage: h = rc/2 (c = 5 >= rc + h = 3.75 and 2h <= c hold; only coverage is broken).
TEST(CheckGrid, RejectsHalfWidthRcOver2) {
  const Box box = periodic_box(3, 20);
  EXPECT_THROW(cellforce::check_grid(unchecked(box, {4, 4, 4}, 1.25), box, 2.5), cellforce::Error);
  EXPECT_NO_THROW(cellforce::check_grid(unchecked(box, {4, 4, 4}, kDefaultFactor * 2.5), box, 2.5));
}

// Exactly-once rule: c = 4 < rc + h = 4.27 with rc = 2.5, h = rc/sqrt(2) (2h = 3.54 <= c holds).
TEST(CheckGrid, RejectsCellSmallerThanRcPlusH) {
  const Box box = periodic_box(3, 16);
  const double h = kDefaultFactor * 2.5;
  EXPECT_THROW(cellforce::check_grid(unchecked(box, {4, 4, 4}, h), box, 2.5), cellforce::Error);
  EXPECT_NO_THROW(cellforce::check_grid(unchecked(box, {2, 2, 2}, h), box, 2.5));
}

// The chapter's rule refuses what the tight rule accepts: c = 5 >= rc + h but < 3h = 5.30.
TEST(CheckGrid, ChapterRuleRejectsCellBelow3h) {
  const Box box = periodic_box(3, 20);
  const Grid g = unchecked(box, {4, 4, 4}, kDefaultFactor * 2.5);
  EXPECT_NO_THROW(cellforce::check_grid(g, box, 2.5, CellRule::kTight));
  EXPECT_THROW(cellforce::check_grid(g, box, 2.5, CellRule::kChapter), cellforce::Error);
}

// At most two cells per axis: h = 3, rc = 2.5, c = 5.75 >= rc + h = 5.5 but 2h = 6 > c.
TEST(CheckGrid, RejectsTwiceHalfWidthAboveCell) {
  const Box box = periodic_box(3, 23);
  EXPECT_THROW(cellforce::check_grid(unchecked(box, {4, 4, 4}, 3.0), box, 2.5), cellforce::Error);
}

// Parity tiling: 5 cells (edge 6 >= rc + h) on a periodic axis is refused, 6 or 4 accepted, on
// any one axis.
TEST(CheckGrid, RejectsOddCellCountOnPeriodicAxis) {
  const Box box = periodic_box(3, 30);
  const double h = kDefaultFactor * 2.5;
  EXPECT_THROW(cellforce::check_grid(unchecked(box, {5, 6, 6}, h), box, 2.5), cellforce::Error);
  EXPECT_THROW(cellforce::check_grid(unchecked(box, {6, 6, 5}, h), box, 2.5), cellforce::Error);
  EXPECT_THROW(cellforce::check_grid(unchecked(box, {3, 6, 6}, h), box, 2.5), cellforce::Error);
  EXPECT_NO_THROW(cellforce::check_grid(unchecked(box, {6, 6, 6}, h), box, 2.5));
  EXPECT_NO_THROW(cellforce::check_grid(unchecked(box, {4, 6, 2}, h), box, 2.5));
}

// Parity needs no tiling on an open axis: 3 cells of edge 6 over particles spanning [0, 18].
TEST(CheckGrid, AcceptsOddCellCountOnOpenAxis) {
  const Box box = cftest::make_box(3, {18, 18, 18}, {false, false, false});
  const std::vector<double> pos = {0, 0, 0, 18, 18, 18};
  const Grid g = unchecked(box, {3, 3, 3}, kDefaultFactor * 2.5, pos);
  EXPECT_EQ(g.n[0], 3u);
  EXPECT_NO_THROW(cellforce::check_grid(g, box, 2.5));
}

// Minimum image: rc = 5.5 > L/2 = 5 is refused, and the message names the cutoff and the box;
// rc = L/2 exactly is legal.
TEST(CheckGrid, RejectsCutoffAboveHalfBox) {
  const Box box = periodic_box(3, 10);
  const Grid g = unchecked(box, {1, 1, 1}, kDefaultFactor * 5.5);
  try {
    cellforce::check_grid(g, box, 5.5);
    ADD_FAILURE() << "check_grid accepted rc = 5.5 in a box of edge 10";
  } catch (const cellforce::Error& e) {
    EXPECT_THAT(lowercase(e.what()), HasSubstr("cutoff"));
    EXPECT_THAT(lowercase(e.what()), HasSubstr("box"));
  }
  EXPECT_NO_THROW(cellforce::check_grid(unchecked(box, {1, 1, 1}, kDefaultFactor * 5.0), box, 5.0));
}

// ---- bin_particle -------------------------------------------------------------------------------

// Checks everything bin_particle promises for one point, independently of how it computes it:
// ids in range or kInvalidCell; the home cell contains the point (1e-9 cell slack, or clamped at a
// far face); the valid P slots are exactly the non-empty subsets of the axes the box steps along,
// each one cell away (mod n on periodic axes) along exactly those axes, in one direction per axis;
// a step happens iff the box of half-width h reaches that face (1e-9 h slack either way) and the
// neighbour exists; the home type and mask equal the types of the listed cells.
::testing::AssertionResult binning_consistent(const Grid& g, const double* x) {
  uint32_t ids[kMaxCellTypes];
  for (auto& id : ids) id = 0xdeadbeefu;
  const Control ctrl = cellforce::bin_particle(g, x, ids);
  auto fail = [&] {
    auto out = ::testing::AssertionFailure() << "x = (";
    for (int a = 0; a < g.dim; ++a) out << (a ? ", " : "") << x[a];
    return out << "): ";
  };
  if (ids[0] >= g.num_cells) return fail() << "home id " << ids[0] << " >= " << g.num_cells;
  int home[3];
  cellforce::cell_coords(g, ids[0], home);
  if (cellforce::home_type(ctrl) != cellforce::cell_type(home))
    return fail() << "home type " << cellforce::home_type(ctrl) << " != cell type "
                  << cellforce::cell_type(home);
  int step[3] = {0, 0, 0};
  for (int a = 0; a < g.dim; ++a) {
    const bool periodic = g.inv_length[a] != 0.0;
    const double xa = periodic ? cellforce::wrap_coordinate(x[a], g.length[a]) : x[a];
    if (!(xa >= 0.0 || !periodic) || (periodic && xa >= g.length[a]))
      return fail() << "wrapped coordinate " << xa << " outside [0, L)";
    const double lo = g.origin[a] + home[a] * g.cell[a];
    const double hi = lo + g.cell[a];
    const double slack = 1e-9 * g.cell[a];
    const bool last = home[a] == int(g.n[a]) - 1;
    if (xa < lo - slack || (xa > hi + slack && !(last && !periodic)))
      return fail() << "axis " << a << ": " << xa << " not in home cell [" << lo << ", " << hi << "]";
    // the single-axis slot tells the step along this axis
    const uint32_t id = ids[1 << a];
    if (id != kInvalidCell) {
      if (id >= g.num_cells) return fail() << "slot " << (1 << a) << " id " << id << " out of range";
      int k[3];
      cellforce::cell_coords(g, id, k);
      const int n = int(g.n[a]);
      if (k[a] == (home[a] + 1) % n) step[a] = +1;
      else if (k[a] == (home[a] - 1 + n) % n) step[a] = -1;
      else return fail() << "slot " << (1 << a) << " is not a neighbour along axis " << a;
      if (n == 2) step[a] = (xa - lo < hi - xa) ? -1 : +1;  // both neighbours are one cell
      if (!periodic && (home[a] + step[a] < 0 || home[a] + step[a] >= n))
        return fail() << "open axis " << a << " wraps";
    }
    const double h = g.half_width;
    const bool near_lo = xa - lo <= h * (1 - 1e-9), near_hi = hi - xa <= h * (1 - 1e-9);
    const bool far_lo = xa - lo > h * (1 + 1e-9), far_hi = hi - xa > h * (1 + 1e-9);
    const bool lo_exists = periodic ? g.n[a] > 1 : home[a] > 0;
    const bool hi_exists = periodic ? g.n[a] > 1 : home[a] < int(g.n[a]) - 1;
    const bool reaches = (near_lo && lo_exists) || (near_hi && hi_exists);
    const bool cannot = (far_lo || !lo_exists) && (far_hi || !hi_exists);
    if (reaches && id == kInvalidCell) return fail() << "box reaches a face on axis " << a << " but no P cell";
    if (cannot && id != kInvalidCell) return fail() << "P cell on axis " << a << " the box does not reach";
  }
  unsigned mask = 1u << cellforce::cell_type(home);
  for (int t = 1; t < (1 << g.dim); ++t) {
    bool expect_valid = true;
    for (int a = 0; a < g.dim; ++a)
      if (((t >> a) & 1) && ids[1 << a] == kInvalidCell) expect_valid = false;
    if (expect_valid != (ids[t] != kInvalidCell))
      return fail() << "slot " << t << " validity does not follow its axes";
    if (ids[t] == kInvalidCell) continue;
    if (ids[t] >= g.num_cells) return fail() << "slot " << t << " id out of range";
    int k[3];
    cellforce::cell_coords(g, ids[t], k);
    for (int a = 0; a < g.dim; ++a) {
      const int n = int(g.n[a]);
      const int want = ((t >> a) & 1) ? (home[a] + step[a] + n) % n : home[a];
      if (k[a] != want) return fail() << "slot " << t << " axis " << a << ": cell " << k[a] << ", expected " << want;
    }
    mask |= 1u << cellforce::cell_type(k);
  }
  for (int t = 1 << g.dim; t < kMaxCellTypes; ++t)
    if (g.dim < 3 && ids[t] != 0xdeadbeefu && ids[t] != kInvalidCell)
      return fail() << "slot " << t << " beyond 2^d written with a cell";
  if (cellforce::type_mask(ctrl) != mask)
    return fail() << "type mask " << cellforce::type_mask(ctrl) << ", expected " << mask;
  return ::testing::AssertionSuccess();
}

struct BinCase {
  const char* name;
  Box box;
  double rc;
};

std::vector<double> special_values(const Grid& g, int a, bool periodic, double l) {
  std::vector<double> v = {0.0, -0.0, l, std::nextafter(l, 0.0)};
  if (periodic) v.insert(v.end(), {-1e-8, -1e-300, -l, 2 * l, 1e3 * l + 0.5, -1e-8 - 7 * l});
  for (uint32_t k = 0; k <= g.n[a]; ++k) {
    const double f = g.origin[a] + k * g.cell[a];
    for (double x : {f, std::nextafter(f, -INFINITY), std::nextafter(f, INFINITY), f + 1e-12,
                     f - 1e-12, f + g.half_width, f - g.half_width, f + 0.5 * g.cell[a]})
      if (periodic || (x >= g.origin[a] && x <= g.origin[a] + l)) v.push_back(x);
  }
  return v;
}

// Every combination of special values (faces, faces +- 1 ulp, +- 1e-12, +- h, centres, 0, -0.0,
// L, nextafter(L, 0), -1e-8, -1e-300, far images) plus 2000 random points, on periodic, open
// and slab grids in 2D and 3D: binning_consistent for each.
TEST(BinParticle, ConsistentOnFacesEdgesAndRandomPoints) {
  const BinCase cases[] = {
      {"periodic3d", periodic_box(3, 20), 2.5},
      {"periodic2d", periodic_box(2, 20), 2.5},
      {"periodic3d_uneven", cftest::make_box(3, {9, 13, 21}, {true, true, true}), 2.5},
      {"two_cells", periodic_box(3, 9), 2.5},
      {"one_cell", periodic_box(3, 5), 2.5},
      {"open3d", cftest::make_box(3, {20, 20, 20}, {false, false, false}), 2.5},
      {"slab3d", cftest::make_box(3, {20, 20, 20}, {true, true, false}), 2.5},
      {"slab2d", cftest::make_box(2, {20, 20, 1}, {true, false, false}), 2.5},
  };
  for (const BinCase& c : cases) {
    const int d = c.box.dim;
    std::vector<double> corners(std::size_t(2 * d));
    for (int a = 0; a < d; ++a) corners[std::size_t(d + a)] = c.box.length[a];
    const Grid g = cellforce::plan_grid(c.box, c.rc, corners.data(), 2);
    std::vector<std::vector<double>> values;
    for (int a = 0; a < d; ++a) values.push_back(special_values(g, a, c.box.periodic[a], c.box.length[a]));
    std::size_t total = 1;
    for (const auto& v : values) total *= v.size();
    double x[3] = {0, 0, 0};
    for (std::size_t idx = 0; idx < total; ++idx) {
      std::size_t r = idx;
      for (int a = 0; a < d; ++a) {
        x[a] = values[std::size_t(a)][r % values[std::size_t(a)].size()];
        r /= values[std::size_t(a)].size();
      }
      ASSERT_TRUE(binning_consistent(g, x)) << c.name;
    }
    Rng rng(5);
    for (int i = 0; i < 2000; ++i) {
      for (int a = 0; a < d; ++a) x[a] = rng.uniform(0.0, c.box.length[a]);
      ASSERT_TRUE(binning_consistent(g, x)) << c.name;
    }
  }
}

// Images of one point bin identically (ids and control bits exact): x = L and x = 0, x = -0.0
// and x = 0, x + k L for k = -3 .. 3 (dyadic L so that x + kL is exact).
TEST(BinParticle, PeriodicImagesBinIdentically) {
  const Box box = periodic_box(3, 16);
  const Grid g = cellforce::plan_grid(box, 2.5, nullptr, 0);
  auto bin = [&](double x0, double x1, double x2) {
    std::vector<uint32_t> ids(kMaxCellTypes);
    const double x[3] = {x0, x1, x2};
    const Control c = cellforce::bin_particle(g, x, ids.data());
    ids.push_back(c);
    return ids;
  };
  EXPECT_EQ(bin(16.0, 3.0, 16.0), bin(0.0, 3.0, 0.0));
  EXPECT_EQ(bin(-0.0, -0.0, -0.0), bin(0.0, 0.0, 0.0));
  for (int k = -3; k <= 3; ++k)
    EXPECT_EQ(bin(1.25 + 16.0 * k, 7.5, 15.0 - 16.0 * k), bin(1.25, 7.5, 15.0)) << "k " << k;
}

// x = -1e-8 is the last cell (wrapped to L - 1e-8), and its box reaches cell 0 across the
// boundary; x = -1e-300 wraps to exactly L in double, which is mapped to 0: cell 0.
TEST(BinParticle, TinyNegativeCoordinates) {
  const Box box = periodic_box(3, 20);
  const Grid g = cellforce::plan_grid(box, 2.5, nullptr, 0);
  ASSERT_EQ(g.n[0], 4u);
  uint32_t ids[kMaxCellTypes];
  const double x[3] = {-1e-8, 2.5, 2.5};
  cellforce::bin_particle(g, x, ids);
  int k[3];
  cellforce::cell_coords(g, ids[0], k);
  EXPECT_EQ(k[0], 3);
  ASSERT_NE(ids[1], kInvalidCell);
  cellforce::cell_coords(g, ids[1], k);
  EXPECT_EQ(k[0], 0);
  const double y[3] = {-1e-300, 2.5, 2.5};
  cellforce::bin_particle(g, y, ids);
  cellforce::cell_coords(g, ids[0], k);
  EXPECT_EQ(k[0], 0);
}

// On a dyadic grid (L = 16, 4 cells of edge 4, exact arithmetic) a point on face k is in cell
// k (mod n), and its box (h = 1.77 < c/2) reaches cell k - 1.
TEST(BinParticle, ExactFacesBelongToTheUpperCell) {
  const Box box = periodic_box(2, 16);
  const Grid g = unchecked(box, {4, 4, 1}, kDefaultFactor * 2.5);
  for (int face = 0; face <= 4; ++face) {
    const double x[3] = {4.0 * face, 2.0, 0.0};
    uint32_t ids[kMaxCellTypes];
    cellforce::bin_particle(g, x, ids);
    int k[3];
    cellforce::cell_coords(g, ids[0], k);
    EXPECT_EQ(k[0], face % 4) << "face " << face;
    ASSERT_NE(ids[1], kInvalidCell);
    cellforce::cell_coords(g, ids[1], k);
    EXPECT_EQ(k[0], (face + 3) % 4) << "face " << face;
  }
}

// Open axes: the bounding-box maximum lies in the last cell (clamped), the minimum in the first,
// and neither has a P cell beyond the open face.
TEST(BinParticle, OpenAxisExtremes) {
  const Box box = cftest::make_box(3, {20, 20, 20}, {false, false, false});
  const std::vector<double> pos = {-3, -3, -3, 17, 17, 17};
  const Grid g = cellforce::plan_grid(box, 2.5, pos.data(), 2);
  ASSERT_GT(g.n[0], 1u);
  uint32_t ids[kMaxCellTypes];
  int k[3];
  cellforce::bin_particle(g, &pos[3], ids);
  cellforce::cell_coords(g, ids[0], k);
  for (int a = 0; a < 3; ++a) EXPECT_EQ(k[a], int(g.n[a]) - 1);
  for (int t = 1; t < 8; ++t) EXPECT_EQ(ids[t], kInvalidCell) << "slot " << t;
  cellforce::bin_particle(g, &pos[0], ids);
  cellforce::cell_coords(g, ids[0], k);
  for (int a = 0; a < 3; ++a) EXPECT_EQ(k[a], 0);
  for (int t = 1; t < 8; ++t) EXPECT_EQ(ids[t], kInvalidCell) << "slot " << t;
}

// ---- box helpers ------------------------------------------------------------------------------------

// wrap_coordinate lands in [0, L) in double and in float, including the float pitfall x = -1e-8
// (which rounds to exactly L) and far images; minimum_image lands in [-L/2, L/2] and leaves open
// axes (inv_length 0) untouched (exact).
TEST(BoxHelpers, WrapAndMinimumImage) {
  for (double l : {1.0, 7.3, 20.0}) {
    for (double x : {-1e-8, -1e-300, -0.0, 0.0, l, std::nextafter(l, 0.0), -l, 3.5 * l, -1e5 * l - 0.1}) {
      const double w = cellforce::wrap_coordinate(x, l);
      EXPECT_GE(w, 0.0) << x;
      EXPECT_LT(w, l) << x;
      const float lf = float(l);
      const float wf = cellforce::wrap_coordinate(float(x), lf);
      EXPECT_GE(wf, 0.0f) << x;
      EXPECT_LT(wf, lf) << x;
    }
    for (double dx : {-0.51 * l, 0.49 * l, 3.2 * l, -7.7 * l}) {
      const double m = cellforce::minimum_image(dx, l, 1.0 / l);
      EXPECT_LE(std::fabs(m), 0.5 * l * (1 + 1e-15)) << dx;
      EXPECT_EQ(cellforce::minimum_image(dx, l, 0.0), dx);
    }
  }
}

// ---- skip_pair: the control-bit rule ----------------------------------------------------------------

// Hand cases of spatial-subdivision.md condition 3.
TEST(SkipPair, HandCases) {
  using cellforce::make_control;
  using cellforce::skip_pair;
  const Control a = make_control(0, 0b11);  // home type 0, touches 0 and 1
  const Control b = make_control(1, 0b11);  // home type 1, touches 0 and 1
  EXPECT_FALSE(skip_pair(0, a, b));  // evaluated in the type-0 cell (a's home)
  EXPECT_TRUE(skip_pair(1, a, b));   // skipped in the type-1 cell: type 0 < 1 is shared
  const Control c = make_control(1, 0b10);  // home 1, touches only type 1
  EXPECT_FALSE(skip_pair(1, a, c));  // type 0 is not common: the type-1 cell is the only one
  EXPECT_FALSE(skip_pair(0, a, make_control(0, 0b1)));  // same home cell
  const Control d = make_control(5, (1u << 5) | (1u << 4) | (1u << 1));
  const Control e = make_control(4, (1u << 4) | (1u << 5));
  EXPECT_FALSE(skip_pair(4, d, e));
  EXPECT_TRUE(skip_pair(5, d, e));
}

// Exhaustive over every 3D control pair (home t in its mask): among the cell types T where the
// pair can meet as an H occupant (T in common and T is one of the two home types), skip_pair lets
// exactly one through, the smaller; none when no home type is common. skip_pair is symmetric.
TEST(SkipPair, ExactlyOnceOverAllControls) {
  std::vector<Control> controls;
  for (unsigned home = 0; home < 8; ++home)
    for (unsigned mask = 0; mask < 256; ++mask)
      if ((mask >> home) & 1u) controls.push_back(cellforce::make_control(home, mask));
  std::size_t failures = 0;
  for (Control a : controls)
    for (Control b : controls) {
      const unsigned common = cellforce::type_mask(a) & cellforce::type_mask(b);
      unsigned meets = 0;
      for (unsigned h : {cellforce::home_type(a), cellforce::home_type(b)})
        if ((common >> h) & 1u) meets |= 1u << h;
      unsigned admitted = 0;
      for (unsigned t = 0; t < 8; ++t) {
        if (!((meets >> t) & 1u)) continue;
        if (cellforce::skip_pair(t, a, b) != cellforce::skip_pair(t, b, a)) ++failures;
        if (!cellforce::skip_pair(t, a, b)) admitted |= 1u << t;
      }
      const unsigned want = meets ? (meets & (~meets + 1u)) : 0u;  // lowest set bit
      if (admitted != want) ++failures;
    }
  EXPECT_EQ(failures, 0u);
}

}  // namespace
}  // namespace cftest
