// Stage 4, traversal (GPU Gems 3 ch. 32, section 32.2.5): each collision cell tests every H
// occupant against every other occupant, H and P, skips the pairs that the control-bit rule
// assigns to another cell, and evaluates Lennard-Jones directly for pairs with r < rc (the narrow
// phase). Occupants are staged per cell (the CPU analogue of shared memory) with coordinates
// relative to the cell centre, formed in double: r_ij keeps its digits far from the origin, and
// with two or more cells per periodic axis the staged images are already the nearest ones, so the
// pair loop wraps only along a periodic axis that has a single cell.
//
// Everything a scene may leave out (2D vs 3D, wrap, multiple types, cutoff mode, energy, virial,
// ghost particles) is a template parameter, chosen once per evaluation by dispatch(). With ghosts
// (Local: compute_local), entries whose particle index is n_local or more are ghosts: a pair of
// two ghosts is skipped before it is tested, a cell holding only ghosts is not staged, and energy
// and virial go to per-particle slots (half of each pair to each side) instead of the cells'
// totals, so that the totals are the locals' sums (accumulate_local).
//
// This header holds the templates; traversal_{single,mixed,double}.cpp instantiate them, one
// precision per file so that the builds run in parallel.
#pragma once

#include "core/cell_totals.h"
#include "cpu/traversal.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <type_traits>

#include "core/lj.h"

namespace cellforce::cpu {
namespace detail {

template <int D, bool Wrap, bool MultiType, CutoffMode Mode, bool Energy, bool Virial, bool Local>
struct Traits {
  static constexpr int kDim = D;
  static constexpr bool kWrap = Wrap;
  static constexpr bool kMultiType = MultiType;
  static constexpr CutoffMode kMode = Mode;
  static constexpr bool kEnergy = Energy;
  static constexpr bool kVirial = Virial;
  static constexpr bool kLocal = Local;
};

template <class F>
void with_bool(bool b, F&& f) {
  if (b) f(std::true_type{});
  else f(std::false_type{});
}

// Turns the run-time choices into one Traits instantiation.
template <class F>
void dispatch(int dim, bool wrap, bool multi, CutoffMode mode, bool energy, bool virial, bool local, F&& f) {
  auto with_mode = [&](auto d, auto w, auto m) {
    auto go = [&](auto cm) {
      with_bool(energy, [&](auto e) {
        with_bool(virial, [&](auto v) {
          with_bool(local, [&](auto l) {
            f(Traits<decltype(d)::value, decltype(w)::value, decltype(m)::value, decltype(cm)::value,
                     decltype(e)::value, decltype(v)::value, decltype(l)::value>{});
          });
        });
      });
    };
    switch (mode) {
      case CutoffMode::kTruncate: go(std::integral_constant<CutoffMode, CutoffMode::kTruncate>{}); break;
      case CutoffMode::kShift: go(std::integral_constant<CutoffMode, CutoffMode::kShift>{}); break;
      case CutoffMode::kForceShift: go(std::integral_constant<CutoffMode, CutoffMode::kForceShift>{}); break;
    }
  };
  auto with_dim = [&](auto d) {
    with_bool(wrap, [&](auto w) { with_bool(multi, [&](auto m) { with_mode(d, w, m); }); });
  };
  if (dim == 2) with_dim(std::integral_constant<int, 2>{});
  else with_dim(std::integral_constant<int, 3>{});
}

// One collision cell's occupants, staged: entry e is sorted position start + e.
template <class Real, class Accum>
struct CellStage {
  std::vector<uint32_t> index;  // particle index (user order)
  std::vector<Control> control;
  std::vector<uint32_t> type;
  std::vector<Real> pos[kMaxDim];   // relative to the cell centre (hi part for float)
  std::vector<Real> low[kMaxDim];   // float pairs: the lo part (StagedCoordinate)
  std::vector<Accum> force[kMaxDim];
  std::vector<Accum> energy;
  std::vector<Accum> virial[kVirialComponents];  // Local: each occupant's half of its pairs' virials

  // P entries, grouped by home type: group t is entries group[t] .. group[t + 1] - 1.
  uint32_t group[kMaxCellTypes + 1];

