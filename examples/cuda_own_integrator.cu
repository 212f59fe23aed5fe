// cellforce as the force kernel of your own GPU integrator: velocity Verlet written here, on your
// own CUDA stream and device arrays, with Context::compute_device between its two half-kicks.
//
// The system is LAMMPS's in.lj at 32,000 particles (fcc at density 0.8442, periodic, Lennard-Jones
// cut at rc = 2.5 and shifted to zero there, T = 1.44, dt = 0.005). Each step queues three things
// on the stream and waits for none of them:
//   kick_drift   v += dt/2 F/m, x += dt v      (this file's kernel)
//   compute_device                            (cellforce: F(x), and U on sampled steps)
//   kick         v += dt/2 F/m                (this file's kernel)
// Every kEvery steps the host waits (cudaStreamSynchronize, then Context::synchronize for what
// cellforce's kernels found) and reads two doubles: the potential energy cellforce wrote and the
// kinetic energy reduced here on the device. The total energy is conserved by velocity Verlet: the
// program exits 1 when it drifts more than kDriftTolerance per particle, and 0 with a "skipped"
// line when no CUDA device can be used.
//
// Build against the installed package: examples/README.md.
#include <cellforce/cellforce.hpp>

#include <cuda_runtime.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

namespace {

constexpr int kCells = 20, kN = 4 * kCells * kCells * kCells, kSteps = 1000, kEvery = 100;
constexpr double kDensity = 0.8442, kCutoff = 2.5, kTemperature = 1.44, kDt = 0.005;
constexpr double kDriftTolerance = 5e-4;  // largest change of the total energy per particle
constexpr int kBlock = 256;
constexpr int kCount = 3 * kN;                                // coordinates
constexpr int kBlocks = (kCount + kBlock - 1) / kBlock;

void check(cudaError_t err, const char* what) {
  if (err != cudaSuccess) throw cellforce::Error(std::string(what) + ": " + cudaGetErrorString(err));
}

// One thread per coordinate; unit masses. v += dt/2 F, then x += dt v.
__global__ void kick_drift(const double* f, double* v, double* x) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= kCount) return;
  v[k] += 0.5 * kDt * f[k];
  x[k] += kDt * v[k];  // positions may leave the box: cellforce takes any periodic image
}

__global__ void kick(const double* f, double* v) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k < kCount) v[k] += 0.5 * kDt * f[k];
}

// The kinetic energy in two passes and a fixed order (no atomics: the same bits every run): each
// block sums its v^2 / 2 into partial[block], then one block sums the partials into *kinetic.
__device__ double block_sum(double value) {
  __shared__ double s[kBlock];
  s[threadIdx.x] = value;
  __syncthreads();
  for (int half = kBlock / 2; half > 0; half /= 2) {
    if (threadIdx.x < half) s[threadIdx.x] += s[threadIdx.x + half];
    __syncthreads();
  }
  return s[0];
}
__global__ void kinetic_partials(const double* v, double* partial) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  const double sum = block_sum(k < kCount ? 0.5 * v[k] * v[k] : 0.0);
  if (threadIdx.x == 0) partial[blockIdx.x] = sum;
}
__global__ void kinetic_total(const double* partial, double* kinetic) {
  double value = 0;
  for (int b = threadIdx.x; b < kBlocks; b += kBlock) value += partial[b];
  const double sum = block_sum(value);
  if (threadIdx.x == 0) *kinetic = sum;
}

// in.lj's start: the fcc lattice and velocities with zero momentum scaled to kTemperature.
void make_system(std::vector<double>& x, std::vector<double>& v) {
  const double a = std::cbrt(4 / kDensity), basis[4][3] = {{0, 0, 0}, {0.5, 0.5, 0}, {0.5, 0, 0.5}, {0, 0.5, 0.5}};
  uint64_t seed = 87287;
  double mean[3] = {0, 0, 0}, v2 = 0;
  for (int i = 0; i < kN; ++i)
    for (int k = 0; k < 3; ++k) {
      const int cell[3] = {i / 4 / (kCells * kCells), i / 4 / kCells % kCells, i / 4 % kCells};
      x[3 * i + k] = (cell[k] + basis[i % 4][k]) * a;
      seed = seed * 6364136223846793005ull + 1442695040888963407ull;
      v[3 * i + k] = double(seed >> 11) / 9007199254740992.0 - 0.5;
      mean[k] += v[3 * i + k] / kN;
    }
  for (int k = 0; k < kCount; ++k) v2 += (v[k] - mean[k % 3]) * (v[k] - mean[k % 3]);
  const double scale = std::sqrt(kTemperature * 3 * (kN - 1) / v2);  // unit masses: 2 KE = sum v^2
  for (int k = 0; k < kCount; ++k) v[k] = (v[k] - mean[k % 3]) * scale;
}

}  // namespace

