// The list force kernel: the evaluations a pair list serves (forces/list_forces.cuh), and in a
// gated Verlet chunk the next step's kick-drift after the forces (forces/fused_step.h).
#include <algorithm>
#include <cmath>
#include <type_traits>

#include "core/error.h"
#include "forces/list_forces.cuh"
#include "md/verlet_step.h"
#include "search/step_gate.cuh"

namespace cellforce::cuda {
namespace {

constexpr int kBlock = kListBlock;
unsigned blocks_for(std::size_t count) { return unsigned((count + kBlock - 1) / kBlock); }

// The minimum-image separation a - b along axis `a` of the grid (positions already wrapped).
__device__ __forceinline__ double image(const Grid& g, int a, double d) {
  return minimum_image(d, g.length[a], g.inv_length[a]);
}

template <int D>
__device__ __forceinline__ double distance2(const Grid& g, const RankedParticle& a, const RankedParticle& b,
                                            double d[3]) {
  d[0] = image(g, 0, a.x - b.x);
  d[1] = image(g, 1, a.y - b.y);
  d[2] = D == 3 ? image(g, 2, a.z - b.z) : 0.0;
  return d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
}

// The separation P - Q of two gathered particles in the pair precision: formed in double and
// rounded once (RankedParticle), or as the fixed-point difference (FixedParticle, float), scaled
// by L_a / 2^32 (`scale`, from the host: fixed_separation in search/list_build.h).
template <int D, class Real>
__device__ __forceinline__ void pair_separation(const Grid& g, const RankedParticle& a, const RankedParticle& b,
                                                const FixedScales&, Real d[3]) {
  double dd[3];
  distance2<D>(g, a, b, dd);
  for (int c = 0; c < 3; ++c) d[c] = Real(dd[c]);
}
template <int D, class Real>
__device__ __forceinline__ void pair_separation(const Grid&, const FixedParticle& a, const FixedParticle& b,
                                                const FixedScales& scale, Real d[3]) {
  static_assert(std::is_same_v<Real, float>, "fixed-point positions serve float pairs");
  d[0] = fixed_separation(a.x, b.x, scale.axis[0]);
  d[1] = fixed_separation(a.y, b.y, scale.axis[1]);
  d[2] = D == 3 ? fixed_separation(a.z, b.z, scale.axis[2]) : 0.0f;
}

// A cube's fixed-point scale folded into the pair's constants, for the force kernel's FixedParticle
// pairs of one type: every axis has the same scale s = s_hi (1 + eps) (fixed_scale: a float pair,
// |eps| <= 2^-24). The kernel forms the separation d' = f (s_hi / lambda) (f the integer difference
// as a float: one multiply per axis, not two; lambda the pair's power-of-two length unit, so the
// division is exact), which is the true one over G = g lambda with g = 1 + eps: r'^2 = r^2 / G^2 is
// already r^2 in the pair's unit up to g, and needs no multiply by inv_s2. With q = lambda^2 / r^2 =
// u / g^2 (u = 1 / r'^2), the force (f12 q^7 - f6 q^4) d is the same expression of u and d' with
// f12 lambda / g^13 and f6 lambda / g^7 (minus f_rc d' / r' with force shift, f_rc unchanged),
// compared with rc^2 / G^2. Every kernel of such a system takes the fold, with observables or
// without, so that a step's forces do not depend on what else it was asked for (a restart between
// output steps repeats the run bit for bit: PairListRequests). With e12 / (g^13 lambda), e6 /
// (g^7 lambda), u_rc / G and rc / G the pair energy and F(r)/r d'_a d'_b come out as the true ones
// over G: the particle energies and the totals are multiplied by g (as v + v eps) and by lambda (a
// power of two, exact) once, at the end. The constants take one more rounding (2^-24 relative,
// against the two roundings per axis the fold saves).
struct FixedFold {
  // The single type's constants (table[0]), folded on the host: f12 lambda g^-13, f6 lambda g^-7,
  // e12 g^-13 / lambda, e6 g^-7 / lambda, u_rc / G and rc / G (f_rc as it is).
  float f12 = 0, f6 = 0, e12 = 0, e6 = 0, u_rc = 0, rc = 0;
  float hi = 0;              // s_hi / lambda
  float rc2 = 0;             // rc^2 / G^2
  double eps = 0;            // g - 1: the observables' sums times g, as v + v eps
  double lambda = 1;         // then times lambda
};

// S threads per rank (S = 1, 2, 4 or 8, adjacent lanes of one warp). With one, the thread reads its
// list a chunk at a time (one 16-byte load for kChunk entries). With S > 1 (small systems, to fill
// the GPU), thread j takes entries j, j + S, ..., kChunk at a time (whole chunks per thread would
// leave the longest share up to a chunk longer, which costs small systems at S = 8 most),
// and the S partial sums are added by a butterfly over the S lanes. Either way the whole force on
// the particle is summed in an order fixed by its list. A batch's kChunk partners are gathered
// before any of its pairs is evaluated (kChunk gathers in flight, not one: the loop waits on the
// gathers' latency otherwise), and its pairs are added in list order.
static_assert(kChunk == 4, "a chunk is one uint4");

// The next step's kick-drift, for a gated Verlet evaluation's force kernel (Drift) on the
// chunk's rank-order state: the block's particles are consecutive ranks, so after their forces are
// summed the block kicks and drifts them a thread per coordinate (the separate kernel's coalesced
// loads and stores, and no register of the force loop held for them), raises the next step's
// displacement into the gate and places the new positions into `next` (the list's other
// rank-ordered array: the partners' positions are read from `ranked` by the kernel's other blocks
// meanwhile). The forces go through shared memory and are never stored. The arithmetic is
// gated_kick_drift_kernel's (integrate/gated_steps.cu), coordinate for coordinate (md/verlet_step.h).
template <int D, int S, int B, class Particle>
__device__ __forceinline__ void next_kick_drift(const NextKickDrift& s, std::size_t n, std::size_t p, uint32_t part,
                                                const double (&force)[D], uint32_t type, Particle* __restrict__ next,
                                                const Grid& grid, uint32_t num_types, DeviceFlags* dflags,
                                                const GateView& gate_next) {
  constexpr int kParticles = B / S;  // the block's ranks
  __shared__ double value[kParticles * D];  // the forces, then the new positions
  __shared__ double square[kParticles * D];
  __shared__ uint32_t types[kParticles];
  const std::size_t first = std::size_t(blockIdx.x) * kParticles;
  const int local = int(threadIdx.x) / S;
  if (p < n && part == 0) {
#pragma unroll
    for (int c = 0; c < D; ++c) value[local * D + c] = force[c];
    types[local] = type;
  }
  __syncthreads();
  for (int c = int(threadIdx.x); c < kParticles * D; c += B) {
    const std::size_t q = first + std::size_t(c / D);
    double term = 0;
    if (q < n) {
      const std::size_t k = first * D + std::size_t(c);
      const int a = c % D;
      const double m = s.mass ? s.mass[q] : s.mass_value, then = s.built[k];
      double xa = s.x[k], va = s.v[k];
      va = kick_value(va, value[c], m, s.h, 2);
      s.v[k] = va;
      const DriftAxis axis = drift_axis(s.box, a);
      bool bad;
      xa = drift_value(xa, va, s.dt, axis, true, bad);
      s.x[k] = xa;
      if (bad) flag_diverged(true, s.order[q], a, s.dt, va, s.flags);
      term = displacement_term(xa, then, axis.length, axis.inv_length);
      value[c] = xa;  // this thread read the force at c above
    }
    square[c] = term;
  }
  __syncthreads();
  double worst = 0;
  if (threadIdx.x < unsigned(kParticles)) {
    const std::size_t q = first + threadIdx.x;
    if (q < n) {
      double d2 = 0, moved[3] = {0, 0, 0};
#pragma unroll
      for (int a = 0; a < D; ++a) d2 += square[threadIdx.x * D + a], moved[a] = value[threadIdx.x * D + a];
      worst = gate_displacement(d2);
      store_ranked<D>(next, q, grid, moved, types[threadIdx.x], num_types, s.order[q], dflags);
    }
  }
  raise_block_displacement(worst, gate_next);
}

// Programmatic dependent launch's two instructions (PTX griddepcontrol, compute capability 9.0):
// let the kernel launched after this one be scheduled; wait for the kernel before this one to
// complete, its memory visible. No-ops for a kernel launched without the attribute, and on older
// devices.
__device__ __forceinline__ void pdl_launch_dependents() {
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
  asm volatile("griddepcontrol.launch_dependents;" ::: "memory");
#endif
}
__device__ __forceinline__ void pdl_wait() {
#if defined(__CUDA_ARCH__) && __CUDA_ARCH__ >= 900
  asm volatile("griddepcontrol.wait;" ::: "memory");
#endif
}

// `ranked` is not __restrict__: in a gated chunk the kernel before this one wrote it (a
// fused force kernel's `next`, or a drift's placing), and this one may run before that one ends
// (programmatic dependent launch), so it must be read only after pdl_wait(). Through a const
// __restrict__ pointer nvcc may read it on the non-coherent path (ld.global.nc), which it takes as
// unchanging while the kernel runs, and issue that read before griddepcontrol.wait (performance.md
// records the SASS of such a kernel; validation/pdl_check.py checks the built kernels for it).
template <class T, int S, bool Folded, bool Drift, class Particle, class Real, class Accum, int B = kBlock>
__global__ void __launch_bounds__(B)
    list_force_kernel(const ListArgs<Real, Accum> args, const uint32_t* __restrict__ order,
                      const Particle* ranked, const uint32_t* __restrict__ length,
                      const unsigned long long* __restrict__ group_chunks, const uint32_t* __restrict__ neighbors,
                      const FixedScales scale, const FixedFold fold, Accum* __restrict__ block_sums,
                      GateView gate, bool by_rank, const NextKickDrift then, Particle* __restrict__ next) {
  static_assert(!Folded || (std::is_same_v<Particle, FixedParticle> && !T::kMultiType),
                "the fold serves fixed-point pairs of one type");
  static_assert(!Drift || !T::kObservables, "the next step's kick-drift follows an evaluation of forces only");
  static_assert(B == kBlock || Drift, "blocks of another size run the next step's kick-drift only");
  constexpr int D = T::kDim;
  const std::size_t n = args.n;
  const std::size_t t = std::size_t(blockIdx.x) * B + threadIdx.x;  // launched with B threads a block
  const std::size_t p = t / S;
  const uint32_t part = uint32_t(t % S);
  // Programmatic dependent launch (the gated evaluations, list_forces): the next step's
  // force kernel may be scheduled once every block of this one has started, and waits below for
  // this one to complete, so that its blocks take the multiprocessors this one's last wave leaves
  // idle instead of waiting for the launch after it. Without the launch attribute both are no-ops.
  // The list's lengths and group chunks come from the build, which completed before the gated
  // evaluations began: read before the wait in the source (nvcc issues them after it; issuing them
  // before it gains nothing measurable); everything the last kernel wrote (positions, the gate)
  // after it.
  pdl_launch_dependents();
  // The particle, its list's length and its group's first chunk are loaded before the gate's
  // barrier (a shut gate discards them), so that their round trip overlaps the gate's.
  Particle P{};
  uint32_t len = 0;
  unsigned long long group_chunk0 = 0;
  if (p < n) len = length[p], group_chunk0 = group_chunks[p / kGroup];
  pdl_wait();
  // A decided call's other route (ListArgs::skip; never with a gate, so the wait above is none):
  // the whole block returns before any barrier, having read only the list's length and chunk,
  // whose values it drops (the route's build may be writing them).
  if (args.skip && *args.skip) return;
  if (p < n) P = ranked[p];
  // The whole block: before any shuffle or barrier. Drift: the next step's first kernel's test, which
  // closes the gate where this step's displacement ran past the limit.
  if constexpr (Drift) {
    if (step_gate_shut(next_step(gate))) return;
  } else {
    if (gate_shut(gate)) return;
  }
  if (gate.gate && t == 0) atomicMax(&gate.gate->served, gate.gate->d2[gate.step % 3]);  // served: this step's
  CellTotals<Accum, true, true> totals;
  Accum f[D] = {};
  Accum ea = 0;
  if (p < n) {
    LJParams<Real> single = args.first;
    Real rc2 = args.rc2;
    if constexpr (Folded) {
      single.inv_s2 = Real(1);  // d' is in the pair's unit already: lj_terms' multiply folds away
      single.f12 = fold.f12, single.f6 = fold.f6, single.e12 = fold.e12, single.e6 = fold.e6;
      single.u_rc = fold.u_rc, single.rc = fold.rc;
      rc2 = fold.rc2;
    }
    // Entry k at entries[(k / kChunk) * kGroup * kChunk + k % kChunk] (list_entry): a warp's
    // threads read consecutive chunks.
    const uint32_t* entries = neighbors + list_entry(group_chunk0, p, 0);
    constexpr uint32_t kStride = S;  // between a batch's entries
    // The batch of entries from k0 on (k0 < len): one 16-byte chunk (S = 1), or kChunk entries
    // S apart.
    auto load_batch = [&](uint32_t k0, uint32_t (&q)[kChunk]) {
      if constexpr (S == 1) {
        const uint4 v = reinterpret_cast<const uint4*>(entries)[std::size_t(k0 / kChunk) * kGroup];
        q[0] = v.x, q[1] = v.y, q[2] = v.z, q[3] = v.w;
      } else {
#pragma unroll
        for (uint32_t b = 0; b < kChunk; ++b) {
          const uint32_t k = k0 + b * kStride;
          q[b] = k < len ? entries[std::size_t(k / kChunk) * kGroup * kChunk + k % kChunk] : 0u;
        }
      }
    };
    constexpr uint32_t kStep = uint32_t(S * kChunk);  // between a thread's batches
    // One batch: its kChunk entries q from k0 on, gathered, then evaluated in list order. In the
    // last batch (Tail), entries past the list are padding (never written): q = p.
    auto batch = [&](auto tail, uint32_t k0, uint32_t (&q)[kChunk], auto&& on_pair) {
      constexpr bool Tail = decltype(tail)::value;
      if constexpr (Tail) {
#pragma unroll
        for (uint32_t b = 0; b < kChunk; ++b)
          if (k0 + b * kStride >= len) q[b] = uint32_t(p);
      }
      Particle Q[kChunk];
#pragma unroll
      for (int b = 0; b < kChunk; ++b) Q[b] = ranked[q[b]];
#pragma unroll
      for (uint32_t b = 0; b < kChunk; ++b) {
        const bool listed = !Tail || k0 + b * kStride < len;  // past the list: the batch's rest is too
        if constexpr (T::kObservables)
          if (!listed) break;
        Real d[3];
        if constexpr (Folded) {
          d[0] = float(int32_t(P.x - Q[b].x)) * fold.hi;
          d[1] = float(int32_t(P.y - Q[b].y)) * fold.hi;
          d[2] = D == 3 ? float(int32_t(P.z - Q[b].z)) * fold.hi : 0.0f;
        } else {
          pair_separation<D>(args.grid, P, Q[b], scale, d);
        }
        Real r2 = d[0] * d[0] + d[1] * d[1];
        if constexpr (D == 3) r2 += d[2] * d[2];
        LJParams<Real> prm;
        if constexpr (T::kMultiType) prm = args.table[P.type * args.num_types + Q[b].type];
        else prm = single;
        Real fr, e = 0;
        if constexpr (T::kObservables) {
          if (!lj_pair<T::kMode, true>(r2, rc2, prm, fr, e)) continue;
        } else {
          // Without observables a pair beyond rc, and a padding entry past the list (q = p),
          // adds fr = 0: +-0 to each sum, which leaves it bitwise as it was (a sum from +0 is
          // never -0). That needs d finite: fixed-point separations always are, padding has
          // d = 0, and a coordinate that is not finite was flagged by the gather (the
          // evaluation then fails naming it; its particles' sums may be NaN instead of
          // skipping the pair). So neither test is a branch: a warp's lanes take both sides of
          // the cutoff anyway, and with no branch in the batch its kChunk gathers stay ahead of
          // its pairs (behind a branch per pair nvcc issues each gather just before its pair).
          lj_terms<T::kMode, false>(r2, prm, fr, e);
          fr = listed && r2 < rc2 ? fr : Real(0);
        }
        on_pair(q[b], d, fr, e);
      }
    };
    // Every entry of this thread's share of the list, in list order: on_pair(q, d, fr, e). With
    // observables only the pairs within rc; without, every entry, fr = 0 beyond rc and past the
    // list (the select in `batch`).
    // The next batch's entries are loaded before this batch's pairs: the list comes from DRAM, and
    // a batch that loads its own entries first waits the whole round trip before its gathers can
    // start. The whole batches come first, with no test of the list's end per entry, then the last
    // one if the list ends inside it.
    auto walk = [&](auto&& on_pair) {
      uint32_t k0 = S == 1 ? 0u : part;
      uint32_t next[kChunk] = {0u, 0u, 0u, 0u};
      if (k0 < len) load_batch(k0, next);
      for (; k0 + (kChunk - 1) * kStride < len; k0 += kStep) {
        uint32_t q[kChunk];
#pragma unroll
        for (uint32_t b = 0; b < kChunk; ++b) q[b] = next[b];
        if (k0 + kStep < len) load_batch(k0 + kStep, next);
        batch(std::false_type{}, k0, q, on_pair);
      }
      if (k0 < len) batch(std::true_type{}, k0, next, on_pair);
    };
    walk([&](uint32_t, const Real (&d)[3], Real fr, Real e) {
      for (int c = 0; c < D; ++c) f[c] += Accum(mul_rn(fr, d[c]));  // no FMA, as the traversals
      if constexpr (T::kObservables) {
        const Real half_e = Real(0.5) * e;
        ea += Accum(half_e);
        totals.template add<D>(half_e, Real(0.5) * fr, d);
      }
    });
    // A pair whose force is not finite leaves every component of the sum not finite (inf x 0 is
    // NaN): only then is the share walked again to flag it, every such pair as a test per pair
    // would (the flag keeps the smallest). Not per pair: ~2 instructions of ~50 an entry.
    bool finite = true;
    for (int c = 0; c < D; ++c) finite = finite && isfinite(f[c]);
    if (!finite)
      walk([&](uint32_t q, const Real (&)[3], Real fr, Real) {
        if (!isfinite(fr)) detail::flag_bad_pair(args.flags, order[p], order[q]);
      });
  }
  // The S parts of a particle (a whole warp takes the shuffles: p < n or not).
  for (int offset = S / 2; offset > 0; offset >>= 1) {
    for (int c = 0; c < D; ++c) f[c] += __shfl_xor_sync(0xffffffffu, f[c], offset);
    if constexpr (T::kObservables) ea += __shfl_xor_sync(0xffffffffu, ea, offset);
  }
  if constexpr (Drift) {
    double force[D];
#pragma unroll
    for (int c = 0; c < D; ++c) force[c] = double(f[c]);  // the values a stored force would hold
    next_kick_drift<D, S, B>(then, n, p, part, force, P.type, next, args.grid, args.num_types, args.flags,
                          next_step(gate));
    return;
  }
  if (p < n && part == 0) {
    const std::size_t i = by_rank ? p : order[p];  // rank order: a gated evaluation's
    for (int c = 0; c < D; ++c) args.forces[i * D + c] = double(f[c]);
    if (args.energies) {
      double e = double(ea);
      if constexpr (Folded) e = (e + e * fold.eps) * fold.lambda;  // FixedFold: the folded energy is the true one over G
      args.energies[i] = e;
    }
  }
  if constexpr (T::kObservables) {
    // The block's sums: each warp's butterfly, then the warps in order (a fixed tree).
    __shared__ Accum partial[kBlock / 32][kCellSums];
    totals.finish();
    const int warp = int(threadIdx.x / 32), lane = int(threadIdx.x % 32);
    for (int k = 0; k < kCellSums; ++k) {
      const Accum v = detail::warp_sum(totals.v[k]);
      if (lane == 0) partial[warp][k] = v;
    }
    __syncthreads();
    if (threadIdx.x < unsigned(kCellSums)) {
      Accum v = partial[0][threadIdx.x];
      for (int w = 1; w < kBlock / 32; ++w) v += partial[w][threadIdx.x];
      if constexpr (Folded) v = (v + v * Accum(fold.eps)) * Accum(fold.lambda);  // FixedFold: the folded totals are the true ones over G
      block_sums[std::size_t(blockIdx.x) * kCellSums + threadIdx.x] = v;
    }
  }
}

// The fused force kernel's block size (search/list_build.h fused_block_size), from the
// occupancy calculator's resident blocks of the kernel's two forms, asked once per kernel, and the
// build's multiprocessor count.
int fused_block(PairList& list, const void* narrow, const void* wide, std::size_t threads) {
  if (list.forced_block) return list.forced_block;
  if (list.threads_per_particle != 1) return kBlock;
  PairList::BlockShape& shape = list.shape;
  if (shape.kernel != narrow) {
    CF_CUDA_CHECK(cudaOccupancyMaxActiveBlocksPerMultiprocessor(&shape.resident[0], narrow, kBlock, 0));
    CF_CUDA_CHECK(cudaOccupancyMaxActiveBlocksPerMultiprocessor(&shape.resident[1], wide, 2 * kBlock, 0));
    shape.kernel = narrow;
  }
  return fused_block_size(threads, list.threads_per_particle, kBlock, shape.resident, list.multiprocessors);
}
}  // namespace

template <class Real, class Accum>
void list_forces(const Switches& sw, const ListArgs<Real, Accum>& given, PairList& list, cudaStream_t stream,
                 const GateView& gate, bool by_rank, const NextKickDrift* then) {
  if (given.n == 0) return;
  if (given.skip && gate.gate) throw Error("internal error: a gated evaluation with a decided call's skip word");
  if (by_rank && (sw.observables || given.energies))
    throw Error("internal error: forces in rank order are for evaluations of forces only");
  if (then && (sw.observables || given.energies || !gate.gate || sw.dim != then->box.dim))
    throw Error("internal error: the next step's kick-drift follows a gated evaluation of forces only");
  ListArgs<Real, Accum> args = given;
  if (by_rank) {
    list.ranked_forces.reserve(std::max<std::size_t>(args.n * std::size_t(args.grid.dim), 1));
    args.forces = list.ranked_forces.data();
  }
  const unsigned blocks = blocks_for(args.n * std::size_t(list.threads_per_particle));
  list.block_sums.reserve(std::size_t(blocks) * kCellSums * sizeof(Accum));
  Switches s = sw;
  s.wrap = false;  // positions are absolute: the minimum image is on every periodic axis
  FixedScales scale;  // FixedParticle: L_a / 2^32 per axis, once per evaluation
  for (int a = 0; a < 3; ++a) scale.axis[a] = fixed_scale(args.grid.length[a]);
  // A cube (every axis the same scale): the fold (FixedFold) for the kernels that take it.
  bool cube = true;
  for (int a = 1; a < args.grid.dim; ++a)
    cube = cube && scale.axis[a].hi == scale.axis[0].hi && scale.axis[a].lo == scale.axis[0].lo;
  FixedFold fold;
  {
    const float hi = scale.axis[0].hi;  // 0 only for an empty axis: no fold (g = 1)
    const double g = hi != 0.0f ? 1.0 + double(scale.axis[0].lo) / double(hi) : 1.0;
    const int k = -std::ilogb(double(args.first.inv_s2)) / 2;  // the single type's unit lambda = 2^k
    const double lambda = std::ldexp(1.0, k), g13 = std::pow(g, -13.0), g7 = std::pow(g, -7.0);
    fold.f12 = float(double(args.first.f12) * (lambda * g13));
    fold.f6 = float(double(args.first.f6) * (lambda * g7));
    fold.e12 = float(double(args.first.e12) * (g13 / lambda));
    fold.e6 = float(double(args.first.e6) * (g7 / lambda));
    fold.u_rc = float(double(args.first.u_rc) / (g * lambda));
    fold.rc = float(double(args.first.rc) / (g * lambda));
    fold.hi = std::ldexp(hi, -k);
    fold.eps = g - 1.0;
    fold.lambda = lambda;
    fold.rc2 = float(double(args.rc2) / (g * g * lambda * lambda));
  }
  auto evaluate = [&](auto& ranked, auto& next) {
    using Particle = typename std::remove_reference_t<decltype(ranked)>::value_type;
    if (!gate.gate) gather(args, list, ranked, stream);  // gated: the step's drift placed them
    if (then && next.capacity() < args.n)
      throw Error("internal error: the next step's kick-drift without the list's second array (rank_order)");
    detail::dispatch(s, [&](auto traits) {
      using T = decltype(traits);
      if constexpr (!T::kWrap) {
        auto go = [&](auto split) {
          auto launch = [&](auto folded) {
            auto with = [&](auto drift) {
              // Gated evaluations follow each other: each may be scheduled while the last one
              // runs (programmatic dependent launch; the kernel waits for it).
              cudaLaunchAttribute overlap{};
              overlap.id = cudaLaunchAttributeProgrammaticStreamSerialization;
              overlap.val.programmaticStreamSerializationAllowed = 1;
              cudaLaunchConfig_t config{};
              config.stream = stream;
              const bool overlapped = gate.gate && list.dependent_launch;
              config.attrs = overlapped ? &overlap : nullptr;
              config.numAttrs = overlapped ? 1 : 0;
              const std::size_t threads = args.n * std::size_t(list.threads_per_particle);
              auto go = [&](auto kernel, unsigned block) {
                config.gridDim = dim3(unsigned((threads + block - 1) / block));
                config.blockDim = dim3(block);
                CF_CUDA_CHECK(cudaLaunchKernelEx(
                    &config, kernel, args, static_cast<const uint32_t*>(list.order.data()),
                    static_cast<const Particle*>(ranked.data()), static_cast<const uint32_t*>(list.length.data()),
                    static_cast<const unsigned long long*>(list.group_chunks.data()),
                    static_cast<const uint32_t*>(list.neighbors.data()), scale, fold,
                    reinterpret_cast<Accum*>(list.block_sums.data()), gate, by_rank, then ? *then : NextKickDrift{},
                    next.data()));
              };
              using Split = std::remove_reference_t<decltype(split)>;
              using Fold = std::remove_reference_t<decltype(folded)>;
              auto kernel = list_force_kernel<T, Split::value, Fold::value, decltype(drift)::value, Particle, Real,
                                              Accum>;
              if constexpr (decltype(drift)::value) {
                // The next step's kick-drift: blocks of 2 kBlock where they fill the last wave
                // better (fused_block).
                auto wide = list_force_kernel<T, Split::value, Fold::value, true, Particle, Real, Accum, 2 * kBlock>;
                list.fused_block = fused_block(list, reinterpret_cast<const void*>(kernel),
                                               reinterpret_cast<const void*>(wide), threads);
                if (list.fused_block == 2 * kBlock) return go(wide, 2 * kBlock);
              }
              go(kernel, kBlock);
            };
            if constexpr (!T::kObservables) {
              if (then) return with(std::true_type{});
            }
            with(std::false_type{});
          };
          if constexpr (std::is_same_v<Particle, FixedParticle> && !T::kMultiType) {
            if (cube) launch(std::true_type{});
            else launch(std::false_type{});
          } else {
            launch(std::false_type{});
          }
        };
        switch (list.threads_per_particle) {
          case 1: go(std::integral_constant<int, 1>{}); break;
          case 2: go(std::integral_constant<int, 2>{}); break;
          case 4: go(std::integral_constant<int, 4>{}); break;
          default: go(std::integral_constant<int, 8>{}); break;
        }
      }
    });
    CF_CUDA_CHECK_LAUNCH();
    if (then) std::swap(ranked, next);  // the next evaluation reads what this one placed
  };
  if constexpr (std::is_same_v<Real, float>) {
    if (gathers_fixed(args)) {
      list.ranked.release();
      evaluate(list.fixed, list.fixed_next);
      return;
    }
  }
  list.fixed.release();
  evaluate(list.ranked, list.ranked_next);
}

#define CF_LIST_FORCES(Real, Accum)                                                                            \
  template void list_forces<Real, Accum>(const Switches&, const ListArgs<Real, Accum>&, PairList&, cudaStream_t, \
                                         const GateView&, bool, const NextKickDrift*);
CF_LIST_FORCES(float, float)
CF_LIST_FORCES(float, double)
CF_LIST_FORCES(double, double)
#undef CF_LIST_FORCES

}  // namespace cellforce::cuda
