// A value a kernel posts into mapped host memory for the host to read without a copy or an event
// (the gate's notice and copy, integrate/gate_readback.cuh, and the list's sizes,
// search/pair_list.cuh SizesReadback). The kernel writes the values, a system-wide fence, then a tag
// (the host's number for the chunk or build, never 0); the host spins on the tag with an acquire
// load, so that the values it then reads are the ones written before it.
#pragma once

#include <cuda_runtime.h>

#include <type_traits>

#include "check.cuh"

namespace cellforce::cuda {

// One T (trivially copyable, with an `unsigned long long tag` member written last) in mapped,
// pinned host memory, made on the current device when first asked for, zeroed (tag 0: nothing
// posted yet), freed with the object. A post still pending when it goes would write freed memory:
// its owner synchronises the stream before (the engines' destructors and each MD run's end).
template <class T>
class MappedPost {
  static_assert(std::is_trivially_copyable_v<T>, "a kernel writes it, the host reads it");
  static_assert(std::is_same_v<decltype(T::tag), unsigned long long>, "the tag the host spins on");

 public:
  MappedPost() = default;
  MappedPost(const MappedPost&) = delete;
  MappedPost& operator=(const MappedPost&) = delete;
  ~MappedPost() {  // a destructor cannot throw: errors are ignored
    if (host_) cudaFreeHost(host_);
  }

  // Where a kernel posts (the device's view of the memory), made where it is not yet. The device
  // pointer is asked for apart from the allocation: a failure between the two leaves the memory
  // held and the pointer asked for again, never a null pointer handed to a kernel.
  T* device() {
    if (!host_) {
      void* p = nullptr;
      CF_CUDA_CHECK(cudaHostAlloc(&p, sizeof(T), cudaHostAllocMapped));
      host_ = static_cast<T*>(p);
      *host_ = T{};
    }
    if (!device_) CF_CUDA_CHECK(cudaHostGetDevicePointer(reinterpret_cast<void**>(&device_), host_, 0));
    return device_;
  }

  // Whether the post tagged `tag` has arrived (an acquire load: the values written before the tag
  // are then read after it). False before the memory is made.
  bool arrived(unsigned long long tag) const {
    return host_ && __atomic_load_n(&host_->tag, __ATOMIC_ACQUIRE) == tag;
  }

  // The tag posted last (an acquire load; 0 before the memory is made or anything was posted).
  unsigned long long tag() const { return host_ ? __atomic_load_n(&host_->tag, __ATOMIC_ACQUIRE) : 0; }

  // The posted values, read once the tag has arrived (volatile: the device writes them; only after
  // arrived() is true, so the memory exists).
  const volatile T& values() const { return *host_; }

 private:
  T* host_ = nullptr;
  T* device_ = nullptr;
};

}  // namespace cellforce::cuda
