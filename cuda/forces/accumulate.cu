// Stage 5, accumulation (GPU Gems 3 ch. 32, section 32.2.5's Jacobi option): each particle's 2^d
// slots, one per cell type, are summed in slot order by one thread per particle; the per-cell
// energies and virials are summed by one block in an order fixed by the cell count. No atomics
// anywhere, so the results are bitwise reproducible. With Gauss-Seidel there is one slot.
#include "check.cuh"
#include "forces/traversal.cuh"

namespace cellforce::cuda {
namespace {

template <class Accum>
__global__ void sum_slots_kernel(const Accum* __restrict__ force_slots,
                                 const Accum* __restrict__ energy_slots, int dim, std::size_t n,
                                 int copies, double* __restrict__ forces, double* __restrict__ energies) {
  const std::size_t i = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n) return;
  const std::size_t stride = n * std::size_t(dim);
  for (int c = 0; c < dim; ++c) {
    Accum f = 0;
    for (int t = 0; t < copies; ++t) f += force_slots[std::size_t(t) * stride + i * dim + c];
    forces[i * dim + c] = double(f);
  }
  if (energy_slots) {
    Accum e = 0;
    for (int t = 0; t < copies; ++t) e += energy_slots[std::size_t(t) * n + i];
    energies[i] = double(e);
  }
}

template <class Accum>
__global__ void sum_virial_slots_kernel(const Accum* __restrict__ virial_slots, std::size_t n_local, int copies,
                                        double* __restrict__ virials) {
  const std::size_t i = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= n_local) return;
  const std::size_t stride = n_local * kVirialComponents;
  for (int k = 0; k < kVirialComponents; ++k) {
    Accum w = 0;
    for (int t = 0; t < copies; ++t) w += virial_slots[std::size_t(t) * stride + i * kVirialComponents + k];
    virials[i * kVirialComponents + k] = double(w);
  }
}

constexpr int kSumThreads = 256;

template <class Accum>
__global__ void __launch_bounds__(kSumThreads)
    sum_cells_kernel(const Accum* __restrict__ cell_sums, const uint32_t* __restrict__ count,
                     double* __restrict__ totals, const unsigned long long* skip) {
  if (skip && *skip) return;
  __shared__ Accum partial[kCellSums][kSumThreads];
  Accum v[kCellSums] = {};
  const std::size_t cells = *count;
  for (std::size_t c = threadIdx.x; c < cells; c += kSumThreads)
    for (int k = 0; k < kCellSums; ++k) v[k] += cell_sums[c * kCellSums + k];
  for (int k = 0; k < kCellSums; ++k) partial[k][threadIdx.x] = v[k];
  __syncthreads();
  for (int half = kSumThreads / 2; half > 0; half >>= 1) {
    if (int(threadIdx.x) < half)
      for (int k = 0; k < kCellSums; ++k) partial[k][threadIdx.x] += partial[k][threadIdx.x + half];
    __syncthreads();
  }
  if (threadIdx.x < kCellSums) totals[threadIdx.x] = double(partial[threadIdx.x][0]);
}

// totals = (energy, w_xx, w_yy, w_zz, w_xy, w_xz, w_yz) to the caller's energy and row-major
// dim x dim virial (either may be null).
__global__ void write_totals_kernel(const double* __restrict__ totals, int dim, double* energy,
                                    double* virial) {
  if (threadIdx.x != 0) return;
  if (energy) *energy = totals[0];
  if (!virial) return;
  for (int k = 0; k < dim * dim; ++k) virial[k] = 0;
  for (int k = 0; k < kVirialComponents; ++k) {
    const int r = virial_row(k), c = virial_col(k);
    if (r >= dim || c >= dim) continue;
    virial[r * dim + c] = virial[c * dim + r] = totals[1 + k];
  }
}

}  // namespace

void write_totals(const double* totals, int dim, double* energy, double* virial, cudaStream_t stream) {
  if (!energy && !virial) return;
  write_totals_kernel<<<1, 32, 0, stream>>>(totals, dim, energy, virial);
  CF_CUDA_CHECK_LAUNCH();
}

template <class Accum>
void sum_slots(const Accum* force_slots, const Accum* energy_slots, int dim, std::size_t n,
               int copies, double* forces, double* energies, cudaStream_t stream) {
  if (n == 0) return;
  constexpr int kBlock = 256;
  const unsigned blocks = unsigned((n + kBlock - 1) / kBlock);
  sum_slots_kernel<Accum><<<blocks, kBlock, 0, stream>>>(force_slots, energy_slots, dim, n, copies,
                                                         forces, energies);
  CF_CUDA_CHECK_LAUNCH();
}

template <class Accum>
void sum_virial_slots(const Accum* virial_slots, std::size_t n_local, int copies, double* virials,
                      cudaStream_t stream) {
  if (n_local == 0) return;
  constexpr int kBlock = 256;
  sum_virial_slots_kernel<Accum><<<unsigned((n_local + kBlock - 1) / kBlock), kBlock, 0, stream>>>(
      virial_slots, n_local, copies, virials);
  CF_CUDA_CHECK_LAUNCH();
}

template <class Accum>
void sum_cells(const Accum* cell_sums, const uint32_t* count, double* totals, cudaStream_t stream,
               const unsigned long long* skip) {
  sum_cells_kernel<Accum><<<1, kSumThreads, 0, stream>>>(cell_sums, count, totals, skip);
  CF_CUDA_CHECK_LAUNCH();
}

template void sum_slots<float>(const float*, const float*, int, std::size_t, int, double*, double*, cudaStream_t);
template void sum_slots<double>(const double*, const double*, int, std::size_t, int, double*, double*, cudaStream_t);
template void sum_virial_slots<float>(const float*, std::size_t, int, double*, cudaStream_t);
template void sum_virial_slots<double>(const double*, std::size_t, int, double*, cudaStream_t);
template void sum_cells<float>(const float*, const uint32_t*, double*, cudaStream_t, const unsigned long long*);
template void sum_cells<double>(const double*, const uint32_t*, double*, cudaStream_t, const unsigned long long*);

}  // namespace cellforce::cuda
