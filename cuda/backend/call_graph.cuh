// Force calls whose rebuild the device decides (GpuEngine::evaluate_device with a skin and pair
// lists, backend/device_calls.cu): one CUDA graph a call, so that the host never waits for the
// displacement or for the list's sizes.
//
//   input + decide ──┬──> the list's gather and force kernel (return at once unless the route is theirs)
//                    └──> SWITCH route {
//                           0: the cells' traversal (the structure kept, its list did not fit)
//                           1: the whole build (stages 1-3, the list's count pass, lengths, layout,
//                              the sizes' post and the early fill into the list's array)
//                              ──> select ──> IF the list fits { the list force kernel } ELSE { the cells' }
//                           2 (the kept structure's list: the most calls): nothing
//                         }
//
// The input pass (take_call_input: the caller's arrays copied and checked, the largest squared
// displacement since the build) is the graph's first node, its last block deciding
// (take_call_input_and_decide); a caller that changes its input arrays from call to call gets it
// queued before the graph instead, and a kernel of its own decides. The decision compares that
// displacement with (skin / 2)^2, as the host's ReusePolicy does, and picks the route
// (a rebuild also where the host asked for one: `force`); after a build `select` reads whether its
// list fitted its array (the early fill's guard wrote nothing where it did not; a list the host
// would decline as crowded counts as not fitting). Entering a conditional node's body holds the
// device up longer than a kernel takes to start (performance.md, "An embedding code's loop"), so
// the most common route, the list the structure kept, is no body: its kernels run beside the
// switch, and return at once where the route is another (CallState::not_listed, ListArgs::skip).
// So the device rebuilds
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
  unsigned long long blocks_done;  // the input pass's blocks done, where its last one decides (0 between calls)
  unsigned long long not_listed;   // 1: this call takes another route than the kept list (its kernels return)
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
void queue_decide(CallState* state, double limit2, cudaGraphConditionalHandle route, cudaStream_t stream);
// take_call_input whose last block then decides as queue_decide's kernel does (one launch: the
// graph's first node where the caller's input arrays are part of its key). n > 0.
void take_call_input_and_decide(const void* in, Scalar scalar, std::size_t stride, const uint32_t* in_types,
                                std::size_t n, const Box& box, uint32_t num_types, double* positions, uint32_t* types,
                                const double* then, DeviceFlags* flags, CallState* state, double limit2,
                                cudaGraphConditionalHandle route, cudaStream_t stream);
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
  // Whether a graph is kept whose key differs from `key` in words [first, last) only.
  bool kept_differing_in(const Key& key, std::size_t first, std::size_t last) const {
    for (const Entry& e : kept_)
      if (e.key.size() == key.size() && std::equal(key.begin(), key.begin() + first, e.key.begin()) &&
          std::equal(key.begin() + last, key.end(), e.key.begin() + last))
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
  // conditions (the route 0, 1 or 2; the list's fit 1 or 0); build(), lists(kept) and cells() queue
  // the bodies (lists(true): the kept list's path beside the switch, its kernels skipped on another
  // route; lists and cells each captured twice). On an exception the graph is not kept and `key` is
  // refused. The least recently used graph gives way past kKept.
  template <class Decide, class Build, class Select, class Lists, class Cells>
  cudaGraphExec_t make(Key key, cudaStream_t stream, Decide&& decide, Build&& build, Select&& select, Lists&& lists,
                       Cells&& cells) {
    cudaGraph_t top = nullptr;
    cudaGraphExec_t exec = nullptr;
    CF_CUDA_CHECK(cudaGraphCreate(&top, 0));
    try {
      FrozenBuffers frozen;
      // Both handles are the top graph's (a handle may serve a conditional node in a child graph).
      cudaGraphConditionalHandle route = 0, listed = 0;
      CF_CUDA_CHECK(cudaGraphConditionalHandleCreate(&route, top, 0, 0));
      CF_CUDA_CHECK(cudaGraphConditionalHandleCreate(&listed, top, 0, 0));
      const std::vector<cudaGraphNode_t> decided = capture(top, {}, stream, [&] { decide(route); });
      capture(top, decided, stream, [&] { lists(true); });
      cudaGraph_t routes[2] = {};
      add_conditional(top, decided, route, cudaGraphCondTypeSwitch, 2, routes);
      capture(routes[0], {}, stream, cells);
      const std::vector<cudaGraphNode_t> built = capture(routes[1], {}, stream, build);
      const std::vector<cudaGraphNode_t> selected = capture(routes[1], built, stream, [&] { select(listed); });
      cudaGraph_t fits[2] = {};
      add_conditional(routes[1], selected, listed, cudaGraphCondTypeIf, 2, fits);
      capture(fits[0], {}, stream, [&] { lists(false); });
      capture(fits[1], {}, stream, cells);
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

  // A conditional node of `type` after `after` (IF of size 2: IF/ELSE; SWITCH: `size` bodies); its
  // bodies into body[0 .. size - 1].
  static cudaGraphNode_t add_conditional(cudaGraph_t graph, const std::vector<cudaGraphNode_t>& after,
                                         cudaGraphConditionalHandle handle, cudaGraphConditionalNodeType type,
                                         unsigned size, cudaGraph_t* body) {
    cudaGraphNodeParams params{};
    params.type = cudaGraphNodeTypeConditional;
    params.conditional.handle = handle;
    params.conditional.type = type;
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
