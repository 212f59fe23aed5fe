// Force calls whose rebuild the device decides (GpuEngine::evaluate_device with a skin and pair
// lists, backend/device_calls.cu): one CUDA graph a call, so that the host never waits for the
// displacement or for the list's sizes.
//
//   decide ──> IF rebuild { the whole build: stages 1-3, the list's count pass, lengths, layout,
//                           the sizes' post and the early fill into the list's array }
//          ──> select ──> IF the list fits { the list force kernel } ELSE { the cells' traversal }
//
// `decide` compares the call's largest squared displacement since the build (take_call_input,
// queued before the graph) with (skin / 2)^2, as the host's ReusePolicy does, and sets the first
// condition (or rebuilds where the host asked it to: `force`); `select` reads whether the last
// build's list fitted its array (the early fill's guard wrote nothing where it did not; a list the
// host would decline as crowded counts as not fitting) and sets the second. So the device rebuilds
// on exactly the calls the host-decided path would, with the same list, and the results are
// bitwise that path's until a list outgrows its array: the cells serve that call, exact; the host
// grows the array when it reads the posted sizes and asks for a build at the next call, from where
// the results are exact but depend on when it read them. The host reads the CallState only when it
// synchronises (statistics) or leaves the graph for its own path.
//
// The bodies are captured from the ordinary code (cudaStreamBeginCaptureToGraph) under
// FrozenBuffers: every buffer must have its room before (a buffer that would grow throws, and the
// capture is abandoned). The graph names every buffer's address: its key holds them all, as the
// build graph's does (backend/build_graph.cuh).
#pragma once

#include <cuda_runtime.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include <cellforce/options.hpp>  // Scalar

#include "check.cuh"
#include "core/box.h"
#include "core/error.h"
#include "device_buffer.cuh"

namespace cellforce::cuda {

// The device's side of the decided calls (device memory, one per engine).
struct CallState {
  unsigned long long d2;        // this call's largest squared displacement (double bits; atomicMax)
  unsigned long long last_d2;   // the last decided call's
  unsigned long long calls;     // calls decided on the device
  unsigned long long builds;    // of them, those that rebuilt
  unsigned long long rebuilt;   // 1: the last decided call rebuilt
  unsigned long long served;    // evaluations of the structure in use, its build's included
  unsigned long long overflow;  // 1: the list of the structure in use did not fit its array
  unsigned long long overflows; // builds whose list did not fit (PairList::overflow: the two words)
  unsigned long long force;     // 1: the next decided call rebuilds (the list's array grew after one)
};

struct DeviceFlags;

// A decided call's input in one pass (one thread a particle): the caller's rows (`scalar` float64 or
// float32, `stride` >= box.dim elements a row) as packed float64 rows into `positions`, its types
// (null: all type 0) into `types`, the first coordinate that is not finite and the first type index
// not below num_types flagged as check_input flags them, and the largest squared displacement from
// `then` (n x box.dim, minimum image on periodic axes, as max_displacement2) into state->d2.
void take_call_input(const void* in, Scalar scalar, std::size_t stride, const uint32_t* in_types, std::size_t n,
                     const Box& box, uint32_t num_types, double* positions, uint32_t* types, const double* then,
                     DeviceFlags* flags, CallState* state, cudaStream_t stream);
// After a call the host served: the structure in use has served `served` evaluations and its list
// fits (overflow false) or the cells serve it.
void reset_call_state(CallState* state, int64_t served, bool overflow, cudaStream_t stream);
void request_build(CallState* state, cudaStream_t stream);
void queue_decide(CallState* state, double limit2, cudaGraphConditionalHandle rebuild, cudaStream_t stream);
void queue_select(const CallState* state, cudaGraphConditionalHandle lists, cudaStream_t stream);

// The graphs of the last few keys (a caller that asks for energies every so often, or writes the
// forces into two arrays by turns, switches between two or three), each made once.
class CallGraph {
 public:
  using Key = std::vector<uint64_t>;
  static constexpr std::size_t kKept = 4;
  CallGraph() = default;
  CallGraph(const CallGraph&) = delete;
  CallGraph& operator=(const CallGraph&) = delete;
  ~CallGraph() {
    for (Entry& e : kept_)
      if (e.exec) cudaGraphExecDestroy(e.exec);  // a destructor cannot throw: errors are ignored
  }

  // The graph of `key`, made already (else null).
  cudaGraphExec_t find(const Key& key) {
    for (Entry& e : kept_)
      if (e.key == key) {
        e.used = ++uses_;
        return e.exec;
      }
    return nullptr;
  }
  // Whether a graph is kept whose key differs from `key` in its first `prefix` words only.
  bool kept_but_prefix(const Key& key, std::size_t prefix) const {
    for (const Entry& e : kept_)
      if (e.key.size() == key.size() && std::equal(key.begin() + prefix, key.end(), e.key.begin() + prefix))
        return true;
    return false;
  }
  // A key whose capture failed (a buffer would have grown): not tried again until the key changes.
  bool refused(const Key& key) const { return !refused_.empty() && key == refused_; }
  void launch(cudaGraphExec_t exec, cudaStream_t stream) {
    CF_CUDA_CHECK(cudaGraphLaunch(exec, stream));
    ++launches_;
  }
  std::size_t launches() const { return launches_; }
  std::size_t captures() const { return captures_; }

