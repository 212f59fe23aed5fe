// How the host reads a gated chunk's outcome (search/step_gate.h): the gate's copy at the chunk's
// end, or, where the gate closed, the notice the first shut kernel posts into mapped host memory
// while the chunk's tail still runs (GateNotice). The host takes whichever comes first: a closed
// gate's notice lets it queue the rebuild behind the chunk's tail (its shut steps, the state's
// write-back and the copy) instead of after it.
// The copy is a one-thread kernel's (post_gate_kernel) into mapped host memory, which then resets
// the gate for the next chunk: no copy engine's copy and no memsets of the gate, each of which
// would cost the device a turnaround between chunks.
#pragma once

#include <cuda_runtime.h>

#include <optional>

#include "check.cuh"
#include "core/error.h"
#include "mapped_post.h"
#include "search/step_gate.h"

namespace cellforce::cuda {

// The gate's copy in mapped host memory: its values, then (after a system-wide fence) the chunk's tag.
struct PostedGate {
  StepGate gate;
  unsigned long long tag;  // the host's chunk number (never 0); 0 before any chunk
};

// The chunk's last kernel (one thread): the gate, final (every kernel of the chunk before it is
// complete), into `out` with the chunk's tag, then the gate reset for the next chunk (zeros, the
// closed step kGateOpen), as the chunk's memsets had it.
template <int = 0>
__global__ void post_gate_kernel(StepGate* gate, PostedGate* out, unsigned long long tag) {
  if (threadIdx.x != 0 || blockIdx.x != 0) return;
  volatile StepGate* g = gate;
  volatile PostedGate* o = out;
  for (int k = 0; k < 3; ++k) o->gate.d2[k] = g->d2[k];
  o->gate.closed = g->closed;
  o->gate.served = g->served;
  o->gate.posted = g->posted;
  __threadfence_system();  // the values reach the host before the tag
  o->tag = tag;
  for (int k = 0; k < 3; ++k) g->d2[k] = 0;
  g->closed = kGateOpen;
  g->served = 0;
  g->posted = 0;
}

class GateReadback {
 public:
  GateReadback() = default;
  GateReadback(const GateReadback&) = delete;
  GateReadback& operator=(const GateReadback&) = delete;
  // After an early read the chunk's tail may still run: nothing of it writes the notice again
  // (StepGate::posted), its post_gate_kernel writes the copy, and every MD run() ends with a
  // synchronisation before the engine (and this memory: MappedPost) can go.
  ~GateReadback() {  // a destructor cannot throw: errors are ignored
    if (arrived_) cudaEventDestroy(arrived_);
  }

  // A new chunk's tag, and where its kernels post the notice (`notice` false: nowhere); the memory
  // is made on the current device when first asked for.
  void begin(GateView& view, bool notice) {
    GateNotice* notice_device = notice_.device();
    copy_.device();  // made here, so that queue_copy cannot fail on it
    if (!arrived_) CF_CUDA_CHECK(cudaEventCreateWithFlags(&arrived_, cudaEventDisableTiming));
    tag_ = ++chunks_;
    view.notice = notice ? notice_device : nullptr;
    view.tag = tag_;
  }

  // Queues the gate's copy at the chunk's end (after every kernel of the chunk), which also resets
  // the gate for the next chunk (post_gate_kernel).
  void queue_copy(StepGate* gate, cudaStream_t stream) {
    post_gate_kernel<<<1, 32, 0, stream>>>(gate, copy_.device(), tag_);
    CF_CUDA_CHECK(cudaGetLastError());
    CF_CUDA_CHECK(cudaEventRecord(arrived_, stream));
  }

  // What the host has of the chunk's gate: its copy (the chunk has ended) and this chunk's notice
  // (posted where the gate closed: the closed step, its displacement, the served one), either or both.
  struct Outcome {
    std::optional<StepGate> copy, notice;
  };
  // Waits for the copy, or (`notice_first`) for the notice or the copy, whichever comes first.
  Outcome wait(bool notice_first) {
    if (notice_first) {
      for (;;) {
        if (std::optional<StepGate> g = posted()) return {std::nullopt, g};
        if (copy_.arrived(tag_)) break;
        const cudaError_t done = cudaEventQuery(arrived_);  // (an error stops the wait)
        if (done == cudaSuccess) break;
        if (done != cudaErrorNotReady) CF_CUDA_CHECK(done);
      }
    } else {
      CF_CUDA_CHECK(cudaEventSynchronize(arrived_));
    }
    return {copied(), posted()};
  }

 private:
  // The chunk's copy (its tag has arrived: the tag's acquire load, or the event after the kernel).
  StepGate copied() const {
    if (!copy_.arrived(tag_)) throw Error("internal error: the gate's copy is not this chunk's");
    const volatile StepGate& c = copy_.values().gate;
    StepGate g{};
    for (int k = 0; k < 3; ++k) g.d2[k] = c.d2[k];
    g.closed = c.closed;
    g.served = c.served;
    g.posted = c.posted;
    return g;
  }

  // The notice of this chunk, where its tag has arrived: the gate it tells (d2 only at the closed step).
  std::optional<StepGate> posted() const {
    if (!notice_.arrived(tag_)) return std::nullopt;
    const volatile GateNotice& n = notice_.values();
    StepGate g{};
    g.closed = n.closed;
    g.d2[g.closed % 3] = n.d2;
    g.served = n.served;
    return g;
  }

  MappedPost<PostedGate> copy_;    // the gate's copy (post_gate_kernel)
  MappedPost<GateNotice> notice_;  // what a shut kernel posts
  cudaEvent_t arrived_ = nullptr;
  unsigned long long chunks_ = 0, tag_ = 0;
};

}  // namespace cellforce::cuda
