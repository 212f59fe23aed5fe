// Stage 2, sort (GPU Gems 3 ch. 32, sections 32.2.3-32.2.4) with CUB's device radix sort: LSD,
// hence stable, restricted to the bits the grid needs. The chapter's own three-phase radix sort
// joins it behind the same interface in issue 3.
#include <cub/device/device_radix_sort.cuh>

#include "stages.cuh"

namespace cellforce::cuda {

void radix_sort_cub(const uint32_t* keys_in, const uint32_t* values_in, uint32_t* keys_out,
                    uint32_t* values_out, std::size_t entries, int key_bits,
                    DeviceBuffer<std::byte>& scratch, cudaStream_t stream) {
  if (entries == 0) return;
  if (entries > std::size_t(INT32_MAX)) throw Error("sort of more than 2^31 entries");
  const int n = int(entries);
  std::size_t bytes = 0;
  CF_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(nullptr, bytes, keys_in, keys_out, values_in,
                                                values_out, n, 0, key_bits, stream));
  scratch.reserve(bytes);
  CF_CUDA_CHECK(cub::DeviceRadixSort::SortPairs(scratch.data(), bytes, keys_in, keys_out, values_in,
                                                values_out, n, 0, key_bits, stream));
}

}  // namespace cellforce::cuda