  // Captures the graph above: decide(handle) and select(handle) queue the kernels that set the
  // conditions; build(), lists() and cells() queue the bodies. On an exception the graph is not
  // kept and `key` is refused. The least recently used graph gives way past kKept.
  template <class Decide, class Build, class Select, class Lists, class Cells>
  cudaGraphExec_t make(Key key, cudaStream_t stream, Decide&& decide, Build&& build, Select&& select, Lists&& lists,
                       Cells&& cells) {
    cudaGraph_t top = nullptr;
    cudaGraphExec_t exec = nullptr;
    CF_CUDA_CHECK(cudaGraphCreate(&top, 0));
    try {
      FrozenBuffers frozen;
      cudaGraphConditionalHandle rebuild = 0, listed = 0;
      CF_CUDA_CHECK(cudaGraphConditionalHandleCreate(&rebuild, top, 0, 0));
      CF_CUDA_CHECK(cudaGraphConditionalHandleCreate(&listed, top, 0, 0));
      const std::vector<cudaGraphNode_t> decided = capture(top, {}, stream, [&] { decide(rebuild); });
      cudaGraph_t body[2] = {};
      const cudaGraphNode_t built = add_if(top, decided, rebuild, 1, body);
      capture(body[0], {}, stream, build);
      const std::vector<cudaGraphNode_t> selected = capture(top, {built}, stream, [&] { select(listed); });
      add_if(top, selected, listed, 2, body);
      capture(body[0], {}, stream, lists);
      capture(body[1], {}, stream, cells);
      CF_CUDA_CHECK(cudaGraphInstantiate(&exec, top, 0));
    } catch (...) {
      if (exec) cudaGraphExecDestroy(exec);
      cudaGraphDestroy(top);
      refused_ = std::move(key);
      throw;
    }
    cudaGraphDestroy(top);
    if (kept_.size() == kKept) {
      auto oldest = kept_.begin();
      for (auto e = kept_.begin(); e != kept_.end(); ++e)
        if (e->used < oldest->used) oldest = e;
      cudaGraphExec_t gone = oldest->exec;
      kept_.erase(oldest);
      CF_CUDA_CHECK(cudaGraphExecDestroy(gone));
    }
    kept_.push_back(Entry{std::move(key), exec, ++uses_});
    refused_.clear();
    ++captures_;
    return exec;
  }

 private:
  // What f queues on `stream`, captured into `graph` after the nodes `after` (none: at its roots);
  // returns the nodes the next capture depends on (`after` where f queued nothing).
  template <class F>
  static std::vector<cudaGraphNode_t> capture(cudaGraph_t graph, const std::vector<cudaGraphNode_t>& after,
                                              cudaStream_t stream, F&& f) {
    CF_CUDA_CHECK(cudaStreamBeginCaptureToGraph(stream, graph, after.empty() ? nullptr : after.data(), nullptr,
                                                after.size(), cudaStreamCaptureModeThreadLocal));
    std::vector<cudaGraphNode_t> leaves;
    try {
      f();
      cudaStreamCaptureStatus status = cudaStreamCaptureStatusNone;
      const cudaGraphNode_t* deps = nullptr;
      std::size_t count = 0;
      CF_CUDA_CHECK(cudaStreamGetCaptureInfo(stream, &status, nullptr, nullptr, &deps, nullptr, &count));
      if (status != cudaStreamCaptureStatusActive) throw Error("internal error: a call graph's capture was invalidated");
      leaves.assign(deps, deps + count);
    } catch (...) {
      cudaGraph_t ended = nullptr;
      cudaStreamEndCapture(stream, &ended);
      (void)cudaGetLastError();
      throw;
    }
    cudaGraph_t ended = nullptr;
    CF_CUDA_CHECK(cudaStreamEndCapture(stream, &ended));
    return leaves;
  }

  // An IF node (size 2: IF/ELSE) after `after`; its bodies into body[0] (and body[1]).
  static cudaGraphNode_t add_if(cudaGraph_t graph, const std::vector<cudaGraphNode_t>& after,
                                cudaGraphConditionalHandle handle, unsigned size, cudaGraph_t* body) {
    cudaGraphNodeParams params{};
    params.type = cudaGraphNodeTypeConditional;
    params.conditional.handle = handle;
    params.conditional.type = cudaGraphCondTypeIf;
    params.conditional.size = size;
    cudaGraphNode_t node = nullptr;
    CF_CUDA_CHECK(
        cudaGraphAddNode(&node, graph, after.empty() ? nullptr : after.data(), nullptr, after.size(), &params));
    for (unsigned i = 0; i < size; ++i) body[i] = params.conditional.phGraph_out[i];
    return node;
  }

  struct Entry {
    Key key;
    cudaGraphExec_t exec = nullptr;
    std::size_t used = 0;
  };
  std::vector<Entry> kept_;
  Key refused_;
  std::size_t uses_ = 0, launches_ = 0, captures_ = 0;
};

}  // namespace cellforce::cuda
