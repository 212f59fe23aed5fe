// cellforce::Context's force calls for a rank's own particles with its ghosts (compute_local,
// count_pairs_local): the checks that only ghosts need, then the engine's evaluate_local, whose
// results are the locals' (backends/force_engine.h).
#include <cellforce/cellforce.hpp>

#include <cstdint>
#include <string>

#include "api/context_impl.h"
#include "core/error.h"
#include "core/system.h"

namespace cellforce {

namespace {

// n_local + n_ghost, and the rule for the box: ghosts stand in for the neighbours across an axis
// the caller divides (or whose images it places itself), which is then open; with every axis
// periodic the minimum image already gives each local every neighbour, so ghosts there would count
// pairs twice (or are a box given as periodic by mistake) and are refused.
std::size_t check_locals(const Box& box, std::size_t n_local, std::size_t n_ghost) {
  if (n_ghost > SIZE_MAX - n_local)
    throw Error("compute_local: " + std::to_string(n_local) + " locals and " + std::to_string(n_ghost) +
                " ghosts overflow a particle count");
  if (n_ghost > 0 && box.dim > 0) {
    bool any_open = false;
    for (int a = 0; a < box.dim; ++a) any_open = any_open || !box.periodic[a];
    if (!any_open)
      throw Error("compute_local: " + std::to_string(n_ghost) +
                  " ghost particles, but every axis of the box is periodic: give the axes the ghosts stand "
                  "in for as open (set_box with periodic false there); on a periodic axis the minimum image "
                  "already finds each local's neighbours, and a ghost that is an image would count its pairs "
                  "twice");
  }
  return n_local + n_ghost;
}

void put(double* to, const double* from, std::size_t count, bool accumulate) {
  for (std::size_t k = 0; k < count; ++k) to[k] = accumulate ? to[k] + from[k] : from[k];
}

}  // namespace

void Context::compute_local(std::size_t n_local, std::size_t n_ghost, const double* positions,
                            const uint32_t* types, const LocalOutputs& out) {
  Impl& s = self();
  s.synchronize();
  s.check_ready();
  const std::size_t n = check_locals(s.box, n_local, n_ghost);
  check_output(positions, "positions", n);
  const SystemView system{s.box, n, positions, types};  // the engine validates it
  const Request request{out.energies != nullptr || out.energy != nullptr,
                        out.virial != nullptr || out.virials != nullptr};
  ForceResult& r = s.result;
  s.get_engine().evaluate_local(system, n_local, s.ff, request, r);
  const std::size_t dim = std::size_t(s.dim);
  const bool add = out.accumulate;
  if (out.forces) put(out.forces, r.forces.data(), n_local * dim, add);
  if (out.energies) put(out.energies, r.energies.data(), n_local, add);
  if (out.energy) put(out.energy, &r.energy, 1, add);
  if (out.virial)
    for (std::size_t row = 0; row < dim; ++row) put(out.virial + row * dim, r.virial[row], dim, add);
  if (out.virials) put(out.virials, r.virials.data(), n_local * dim * dim, add);
  s.record_statistics();
}

PairCounts Context::count_pairs_local(std::size_t n_local, std::size_t n_ghost, const double* positions,
                                      const uint32_t* types) {
  Impl& s = self();
  s.synchronize();
  s.check_ready();
  const std::size_t n = check_locals(s.box, n_local, n_ghost);
  check_output(positions, "positions", n);
  ForceEngine& engine = s.get_engine();
  ForceResult scratch;
  engine.evaluate_local(SystemView{s.box, n, positions, types}, n_local, s.ff, Request{false, false}, scratch);
  return pair_counts(engine.stats());
}

}  // namespace cellforce
