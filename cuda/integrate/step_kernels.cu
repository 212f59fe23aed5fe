// The ungated step kernels (integrate/step_kernels.cuh).
#include <cub/device/device_reduce.cuh>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/iterator/transform_iterator.h>

#include <algorithm>

#include "check.cuh"
#include "core/random.h"
#include "integrate/step_kernels.cuh"

namespace cellforce::cuda {
namespace {

constexpr int kBlock = 256;
unsigned blocks_for(std::size_t n) { return unsigned((n + kBlock - 1) / kBlock); }

// Coordinate k of kick_value, in place.
__device__ __forceinline__ void kick_coordinate(double* __restrict__ v, const double* __restrict__ f,
                                                const double* __restrict__ mass, double h, int kicks, int dim,
                                                std::size_t k) {
  v[k] = kick_value(v[k], f[k], mass[k / std::size_t(dim)], h, kicks);
}

__global__ void kick_kernel(double* __restrict__ v, const double* __restrict__ f,
                            const double* __restrict__ mass, double h, int kicks, std::size_t n, int dim) {
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= n * std::size_t(dim)) return;
  kick_coordinate(v, f, mass, h, kicks, dim, k);
}

// Coordinate k of drift_value, in place (a particle that fails raises its index).
__device__ __forceinline__ double drift_coordinate(double* __restrict__ x, const double* __restrict__ v, double h,
                                                   const DriftBox& box, bool wrap, std::size_t k, MdFlags* flags) {
  const std::size_t i = k / std::size_t(box.dim);
  const int a = int(k - i * std::size_t(box.dim));
  const double va = v[k];
  bool bad;
  const double xa = drift_value(x[k], va, h, drift_axis(box, a), wrap, bad);
  x[k] = xa;
  flag_diverged(bad, i, a, h, va, flags);
  return xa;
}

// A drift per particle (drift_coordinate on each axis).
__global__ void drift_kernel(double* __restrict__ x, const double* __restrict__ v, double h, DriftBox box,
                             bool wrap, std::size_t n, MdFlags* flags) {
  const std::size_t i = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  for (int a = 0; a < box.dim; ++a) drift_coordinate(x, v, h, box, wrap, i * box.dim + a, flags);
}

// One coordinate k of velocity Verlet's kicks and drift: `kicks` half kicks v += (h / m) F (two:
// the previous step's closing kick and this step's opening one, rounded one after the other
// exactly as two kicks would), then the full drift x += dt v with the check and the
// wrap of drift_kernel. Returns the new coordinate.
__device__ __forceinline__ double kick_drift_coordinate(double* __restrict__ x, double* __restrict__ v,
                                                        const double* __restrict__ f,
                                                        const double* __restrict__ mass, double h, int kicks,
                                                        double dt, const DriftBox& box, std::size_t k,
                                                        MdFlags* flags) {
  kick_coordinate(v, f, mass, h, kicks, box.dim, k);
  return drift_coordinate(x, v, dt, box, true, k, flags);
}

// The kicks and the drift in one pass, a thread per coordinate (coalesced): one read and write of
// the state per step instead of three.
__global__ void kick_drift_kernel(double* __restrict__ x, double* __restrict__ v, const double* __restrict__ f,
                                  const double* __restrict__ mass, double h, int kicks, double dt, DriftBox box,
                                  std::size_t n, MdFlags* flags) {
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= n * std::size_t(box.dim)) return;
  kick_drift_coordinate(x, v, f, mass, h, kicks, dt, box, k, flags);
}

// BAOAB's O step: v = c1 v + c2 sqrt(kT / m) xi, xi from counter_normal keyed by the step and the
// particle's stable ID (its index in the caller's order), as the host integrator draws it.
__global__ void thermostat_kernel(double* __restrict__ v, const double* __restrict__ mass, double c1,
                                  double c2, double kT, uint64_t seed, uint64_t stream, std::size_t n, int dim) {
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= n * std::size_t(dim)) return;
  const double sigma = thermostat_sigma(c2, kT, mass[k / std::size_t(dim)]);
  v[k] = thermostat_value(v[k], c1, sigma, counter_normal(seed, stream, k));
}

// m v^2 / 2 of particle i (summed over axes), for the kinetic-energy reduction.
struct KineticTerm {
  const double* v;
  const double* mass;
  int dim;
  __host__ __device__ double operator()(std::size_t i) const {
    double v2 = 0;
    for (int a = 0; a < dim; ++a) v2 += v[i * dim + a] * v[i * dim + a];
    return 0.5 * mass[i] * v2;
  }
};

__global__ void add_kernel(double* __restrict__ f, const double* __restrict__ add, std::size_t count) {
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k < count) f[k] += add[k];
}
}  // namespace

void queue_add(double* f, const double* add, std::size_t count, cudaStream_t stream) {
  if (count == 0) return;
  add_kernel<<<blocks_for(count), kBlock, 0, stream>>>(f, add, count);
  CF_CUDA_CHECK_LAUNCH();
}

void queue_kick(double* v, const double* f, const double* mass, double h, int kicks, std::size_t n, int dim,
                cudaStream_t stream) {
  if (n == 0) return;
  kick_kernel<<<blocks_for(n * dim), kBlock, 0, stream>>>(v, f, mass, h, kicks, n, dim);
  CF_CUDA_CHECK_LAUNCH();
}

void queue_drift(double* x, const double* v, double h, const DriftBox& box, bool wrap, std::size_t n,
                 MdFlags* flags, cudaStream_t stream) {
  if (n == 0) return;
  drift_kernel<<<blocks_for(n), kBlock, 0, stream>>>(x, v, h, box, wrap, n, flags);
  CF_CUDA_CHECK_LAUNCH();
}

void queue_kick_drift(double* x, double* v, const double* f, const double* mass, double h, int kicks, double dt,
                      const DriftBox& box, std::size_t n, MdFlags* flags, cudaStream_t stream) {
  if (n == 0) return;
  kick_drift_kernel<<<blocks_for(n * box.dim), kBlock, 0, stream>>>(x, v, f, mass, h, kicks, dt, box, n, flags);
  CF_CUDA_CHECK_LAUNCH();
}

void queue_thermostat(double* v, const double* mass, double c1, double c2, double kT, uint64_t seed,
                      uint64_t noise_stream, std::size_t n, int dim, cudaStream_t stream) {
  if (n == 0) return;
  thermostat_kernel<<<blocks_for(n * dim), kBlock, 0, stream>>>(v, mass, c1, c2, kT, seed, noise_stream, n, dim);
  CF_CUDA_CHECK_LAUNCH();
}

void sum_kinetic_energy(const double* v, const double* mass, std::size_t n, int dim, double* result,
                        DeviceBuffer<std::byte>& scratch, cudaStream_t stream) {
  if (n == 0) {
    CF_CUDA_CHECK(cudaMemsetAsync(result, 0, sizeof(double), stream));
    return;
  }
  auto terms = thrust::make_transform_iterator(thrust::counting_iterator<std::size_t>(0), KineticTerm{v, mass, dim});
  std::size_t bytes = 0;
  CF_CUDA_CHECK(cub::DeviceReduce::Sum(nullptr, bytes, terms, result, n, stream));
  scratch.reserve(std::max<std::size_t>(bytes, 1));
  CF_CUDA_CHECK(cub::DeviceReduce::Sum(scratch.data(), bytes, terms, result, n, stream));
}

}  // namespace cellforce::cuda