int main() {
  int devices = 0;
  const cudaError_t found = cudaGetDeviceCount(&devices);
  if (found != cudaSuccess || devices == 0) {
    std::printf("cuda_own_integrator: skipped: no CUDA device (%s)\n",
                found != cudaSuccess ? cudaGetErrorString(found) : "none found");
    return 0;
  }
  double *x = nullptr, *v = nullptr, *f = nullptr, *partial = nullptr, *sums = nullptr;  // sums: U, KE
  cudaStream_t stream = nullptr;
  int status = 0;
  try {
    cellforce::Context ctx(3);
    const double edge = kCells * std::cbrt(4 / kDensity), box[3] = {edge, edge, edge};
    const bool periodic[3] = {true, true, true};
    ctx.set_box(box, periodic);
    ctx.set_cutoff(kCutoff, cellforce::CutoffMode::kShift);
    ctx.add_type("A", 1.0, 1.0);
    // Device arrays need the cuda backend (compute_device refuses the cpu). Precision stays double
    // (the default); set_precision(cellforce::Precision::kMixed) is the fast choice.
    try {
      ctx.set_backend(cellforce::Backend::kCuda);
      std::printf("cellforce %s on %s\n", cellforce::version(), ctx.description().c_str());  // makes the engine
    } catch (const cellforce::DeviceError& e) {  // no usable device, or a cellforce built without CUDA
      std::printf("cuda_own_integrator: skipped: the cuda backend cannot be used (%s)\n", e.message().c_str());
      return 0;
    }

    std::vector<double> hx(kCount), hv(kCount);
    make_system(hx, hv);
    check(cudaStreamCreateWithFlags(&stream, cudaStreamNonBlocking), "cudaStreamCreate");
    for (double** p : {&x, &v, &f}) check(cudaMalloc(p, kCount * sizeof(double)), "cudaMalloc");
    check(cudaMalloc(&partial, kBlocks * sizeof(double)), "cudaMalloc");
    check(cudaMalloc(&sums, 2 * sizeof(double)), "cudaMalloc");
    check(cudaMemcpy(x, hx.data(), kCount * sizeof(double), cudaMemcpyHostToDevice), "upload");
    check(cudaMemcpy(v, hv.data(), kCount * sizeof(double), cudaMemcpyHostToDevice), "upload");

    // Outputs holds device pointers here: the forces, and the energy on the sampled steps only
    // (a null output is left out of the kernels). Types: null, all type 0.
    const cellforce::Outputs forces_only{f, nullptr, nullptr, nullptr}, with_energy{f, nullptr, &sums[0], nullptr};
    ctx.compute_device(kN, x, nullptr, with_energy, stream);  // F(x0) for the first half-kick
    double e0 = 0, drift = 0;
    std::printf("%6s %12s %12s %12s\n", "step", "ke/atom", "pe/atom", "etot/atom");
    for (int step = 0; step <= kSteps; ++step) {
      if (step > 0) {
        kick_drift<<<kBlocks, kBlock, 0, stream>>>(f, v, x);
        ctx.compute_device(kN, x, nullptr, step % kEvery == 0 ? with_energy : forces_only, stream);
        kick<<<kBlocks, kBlock, 0, stream>>>(f, v);
      }
      if (step % kEvery != 0) continue;
      kinetic_partials<<<kBlocks, kBlock, 0, stream>>>(v, partial);
      kinetic_total<<<1, kBlock, 0, stream>>>(partial, &sums[1]);
      check(cudaGetLastError(), "kernel launch");
      double u_ke[2];
      check(cudaMemcpyAsync(u_ke, sums, sizeof(u_ke), cudaMemcpyDeviceToHost, stream), "download");
      check(cudaStreamSynchronize(stream), "cudaStreamSynchronize");
      ctx.synchronize();  // throws what cellforce's kernels found (a non-finite position, ...)
      const double total = u_ke[0] + u_ke[1];
      if (step == 0) e0 = total;
      drift = std::max(drift, std::abs(total - e0) / kN);
      std::printf("%6d %12.8f %12.8f %12.8f\n", step, u_ke[1] / kN, u_ke[0] / kN, total / kN);
    }
    std::printf("energy conserved: largest |etot - etot(0)| per particle %.1e (tolerance %.0e)\n", drift,
                kDriftTolerance);
    if (!(drift <= kDriftTolerance)) {
      std::fprintf(stderr, "cuda_own_integrator: check failed: the total energy drifted %.3g per particle\n", drift);
      status = 1;
    }
  } catch (const cellforce::Error& e) {  // cellforce's errors and this file's CUDA checks
    std::fprintf(stderr, "cuda_own_integrator: %s\n", e.what());
    status = 1;
  }
  for (double* p : {x, v, f, partial, sums}) cudaFree(p);
  if (stream) cudaStreamDestroy(stream);
  return status;
}
