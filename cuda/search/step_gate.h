// The step gate: an MD run with pair lists (velocity Verlet or Langevin) queues many steps without a
// host wait per step for the skin's rebuild decision (core/reuse.h), and still rebuilds on exactly
// the steps that decision names.
//
// Each gated step's last drift (Verlet's kick-drift, Langevin's second half drift; in fast mode a
// Verlet step's kick-drift after the chunk's first runs in the previous step's force kernel)
// measures the largest squared displacement since the build (the arithmetic of the
// engines' own check, so the same number) into the gate. The step's list kernels run only while it
// is within (skin / 2)^2; the next step's first kernel (or that force kernel) finds a step past it
// and closes the gate at that step, and from then on every queued kernel of the chunk returns at
// once: positions and velocities stay as they were after the closed step's drifts (in fast mode in
// the chunk's rank-order copy, written back at the chunk's end). The host reads the gate once per
// chunk of steps and resumes at the closed step with an ordinary evaluation, which rebuilds. Plain
// C++: backend/engine.h includes it.
//
// The notice: the first kernel of a chunk that finds the gate shut also writes the
// closed step and the gate's values into host memory the device maps (GateNotice), so that the host,
// which waits for that or for the chunk's end, queues the rebuild while the chunk's tail (its shut
// steps, the state's write-back, the gate's copy) still runs, instead of after it.
#pragma once

#include <cstdint>

namespace cellforce::cuda {

constexpr unsigned long long kGateOpen = ~0ull;

struct StepGate {
  // Per step mod 3: the bits of the largest squared displacement since the build (a double >= 0,
  // +inf for one that is not finite: the bits order as the values do). Zeroed before a chunk (by the
  // last chunk's post_gate_kernel, integrate/gate_readback.cuh, or the chunk's memsets).
  unsigned long long d2[3];
  // The first step whose evaluation the structure could not serve, as the next step's kick-drift
  // finds it; kGateOpen while there is none (the host checks the chunk's last step itself).
  unsigned long long closed;
  // The bits of the largest squared displacement that a gated evaluation served.
  unsigned long long served;
  // Nonzero once a kernel posted the chunk's notice (GateNotice): the first post is the only one.
  unsigned long long posted;
};

// What the first shut kernel of a chunk tells the host (mapped host memory): the step the gate
// closed at, that step's squared displacement and the largest one served (StepGate's bits), then,
// after a system-wide fence, the chunk's tag. The values are final when it is written: every
// kernel before it in the chunk is complete. Later shut kernels post nothing (StepGate::posted).
struct GateNotice {
  unsigned long long closed;
  unsigned long long d2;
  unsigned long long served;
  unsigned long long tag;  // written last; the host's chunk number (never 0), 0 before any chunk
};

// What a gated kernel of one step reads: the gate (null: no gate, the kernel always runs), the
// step, the bits of (skin / 2)^2, and where to post the notice (null: nowhere) with the chunk's tag.
struct GateView {
  StepGate* gate = nullptr;
  uint64_t step = 0;
  unsigned long long limit = 0;
  GateNotice* notice = nullptr;
  unsigned long long tag = 0;
};

}  // namespace cellforce::cuda
