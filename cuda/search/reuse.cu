// Reuse of the neighbour structure (src/core/reuse.h) on the device: the largest displacement
// since the build, by a CUB max-reduction over particles, read back once per evaluation (the step
// gate's kick-drift measures the same number on gated steps: step_gate.h).
#include <cub/device/device_reduce.cuh>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/iterator/transform_iterator.h>

#include "search/stages.cuh"

namespace cellforce::cuda {
namespace {

// Squared displacement of particle i, minimum image on periodic axes (inv_length 0 elsewhere).
struct Displacement2 {
  const double* now;
  const double* then;
  int dim;
  double length[kMaxDim];
  double inv_length[kMaxDim];
  __host__ __device__ double operator()(std::size_t i) const {
    double d2 = 0;
    for (int a = 0; a < dim; ++a) {
      d2 += displacement_term(now[i * dim + a], then[i * dim + a], length[a], inv_length[a]);
    }
    return d2;
  }
};

}  // namespace

double max_displacement2(const Box& box, const double* now, const double* then, std::size_t n,
                         DeviceBuffer<std::byte>& scratch, cudaStream_t stream) {
  if (n == 0) return 0.0;
  Displacement2 f{now, then, box.dim, {0, 0, 0}, {0, 0, 0}};
  for (int a = 0; a < box.dim; ++a) {
    f.length[a] = box.length[a];
    f.inv_length[a] = box.periodic[a] ? 1.0 / box.length[a] : 0.0;
  }
  auto d2 = thrust::make_transform_iterator(thrust::counting_iterator<std::size_t>(0), f);
  // As count_valid: the result in the first 256 bytes, CUB's temporaries after them.
  constexpr std::size_t kResultBytes = 256;
  std::size_t bytes = 0;
  CF_CUDA_CHECK(cub::DeviceReduce::Max(nullptr, bytes, d2, static_cast<double*>(nullptr), n, stream));
  scratch.reserve(kResultBytes + bytes);
  auto* result = reinterpret_cast<double*>(scratch.data());
  CF_CUDA_CHECK(cub::DeviceReduce::Max(scratch.data() + kResultBytes, bytes, d2, result, n, stream));
  double worst = 0;
  CF_CUDA_CHECK(cudaMemcpyAsync(&worst, result, sizeof(worst), cudaMemcpyDeviceToHost, stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(stream));
  return worst;
}

}  // namespace cellforce::cuda

// ---- the particles' bounds (grid planning of open axes in resident evaluations) ----------------
namespace cellforce::cuda {
namespace {

struct Coordinate {
  const double* positions;
  int dim, axis;
  __host__ __device__ double operator()(std::size_t i) const { return positions[i * dim + axis]; }
};

}  // namespace

void bounding_box(const double* positions, std::size_t n, int dim, double lo[], double hi[],
                  DeviceBuffer<std::byte>& scratch, cudaStream_t stream) {
  for (int a = 0; a < dim; ++a) lo[a] = hi[a] = 0.0;
  if (n == 0) return;
  constexpr std::size_t kResultBytes = 256;  // 2 x dim results first, CUB's temporaries after them
  std::size_t bytes = 0;
  auto first = thrust::make_transform_iterator(thrust::counting_iterator<std::size_t>(0), Coordinate{positions, dim, 0});
  CF_CUDA_CHECK(cub::DeviceReduce::Min(nullptr, bytes, first, static_cast<double*>(nullptr), n, stream));
  scratch.reserve(kResultBytes + bytes);
  auto* result = reinterpret_cast<double*>(scratch.data());
  for (int a = 0; a < dim; ++a) {
    auto x = thrust::make_transform_iterator(thrust::counting_iterator<std::size_t>(0), Coordinate{positions, dim, a});
    std::size_t b = bytes;
    CF_CUDA_CHECK(cub::DeviceReduce::Min(scratch.data() + kResultBytes, b, x, result + a, n, stream));
    b = bytes;
    CF_CUDA_CHECK(cub::DeviceReduce::Max(scratch.data() + kResultBytes, b, x, result + dim + a, n, stream));
  }
  double host[2 * kMaxDim] = {};
  CF_CUDA_CHECK(cudaMemcpyAsync(host, result, 2 * std::size_t(dim) * sizeof(double), cudaMemcpyDeviceToHost, stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(stream));
  for (int a = 0; a < dim; ++a) {
    lo[a] = host[a];
    hi[a] = host[dim + a];
  }
}

}  // namespace cellforce::cuda
