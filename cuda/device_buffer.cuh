// Device memory sized from counts: a buffer grows when a count says it must, and shrinks only when
// its owner releases it (release(): dead until its next use).
// A buffer bound to a stream (bind) grows in stream order (cudaFreeAsync / cudaMallocAsync on that
// stream), so that growing it never waits for the device: work queued earlier on the stream still
// reads the old memory, work queued later the new. Unbound, growth frees with cudaFree, which
// waits for the device.
#pragma once

#include <cuda_runtime.h>

#include <cstddef>
#include <utility>

#include "check.cuh"

namespace cellforce::cuda {

// While a FrozenBuffers lives on this thread, no buffer may take or give back memory: inside the
// capture of a CUDA graph (backend/call_graph.cuh) memory taken would be the graph's own, and
// memory given back would be freed at every launch. A buffer that would throws instead, and the
// capture is abandoned.
inline int& frozen_buffers() {
  static thread_local int depth = 0;
  return depth;
}
struct FrozenBuffers {
  FrozenBuffers() { ++frozen_buffers(); }
  ~FrozenBuffers() { --frozen_buffers(); }
  FrozenBuffers(const FrozenBuffers&) = delete;
  FrozenBuffers& operator=(const FrozenBuffers&) = delete;
};

template <class T>
class DeviceBuffer {
 public:
  using value_type = T;
  DeviceBuffer() = default;
  explicit DeviceBuffer(std::size_t n) { reserve(n); }
  ~DeviceBuffer() {
    // A destructor cannot throw: an error here shows up at the next checked CUDA call. cudaFree
    // also frees stream-ordered memory, without waiting for the work that uses it: the owner of a
    // bound buffer synchronises its stream first.
    if (ptr_) cudaFree(ptr_);
  }
  DeviceBuffer(const DeviceBuffer&) = delete;
  DeviceBuffer& operator=(const DeviceBuffer&) = delete;
  DeviceBuffer(DeviceBuffer&& o) noexcept
      : ptr_(std::exchange(o.ptr_, nullptr)), capacity_(std::exchange(o.capacity_, 0)),
        stream_(o.stream_), bound_(o.bound_) {}
  DeviceBuffer& operator=(DeviceBuffer&& o) noexcept {
    std::swap(ptr_, o.ptr_);
    std::swap(capacity_, o.capacity_);
    std::swap(stream_, o.stream_);
    std::swap(bound_, o.bound_);
    return *this;
  }

  // From now on the buffer grows in the order of `stream` (see above).
  void bind(cudaStream_t stream) {
    stream_ = stream;
    bound_ = true;
  }

  // Makes room for n elements; the contents are not kept when it grows.
  void reserve(std::size_t n) {
    if (n <= capacity_) return;
    if (frozen_buffers()) throw Error("internal error: a device buffer grew inside a graph's capture");
    T* old = std::exchange(ptr_, nullptr);
    capacity_ = 0;
    if (bound_) {
      if (old) CF_CUDA_CHECK(cudaFreeAsync(old, stream_));
      CF_CUDA_CHECK(cudaMallocAsync(reinterpret_cast<void**>(&ptr_), n * sizeof(T), stream_));
    } else {
      if (old) CF_CUDA_CHECK(cudaFree(old));
      CF_CUDA_CHECK(cudaMalloc(reinterpret_cast<void**>(&ptr_), n * sizeof(T)));
    }
    capacity_ = n;
  }
  // Frees the memory (in stream order when bound: work queued earlier still reads it), so that a
  // buffer dead between two uses does not add to the peak.
  void release() {
    if (ptr_ && frozen_buffers()) throw Error("internal error: a device buffer was freed inside a graph's capture");
    T* old = std::exchange(ptr_, nullptr);
    capacity_ = 0;
    if (!old) return;
    if (bound_) CF_CUDA_CHECK(cudaFreeAsync(old, stream_));
    else CF_CUDA_CHECK(cudaFree(old));
  }
  T* data() const { return ptr_; }
  std::size_t capacity() const { return capacity_; }
  std::size_t bytes() const { return capacity_ * sizeof(T); }

 private:
  T* ptr_ = nullptr;
  std::size_t capacity_ = 0;
  cudaStream_t stream_ = nullptr;
  bool bound_ = false;
};

}  // namespace cellforce::cuda
