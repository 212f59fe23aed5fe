// The build's fixed part as a CUDA graph: at a build, the host launches ~20 operations, ten of them
// CUB dispatches, before the count pass of the pair list; at a few hundred thousand particles each
// is shorter on the device than on the host, so the device would wait for the host between them
// (performance.md has the timeline). A graph of them is launched in one call and run back to back.
//
// The part (backend/structure_build.cu Impl::build from the cell IDs to build_pair_list's
// partition) is queued by
// the ordinary code, captured from the stream, and replayed while nothing it depends on changes.
// What it depends on is its key: the system's size, the grid, the options, the device arrays it
// reads and writes (every buffer's address and capacity) and the host's choices. The rule:
//   - a build whose key is the graph's replays the graph: the host runs the part's bookkeeping
//     but queues none of its operations (queuing() is false);
//   - a build whose key is the key the last build began and ended with (the last build changed
//     nothing the part depends on: no buffer grew or was freed) captures the part, launches the
//     captured graph and keeps it; the same code from the same key queues the same operations,
//     so a capture takes nothing anew (a buffer taken in capture would be the graph's own);
//   - any other build queues the part operation by operation (the first builds of a system, a
//     build after a list grew or the masks' room changed).
// A replay or capture that ends with another key than it began with would have run on stale
// arrays: an internal error, thrown. With `audit` (tests), a replay's bookkeeping runs under a
// stream capture of its own that must record nothing: an operation of the part queued again by
// the host (a missing guard) or a buffer taken anew is an internal error too.
#pragma once

#include <cuda_runtime.h>

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string>
#include <type_traits>
#include <vector>

#include "check.cuh"
#include "core/error.h"

namespace cellforce::cuda {

class BuildGraph {
 public:
  using Key = std::vector<uint64_t>;
  enum class Mode { kIdle, kQueue, kCapture, kReplay };

  BuildGraph() = default;
  BuildGraph(const BuildGraph&) = delete;
  BuildGraph& operator=(const BuildGraph&) = delete;
  ~BuildGraph() {
    if (exec_) cudaGraphExecDestroy(exec_);  // a destructor cannot throw: errors are ignored
  }

  // The part begins: queued, captured or replayed (launched here, so that the device runs it while
  // the host does the part's bookkeeping) by the rule above. `allowed`: the build may use a graph at all.
  void begin(Key key, bool allowed, cudaStream_t stream, bool audit = false) {
    key_ = std::move(key);
    mode_ = Mode::kIdle;
    if (!allowed) {  // queued, and no graph kept: nothing reuses what this build leaves
      drop();
      last_before_.clear();
      last_after_.clear();
      return;
    }
    mode_ = Mode::kQueue;
    if (exec_ && key_ == graph_key_) {
      CF_CUDA_CHECK(cudaGraphLaunch(exec_, stream));
      mode_ = Mode::kReplay;
      ++replays_;
      if (audit) {
        CF_CUDA_CHECK(cudaStreamBeginCapture(stream, cudaStreamCaptureModeThreadLocal));
        auditing_ = true;
      }
    } else if (!last_before_.empty() && key_ == last_before_ && key_ == last_after_) {
      drop();
      CF_CUDA_CHECK(cudaStreamBeginCapture(stream, cudaStreamCaptureModeThreadLocal));
      mode_ = Mode::kCapture;
    }
  }

  // The part of a build begun with `allowed` ends; `key` is the key now. A capture is
  // instantiated, launched and kept.
  void end(const Key& key, cudaStream_t stream) {
    const Mode mode = mode_;
    mode_ = Mode::kIdle;
    if (auditing_) {
      auditing_ = false;
      cudaGraph_t queued = nullptr;
      CF_CUDA_CHECK(cudaStreamEndCapture(stream, &queued));
      std::size_t nodes = 0;
      const cudaError_t counted = cudaGraphGetNodes(queued, nullptr, &nodes);
      cudaGraphDestroy(queued);
      CF_CUDA_CHECK(counted);
      if (nodes > 0)
        throw Error("internal error: a replayed build queued " + std::to_string(nodes) +
                    " operation(s) of the part its graph holds");
    }
    if (mode == Mode::kCapture) {
      cudaGraph_t graph = nullptr;
      CF_CUDA_CHECK(cudaStreamEndCapture(stream, &graph));
      if (key != key_) {
        cudaGraphDestroy(graph);
        throw Error("internal error: the build's graph was captured while a buffer it names changed");
      }
      const cudaError_t made = cudaGraphInstantiate(&exec_, graph, 0);
      cudaGraphDestroy(graph);
      if (made != cudaSuccess) {
        exec_ = nullptr;
        CF_CUDA_CHECK(made);
      }
      CF_CUDA_CHECK(cudaGraphLaunch(exec_, stream));
      graph_key_ = key_;
      ++captures_;
    } else if (mode == Mode::kReplay && key != key_) {
      drop();
      throw Error("internal error: the build's graph was replayed while a buffer it names changed");
    }
    last_before_ = std::move(key_);
    last_after_ = key;
    key_.clear();
  }

  // An exception left the part: a capture in progress is ended and thrown away, and nothing is
  // reused from it (never throws).
  void abandon(cudaStream_t stream) noexcept {
    if (mode_ == Mode::kCapture || auditing_) {
      cudaGraph_t graph = nullptr;
      if (cudaStreamEndCapture(stream, &graph) == cudaSuccess && graph) cudaGraphDestroy(graph);
      (void)cudaGetLastError();
    }
    mode_ = Mode::kIdle;
    auditing_ = false;
    key_.clear();
    last_before_.clear();
    last_after_.clear();
  }

  // Whether an operation of the part is to be queued now (false while a graph replays them).
  bool queuing() const { return mode_ != Mode::kReplay; }
  bool capturing() const { return mode_ == Mode::kCapture; }
  bool open() const { return mode_ != Mode::kIdle; }  // a build begun with `allowed` has not ended
  std::size_t replays() const { return replays_; }    // builds whose part a graph replayed
  std::size_t captures() const { return captures_; }  // graphs captured

 private:
  void drop() {
    if (exec_) {
      cudaGraphExec_t exec = exec_;
      exec_ = nullptr;
      graph_key_.clear();
      CF_CUDA_CHECK(cudaGraphExecDestroy(exec));
    }
  }

  Mode mode_ = Mode::kIdle;
  bool auditing_ = false;  // a replay's bookkeeping under a capture that must stay empty
  Key key_, graph_key_, last_before_, last_after_;
  cudaGraphExec_t exec_ = nullptr;
  std::size_t replays_ = 0, captures_ = 0;
};

// Appends a value's bits to a key.
template <class T>
void add_to_key(BuildGraph::Key& key, const T& value) {
  static_assert(sizeof(T) <= sizeof(uint64_t) && std::is_trivially_copyable_v<T>);
  uint64_t bits = 0;
  std::memcpy(&bits, &value, sizeof(T));
  key.push_back(bits);
}

}  // namespace cellforce::cuda
