// The steps a pair list serves behind the step gate (search/step_gate.h), as kernels: a chunk of
// steps is queued without a host wait per step; each step's first kernel tests the gate and the
// step's last drift measures every particle's displacement since the build into it and places the
// new positions in the list's rank order (search/rank_order.cuh), so that the evaluation needs no
// gather. The per-coordinate arithmetic is md/verlet_step.h's, the ungated kernels' and the host
// loop's, bit for bit. The MD engine (backend/md_engine.cu) decides the chunk's length and reads
// the gate once at its end.
#pragma once

#include <cuda_runtime.h>

#include <cstddef>
#include <cstdint>

#include "md/verlet_step.h"
#include "search/rank_order.h"
#include "search/step_gate.h"

namespace cellforce::cuda {

// Where a gated chunk's kernels find the MD state. kCaller: the caller's order, as
// set_state() holds it (lean memory mode, whose gated evaluations leave the forces in that order
// too). With the forces in rank order (fast mode) the chunk runs on a copy of the state in the
// list's rank order: its first kernel (kGather) reads the caller's order at order[p] and writes
// rank p's entries, the later ones (kRank) read and write rank order, coalesced whatever the
// caller's numbering; the chunk's end writes the positions and velocities back (unrank_state).
// The arithmetic is the same in every order: the same bits.
enum class StateOrder { kCaller, kGather, kRank };

// The state's arrays: the caller's order, and the chunk's rank-order copy (null in lean mode).
// With every mass the same, the masses are `mass_value` and both mass arrays null (no load per
// coordinate); `built_is_x`: the chunk starts at the positions the structure was just
// built from, so kGather copies them as the build's positions instead of reading those too.
struct GatedState {
  double* x;
  double* v;
  const double* f;  // the last ordinary evaluation's forces (the caller's order)
  const double* mass;   // null: every mass is mass_value
  const double* built;  // the build's positions (n x dim)
  double* x_ranked;
  double* v_ranked;
  double* mass_ranked;  // null with `mass`
  double* built_ranked;
  const double* f_ranked;  // the gated evaluations' forces (RankOrder::forces)
  double mass_value;
  bool built_is_x;
};

// One step of a gated chunk. Verlet: one kick-drift kernel (`kicks` half kicks with h = dt / 2, the
// drift by dt). Langevin: the kicks and the first half drift, the thermostat, the second half drift
// (three kernels; the second and third in the order the first left the state in). `gate_first`:
// the step is queued past the expected rebuild, so its first kernel reads the gate before the
// state (a step the gate shut then costs its read only).
struct GatedStep {
  GatedState state{};
  bool langevin = false;
  double dt = 0;
  int kicks = 2;
  bool gate_first = false;
  StateOrder order = StateOrder::kCaller;
  DriftBox box{};
  std::size_t n = 0;
  MdFlags* flags = nullptr;
  GateView gate{};   // its step is this step
  RankOrder to{};    // where the last drift places the positions
  double c1 = 0, c2 = 0, kT = 0;  // Langevin: exp(-gamma dt), sqrt(1 - c1^2), the temperature
  uint64_t seed = 0;
};

// Queues the step's kernels (2 or 3 dimensions: box.dim).
void queue_gated_step(const GatedStep& step, cudaStream_t stream);

// After the gated evaluation of gate.step, unless the gate shut it: forces += an external force
// (n x dim, the caller's order), into the evaluation's forces in rank order (`order`: the particle
// of rank p, RankOrder::order) or, with order null, in the caller's order.
void queue_gated_external(const GateView& gate, double* forces, const double* external, const uint32_t* order,
                          std::size_t n, int dim, cudaStream_t stream);

}  // namespace cellforce::cuda
