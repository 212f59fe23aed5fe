// The uniform grid of GPU Gems 3 ch. 32 (section 32.1.2), restated for a cutoff search: geometry,
// cell coordinates and IDs, cell types (parity per axis) and the control bits of section 32.1.3.
// The conditions that make the search exact are in ../shared/design/spatial-subdivision.md;
// plan_grid() chooses a grid that meets them and check_grid() refuses one that does not.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>

#include <cellforce/options.hpp>  // Precision

#include "core/box.h"
#include "core/hd.h"

namespace cellforce {

inline constexpr uint32_t kInvalidCell = 0xffffffffu;  // unused P-cell entry, as in the chapter
inline constexpr int kMaxCellTypes = 1 << kMaxDim;

// Largest grid plan_grid() builds. Cells are never allocated (the structure is sorted entries),
// but the sort key's (cell ID << 1 | phantom) part must fit 31 bits.
inline constexpr uint64_t kMaxCells = uint64_t(1) << 30;

// Most bits of a particle's slab (below) in the sort key.
inline constexpr int kMaxSlabBits = 3;

// The rule that bounds the cell edge from below (condition 3 of the design note).
enum class CellRule : uint8_t {
  kTight,    // c >= rc + h (about 1.707 rc): exact, proven by the tests
  kChapter,  // c >= 1.5 * 2h (about 2.12 rc): the chapter's own, more conservative bound
};

struct GridOptions {
  CellRule rule = CellRule::kTight;
  // h / rc. Coverage needs h >= rc / sqrt(2); the default adds 1e-6 relative so that rounding in
  // the binning of a particle cannot drop a pair at distance just under rc (the narrow phase's
  // strict r < rc test decides what interacts, so a wider box only adds candidates).
  double half_width_factor = 0.70710678118654752440 * (1.0 + 1e-6);
  // The sort key carries each particle's slab (sort_key()): where pair lists are built
  // from the structure (the CUDA engine sets it), whose force kernel gathers partners by rank. A
  // structure traversed by its cells has no use for the order, and its sort (every step without a
  // skin) no bits to spare for it.
  bool slabs = false;
};

// Plain data, passed by value to kernels. Axes a >= dim have n[a] == 1.
struct Grid {
  int dim = 3;
  uint32_t n[kMaxDim] = {1, 1, 1};          // cells per axis
  double origin[kMaxDim] = {0, 0, 0};       // lower corner: 0 on periodic axes, bbox min on open
  double cell[kMaxDim] = {1, 1, 1};         // edge c_a
  double inv_cell[kMaxDim] = {1, 1, 1};
  double length[kMaxDim] = {0, 0, 0};       // box edge on periodic axes, 0 on open axes
  double inv_length[kMaxDim] = {0, 0, 0};   // 1/L on periodic axes, 0 on open axes
  double half_width = 0;                    // h, half-width of each particle's box
  double half_width_cells[kMaxDim] = {0, 0, 0};  // h / c_a
  uint32_t num_cells = 1;
  int slab_bits = 0;  // bits of the slab in the sort key (0..kMaxSlabBits, 0 without GridOptions::slabs; sort_key())
  int key_bits = 1;   // bits of the sort key; invalid entries sort last

