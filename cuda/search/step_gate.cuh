// The step gate's device side (step_gate.h): the tests the gated kernels make first.
#pragma once

#include <cmath>

#include "search/step_gate.h"

namespace cellforce::cuda {

// The notice of a shut gate (GateNotice, step_gate.h): the step it closed at and the gate's values
// (final: every kernel before this one is complete), a fence, then the chunk's tag, which the host
// waits for. One thread (block 0's first) of a kernel that found the gate shut, once a chunk: the
// kernels run one after the other, so the first to find the gate shut posts and marks it posted.
__device__ __forceinline__ void post_notice(const GateView& view, unsigned long long closed) {
  if (!view.notice) return;
  volatile StepGate* g = view.gate;
  if (g->posted) return;
  g->posted = 1;
  volatile GateNotice* out = view.notice;
  out->closed = closed;
  out->d2 = g->d2[closed % 3];
  out->served = g->served;
  __threadfence_system();  // the values reach the host before the tag
  out->tag = view.tag;
}

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
    const unsigned long long closed = g->closed;
    shut = closed != kGateOpen || g->d2[view.step % 3] > view.limit;
    if (shut && blockIdx.x == 0) post_notice(view, closed != kGateOpen ? closed : view.step);
  }
  __syncthreads();
  return shut != 0;
}

// The same gate at the next step (a kernel that tests, or drifts, the step after its own).
__device__ __forceinline__ GateView next_step(GateView view) {
  ++view.step;
  return view;
}

// A particle's squared displacement as the gate takes it: a NaN (a diverged particle) is +inf,
// which closes the gate.
__device__ __forceinline__ double gate_displacement(double d2) { return isnan(d2) ? INFINITY : d2; }

// Raises the block's largest squared displacement into the gate's slot for gate.step: `worst`,
// each thread's (0 for a thread with no particle). Every thread of the block must call it (a
// barrier; blocks of whole warps). The slot is read before the atomic: few blocks raise it.
__device__ __forceinline__ void raise_block_displacement(double worst, const GateView& gate) {
  __shared__ double warp_worst[32];
  for (int offset = 16; offset > 0; offset >>= 1) worst = fmax(worst, __shfl_xor_sync(0xffffffffu, worst, offset));
  if (threadIdx.x % 32 == 0) warp_worst[threadIdx.x / 32] = worst;
  __syncthreads();
  if (threadIdx.x == 0) {
    worst = warp_worst[0];
    for (unsigned w = 1; w < blockDim.x / 32; ++w) worst = fmax(worst, warp_worst[w]);
    const auto bits = static_cast<unsigned long long>(__double_as_longlong(worst));
    volatile StepGate* g = gate.gate;
    if (bits > g->d2[gate.step % 3]) atomicMax(&gate.gate->d2[gate.step % 3], bits);
  }
}

// The gate at the first kernel of a gated step (the MD engine's kick-drift, or the previous step's
// force kernel where it runs this step's kick-drift), read by one thread per block and
// shared: shut at an earlier step, or the previous step's displacement past the limit (its
// evaluation did not run: the gate closes there, at step - 1). Open, block 0 zeroes the next
// step's slot. Every thread of the block must call it (a barrier).
__device__ __forceinline__ bool step_gate_shut(const GateView& gate) {
  volatile StepGate* g = gate.gate;
  __shared__ int shut;
  if (threadIdx.x == 0) {
    shut = g->closed != kGateOpen;
    if (!shut && g->d2[(gate.step + 2) % 3] > gate.limit) {  // step - 1 ran past skin / 2
      shut = 1;
      if (blockIdx.x == 0) g->closed = gate.step - 1;
    }
    if (shut && blockIdx.x == 0) post_notice(gate, g->closed);
    if (!shut && blockIdx.x == 0) g->d2[(gate.step + 1) % 3] = 0;  // the next step's slot
  }
  __syncthreads();
  return shut != 0;
}

}  // namespace cellforce::cuda
