// FIRE's kernels and reductions (integrate/fire_kernels.cuh).
#include <cub/device/device_reduce.cuh>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/iterator/transform_iterator.h>

#include <algorithm>

#include "check.cuh"
#include "core/hd.h"
#include "integrate/fire_kernels.cuh"
#include "md/fire_step.h"

namespace cellforce::cuda {
namespace {

constexpr int kBlock = 256;
unsigned blocks_for(std::size_t n) { return unsigned((n + kBlock - 1) / kBlock); }

// Particle i's terms of ForceSums (its per-particle |F_i|^2 summed as largest_force sums it).
struct ForceTerm {
  const double* f;
  const double* v;
  int dim;
  __host__ __device__ ForceSums operator()(std::size_t i) const {
    double p = 0, f2 = 0;
    for (int a = 0; a < dim; ++a) {
      const double fa = f[i * dim + a];
      p = p + mul_rn(fa, v[i * dim + a]);
      f2 = f2 + mul_rn(fa, fa);
    }
    return ForceSums{p, f2, f2, i};
  }
};

struct CombineForceSums {
  __host__ __device__ ForceSums operator()(const ForceSums& a, const ForceSums& b) const {
    const bool a_nan = a.largest2 != a.largest2, b_nan = b.largest2 != b.largest2;
    bool take_b;
    if (a_nan != b_nan) take_b = b_nan;
    else if (a_nan || a.largest2 == b.largest2) take_b = b.particle < a.particle;
    else take_b = b.largest2 > a.largest2;
    return ForceSums{a.power + b.power, a.f2 + b.f2, take_b ? b.largest2 : a.largest2,
                     take_b ? b.particle : a.particle};
  }
};

// Particle i's v^2.
struct SpeedTerm {
  const double* v;
  int dim;
  __host__ __device__ double operator()(std::size_t i) const {
    double v2 = 0;
    for (int a = 0; a < dim; ++a) v2 = v2 + mul_rn(v[i * dim + a], v[i * dim + a]);
    return v2;
  }
};

// An uphill step's step back by half a step (x -= half_dt v, v = 0) when `uphill`, then the kick
// v += (dt / m) F; per particle.
__global__ void fire_kick_kernel(double* __restrict__ x, double* __restrict__ v, const double* __restrict__ f,
                                 const double* __restrict__ mass, double dt, double half_dt, bool uphill,
                                 std::size_t n, int dim) {
  const std::size_t i = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  const std::size_t k = i * dim;
  if (uphill) fire_step_back(x + k, v + k, half_dt, dim);
  fire_kick(v + k, f + k, dt, mass[i], dim);
}

// The velocity mixing (the sums from the device: sums->v2, sums->forces.f2), the displacement cap
// and the drift, then the wrap on periodic axes; a coordinate that is not finite raises
// sums->bad_position (axis x n + particle, the smallest: the host's wrap names the same one).
__global__ void fire_drift_kernel(double* __restrict__ x, double* __restrict__ v, const double* __restrict__ f,
                                  FireScalars* sums, double alpha, double dt, double max_displacement,
                                  WrapBox box, std::size_t n) {
  const std::size_t i = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  const int dim = box.dim;
  const std::size_t k = i * dim;
  double mix = 0;
  if (fire_mix_factor(alpha, sums->v2, sums->forces.f2, mix)) fire_mix(v + k, f + k, alpha, mix, dim);
  fire_cap(v + k, dt, max_displacement, dim);
  fire_drift(x + k, v + k, dt, dim);
  for (int a = 0; a < dim; ++a) {
    const double xa = x[k + a];
    if (!isfinite(xa))
      atomicMin(&sums->bad_position, static_cast<unsigned long long>(a) * n + i);
    else if (box.periodic[a])
      x[k + a] = wrap_coordinate(xa, box.length[a]);
  }
}

}  // namespace

void queue_fire_kick(double* x, double* v, const double* f, const double* mass, double dt, double half_dt,
                     bool uphill, std::size_t n, int dim, cudaStream_t stream) {
  if (n == 0) return;
  fire_kick_kernel<<<blocks_for(n), kBlock, 0, stream>>>(x, v, f, mass, dt, half_dt, uphill, n, dim);
  CF_CUDA_CHECK_LAUNCH();
}

void sum_fire_speeds(const double* v, std::size_t n, int dim, double* v2, DeviceBuffer<std::byte>& scratch,
                     cudaStream_t stream) {
  auto speeds = thrust::make_transform_iterator(thrust::counting_iterator<std::size_t>(0), SpeedTerm{v, dim});
  std::size_t bytes = 0;
  CF_CUDA_CHECK(cub::DeviceReduce::Sum(nullptr, bytes, speeds, v2, n, stream));
  scratch.reserve(std::max<std::size_t>(bytes, 1));
  CF_CUDA_CHECK(cub::DeviceReduce::Sum(scratch.data(), bytes, speeds, v2, n, stream));
}

void queue_fire_drift(double* x, double* v, const double* f, FireScalars* sums, double alpha, double dt,
                      double max_displacement, const WrapBox& box, std::size_t n, cudaStream_t stream) {
  if (n == 0) return;
  fire_drift_kernel<<<blocks_for(n), kBlock, 0, stream>>>(x, v, f, sums, alpha, dt, max_displacement, box, n);
  CF_CUDA_CHECK_LAUNCH();
}

void sum_fire_forces(const double* f, const double* v, std::size_t n, int dim, ForceSums* out,
                     DeviceBuffer<std::byte>& scratch, cudaStream_t stream) {
  if (n == 0) return;
  const ForceSums none{0, 0, -1, 0};  // largest_force's answer without particles
  auto terms = thrust::make_transform_iterator(thrust::counting_iterator<std::size_t>(0), ForceTerm{f, v, dim});
  std::size_t bytes = 0;
  CF_CUDA_CHECK(cub::DeviceReduce::Reduce(nullptr, bytes, terms, out, n, CombineForceSums{}, none, stream));
  scratch.reserve(std::max<std::size_t>(bytes, 1));
  CF_CUDA_CHECK(cub::DeviceReduce::Reduce(scratch.data(), bytes, terms, out, n, CombineForceSums{}, none, stream));
}

}  // namespace cellforce::cuda
