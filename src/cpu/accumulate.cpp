// Stage 5, Jacobi accumulation: each particle's 2^d slots (one per cell type) are summed in slot
// order, and the per-cell energies and virials in cell order (with ghosts: the locals' energies
// and virials in index order). No two cells write one slot and every sum has a fixed order, so
// the result is bitwise reproducible whatever the thread count.
#include <omp.h>

#include "cpu/traversal.h"

namespace cellforce::cpu {
namespace {

// Particle i's force and (with `energy`) energy: its `copies` slots summed in slot order.
template <class Accum>
void sum_slots(const Accumulators<Accum>& acc, std::size_t copies, std::size_t d, std::size_t n, std::size_t i,
               bool energy, ForceResult& result) {
  for (std::size_t c = 0; c < d; ++c) {
    Accum f = 0;
    for (std::size_t t = 0; t < copies; ++t) f += acc.force[(t * n + i) * d + c];
    result.forces[i * d + c] = double(f);
  }
  if (energy) {
    Accum e = 0;
    for (std::size_t t = 0; t < copies; ++t) e += acc.energy[t * n + i];
    result.energies[i] = double(e);
  }
}

}  // namespace

template <class Accum>
void accumulate(const Accumulators<Accum>& acc, Accumulation mode, int dim, std::size_t n,
                const Request& request, ForceResult& result) {
  const std::size_t d = std::size_t(dim);
  const std::size_t copies = mode == Accumulation::kJacobi ? (std::size_t(1) << dim) : 1;
  result.dim = dim;
  result.forces.resize(n * d);
  result.energies.resize(request.energy ? n : 0);
#pragma omp parallel for schedule(static)
  for (std::size_t i = 0; i < n; ++i) {
    sum_slots(acc, copies, d, n, i, request.energy, result);
  }
  result.energy = 0;
  if (request.energy) {
    Accum e = 0;
    for (const Accum v : acc.cell_energy) e += v;
    result.energy = double(e);
  }
  double w[kVirialComponents] = {};
  if (request.virial) {
    Accum sum[kVirialComponents] = {};
    const std::size_t cells = acc.cell_virial.size() / kVirialComponents;
    for (std::size_t ci = 0; ci < cells; ++ci)
      for (int k = 0; k < kVirialComponents; ++k) sum[k] += acc.cell_virial[ci * kVirialComponents + k];
    for (int k = 0; k < kVirialComponents; ++k) w[k] = double(sum[k]);
  }
  set_virial(result, dim, w);
}

namespace {

// The position of virial component (r, c) among the kVirialComponents (xx, yy, zz, xy, xz, yz).
constexpr int component_of(int r, int c) {
  if (r == c) return r;
  const int lo = r < c ? r : c, hi = r < c ? c : r;
  return lo == 0 ? (hi == 1 ? 3 : 4) : 5;
}

}  // namespace

template <class Accum>
void accumulate_local(const Accumulators<Accum>& acc, Accumulation mode, int dim, std::size_t n,
                      std::size_t n_local, const Request& request, ForceResult& result) {
  const std::size_t d = std::size_t(dim), dd = d * d;
  const std::size_t copies = mode == Accumulation::kJacobi ? (std::size_t(1) << dim) : 1;
  constexpr std::size_t kc = kVirialComponents;
  result.dim = dim;
  result.forces.resize(n_local * d);
  result.energies.resize(request.energy ? n_local : 0);
  result.virials.resize(request.virial ? n_local * dd : 0);
  std::vector<double> w6(request.virial ? n_local * kc : 0);  // each local's components, summed
#pragma omp parallel for schedule(static)
  for (std::size_t i = 0; i < n_local; ++i) {
    sum_slots(acc, copies, d, n, i, request.energy, result);
    if (request.virial) {
      for (std::size_t k = 0; k < kc; ++k) {
        Accum w = 0;
        for (std::size_t t = 0; t < copies; ++t) w += acc.virial[(t * n + i) * kc + k];
        w6[i * kc + k] = double(w);
      }
      double* out = result.virials.data() + i * dd;
      for (int r = 0; r < dim; ++r)
        for (int c = 0; c < dim; ++c) out[std::size_t(r) * d + std::size_t(c)] = w6[i * kc + std::size_t(component_of(r, c))];
    }
  }
  // The totals: the locals' shares in index order (a pair of two locals whole, with a ghost half).
  result.energy = 0;
  for (const double e : result.energies) result.energy += e;
  double w[kVirialComponents] = {};
  for (std::size_t i = 0; i < w6.size() / kc; ++i)
    for (std::size_t k = 0; k < kc; ++k) w[k] += w6[i * kc + k];
  set_virial(result, dim, w);
}

template void accumulate<float>(const Accumulators<float>&, Accumulation, int, std::size_t,
                                const Request&, ForceResult&);
template void accumulate<double>(const Accumulators<double>&, Accumulation, int, std::size_t,
                                 const Request&, ForceResult&);

template void accumulate_local<float>(const Accumulators<float>&, Accumulation, int, std::size_t, std::size_t,
                                      const Request&, ForceResult&);
template void accumulate_local<double>(const Accumulators<double>&, Accumulation, int, std::size_t, std::size_t,
                                       const Request&, ForceResult&);

}  // namespace cellforce::cpu