  void load(const TraversalInput& in, const CollisionCell& cell, int dim) {
    const std::size_t m = std::size_t(cell.h) + cell.p;
    if (index.size() < m) {
      index.resize(m);
      control.resize(m);
      type.resize(m);
      for (int a = 0; a < kMaxDim; ++a) {
        pos[a].resize(m);
        if constexpr (StagedCoordinate<Real>::kCompensated) low[a].resize(m);
        force[a].resize(m);
      }
      energy.resize(m);
      for (auto& w : virial) w.resize(m);
    }
    int k[kMaxDim];
    cell_coords(in.grid, cell.cell, k);
    double center[kMaxDim];
    for (int a = 0; a < dim; ++a) center[a] = cell_center(in.grid, a, k[a]);
    // H entries keep their sorted order; P entries are placed stably by home type (a counting
    // sort), so that the control-bit rule is decided once per group instead of once per pair.
    const int types = 1 << dim;
    uint32_t next[kMaxCellTypes + 1] = {};
    for (uint32_t e = cell.h; e < m; ++e) ++next[home_type(in.control[in.sorted_ids[cell.start + e]]) + 1];
    next[0] = cell.h;
    for (int t = 0; t < types; ++t) next[t + 1] += next[t];
    for (int t = 0; t <= types; ++t) group[t] = next[t];
    const double* x = in.system.positions;
    for (uint32_t e = 0; e < m; ++e) {
      const uint32_t i = in.sorted_ids[cell.start + e];
      const Control c = in.control[i];
      const uint32_t to = e < cell.h ? e : next[home_type(c)]++;
      index[to] = i;
      control[to] = c;
      type[to] = in.system.types ? in.system.types[i] : 0u;
      for (int a = 0; a < dim; ++a) {
        const auto v = StagedCoordinate<Real>::from(
            relative_coordinate(in.grid, a, x[std::size_t(i) * dim + a], center[a]));
        pos[a][to] = v.hi;
        if constexpr (StagedCoordinate<Real>::kCompensated) low[a][to] = v.lo;
      }
    }
  }
};

// The candidate loop shared by the force traversal and the pair recorder: H x H pairs once, H x P
// pairs unless the control-bit rule skips them. visit(a, b, d, r2) gets d = x_a - x_b.
// For an H occupant a, skip_pair depends on a P occupant b only through b's home type (a's home
// type is the cell's type, and b's mask always holds b's home type), so the rule is applied once
// per group of P occupants with one home type, with a stand-in control word for the group.
// Local: occupants whose index is n_local or more are ghosts, and a pair of two is never tested.
template <int D, bool Wrap, bool Local, class Real, class Stage, class Visit>
inline void for_each_candidate(const Stage& s, const CollisionCell& cell, unsigned cell_type,
                               const Real* length, const Real* inv_length, std::size_t n_local,
                               Visit&& visit) {
  const uint32_t h = cell.h;
  auto test = [&](uint32_t a, uint32_t b) {
    Real d[D];
    Real r2 = 0;
    for (int c = 0; c < D; ++c) {
      Real v = s.pos[c][a] - s.pos[c][b];
      if constexpr (StagedCoordinate<Real>::kCompensated) v += s.low[c][a] - s.low[c][b];
      if constexpr (Wrap) v = minimum_image(v, length[c], inv_length[c]);
      d[c] = v;
      r2 += v * v;
    }
    visit(a, b, d, r2);
  };
  for (uint32_t a = 0; a < h; ++a) {
    // Local: with a ghost at a, the partners b that are ghosts too are left out.
    const bool ghost_a = Local && s.index[a] >= n_local;
    auto partner = [&](uint32_t b) {
      if constexpr (Local)
        if (ghost_a && s.index[b] >= n_local) return;
      test(a, b);
    };
    for (uint32_t b = a + 1; b < h; ++b) partner(b);  // both at home: same type, never skipped
    for (unsigned t = 0; t < (1u << D); ++t) {
      if (skip_pair(cell_type, s.control[a], make_control(t, 1u << t))) continue;
      for (uint32_t b = s.group[t]; b < s.group[t + 1]; ++b) partner(b);
    }
  }
}

// Local: whether every occupant of `cell` is a ghost (the cell then has no pair to evaluate).
inline bool only_ghosts(const TraversalInput& in, const CollisionCell& cell) {
  const std::size_t m = std::size_t(cell.h) + cell.p;
  for (std::size_t e = 0; e < m; ++e)
    if (in.sorted_ids[cell.start + e] < in.n_local) return false;
  return true;
}

// Writes one cell's staged sums to the occupants' slots (Jacobi: slot `type`, written by this cell
// only, condition 1; Gauss-Seidel: added to the single accumulator) and its totals to cell ci.
template <class T, class Real, class Accum, class Totals>
void store_cell(const CellStage<Real, Accum>& s, uint32_t m, std::size_t ci, unsigned type, std::size_t n,
                bool jacobi, const Totals& totals, Accumulators<Accum>& out) {
  constexpr int D = T::kDim;
  constexpr bool kVirials = T::kLocal && T::kVirial;  // per particle, in Local mode
  Accum* force = out.force.data() + (jacobi ? std::size_t(type) * n * D : 0);
  Accum* energy = T::kEnergy ? out.energy.data() + (jacobi ? std::size_t(type) * n : 0) : nullptr;
  Accum* virial = kVirials ? out.virial.data() + (jacobi ? std::size_t(type) * n * kVirialComponents : 0) : nullptr;
  auto put = [jacobi](Accum& slot, Accum v) {
    if (jacobi) slot = v;
    else slot += v;
  };
  for (uint32_t e = 0; e < m; ++e) {
    const std::size_t i = s.index[e];
    for (int c = 0; c < D; ++c) put(force[i * D + c], s.force[c][e]);
    if constexpr (T::kEnergy) put(energy[i], s.energy[e]);
    if constexpr (kVirials)
      for (int k = 0; k < kVirialComponents; ++k) put(virial[i * kVirialComponents + k], s.virial[k][e]);
  }
  if constexpr (T::kEnergy && !T::kLocal) out.cell_energy[ci] = totals.v[0];
  if constexpr (T::kVirial && !T::kLocal)
    for (int k = 0; k < kVirialComponents; ++k) out.cell_virial[ci * kVirialComponents + k] = totals.v[1 + k];
}

// Adds a pair's virial r_ab (x) f_ab = fr d (x) d, half to each side, to a and b's staged slots
// (components as kVirialComponents orders them).
template <int D, class Real, class Accum>
inline void add_pair_virial(CellStage<Real, Accum>& s, uint32_t a, uint32_t b, Real fr, const Real* d) {
  const Real h = Real(0.5) * fr;
  Real w[kVirialComponents] = {h * d[0] * d[0], h * d[1] * d[1], 0, h * d[0] * d[1], 0, 0};
  if constexpr (D == 3) {
    w[2] = h * d[2] * d[2];
    w[4] = h * d[0] * d[2];
    w[5] = h * d[1] * d[2];
  }
  for (int k = 0; k < kVirialComponents; ++k) {
    s.virial[k][a] += Accum(w[k]);
    s.virial[k][b] += Accum(w[k]);
  }
}

template <class T, class Real, class Accum>
TraversalReport run(const TraversalInput& in, Accumulation mode, Accumulators<Accum>& out) {
  constexpr int D = T::kDim;
  const Grid& g = in.grid;
  const std::size_t n = in.system.n;
  const std::size_t nt = in.ff.num_types();
  const std::vector<LJParams<Real>> table = make_pair_table<Real>(in.ff);
  const Real rc2 = Real(in.ff.cutoff) * Real(in.ff.cutoff);
  Real length[kMaxDim], inv_length[kMaxDim];
  wrap_lengths(g, length, inv_length);
  const bool jacobi = mode == Accumulation::kJacobi;

  TraversalReport report;
  const std::size_t ncells = in.cells.size();
  const int passes = jacobi ? 1 : g.num_types();

#pragma omp parallel
  {
    CellStage<Real, Accum> s;
    TraversalReport local;
    for (int pass = 0; pass < passes; ++pass) {
      const std::size_t lo = jacobi ? 0 : in.type_start[pass];
      const std::size_t hi = jacobi ? ncells : in.type_start[pass + 1];
      // Gauss-Seidel: cells of one type share no particle, and the loop's barrier ends the pass.
#pragma omp for schedule(dynamic, 1)
      for (std::size_t ci = lo; ci < hi; ++ci) {
        const CollisionCell& cell = in.cells[ci];
        if constexpr (T::kLocal)
          if (only_ghosts(in, cell)) continue;  // its slots keep the zeros traverse() gave them
        const uint32_t m = cell.h + cell.p;
        s.load(in, cell, D);
        for (int a = 0; a < D; ++a) std::fill_n(s.force[a].begin(), m, Accum(0));
        if constexpr (T::kEnergy) std::fill_n(s.energy.begin(), m, Accum(0));
        if constexpr (T::kLocal && T::kVirial)
          for (auto& w : s.virial) std::fill_n(w.begin(), m, Accum(0));
        CellTotals<Accum, T::kEnergy && !T::kLocal, T::kVirial && !T::kLocal> totals;  // core/cell_totals.h
        const unsigned type = cell_type_of_id(g, cell.cell);
        local.max_occupancy = std::max<std::size_t>(local.max_occupancy, m);

        for_each_candidate<D, T::kWrap, T::kLocal>(
            s, cell, type, length, inv_length, in.n_local,
            [&](uint32_t a, uint32_t b, const Real* d, Real r2) {
              ++local.candidates;
              const LJParams<Real>& p = T::kMultiType ? table[s.type[a] * nt + s.type[b]] : table[0];
              Real fr, e = 0;
              if (!lj_pair<T::kMode, T::kEnergy>(r2, rc2, p, fr, e)) return;
              ++local.interacting;
              if (!std::isfinite(fr)) [[unlikely]] {
                const uint32_t i = std::min(s.index[a], s.index[b]), j = std::max(s.index[a], s.index[b]);
                if (!local.bad || std::make_pair(i, j) < std::make_pair(local.bad_i, local.bad_j)) {
                  local.bad = true;
                  local.bad_i = i;
                  local.bad_j = j;
                  local.bad_r2 = double(r2);
                }
              }
              for (int c = 0; c < D; ++c) {
                const Real f = fr * d[c];
                s.force[c][a] += f;
                s.force[c][b] -= f;
              }
              if constexpr (T::kEnergy) {
                const Accum half = Accum(Real(0.5) * e);
                s.energy[a] += half;
                s.energy[b] += half;
              }
              if constexpr (T::kLocal && T::kVirial) add_pair_virial<D>(s, a, b, fr, d);
              if constexpr (!T::kLocal) totals.template add<D>(e, fr, d);
            });
        totals.finish();
        store_cell<T>(s, m, ci, type, n, jacobi, totals, out);
      }
    }
#pragma omp critical(cellforce_traversal_report)
    {
      report.candidates += local.candidates;
      report.interacting += local.interacting;
      report.max_occupancy = std::max(report.max_occupancy, local.max_occupancy);
      if (local.bad && (!report.bad || std::make_pair(local.bad_i, local.bad_j) <
                                           std::make_pair(report.bad_i, report.bad_j))) {
        report.bad = true;
        report.bad_i = local.bad_i;
        report.bad_j = local.bad_j;
        report.bad_r2 = local.bad_r2;
      }
    }
  }
  return report;
}

}  // namespace detail

template <class Real, class Accum>
TraversalReport traverse(const TraversalInput& in, const Request& request, Accumulation mode,
                         Accumulators<Accum>& out) {
  const Grid& g = in.grid;
  const std::size_t n = in.system.n, dim = std::size_t(g.dim);
  const std::size_t copies = mode == Accumulation::kJacobi ? std::size_t(g.num_types()) : 1;
  // Local: energies and virials per particle (the totals are the locals' sums), none per cell.
  const bool cells = !in.local;
  out.force.assign(copies * n * dim, Accum(0));
  out.energy.assign(request.energy ? copies * n : 0, Accum(0));
  out.virial.assign(in.local && request.virial ? copies * n * kVirialComponents : 0, Accum(0));
  out.cell_energy.assign(cells && request.energy ? in.cells.size() : 0, Accum(0));
  out.cell_virial.assign(cells && request.virial ? in.cells.size() * kVirialComponents : 0, Accum(0));
  TraversalReport report;
  detail::dispatch(g.dim, g.any_wrap_inside_cell(), in.ff.num_types() > 1, in.ff.mode, request.energy,
                   request.virial, in.local,
                   [&](auto traits) { report = detail::run<decltype(traits), Real, Accum>(in, mode, out); });
  return report;
}

}  // namespace cellforce::cpu
