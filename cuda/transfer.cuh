// Host <-> device copies queued on a stream, for the engines' host code: a host array into a
// DeviceBuffer (reserved to at least one element, so that its pointer is never null) and a device
// array into a host vector (resized to `count`). Neither waits: the caller synchronises before it
// reads a download.
#pragma once

#include <cuda_runtime.h>

#include <algorithm>
#include <cstddef>
#include <vector>

#include "check.cuh"
#include "device_buffer.cuh"

namespace cellforce::cuda {

template <class T>
void upload(DeviceBuffer<T>& d, const T* h, std::size_t count, cudaStream_t stream) {
  d.reserve(std::max<std::size_t>(count, 1));
  if (count) CF_CUDA_CHECK(cudaMemcpyAsync(d.data(), h, count * sizeof(T), cudaMemcpyHostToDevice, stream));
}

template <class T>
void upload(DeviceBuffer<T>& d, const std::vector<T>& h, cudaStream_t stream) {
  upload(d, h.data(), h.size(), stream);
}

template <class T>
void download(std::vector<T>& h, const T* d, std::size_t count, cudaStream_t stream) {
  h.resize(count);
  if (count) CF_CUDA_CHECK(cudaMemcpyAsync(h.data(), d, count * sizeof(T), cudaMemcpyDeviceToHost, stream));
}

}  // namespace cellforce::cuda
