// Stage 5, Jacobi accumulation: each particle's 2^d slots (one per cell type) are summed in slot
// order, and the per-cell energies and virials in cell order. No two cells write one slot and
// every sum has a fixed order, so the result is bitwise reproducible whatever the thread count.
#include <omp.h>

#include "cpu/traversal.h"

namespace cellforce::cpu {

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
    for (std::size_t c = 0; c < d; ++c) {
      Accum f = 0;
      for (std::size_t t = 0; t < copies; ++t) f += acc.force[(t * n + i) * d + c];
      result.forces[i * d + c] = double(f);
    }
    if (request.energy) {
      Accum e = 0;
      for (std::size_t t = 0; t < copies; ++t) e += acc.energy[t * n + i];
      result.energies[i] = double(e);
    }
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

template void accumulate<float>(const Accumulators<float>&, Accumulation, int, std::size_t,
                                const Request&, ForceResult&);
template void accumulate<double>(const Accumulators<double>&, Accumulation, int, std::size_t,
                                 const Request&, ForceResult&);

}  // namespace cellforce::cpu
