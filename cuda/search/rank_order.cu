// The pair list's rank order (search/pair_list.cuh): the particles' positions gathered into it,
// where a gated chunk's drifts place them instead (RankOrder), and arrays in rank order written
// back to the caller's order.
#include <algorithm>

#include "check.cuh"
#include "search/pair_list.cuh"
#include "with_dim.cuh"

namespace cellforce::cuda {
namespace {

constexpr int kBlock = kListBlock;
unsigned blocks_for(std::size_t count) { return unsigned((count + kBlock - 1) / kBlock); }

template <int D, class Particle>
__global__ void gather_ranked(Grid g, const double* __restrict__ positions, const uint32_t* __restrict__ types,
                              const uint32_t* __restrict__ order, std::size_t n, uint32_t num_types,
                              Particle* __restrict__ ranked, DeviceFlags* flags, const unsigned long long* skip) {
  const std::size_t p = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (p >= n || (skip && *skip)) return;
  const std::size_t i = order[p];
  double v[3] = {0, 0, 0};
  for (int a = 0; a < D; ++a) v[a] = positions[i * D + a];
  store_ranked<D>(ranked, p, g, v, types ? types[i] : 0u, num_types, i, flags);
}

}  // namespace

template <class Particle, class Real, class Accum>
void gather(const ListArgs<Real, Accum>& args, PairList& list, DeviceBuffer<Particle>& ranked, cudaStream_t stream) {
  ranked.reserve(std::max<std::size_t>(args.n, 1));
  with_dim(args.grid.dim, [&](auto d) {
    gather_ranked<decltype(d)::value><<<blocks_for(args.n), kBlock, 0, stream>>>(
        args.grid, args.positions, args.types, list.order.data(), args.n, args.num_types, ranked.data(), args.flags,
        args.skip);
  });
  CF_CUDA_CHECK_LAUNCH();
}

template <class Real, class Accum>
RankOrder rank_order(const ListArgs<Real, Accum>& args, PairList& list, bool forces_by_rank, bool fused) {
  RankOrder to;
  to.rank = list.rank.data();
  to.order = list.order.data();
  if (forces_by_rank) {
    list.ranked_forces.reserve(std::max<std::size_t>(args.n * std::size_t(args.grid.dim), 1));
    to.forces = list.ranked_forces.data();
  } else {
    list.ranked_forces.release();
  }
  to.fixed = gathers_fixed(args);
  const std::size_t n = std::max<std::size_t>(args.n, 1);
  if (to.fixed) {
    list.ranked.release();
    list.ranked_next.release();
    list.fixed.reserve(n);
    if (fused) list.fixed_next.reserve(n);
    else list.fixed_next.release();
    to.particles = list.fixed.data();
  } else {
    list.fixed.release();
    list.fixed_next.release();
    list.ranked.reserve(n);
    if (fused) list.ranked_next.reserve(n);
    else list.ranked_next.release();
    to.particles = list.ranked.data();
  }
  to.grid = args.grid;
  to.types = args.types;
  to.num_types = args.num_types;
  to.flags = args.flags;
  return to;
}


namespace {
// A thread per coordinate of the caller's order: the stores coalesced, the loads gathered by rank.
// A thread per rank would scatter its stores, which costs most where the caller's numbering is
// far from the rank order (a shuffled one).
template <int D>
__global__ void unrank_kernel(const uint32_t* __restrict__ rank, const double* __restrict__ ranked, std::size_t n,
                              double* __restrict__ out) {
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= n * D) return;
  const std::size_t i = k / D, a = k % D;
  out[k] = ranked[std::size_t(rank[i]) * D + a];
}
}  // namespace

void unrank(const uint32_t* rank, const double* ranked, std::size_t n, int dim, double* out, cudaStream_t stream) {
  if (n == 0) return;
  with_dim(dim, [&](auto d) {
    constexpr int D = decltype(d)::value;
    unrank_kernel<D><<<blocks_for(n * D), kBlock, 0, stream>>>(rank, ranked, n, out);
  });
  CF_CUDA_CHECK_LAUNCH();
}

void unrank_forces(const PairList& list, std::size_t n, int dim, double* forces, cudaStream_t stream) {
  unrank(list.rank.data(), list.ranked_forces.data(), n, dim, forces, stream);
}

#define CF_RANK_ORDER(Real, Accum) \
  template RankOrder rank_order<Real, Accum>(const ListArgs<Real, Accum>&, PairList&, bool, bool);
CF_RANK_ORDER(float, float)
CF_RANK_ORDER(float, double)
CF_RANK_ORDER(double, double)
#undef CF_RANK_ORDER
template void gather(const ListArgs<float, float>&, PairList&, DeviceBuffer<FixedParticle>&, cudaStream_t);
template void gather(const ListArgs<float, double>&, PairList&, DeviceBuffer<FixedParticle>&, cudaStream_t);
template void gather(const ListArgs<float, float>&, PairList&, DeviceBuffer<RankedParticle>&, cudaStream_t);
template void gather(const ListArgs<float, double>&, PairList&, DeviceBuffer<RankedParticle>&, cudaStream_t);
template void gather(const ListArgs<double, double>&, PairList&, DeviceBuffer<RankedParticle>&, cudaStream_t);

}  // namespace cellforce::cuda
