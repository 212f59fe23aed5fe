// The gated step kernels (integrate/gated_steps.cuh).
#include <type_traits>

#include "check.cuh"
#include "core/box.h"
#include "core/random.h"
#include "integrate/gated_steps.cuh"
#include "search/rank_order.cuh"  // place_ranked
#include "search/step_gate.cuh"
#include "with_dim.cuh"

namespace cellforce::cuda {
namespace {

constexpr int kBlock = 256;  // the thermostat's threads a block (a thread per coordinate)
unsigned blocks_for(std::size_t n) { return unsigned((n + kBlock - 1) / kBlock); }

// A gated step's last drift of coordinate k (particle i, on `axis`) from xa by h va, wrapped,
// stored (also into `moved`, for Placing::place) and checked. Returns its term of the particle's
// squared displacement from `then` (the build's position), for the gate.
__device__ __forceinline__ double last_drift(double* __restrict__ x, std::size_t k, std::size_t i, int a, double xa,
                                             double va, double h, const DriftAxis& axis, double then,
                                             MdFlags* flags, double& moved) {
  bool bad;
  xa = drift_value(xa, va, h, axis, true, bad);
  x[k] = xa;
  moved = xa;
  flag_diverged(bad, i, a, h, va, flags);
  return displacement_term(xa, then, axis.length, axis.inv_length);
}

constexpr int kGateParticles = 128;  // particles per block of the gated kernels (dim threads each)

// Whether the gate closed at an earlier step (a later kernel of a gated step: the first one
// decided). Every thread of the block must call it (a barrier).
__device__ __forceinline__ bool step_gate_closed(const GateView& gate) {
  __shared__ int shut;
  if (threadIdx.x == 0) shut = static_cast<volatile StepGate*>(gate.gate)->closed != kGateOpen;
  __syncthreads();
  return shut != 0;
}

// Raises the block's largest squared displacement into the gate's slot for this step: `sq`, one
// coordinate's term per thread (dim threads a particle, kGateParticles particles a block), summed
// over axes as search/reuse.cu sums it (rounded squares, in axis order: the same bits as the
// host's check). A particle whose displacement is not a number closes the gate
// (search/step_gate.cuh).
__device__ __forceinline__ void raise_displacement(double sq, int dim, std::size_t n, const GateView& gate) {
  __shared__ double square[kGateParticles * kMaxDim];
  square[threadIdx.x] = sq;
  __syncthreads();
  double worst = 0;
  const std::size_t i = std::size_t(blockIdx.x) * kGateParticles + threadIdx.x;
  if (threadIdx.x < kGateParticles && i < n) {
    double d2 = 0;
    for (int a = 0; a < dim; ++a) d2 += square[threadIdx.x * dim + a];
    worst = gate_displacement(d2);
  }
  raise_block_displacement(worst, gate);
}



// Particle slot `at`'s mass: from `mass` (the order's array), or the one mass of all (GatedState).
__device__ __forceinline__ double mass_of(const double* __restrict__ mass, std::size_t at, double value) {
  return mass ? mass[at] : value;
}

// Thread k's state slot (coordinate k of slot k / D): `slot` indexes the order the kernel reads
// (the caller's index for kCaller, else the rank), `particle` is the caller's index (flags, the
// thermostat's key, types), `from` where its state is read (the caller's index for kGather).
template <int D, StateOrder O>
struct StateSlot {
  std::size_t slot = 0, particle = 0, from = 0;
  int axis = 0;
  __device__ StateSlot(std::size_t k, bool in, const uint32_t* __restrict__ order) {
    slot = k / D;
    axis = int(k - slot * D);
    particle = slot;
    if constexpr (O != StateOrder::kCaller) {
      if (in) particle = order[slot];
    }
    from = O == StateOrder::kGather ? particle : slot;
  }
  __device__ std::size_t read() const { return from * D + std::size_t(axis); }   // coordinate k's source
  __device__ std::size_t write() const { return slot * D + std::size_t(axis); }  // and destination
};

// The arrays a kernel of order O reads (kCaller, kGather: the caller's; kRank: the copy) and
// writes (kCaller: the caller's; else the copy). The forces: the caller's order for kCaller
// (lean) and for kGather (the chunk's first step follows an ordinary evaluation, or a chunk whose
// last forces unrank_forces put back in the caller's order); the gated evaluations' rank order for
// kRank.
template <StateOrder O>
struct StateArrays {
  const double *x_in, *v_in, *f_in, *mass_in, *built_in;
  double *x_out, *v_out;
  __device__ explicit StateArrays(const GatedState& s) {
    const bool copy = O == StateOrder::kRank;
    x_in = copy ? s.x_ranked : s.x;
    v_in = copy ? s.v_ranked : s.v;
    f_in = copy ? s.f_ranked : s.f;
    mass_in = copy ? s.mass_ranked : s.mass;
    built_in = copy ? s.built_ranked : s.built;
    x_out = O == StateOrder::kCaller ? s.x : s.x_ranked;
    v_out = O == StateOrder::kCaller ? s.v : s.v_ranked;
  }
};

// What a gated step's last drift kernel places in the list's rank order: the thread for slot `own`
// of the block (threads below kGateParticles) loads its rank, caller's index and type with the
// other loads (before the gate, but for GateFirst); after raise_displacement's barriers it reads
// the particle's new coordinates from `moved` (coordinate thread c's at moved[c]) and writes its
// entry of the gathered array as the evaluation's gather would (place_ranked), so the evaluation
// has no gather kernel (which would cost a launch and a read of the positions a step). In rank
// order the slot is the rank: the entries are written coalesced.
template <StateOrder O>
struct Placing {
  std::size_t own = 0, particle = 0;
  bool places = false;
  uint32_t rank = 0, type = 0;
  __device__ Placing(const RankOrder& to, std::size_t n) {
    own = std::size_t(blockIdx.x) * kGateParticles + threadIdx.x;
    places = threadIdx.x < kGateParticles && own < n;
    if (!places) return;
    if constexpr (O == StateOrder::kCaller) {
      particle = own, rank = to.rank[own];
    } else {
      particle = to.order[own], rank = uint32_t(own);
    }
    type = to.types ? to.types[particle] : 0u;
  }
  template <int D>
  __device__ void place(const RankOrder& to, const double* moved) const {
    if (!places) return;
    double v[3] = {0, 0, 0};
    for (int a = 0; a < D; ++a) v[a] = moved[threadIdx.x * D + a];
    place_ranked<D>(to, particle, rank, v, type);
  }
};

// The gated kernels of a step load every coordinate they read before the gate's barrier, in one
// batch, and template the dimension (a constant divisor), so that the kick-drift's thread waits on
// one round trip, not on four dependent ones in a row (the gate, then mass, velocity and force, then
// the position, which nvcc would load after the velocity's store, then the build's position after
// the position's store; performance.md records the measurement). A shut gate discards what was
// loaded.

// The kick-drift of a Verlet step behind the step gate (search/step_gate.h): the gate (step_gate_shut: the
// kernel returns with the state as it was), then the kick-drift, then each particle's squared
// displacement from the build's positions into the gate, and its new position into the list's
// rank order (Placing). The state: StateOrder (kGather also copies the mass and the build's
// position into rank order).
// GateFirst (a step queued past the expected rebuild, which the gate most likely shuts): the gate
// is read before the loads, so that a shut step costs its read, not the state's; the other steps
// load first (above).
template <int D, bool GateFirst, StateOrder O>
__global__ void __launch_bounds__(kGateParticles * 3)
    gated_kick_drift_kernel(GatedState s, double h, int kicks, double dt, DriftBox box, std::size_t n,
                            MdFlags* flags, GateView gate, RankOrder to) {
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  const bool in = k < n * std::size_t(D);
  if constexpr (GateFirst) {
    if (step_gate_shut(gate)) return;
  }
  const StateSlot<D, O> at(k, in, to.order);
  const StateArrays<O> a(s);
  const Placing<O> placing(to, n);
  double xa = 0, va = 0, fa = 0, m = 1, then = 0;
  if (in) {
    const std::size_t r = at.read();
    xa = a.x_in[r], va = a.v_in[r], m = mass_of(a.mass_in, at.from, s.mass_value), fa = a.f_in[r];
    then = O == StateOrder::kGather && s.built_is_x ? xa : a.built_in[r];
  }
  if constexpr (!GateFirst) {
    if (step_gate_shut(gate)) return;
  }
  __shared__ double moved[kGateParticles * D];
  double sq = 0;
  if (in) {
    const std::size_t w = at.write();
    if constexpr (O == StateOrder::kGather) {
      s.built_ranked[w] = then;
      if (at.axis == 0 && s.mass_ranked) s.mass_ranked[at.slot] = m;
    }
    va = kick_value(va, fa, m, h, kicks);
    a.v_out[w] = va;
    sq = last_drift(a.x_out, w, at.particle, at.axis, xa, va, dt, drift_axis(box, at.axis), then, flags,
                    moved[threadIdx.x]);
  }
  raise_displacement(sq, D, n, gate);  // its barrier: `moved` is written
  placing.template place<D>(to, moved);
}

// A Langevin (BAOAB) step behind the step gate, in three kernels around the thermostat: (1) the gate
// (step_gate_shut), `kicks` half kicks (the previous step's closing one, deferred, and this step's
// opening one, rounded one after the other as kick_kernel would) and the first half drift; (2) the
// thermostat (gated_thermostat_kernel); (3) the second half drift with the wrap, the displacement
// into the gate and the new positions into the list's rank order (Placing). The same arithmetic,
// kernel for kernel, as the ungated step. (1) takes gated_kick_drift_kernel's StateOrder and
// GateFirst; (2) and (3) follow (1) in the chunk (kCaller or kRank).
template <int D, bool GateFirst, StateOrder O>
__global__ void __launch_bounds__(kGateParticles * 3)
    gated_langevin_kick_drift_kernel(GatedState s, double h, int kicks, DriftBox box, std::size_t n,
                                     MdFlags* flags, GateView gate, const uint32_t* __restrict__ order) {
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  const bool in = k < n * std::size_t(D);
  if constexpr (GateFirst) {  // as gated_kick_drift_kernel
    if (step_gate_shut(gate)) return;
  }
  const StateSlot<D, O> at(k, in, order);
  const StateArrays<O> a(s);
  double xa = 0, va = 0, fa = 0, m = 1, then = 0;
  if (in) {
    const std::size_t r = at.read();
    xa = a.x_in[r], va = a.v_in[r], m = mass_of(a.mass_in, at.from, s.mass_value), fa = a.f_in[r];
    if constexpr (O == StateOrder::kGather) then = s.built_is_x ? xa : s.built[r];
  }
  if constexpr (!GateFirst) {
    if (step_gate_shut(gate)) return;
  }
  if (!in) return;
  const std::size_t w = at.write();
  if constexpr (O == StateOrder::kGather) {
    s.built_ranked[w] = then;
    if (at.axis == 0 && s.mass_ranked) s.mass_ranked[at.slot] = m;
  }
  va = kick_value(va, fa, m, h, kicks);
  a.v_out[w] = va;
  bool bad;
  a.x_out[w] = drift_value(xa, va, h, drift_axis(box, at.axis), false, bad);
  flag_diverged(bad, at.particle, at.axis, h, va, flags);
}

template <int D, StateOrder O>
__global__ void __launch_bounds__(kGateParticles * 3)
    gated_langevin_drift_kernel(GatedState s, double h, DriftBox box, std::size_t n, MdFlags* flags,
                                GateView gate, RankOrder to) {
  static_assert(O != StateOrder::kGather, "the chunk's first kernel is (1)");
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  const bool in = k < n * std::size_t(D);
  const StateSlot<D, O> at(k, in, to.order);
  const StateArrays<O> a(s);
  const Placing<O> placing(to, n);
  double xa = 0, va = 0, then = 0;
  if (in) {
    const std::size_t r = at.read();
    xa = a.x_in[r], va = a.v_in[r], then = a.built_in[r];
  }
  if (step_gate_closed(gate)) return;
  __shared__ double moved[kGateParticles * D];
  double sq = 0;
  if (in) {
    sq = last_drift(a.x_out, at.write(), at.particle, at.axis, xa, va, h, drift_axis(box, at.axis), then, flags,
                    moved[threadIdx.x]);
  }
  raise_displacement(sq, D, n, gate);  // its barrier: `moved` is written
  placing.template place<D>(to, moved);
}

// thermostat_kernel behind the step gate (the step's first kernel decided; stream = the step), on
// the state of StateOrder O (kCaller or kRank): the noise keyed by the caller's index all the same.
template <int D, StateOrder O>
__global__ void gated_thermostat_kernel(GatedState s, double c1, double c2, double kT, uint64_t seed, std::size_t n,
                                        GateView gate, const uint32_t* __restrict__ order) {
  static_assert(O != StateOrder::kGather, "the chunk's first kernel is (1)");
  if (step_gate_closed(gate)) return;
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  const bool in = k < n * std::size_t(D);
  if (!in) return;
  const StateSlot<D, O> at(k, in, order);
  const StateArrays<O> a(s);
  const std::size_t w = at.write();
  const double sigma = thermostat_sigma(c2, kT, mass_of(a.mass_in, at.slot, s.mass_value));
  a.v_out[w] = thermostat_value(a.v_in[w], c1, sigma, counter_normal(seed, gate.step, at.particle * D + std::size_t(at.axis)));
}

// Runs f with std::integral_constant<StateOrder, o>.
template <class F>
void with_state_order(StateOrder o, F&& f) {
  switch (o) {
    case StateOrder::kCaller: f(std::integral_constant<StateOrder, StateOrder::kCaller>{}); return;
    case StateOrder::kGather: f(std::integral_constant<StateOrder, StateOrder::kGather>{}); return;
    case StateOrder::kRank: f(std::integral_constant<StateOrder, StateOrder::kRank>{}); return;
  }
}

// The evaluation's gate, as gate_shut reads it (the evaluation's kernel posted the notice), read by
// one thread of the block.
// `forces` and the thread index k are in rank order where `order` is given (p its rank), else in the
// caller's order; `external` is in the caller's order.
__global__ void gated_external_kernel(GateView gate, double* __restrict__ forces, const double* __restrict__ external,
                                      const uint32_t* __restrict__ order, std::size_t n, int dim) {
  __shared__ int shut;
  if (threadIdx.x == 0) {
    const volatile StepGate* g = gate.gate;
    shut = g->closed != kGateOpen || g->d2[gate.step % 3] > gate.limit;
  }
  __syncthreads();
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (shut || k >= n * std::size_t(dim)) return;
  const std::size_t p = k / std::size_t(dim), axis = k % std::size_t(dim);
  forces[k] += external[(order ? std::size_t(order[p]) : p) * std::size_t(dim) + axis];
}

}  // namespace

void queue_gated_external(const GateView& gate, double* forces, const double* external, const uint32_t* order,
                          std::size_t n, int dim, cudaStream_t stream) {
  if (n == 0) return;
  gated_external_kernel<<<blocks_for(n * std::size_t(dim)), kBlock, 0, stream>>>(gate, forces, external, order, n, dim);
  CF_CUDA_CHECK_LAUNCH();
}

void queue_gated_step(const GatedStep& g, cudaStream_t stream) {
  const std::size_t n = g.n;
  const unsigned blocks = unsigned((n + kGateParticles - 1) / kGateParticles);
  const unsigned threads = unsigned(kGateParticles * g.box.dim);
  with_state_order(g.order, [&](auto o) {
    constexpr StateOrder O = decltype(o)::value;
    with_dim(g.box.dim, [&](auto dim) {
      constexpr int D = decltype(dim)::value;
      if (!g.langevin) {
        auto kick_drift = [&](auto gate_first) {
          gated_kick_drift_kernel<D, decltype(gate_first)::value, O><<<blocks, threads, 0, stream>>>(
              g.state, 0.5 * g.dt, g.kicks, g.dt, g.box, n, g.flags, g.gate, g.to);
        };
        if (g.gate_first) kick_drift(std::true_type{});
        else kick_drift(std::false_type{});
        CF_CUDA_CHECK_LAUNCH();
        return;
      }
      auto kick_drift = [&](auto gate_first) {
        gated_langevin_kick_drift_kernel<D, decltype(gate_first)::value, O><<<blocks, threads, 0, stream>>>(
            g.state, 0.5 * g.dt, g.kicks, g.box, n, g.flags, g.gate, g.to.order);
      };
      if (g.gate_first) kick_drift(std::true_type{});
      else kick_drift(std::false_type{});
      CF_CUDA_CHECK_LAUNCH();
      constexpr StateOrder After = O == StateOrder::kCaller ? O : StateOrder::kRank;  // (1) gathered
      gated_thermostat_kernel<D, After><<<blocks_for(n * D), kBlock, 0, stream>>>(g.state, g.c1, g.c2, g.kT, g.seed, n,
                                                                                 g.gate, g.to.order);
      CF_CUDA_CHECK_LAUNCH();
      gated_langevin_drift_kernel<D, After><<<blocks, threads, 0, stream>>>(g.state, 0.5 * g.dt, g.box, n, g.flags,
                                                                           g.gate, g.to);
      CF_CUDA_CHECK_LAUNCH();
    });
  });
}

}  // namespace cellforce::cuda
