// Host <-> device copies of a caller's pageable host arrays through two pinned chunks of the
// engine's own: the copy between the caller's memory and a chunk (on the host) overlaps the DMA of
// the other chunk, and the DMA runs at the link's pinned rate. A pageable cudaMemcpy stages through
// the driver's buffers at a fraction of that rate, and a download into a freshly allocated vector
// also pays a page fault for every page it writes. Memory held: two chunks, whatever the arrays'
// size.
#pragma once

#include <cuda_runtime.h>

#include <algorithm>
#include <cstddef>
#include <cstring>

#include "check.cuh"

namespace cellforce::cuda {

class PinnedStaging {
 public:
  PinnedStaging() = default;
  PinnedStaging(const PinnedStaging&) = delete;
  PinnedStaging& operator=(const PinnedStaging&) = delete;
  ~PinnedStaging() {  // a destructor cannot throw: errors are ignored
    for (int k = 0; k < 2; ++k) {
      if (done_[k]) {
        cudaEventSynchronize(done_[k]);
        cudaEventDestroy(done_[k]);
      }
      if (chunk_[k]) cudaFreeHost(chunk_[k]);
    }
  }

  // Queues the copy of h[0, count) to d on `stream` and returns once the last chunk is staged (the
  // DMA may still run: the chunks are reused only after their copies completed). `check(chunk,
  // count)` sees each chunk's elements once, as staged, and returns false to stop: upload then
  // returns false, with d partly written.
  template <class T, class Check>
  bool upload(T* d, const T* h, std::size_t count, cudaStream_t stream, Check&& check) {
    ready();
    const std::size_t per = kChunkBytes / sizeof(T);
    for (std::size_t first = 0, k = 0; first < count; first += per, k ^= 1) {
      const std::size_t m = std::min(per, count - first);
      CF_CUDA_CHECK(cudaEventSynchronize(done_[k]));  // the chunk's previous copy has left it
      T* chunk = static_cast<T*>(chunk_[k]);
      std::memcpy(chunk, h + first, m * sizeof(T));
      if (!check(static_cast<const T*>(chunk), m)) return false;
      CF_CUDA_CHECK(cudaMemcpyAsync(d + first, chunk, m * sizeof(T), cudaMemcpyHostToDevice, stream));
      CF_CUDA_CHECK(cudaEventRecord(done_[k], stream));
    }
    return true;
  }

  // Copies d[0, count) to h after the work queued on `stream` so far; returns with h written.
  template <class T>
  void download(T* h, const T* d, std::size_t count, cudaStream_t stream) {
    ready();
    const std::size_t per = kChunkBytes / sizeof(T);
    std::size_t pending_first = 0, pending_count = 0;
    int pending = -1;
    auto drain = [&] {  // the chunk in flight to its place in h
      if (pending < 0) return;
      CF_CUDA_CHECK(cudaEventSynchronize(done_[pending]));
      std::memcpy(h + pending_first, chunk_[pending], pending_count * sizeof(T));
      pending = -1;
    };
    for (std::size_t first = 0, k = 0; first < count; first += per, k ^= 1) {
      const std::size_t m = std::min(per, count - first);
      CF_CUDA_CHECK(cudaEventSynchronize(done_[k]));
      CF_CUDA_CHECK(cudaMemcpyAsync(chunk_[k], d + first, m * sizeof(T), cudaMemcpyDeviceToHost, stream));
      CF_CUDA_CHECK(cudaEventRecord(done_[k], stream));
      drain();  // the other chunk, while this one's DMA runs
      pending = int(k);
      pending_first = first;
      pending_count = m;
    }
    drain();
  }

 private:
  static constexpr std::size_t kChunkBytes = std::size_t(4) << 20;

  void ready() {
    for (int k = 0; k < 2; ++k) {
      if (!chunk_[k]) CF_CUDA_CHECK(cudaMallocHost(&chunk_[k], kChunkBytes));
      if (!done_[k]) CF_CUDA_CHECK(cudaEventCreateWithFlags(&done_[k], cudaEventDisableTiming));
    }
  }

  void* chunk_[2] = {};
  cudaEvent_t done_[2] = {};
};

}  // namespace cellforce::cuda
