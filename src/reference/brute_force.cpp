// The double-precision oracle: all pairs under the minimum image, no grid, no sort, no control
// bits. It shares only the input checks and the pair evaluator (whose analytic values the tests
// check on their own) with the pipeline.
#include "reference/brute_force.h"

#include <omp.h>

#include <cmath>

#include "core/error.h"
#include "core/lj.h"

namespace cellforce {
namespace {

struct Geometry {
  int dim;
  double length[kMaxDim] = {0, 0, 0};
  double inv_length[kMaxDim] = {0, 0, 0};
  explicit Geometry(const Box& box) : dim(box.dim) {
    for (int a = 0; a < dim; ++a)
      if (box.periodic[a]) {
        length[a] = box.length[a];
        inv_length[a] = 1.0 / box.length[a];
      }
  }
  // d = minimum image of x_i - x_j; returns r^2.
  double separation(const double* x, std::size_t i, std::size_t j, double d[kMaxDim]) const {
    double r2 = 0;
    for (int a = 0; a < dim; ++a) {
      d[a] = cellforce::separation(x[i * dim + a], x[j * dim + a], length[a], inv_length[a]);
      r2 += d[a] * d[a];
    }
    return r2;
  }
};

template <CutoffMode Mode>
void run(const SystemView& sys, const ForceField& ff, const Request& request, ForceResult& out) {
  const std::size_t n = sys.n, nt = ff.num_types();
  const int dim = sys.box.dim;
  const Geometry geo(sys.box);
  const auto table = make_pair_table<double>(ff);
  const double rc2 = ff.cutoff * ff.cutoff;
  auto type = [&](std::size_t i) { return sys.types ? sys.types[i] : 0u; };
  out.dim = dim;
  out.forces.assign(n * dim, 0.0);
  out.energies.assign(request.energy ? n : 0, 0.0);
  double bad_r2 = -1;
  std::size_t bad_i = 0, bad_j = 0;
  // Forces and energies: particle i sums over all j in index order (no Newton's third law).
#pragma omp parallel for schedule(dynamic, 16)
  for (std::size_t i = 0; i < n; ++i) {
    double f[kMaxDim] = {0, 0, 0}, e_i = 0;
    for (std::size_t j = 0; j < n; ++j) {
      if (j == i) continue;
      double d[kMaxDim];
      const double r2 = geo.separation(sys.positions, i, j, d);
      double fr, e = 0;
      if (!lj_pair<Mode, true>(r2, rc2, table[type(i) * nt + type(j)], fr, e)) continue;
      if (!std::isfinite(fr)) {
#pragma omp critical(cellforce_brute_bad)
        if (bad_r2 < 0 || std::min(i, j) < bad_i || (std::min(i, j) == bad_i && std::max(i, j) < bad_j)) {
          bad_r2 = r2;
          bad_i = std::min(i, j);
          bad_j = std::max(i, j);
        }
      }
      for (int a = 0; a < dim; ++a) f[a] += fr * d[a];
      e_i += 0.5 * e;
    }
    for (int a = 0; a < dim; ++a) out.forces[i * dim + a] = f[a];
    if (request.energy) out.energies[i] = e_i;
  }
  if (bad_r2 >= 0) throw_close_pair(sys, uint32_t(bad_i), uint32_t(bad_j), bad_r2, &ff);
  out.energy = 0;
  if (request.energy)
    for (std::size_t i = 0; i < n; ++i) out.energy += out.energies[i];
  for (auto& row : out.virial)
    for (double& v : row) v = 0;
  if (request.virial) {
    // Over pairs i < j, each thread over its own rows, reduced in thread order.
    const int threads = omp_get_max_threads();
    std::vector<double> partial(std::size_t(threads) * 9, 0.0);
#pragma omp parallel for schedule(static, 16)
    for (std::size_t i = 0; i < n; ++i) {
      double* w = partial.data() + std::size_t(omp_get_thread_num()) * 9;
      for (std::size_t j = i + 1; j < n; ++j) {
        double d[kMaxDim];
        const double r2 = geo.separation(sys.positions, i, j, d);
        double fr, e;
        if (!lj_pair<Mode, false>(r2, rc2, table[type(i) * nt + type(j)], fr, e)) continue;
        for (int a = 0; a < dim; ++a)
          for (int b = 0; b < dim; ++b) w[a * 3 + b] += d[a] * fr * d[b];
      }
    }
    for (int t = 0; t < threads; ++t)
      for (int a = 0; a < dim; ++a)
        for (int b = 0; b < dim; ++b) out.virial[a][b] += partial[std::size_t(t) * 9 + a * 3 + b];
  }
}

}  // namespace

void brute_force(const SystemView& system, const ForceField& ff, const Request& request,
                 ForceResult& result) {
  validate_system(system, ff);
  switch (ff.mode) {
    case CutoffMode::kTruncate: run<CutoffMode::kTruncate>(system, ff, request, result); break;
    case CutoffMode::kShift: run<CutoffMode::kShift>(system, ff, request, result); break;
    case CutoffMode::kForceShift: run<CutoffMode::kForceShift>(system, ff, request, result); break;
  }
}

std::vector<std::pair<uint32_t, uint32_t>> brute_force_pairs(const SystemView& system,
                                                             const ForceField& ff) {
  validate_system(system, ff);
  const Geometry geo(system.box);
  const double rc2 = ff.cutoff * ff.cutoff;
  std::vector<std::pair<uint32_t, uint32_t>> pairs;
  for (std::size_t i = 0; i < system.n; ++i)
    for (std::size_t j = i + 1; j < system.n; ++j) {
      double d[kMaxDim];
      if (geo.separation(system.positions, i, j, d) < rc2) pairs.emplace_back(uint32_t(i), uint32_t(j));
    }
  return pairs;
}

}  // namespace cellforce
