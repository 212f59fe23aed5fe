#include "cli/embed_loop.h"

#include <cuda_runtime.h>

#include <algorithm>
#include <chrono>
#include <string>
#include <vector>

#include <cellforce/error.hpp>

namespace cellforce {
namespace {

void check(cudaError_t err, const char* what) {
  if (err != cudaSuccess)
    throw Error(std::string("bench --embed: ") + what + ": " + cudaGetErrorName(err) + " (" +
                cudaGetErrorString(err) + ")");
}

template <class T>
T* device_array(std::size_t count, const T* from = nullptr) {
  void* p = nullptr;
  check(cudaMalloc(&p, std::max<std::size_t>(count, 1) * sizeof(T)), "cudaMalloc");
  if (from) check(cudaMemcpy(p, from, count * sizeof(T), cudaMemcpyHostToDevice), "upload");
  return static_cast<T*>(p);
}

constexpr int kBlock = 256;
unsigned blocks(std::size_t count) { return unsigned((count + kBlock - 1) / kBlock); }

// v += dt/2 F/m, then (drift) x += dt v: one thread per coordinate.
__global__ void kick_drift(std::size_t count, int dim, double half_dt, double dt, const double* forces,
                           const double* inv_mass, double* velocities, double* positions, bool drift) {
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= count) return;
  const double v = velocities[k] + half_dt * forces[k] * inv_mass[k / std::size_t(dim)];
  velocities[k] = v;
  if (drift) positions[k] += dt * v;
}

// Sum of m v^2 / 2 into *kinetic (zeroed before): a block's partial sums, then one atomic each.
__global__ void kinetic_energy(std::size_t count, int dim, const double* velocities, const double* inv_mass,
                               double* kinetic) {
  __shared__ double partial[kBlock];
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  const double v = k < count ? velocities[k] : 0.0;
  partial[threadIdx.x] = k < count ? 0.5 * v * v / inv_mass[k / std::size_t(dim)] : 0.0;
  __syncthreads();
  for (int s = kBlock / 2; s > 0; s /= 2) {
    if (int(threadIdx.x) < s) partial[threadIdx.x] += partial[threadIdx.x + s];
    __syncthreads();
  }
  if (threadIdx.x == 0) atomicAdd(kinetic, partial[0]);
}

}  // namespace

struct EmbeddedVerlet::Impl {
  Context& ctx;
  std::size_t n = 0;
  int dim = 3;
  double dt = 0;
  cudaStream_t stream = nullptr;
  double *x = nullptr, *v = nullptr, *f = nullptr, *inv_mass = nullptr, *sums = nullptr;  // sums: U, KE
  uint32_t* types = nullptr;
  double call_seconds = 0;  // host time inside compute_device, over `calls` calls
  int64_t calls = 0;

  explicit Impl(Context& c) : ctx(c) {}
  ~Impl() {
    for (void* p : {static_cast<void*>(x), static_cast<void*>(v), static_cast<void*>(f), static_cast<void*>(inv_mass),
                    static_cast<void*>(sums), static_cast<void*>(types)})
      if (p) cudaFree(p);
    if (stream) cudaStreamDestroy(stream);
  }

  void forces(bool observe) {
    Outputs out;
    out.forces = f;
    out.energy = observe ? sums : nullptr;
    const auto t0 = std::chrono::steady_clock::now();
    ctx.compute_device(n, x, types, out, stream);
    call_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    ++calls;
  }
  void kick(bool drift) {
    const std::size_t count = n * std::size_t(dim);
    if (count == 0) return;
    kick_drift<<<blocks(count), kBlock, 0, stream>>>(count, dim, 0.5 * dt, dt, f, inv_mass, v, x, drift);
    check(cudaGetLastError(), "kick_drift launch");
  }
};

EmbeddedVerlet::EmbeddedVerlet(Context& ctx, std::size_t n, const double* positions, const double* velocities,
                               const uint32_t* types, const double* masses, double dt)
    : impl_(std::make_unique<Impl>(ctx)) {
  Impl& s = *impl_;
  s.n = n;
  s.dim = ctx.dim();
  s.dt = dt;
  const std::size_t count = n * std::size_t(s.dim);
  std::vector<double> inv_mass(n);
  for (std::size_t i = 0; i < n; ++i) inv_mass[i] = 1.0 / masses[i];
  check(cudaStreamCreateWithFlags(&s.stream, cudaStreamNonBlocking), "cudaStreamCreate");
  s.x = device_array(count, positions);
  s.v = device_array(count, velocities);
  s.f = device_array<double>(count);
  s.inv_mass = device_array(n, inv_mass.data());
  s.types = types ? device_array(n, types) : nullptr;  // null: all type 0
  s.sums = device_array<double>(2);
  s.forces(true);
}

EmbeddedVerlet::~EmbeddedVerlet() = default;

double EmbeddedVerlet::call_host_seconds() const {
  return impl_->calls ? impl_->call_seconds / double(impl_->calls) : 0.0;
}

void EmbeddedVerlet::step(int64_t count, bool observe) {
  Impl& s = *impl_;
  for (int64_t k = 0; k < count; ++k) {
    s.kick(true);
    s.forces(observe && k + 1 == count);
    s.kick(false);
  }
}

double EmbeddedVerlet::total_energy() {
  Impl& s = *impl_;
  const std::size_t count = s.n * std::size_t(s.dim);
  check(cudaMemsetAsync(s.sums + 1, 0, sizeof(double), s.stream), "memset");
  if (count) kinetic_energy<<<blocks(count), kBlock, 0, s.stream>>>(count, s.dim, s.v, s.inv_mass, s.sums + 1);
  check(cudaGetLastError(), "kinetic_energy launch");
  double sums[2] = {0, 0};
  check(cudaMemcpyAsync(sums, s.sums, sizeof(sums), cudaMemcpyDeviceToHost, s.stream), "download");
  check(cudaStreamSynchronize(s.stream), "cudaStreamSynchronize");
  s.ctx.synchronize();  // what the force calls' kernels found
  return sums[0] + sums[1];
}

void EmbeddedVerlet::download(double* positions, double* forces) {
  Impl& s = *impl_;
  const std::size_t bytes = s.n * std::size_t(s.dim) * sizeof(double);
  check(cudaStreamSynchronize(s.stream), "cudaStreamSynchronize");
  s.ctx.synchronize();
  check(cudaMemcpy(positions, s.x, bytes, cudaMemcpyDeviceToHost), "download");
  check(cudaMemcpy(forces, s.f, bytes, cudaMemcpyDeviceToHost), "download");
}

}  // namespace cellforce
