// How the host reads a gated chunk's outcome (step_gate.h), change 77: the gate's copy into pinned
// memory at the chunk's end, or, where the gate closed, the notice the first shut kernel posts into
// mapped host memory while the chunk's tail still runs (GateNotice). The host takes whichever comes
// first: a closed gate's notice lets it queue the rebuild behind the chunk's tail (at 256,000
// particles ~25 us of shut steps, the state's write-back and the copy) instead of after it.
#pragma once

#include <cuda_runtime.h>

#include <optional>

#include "check.cuh"
#include "step_gate.h"

namespace cellforce::cuda {

class GateReadback {
 public:
  GateReadback() = default;
  GateReadback(const GateReadback&) = delete;
  GateReadback& operator=(const GateReadback&) = delete;
  // After an early read the chunk's tail may still run, but nothing of it writes the notice again
  // (StepGate::posted), and every MD run() ends with a synchronisation before the engine can go.
  ~GateReadback() {  // a destructor cannot throw: errors are ignored
    if (copy_) cudaFreeHost(copy_);
    if (notice_) cudaFreeHost(notice_);
    if (arrived_) cudaEventDestroy(arrived_);
  }

  // A new chunk's tag, and where its kernels post the notice (`notice` false: nowhere); the memory
  // is made on the current device when first asked for.
  void begin(GateView& view, bool notice) {
    make();
    tag_ = ++chunks_;
    view.notice = notice ? notice_device_ : nullptr;
    view.tag = tag_;
  }

  // Queues the gate's copy at the chunk's end (after every kernel of the chunk).
  void queue_copy(const StepGate* gate, cudaStream_t stream) {
    CF_CUDA_CHECK(cudaMemcpyAsync(copy_, gate, sizeof(StepGate), cudaMemcpyDeviceToHost, stream));
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
        const cudaError_t done = cudaEventQuery(arrived_);
        if (done == cudaSuccess) break;
        if (done != cudaErrorNotReady) CF_CUDA_CHECK(done);
      }
    } else {
      CF_CUDA_CHECK(cudaEventSynchronize(arrived_));
    }
    return {*copy_, posted()};
  }

 private:
  void make() {
    void* p = nullptr;
    if (!copy_) {
      CF_CUDA_CHECK(cudaHostAlloc(&p, sizeof(StepGate), cudaHostAllocDefault));
      copy_ = static_cast<StepGate*>(p);
    }
    if (!notice_) {
      CF_CUDA_CHECK(cudaHostAlloc(&p, sizeof(GateNotice), cudaHostAllocMapped));
      notice_ = static_cast<GateNotice*>(p);
      *notice_ = GateNotice{};  // tag 0: no chunk's
    }
    if (!notice_device_)
      CF_CUDA_CHECK(cudaHostGetDevicePointer(reinterpret_cast<void**>(&notice_device_), notice_, 0));
    if (!arrived_) CF_CUDA_CHECK(cudaEventCreateWithFlags(&arrived_, cudaEventDisableTiming));
  }

  // The notice of this chunk, where its tag has arrived: the gate it tells (d2 only at the closed step).
  std::optional<StepGate> posted() const {
    // An acquire load of the tag: the values, written before it (the kernel's system fence), are read after.
    if (__atomic_load_n(&notice_->tag, __ATOMIC_ACQUIRE) != tag_) return std::nullopt;
    const volatile GateNotice* n = notice_;
    StepGate g{};
    g.closed = n->closed;
    g.d2[g.closed % 3] = n->d2;
    g.served = n->served;
    return g;
  }

  StepGate* copy_ = nullptr;     // pinned: the gate's copy
  GateNotice* notice_ = nullptr;  // mapped: what a shut kernel posts
  GateNotice* notice_device_ = nullptr;
  cudaEvent_t arrived_ = nullptr;
  unsigned long long chunks_ = 0, tag_ = 0;
};

}  // namespace cellforce::cuda
