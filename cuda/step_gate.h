// The step gate: an MD run with pair lists (velocity Verlet or Langevin) queues many steps without a
// host wait per step for the skin's rebuild decision (core/reuse.h), and still rebuilds on exactly
// the steps that decision names.
//
// Each gated step's last drift (Verlet's kick-drift, Langevin's second half drift; in fast mode a
// Verlet step's kick-drift after the chunk's first runs in the previous step's force kernel,
// change 59) measures the largest squared displacement since the build (the arithmetic of the
// engines' own check, so the same number) into the gate. The step's list kernels run only while it
// is within (skin / 2)^2; the next step's first kernel (or that force kernel) finds a step past it
// and closes the gate at that step, and from then on every queued kernel of the chunk returns at
// once: positions and velocities stay as they were after the closed step's drifts (in fast mode in
// the chunk's rank-order copy, written back at the chunk's end; change 58). The host reads the gate
// once per chunk of steps and resumes at the closed step with an ordinary evaluation, which
// rebuilds. Plain C++: engine.h includes it.
#pragma once

#include <cstdint>

namespace cellforce::cuda {

constexpr unsigned long long kGateOpen = ~0ull;

struct StepGate {
  // Per step mod 3: the bits of the largest squared displacement since the build (a double >= 0,
  // +inf for one that is not finite: the bits order as the values do). Zeroed before a chunk.
  unsigned long long d2[3];
  // The first step whose evaluation the structure could not serve, as the next step's kick-drift
  // finds it; kGateOpen while there is none (the host checks the chunk's last step itself).
  unsigned long long closed;
  // The bits of the largest squared displacement that a gated evaluation served.
  unsigned long long served;
};

// What a gated kernel of one step reads: the gate (null: no gate, the kernel always runs), the
// step, and the bits of (skin / 2)^2.
struct GateView {
  StepGate* gate = nullptr;
  uint64_t step = 0;
  unsigned long long limit = 0;
};

}  // namespace cellforce::cuda
