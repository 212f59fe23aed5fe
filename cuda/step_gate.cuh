// The step gate's device side (step_gate.h): the test every gated evaluation kernel makes first.
#pragma once

#include "step_gate.h"

namespace cellforce::cuda {

// Whether the evaluation of view.step must not run: the gate closed at an earlier step, or this
// step's displacement is past the limit (the next kick-drift closes the gate here). The same
// answer in every block of a launch: the gate is written only by earlier kernels. One thread per
// block reads it (through volatile: never a stale cached value) and shares the answer: a load of
// the one address from every warp would queue on a single L2 slice. Every thread of the block
// must call it (a barrier), before anything else.
__device__ __forceinline__ bool gate_shut(const GateView& view) {
  if (!view.gate) return false;
  __shared__ int shut;
  if (threadIdx.x == 0) {
    const volatile StepGate* g = view.gate;
    shut = g->closed != kGateOpen || g->d2[view.step % 3] > view.limit;
  }
  __syncthreads();
  return shut != 0;
}

}  // namespace cellforce::cuda
