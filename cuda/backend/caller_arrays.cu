#include "backend/caller_arrays.cuh"

#include "check.cuh"

namespace cellforce::cuda {
namespace {

// One thread a coordinate: row i's element a of the caller's array into out[i * dim + a].
template <class T>
__global__ void pack_positions_kernel(const T* __restrict__ in, std::size_t stride, std::size_t n, int dim,
                                      double* __restrict__ out) {
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= n * std::size_t(dim)) return;
  const std::size_t i = k / std::size_t(dim), a = k % std::size_t(dim);
  out[k] = double(in[i * stride + a]);
}

}  // namespace

void pack_positions(const void* in, Scalar scalar, std::size_t stride, std::size_t n, int dim, double* out,
                    cudaStream_t stream) {
  const std::size_t count = n * std::size_t(dim);
  if (count == 0) return;
  constexpr int kBlock = 256;
  const unsigned blocks = unsigned((count + kBlock - 1) / kBlock);
  if (scalar == Scalar::kFloat32)
    pack_positions_kernel<<<blocks, kBlock, 0, stream>>>(static_cast<const float*>(in), stride, n, dim, out);
  else
    pack_positions_kernel<<<blocks, kBlock, 0, stream>>>(static_cast<const double*>(in), stride, n, dim, out);
  CF_CUDA_CHECK_LAUNCH();
}

}  // namespace cellforce::cuda
