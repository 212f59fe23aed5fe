// Reuse of the neighbour structure: the rebuild policy, the displacement since the last build,
// and the audit's own pair search and coverage count.
#include "core/reuse.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "core/error.h"
#include "core/hd.h"

namespace cellforce {

void validate_reuse(const ReuseOptions& o) {
  if (!std::isfinite(o.skin) || o.skin < 0) {
    std::ostringstream s;
    s << "skin " << o.skin << ": expected a finite length >= 0 (0 rebuilds on every evaluation)";
    throw Error(s.str());
  }
  if (o.every < 0)
    throw Error("every " + std::to_string(o.every) + ": expected a count >= 0 (0: no limit)");
}

bool pair_lists_serve(const ReuseOptions& r, Accumulation accumulation, const Box& box, double cutoff) {
  if (!r.list || !(r.skin > 0) || accumulation != Accumulation::kJacobi) return false;
  for (int a = 0; a < box.dim; ++a)
    if (box.periodic[a] && 2.0 * (cutoff + r.skin) > box.length[a]) return false;
  return true;
}

ReuseOptions resolve_reuse(const ReuseOptions& options, Backend backend, Accumulation accumulation, bool md,
                           const Box& box, double cutoff, ListMemory memory) {
  if (!options.automatic) return options;
  ReuseOptions r = options;
  r.automatic = false;  // resolved: what the engine runs
  r.skin = 0.0;
  r.list = false;
  (void)md;  // force calls take the rule of steps: on CUDA the device decides their rebuilds
  if (backend != Backend::kCuda || !(cutoff > 0)) return r;
  ReuseOptions lists = r;
  lists.skin = (memory == ListMemory::kLean ? kAutoLeanSkinPerCutoff : kAutoSkinPerCutoff) * cutoff;
  lists.list = true;
  return pair_lists_serve(lists, accumulation, box, cutoff) ? lists : r;
}

std::string describe_reuse(const ReuseOptions& requested, const ReuseOptions& resolved, Backend backend,
                           Accumulation accumulation, bool md, const Box& box, double cutoff, ListMemory memory) {
  (void)md;
  std::ostringstream s;
  if (resolved.skin > 0) {
    s << "skin " << resolved.skin;
    if (requested.automatic && memory == ListMemory::kLean)
      s << " (auto: " << kAutoLeanSkinPerCutoff << " rc, lean memory)";
    else if (requested.automatic)
      s << " (auto: " << kAutoSkinPerCutoff << " rc)";
    const bool lists = backend == Backend::kCuda && pair_lists_serve(resolved, accumulation, box, cutoff);
    s << (lists ? ", pair lists" : ", cells reused");
    if (!resolved.check) s << ", rebuilt every " << resolved.every << " (not checked)";
    else if (resolved.every > 0) s << ", rebuilt at least every " << resolved.every;
  } else {
    s << "none, stages 1-3 every evaluation";
    if (requested.automatic)
      s << " (auto: " << (backend != Backend::kCuda                 ? "no skin on the cpu"
                          : accumulation != Accumulation::kJacobi ? "pair lists need jacobi"
                                                                  : "rc + skin exceeds half the box")
        << ")";
  }
  return s.str();
}

namespace {

bool same_system(const Box& box, std::size_t n, double cutoff, const SystemView& system, double system_cutoff) {
  if (system.n != n || system_cutoff != cutoff || system.box.dim != box.dim) return false;
  for (int a = 0; a < box.dim; ++a)
    if (system.box.length[a] != box.length[a] || system.box.periodic[a] != box.periodic[a]) return false;
  return true;
}

}  // namespace

bool ReusePolicy::must_rebuild(const SystemView& system, double cutoff) const {
  if (!enabled() || !valid_ || !same_system(box_, n_, cutoff_, system, cutoff)) return true;
  return options_.every > 0 && served_ >= options_.every;
}

bool ReusePolicy::retired(const SystemView& system, double cutoff) const {
  return enabled() && valid_ && same_system(box_, n_, cutoff_, system, cutoff) && options_.every > 0 &&
         served_ >= options_.every;
}

void ReusePolicy::built(const SystemView& system, double cutoff) {
  valid_ = enabled();
  box_ = system.box;
  n_ = system.n;
  cutoff_ = cutoff;
  served_ = 1;
  ++builds_;
}

double max_displacement2(const Box& box, std::size_t n, const double* now, const double* then) {
  const int dim = box.dim;
  double inv[kMaxDim] = {0, 0, 0};
  for (int a = 0; a < dim; ++a) inv[a] = box.periodic[a] ? 1.0 / box.length[a] : 0.0;
  double worst = 0;
#pragma omp parallel for reduction(max : worst) schedule(static)
  for (std::size_t i = 0; i < n; ++i) {
    double d2 = 0;
    for (int a = 0; a < dim; ++a) {
      const std::size_t k = i * std::size_t(dim) + std::size_t(a);
      d2 += displacement_term(now[k], then[k], box.length[a], inv[a]);
    }
    worst = std::max(worst, d2);
  }
  return worst;
}

std::vector<std::pair<uint32_t, uint32_t>> pairs_within(const SystemView& s, double cutoff) {
  const int dim = s.box.dim;
  const std::size_t n = s.n;
  std::vector<std::pair<uint32_t, uint32_t>> pairs;
  if (n < 2) return pairs;
  auto pos = [&](std::size_t i, int a) { return s.positions[i * std::size_t(dim) + std::size_t(a)]; };
  double origin[kMaxDim] = {0, 0, 0}, edge[kMaxDim] = {1, 1, 1}, inv_length[kMaxDim] = {0, 0, 0};
  std::size_t m[kMaxDim] = {1, 1, 1};
  // Cells per axis: edges >= cutoff, and no more cells in all than about twice the particles (a
  // dilute scene in a huge box): counts are capped in double before any integer conversion, so a
  // particle far away cannot overflow them.
  const double cap = double(2 * n + 8);
  double extent[kMaxDim] = {0, 0, 0};
  for (int a = 0; a < dim; ++a) {
    if (s.box.periodic[a]) {
      inv_length[a] = 1.0 / s.box.length[a];
      extent[a] = s.box.length[a];
    } else {
      double lo = pos(0, a), hi = lo;
      for (std::size_t i = 1; i < n; ++i) lo = std::min(lo, pos(i, a)), hi = std::max(hi, pos(i, a));
      origin[a] = lo;
      extent[a] = hi - lo;
    }
    m[a] = std::size_t(std::clamp(std::floor(extent[a] / cutoff), 1.0, cap));
  }
  while (double(m[0]) * double(m[1]) * double(m[2]) > cap) {
    const int a = int(std::max_element(m, m + dim) - m);
    m[a] = std::max<std::size_t>(1, m[a] / 2);
  }
  for (int a = 0; a < dim; ++a)
    edge[a] = s.box.periodic[a] ? s.box.length[a] / double(m[a]) : std::max(extent[a] / double(m[a]), cutoff);
  auto coordinate = [&](std::size_t i, int a) {
    double x = pos(i, a);
    if (s.box.periodic[a]) x = wrap_coordinate(x, s.box.length[a]);
    const double k = std::floor((x - origin[a]) / edge[a]);  // clamped before the conversion
    return std::size_t(std::clamp(k, 0.0, double(m[a] - 1)));
  };
  std::vector<std::size_t> cell_of(n), start(m[0] * m[1] * m[2] + 1, 0), order(n);
  for (std::size_t i = 0; i < n; ++i) {
    std::size_t k[kMaxDim] = {0, 0, 0};
    for (int a = 0; a < dim; ++a) k[a] = coordinate(i, a);
    cell_of[i] = k[0] + m[0] * (k[1] + m[1] * k[2]);
    ++start[cell_of[i] + 1];
  }
  for (std::size_t c = 0; c + 1 < start.size(); ++c) start[c + 1] += start[c];
  {
    std::vector<std::size_t> fill(start.begin(), start.end() - 1);
    for (std::size_t i = 0; i < n; ++i) order[fill[cell_of[i]]++] = i;
  }
  const double rc2 = cutoff * cutoff;
  for (std::size_t i = 0; i < n; ++i) {
    std::size_t k[kMaxDim] = {cell_of[i] % m[0], (cell_of[i] / m[0]) % m[1], cell_of[i] / (m[0] * m[1])};
    // The distinct neighbouring cells along each axis (fewer than three when the axis has fewer).
    std::vector<std::size_t> near[kMaxDim];
    for (int a = 0; a < kMaxDim; ++a) {
      for (int d = -1; d <= 1; ++d) {
        const auto kk = std::ptrdiff_t(k[a]) + d, ma = std::ptrdiff_t(m[a]);
        std::ptrdiff_t c = kk;
        if (a < dim && s.box.periodic[a]) c = (kk % ma + ma) % ma;
        if (c < 0 || c >= ma) continue;
        if (std::find(near[a].begin(), near[a].end(), std::size_t(c)) == near[a].end())
          near[a].push_back(std::size_t(c));
      }
    }
    for (std::size_t z : near[2])
      for (std::size_t y : near[1])
        for (std::size_t x : near[0]) {
          const std::size_t c = x + m[0] * (y + m[1] * z);
          for (std::size_t e = start[c]; e < start[c + 1]; ++e) {
            const std::size_t j = order[e];
            if (j <= i) continue;
            double r2 = 0;
            for (int a = 0; a < dim; ++a) {
              const double d = separation(pos(i, a), pos(j, a), s.box.length[a], inv_length[a]);
              r2 += d * d;
            }
            if (r2 < rc2) pairs.emplace_back(uint32_t(i), uint32_t(j));
          }
        }
  }
  return pairs;
}

ReuseAudit audit_reuse(const Grid& grid, const uint32_t* build_keys, const Control* control,
                       const SystemView& system, double cutoff,
                       const std::vector<std::pair<uint32_t, uint32_t>>& pairs) {
  const int dim = grid.dim;
  const std::size_t slots = std::size_t(1) << dim;
  const double rc2 = cutoff * cutoff;
  // The separation the traversal forms in cell `cell`: each coordinate relative to the centre (the
  // image nearest it on a periodic axis), the difference wrapped again where one cell wraps.
  auto staged_r2 = [&](uint32_t cell, uint32_t i, uint32_t j) {
    int k[kMaxDim];
    cell_coords(grid, cell, k);
    double r2 = 0;
    for (int a = 0; a < dim; ++a) {
      const double center = cell_center(grid, a, k[a]);
      const double xi = relative_coordinate(grid, a, system.positions[std::size_t(i) * dim + a], center);
      const double xj = relative_coordinate(grid, a, system.positions[std::size_t(j) * dim + a], center);
      double d = xi - xj;
      if (grid.wraps_inside_cell(a)) d = minimum_image(d, grid.length[a], grid.inv_length[a]);
      r2 += d * d;
    }
    return r2;
  };
  ReuseAudit audit;
  const int sb = grid.slab_bits;
  for (const auto& [i, j] : pairs) {
    const uint32_t* ki = build_keys + std::size_t(i) * slots;
    const uint32_t* kj = build_keys + std::size_t(j) * slots;
    const uint32_t home_i = key_cell(ki[0], sb), home_j = key_cell(kj[0], sb);
    int visits = 0;
    for (std::size_t t = 0; t < slots; ++t) {
      if (ki[t] == kInvalidCell) continue;
      const uint32_t cell = key_cell(ki[t], sb);
      if (cell != home_i && cell != home_j) continue;  // P x P pairs are never tested
      for (std::size_t u = 0; u < slots; ++u)
        if (kj[u] != kInvalidCell && key_cell(kj[u], sb) == cell &&
            !skip_pair(cell_type_of_id(grid, cell), control[i], control[j]) && staged_r2(cell, i, j) < rc2)
          ++visits;
    }
    if (visits == 0) ++audit.missed;
    if (visits > 1) ++audit.repeated;
  }
  return audit;
}

ReuseAudit audit_lists(const std::vector<std::vector<uint32_t>>& partners,
                       const std::vector<std::pair<uint32_t, uint32_t>>& pairs) {
  std::vector<std::vector<uint32_t>> sorted = partners;
  for (std::vector<uint32_t>& p : sorted) std::sort(p.begin(), p.end());
  auto times = [&](uint32_t i, uint32_t j) -> std::size_t {
    if (i >= sorted.size()) return 0;
    const auto [lo, hi] = std::equal_range(sorted[i].begin(), sorted[i].end(), j);
    return std::size_t(hi - lo);
  };
  ReuseAudit a;
  for (const auto& [i, j] : pairs) {
    const std::size_t ij = times(i, j), ji = times(j, i);
    if (ij == 0 || ji == 0) ++a.missed;
    else if (ij > 1 || ji > 1) ++a.repeated;
  }
  return a;
}

}  // namespace cellforce