  int num_types() const { return 1 << dim; }
  // An axis with one cell that wraps: pairs inside a cell may need the minimum image there.
  CF_HD bool wraps_inside_cell(int a) const { return inv_length[a] != 0.0 && n[a] == 1; }
  bool any_wrap_inside_cell() const {
    for (int a = 0; a < dim; ++a)
      if (wraps_inside_cell(a)) return true;
    return false;
  }
};

// ---- control bits: home type in bits 0..2, mask of touched types in bits 3..10 ----------------
using Control = uint16_t;
CF_HD Control make_control(unsigned home_type, unsigned type_mask) {
  return Control(home_type | (type_mask << 3));
}
CF_HD unsigned home_type(Control c) { return c & 7u; }
CF_HD unsigned type_mask(Control c) { return c >> 3; }

// The chapter's rule (condition 3): in a cell of type T, skip the pair when one particle's home
// type T' is < T and T' is among the types both particles touch. The pair is then evaluated in
// the cell of type T' that is one particle's home cell, or it is out of range.
CF_HD bool skip_pair(unsigned cell_type, Control a, Control b) {
  const unsigned common = type_mask(a) & type_mask(b);
  const unsigned ta = home_type(a), tb = home_type(b);
  return (ta < cell_type && ((common >> ta) & 1u)) || (tb < cell_type && ((common >> tb) & 1u));
}

// ---- cell coordinates, IDs and types ------------------------------------------------------------
CF_HD uint32_t cell_id(const Grid& g, const int k[kMaxDim]) {
  return uint32_t(k[0]) + g.n[0] * (uint32_t(k[1]) + g.n[1] * uint32_t(k[2]));
}
CF_HD void cell_coords(const Grid& g, uint32_t id, int k[kMaxDim]) {
  k[0] = int(id % g.n[0]);
  id /= g.n[0];
  k[1] = int(id % g.n[1]);
  k[2] = int(id / g.n[1]);
}
CF_HD unsigned cell_type(const int k[kMaxDim]) {
  return unsigned(k[0] & 1) | unsigned(k[1] & 1) << 1 | unsigned(k[2] & 1) << 2;
}
CF_HD unsigned cell_type_of_id(const Grid& g, uint32_t id) {
  int k[kMaxDim];
  cell_coords(g, id, k);
  return cell_type(k);
}
CF_HD double cell_center(const Grid& g, int a, int k) {
  return g.origin[a] + mul_rn(k + 0.5, g.cell[a]);
}

// Position of x relative to a point of a cell along axis a, as the image nearest to that point on
// a periodic axis. Forming r_ij from these keeps the digits a far-from-origin coordinate loses;
// a coordinate outside a periodic box is wrapped exactly first (the point, a cell's centre, is
// inside it), so x = 1e16 in a box of 10 stages as the point it is modulo L. In-box coordinates
// (every MD step's) take wrap_coordinate's one-compare path and stage bit for bit as before.
CF_HD double relative_coordinate(const Grid& g, int a, double x, double point) {
  if (g.inv_length[a] == 0.0) return x - point;
  return minimum_image(wrap_coordinate(x, g.length[a]) - point, g.length[a], g.inv_length[a]);
}

// A staged coordinate in the pair precision. Double pairs take the double value. Float pairs
// take it as hi + lo, hi = float(v) and lo = float(v - hi): the difference of two staged
// coordinates, (hi_a - hi_b) + (lo_a - lo_b), is then the double difference rounded about once
// to float, its error relative to r_ij, not to the distance from the cell centre (which, up to
// c/2 + h ~ 2-6 sigma, cost float pairs a rounding of ~3e-7 sigma per coordinate: forces in a
// perfect lattice of ~1e-5 instead of ~0).
template <class Real>
struct StagedCoordinate {
  Real hi;
  Real lo;
  static constexpr bool kCompensated = false;
  CF_HD static StagedCoordinate from(double v) { return {Real(v), Real(0)}; }
};
template <>
struct StagedCoordinate<float> {
  float hi;
  float lo;
  static constexpr bool kCompensated = true;
  CF_HD static StagedCoordinate from(double v) {
    const float hi = float(v);
    return {hi, float(v - double(hi))};
  }
};

// ---- the sort key (stage 1 writes it, stage 2 sorts it, stage 3 and the traversal read it) -----
// key = (cell ID << 1 | phantom) << slab_bits | slab. Sorted, a cell's H entries come before its P
// entries (the design note's stage 2), and each group runs by slab: the particle's place inside its
// own H cell along the grid's last axis, in 2^slab_bits layers (2-3 bits; fewer only where the cell
// part leaves less than 2 of the key's 32, above 2^28 cells). Ties keep stage 1's order, the
// particles' own. Without the slab a cell's entries would run in the caller's numbering; a
// numbering that is not in space (any after a long run: diffusion mixes a cell's particles within
// a few thousand steps of in.lj) scatters the partners that a warp of consecutive ranks gathers
// (performance.md records the measurement). The slab depends on the particle alone, so the P
// entries that one H cell sends to a neighbour keep their H order there.
CF_HD uint32_t sort_key(const Grid& g, uint32_t cell, bool phantom, uint32_t slab) {
  return ((cell << 1) | uint32_t(phantom)) << g.slab_bits | slab;
}
CF_HD uint32_t key_cell(uint32_t key, int slab_bits) { return key >> (slab_bits + 1); }
CF_HD bool key_is_phantom(uint32_t key, int slab_bits) { return (key >> slab_bits) & 1u; }

// Bins one particle. x is its position (any image on periodic axes). Writes the H cell ID to
// ids[0] and, for t = 1 .. 2^d - 1, the P cell reached by stepping along the axes whose bit is set
// in t, or kInvalidCell where the box does not reach that far; and, where slab is given, the
// particle's slab in its H cell (sort_key()). Returns the control bits. D is the
// grid's dimension (g.dim): with it known at compile time every loop unrolls and every array and
// Grid field is indexed by a constant, so a kernel keeps them in registers (with a run-time
// dimension the CUDA cell-ID kernel would copy the Grid and the arrays to local memory).
template <int D>
CF_HD Control bin_particle_in(const Grid& g, const double x[kMaxDim], uint32_t ids[kMaxCellTypes],
                              uint32_t* slab = nullptr) {
  static_assert(D == 2 || D == 3, "two or three axes");
  int k[kMaxDim] = {0, 0, 0};
  int step[kMaxDim] = {0, 0, 0};  // -1 or +1: the neighbour the box reaches along the axis
  for (int a = 0; a < D; ++a) {
    const double xa = g.inv_length[a] != 0.0 ? wrap_coordinate(x[a], g.length[a]) : x[a];
    const double u = mul_rn(xa - g.origin[a], g.inv_cell[a]);  // rounded alone: f below is u's on both sides
    const int n = int(g.n[a]);
    int ka = int(std::floor(u));
    ka = ka < 0 ? 0 : (ka >= n ? n - 1 : ka);  // a coordinate may round onto the far face
    const double f = u - ka;                    // position inside the cell, in cell units
    const double hc = g.half_width_cells[a];
    int s = 0;
    if (n > 1) {
      if (f <= hc) s = -1;
      else if (1.0 - f <= hc) s = +1;
      const bool periodic = g.inv_length[a] != 0.0;
      if (!periodic && (ka + s < 0 || ka + s >= n)) s = 0;  // nothing beyond an open face
    }
    k[a] = ka;
    step[a] = s;
    if (a == D - 1 && slab) {  // f is in [0, 1] but for rounding; a NaN coordinate takes slab 0
      const uint32_t layers = 1u << g.slab_bits;
      const double l = f * double(layers);
      *slab = !(l > 0.0) ? 0u : (l >= double(layers - 1) ? layers - 1 : uint32_t(l));
    }
  }
  const unsigned home = cell_type(k);
  unsigned mask = 1u << home;
  ids[0] = cell_id(g, k);
  constexpr int kSlots = 1 << D;
  for (int t = 1; t < kSlots; ++t) {
    int kt[kMaxDim] = {k[0], k[1], k[2]};
    bool valid = true;
    for (int a = 0; a < D; ++a) {
      if (!((t >> a) & 1)) continue;
      if (step[a] == 0) valid = false;
      const int n = int(g.n[a]);
      kt[a] = (k[a] + step[a] + n) % n;
    }
    if (valid) {
      ids[t] = cell_id(g, kt);
      mask |= 1u << cell_type(kt);
    } else {
      ids[t] = kInvalidCell;
    }
  }
  return make_control(home, mask);
}

// g.dim is 2 or 3 (a scene, the API and the readers reject any other: validate.cpp, context.cpp).
CF_HD Control bin_particle(const Grid& g, const double x[kMaxDim], uint32_t ids[kMaxCellTypes],
                           uint32_t* slab = nullptr) {
  return g.dim == 2 ? bin_particle_in<2>(g, x, ids, slab) : bin_particle_in<3>(g, x, ids, slab);
}

// ---- collision cells (stage 3, both backends) ---------------------------------------------------
// A collision cell holds at least one H entry and at least two entries in all (section 32.2.5).
struct CollisionCell {
  uint32_t start;  // first entry in sorted order
  uint32_t h;      // H entries: sorted positions start .. start + h - 1
  uint32_t p;      // P entries: sorted positions start + h .. start + h + p - 1
  uint32_t cell;   // cell ID
};

// ---- planning (host) ----------------------------------------------------------------------------

// Chooses the grid for a box, cutoff and (for open axes) the particles' bounding box:
// h = half_width_factor * rc; on a periodic axis the largest even n with L/n >= the rule's minimum
// cell (one cell if even two do not fit); on an open axis cells of at least that edge over the
// particles' extent. The grid is coarsened if it would exceed kMaxCells. positions: n_particles x
// box.dim, row-major, user order; only read on open axes.
// With skin > 0 (reuse, core/reuse.h) the grid is planned for the cutoff rc + skin, and a
// periodic axis that would get two cells too small to hold a particle's box after it moves by
// skin / 2 (c/2 + h + skin/2 >= L/2, so the staged image could flip) gets one cell instead.
Grid plan_grid(const Box& box, double cutoff, const double* positions, std::size_t n_particles,
               const GridOptions& options = {}, double skin = 0.0);

// Builds a grid with the given cells per axis and half-width, without checking any condition:
// for tests that show what breaks when a condition does not hold.
Grid make_grid_unchecked(const Box& box, const uint32_t cells[kMaxDim], double half_width,
                         const double* positions, std::size_t n_particles);

// Refuses a grid whose cells are so large that staging positions relative to their cell centres
// (|x - centre| <= c/2 + h) rounds r_ij by more than the pair precision resolves: coarsening keeps
// a grid of a huge box (edge 5e9, or one particle 5e9 away on an open axis) within kMaxCells with
// cells of ~5e6, where each staged coordinate rounds by ~5e-10 in double. Float pairs resolve
// ulp_float(rc) and take a rounding up to that; double pairs take up to 2^-40 rc (~1e-12 rc, cells
// up to ~8000 rc wide; the double engine's own error is ~1e-16). Throws cellforce::Error naming the
// length at fault and what would help: a skin so far beyond the cutoff that even the finest cells for
// rc + skin are too wide (the skin, the largest one that stages exactly, the box), or a grid that its
// cell limit coarsened (the cutoff, the box edge or the particles' span on an open axis, and the
// cells the cutoff would take). skin and rule: as the grid was planned with (plan_grid, GridOptions).
void check_staging(const Grid& grid, double physical_cutoff, Precision precision, double skin = 0.0,
                   CellRule rule = CellRule::kTight);

// Throws cellforce::Error naming the violated condition (and axis, box, cutoff) when the grid
// does not satisfy the design note's conditions for this cutoff and rule. With skin > 0 the
// coverage and control-bit conditions are checked for rc + skin (minimum image still for rc),
// and on a periodic axis of two or more cells c/2 + h + skin/2 < L/2: a particle that has moved
// skin / 2 since the build is still staged as the image next to its cell.
void check_grid(const Grid& grid, const Box& box, double cutoff, CellRule rule = CellRule::kTight,
                double skin = 0.0);

// Smallest cell edge the rule allows for half-width h and cutoff rc.
double min_cell_edge(CellRule rule, double cutoff, double half_width);

}  // namespace cellforce
