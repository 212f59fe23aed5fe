// The CUDA backend's integration and state-access jobs: the MD state lives in device memory for
// the whole run, and velocity Verlet and Langevin BAOAB (md/md.h's advance(), step for step) run
// as kernels on the force engine's stream, with the forces from its resident evaluations. The
// host queues a call's steps without waiting (the search keeps its counts on the device), except
// with an open axis (the particles' bounds, on steps that build the structure) and with a skin
// (the largest displacement: per step, or, with pair lists (Verlet or Langevin), per chunk of
// steps queued behind the step gate, step_gate.h); the flags (a drift that diverged, a force that is not finite) are
// read once per advance() call. Nothing of the particles crosses PCIe except in set_state,
// get_state and the error path; observables() reads 8 numbers.
//
// FIRE (minimize(), md/minimize.h's algorithm) runs as kernels on the same stream: per step one
// kernel steps back (on an uphill step) and kicks, a reduction sums v^2, one kernel mixes, caps,
// drifts and wraps (md/fire_step.h's per-particle arithmetic, the host's bits), the force engine
// evaluates (with energy and virial), and one reduction gives P = F.v, sum F^2 and the largest
// |F_i| with its particle. The scalar decisions (dt, alpha, the downhill count, convergence) are
// the host's FireSchedule: each step the host reads back those few numbers (FireScalars: 56
// bytes, with the evaluation's energy and a non-finite-position flag) and the force engine's
// flags, one synchronisation per step; the particles stay on the device.
#include <cub/device/device_reduce.cuh>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/iterator/transform_iterator.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <optional>

#include "backends/md_engine.h"
#include "check.cuh"
#include "core/box.h"
#include "core/error.h"
#include "core/hd.h"
#include "core/random.h"
#include "core/text.h"
#include "device_buffer.cuh"
#include "force_engine.h"  // cuda/force_engine.h
#include "gate_readback.cuh"  // GateReadback: the gate's copy and notice
#include "md/fire_step.h"
#include "pair_list.cuh"  // place_ranked
#include "step_gate.cuh"
#include "traversal.cuh"   // kCellSums
#include "verlet_step.cuh"
#include "with_dim.cuh"

namespace cellforce {
namespace {

using cuda::DeviceBuffer;
using cuda::drift_axis;
using cuda::drift_value;
using cuda::DriftAxis;
using cuda::DriftBox;
using cuda::flag_diverged;
using cuda::kick_value;
using cuda::MdFlags;
using cuda::step_gate_shut;
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
// exactly as two kick_kernel launches would), then the full drift x += dt v with the check and the
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

constexpr int kGateParticles = 128;  // particles per block of the gated kernels (dim threads each)

// Whether the gate closed at an earlier step (a later kernel of a gated step: the first one
// decided). Every thread of the block must call it (a barrier).
__device__ __forceinline__ bool step_gate_closed(const cuda::GateView& gate) {
  __shared__ int shut;
  if (threadIdx.x == 0) shut = static_cast<volatile cuda::StepGate*>(gate.gate)->closed != cuda::kGateOpen;
  __syncthreads();
  return shut != 0;
}

// Raises the block's largest squared displacement into the gate's slot for this step: `sq`, one
// coordinate's term per thread (dim threads a particle, kGateParticles particles a block), summed
// over axes as cuda/reuse.cu sums it (rounded squares, in axis order: the same bits as the host's
// check). A particle whose displacement is not a number closes the gate (step_gate.cuh).
__device__ __forceinline__ void raise_displacement(double sq, int dim, std::size_t n, const cuda::GateView& gate) {
  __shared__ double square[kGateParticles * kMaxDim];
  square[threadIdx.x] = sq;
  __syncthreads();
  double worst = 0;
  const std::size_t i = std::size_t(blockIdx.x) * kGateParticles + threadIdx.x;
  if (threadIdx.x < kGateParticles && i < n) {
    double d2 = 0;
    for (int a = 0; a < dim; ++a) d2 += square[threadIdx.x * dim + a];
    worst = cuda::gate_displacement(d2);
  }
  cuda::raise_block_displacement(worst, gate);
}

// Where a gated chunk's kernels find the MD state (change 58). kCaller: the caller's order, as
// set_state() holds it (lean memory mode, whose gated evaluations leave the forces in that order
// too). With the forces in rank order (fast mode) the chunk runs on a copy of the state in the
// list's rank order: its first kernel (kGather) reads the caller's order at order[p] and writes
// rank p's entries, the later ones (kRank) read and write rank order, coalesced whatever the
// caller's numbering; the chunk's end writes the positions and velocities back (unrank_state).
// The arithmetic is the same in every order: the same bits.
enum class StateOrder { kCaller, kGather, kRank };

// The state's arrays: the caller's order, and the chunk's rank-order copy (null in lean mode).
// Change 60: with every mass the same, the masses are `mass_value` and both mass arrays null (no
// load per coordinate); `built_is_x`: the chunk starts at the positions the structure was just
// built from, so kGather copies them as the build's positions instead of reading those too.
struct GatedState {
  double* x;
  double* v;
  const double* f;  // the last ordinary evaluation's forces (the caller's order)
  const double* mass;   // null: every mass is mass_value
  const double* built;  // the build's positions (n x dim)
  double* x_ranked;
  double* v_ranked;
  double* mass_ranked;  // null with `mass`
  double* built_ranked;
  const double* f_ranked;  // the gated evaluations' forces (RankOrder::forces)
  double mass_value;
  bool built_is_x;
};

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

// What a gated step's last drift kernel places in the list's rank order (change 49): the thread
// for slot `own` of the block (threads below kGateParticles) loads its rank, caller's index and
// type with the other loads (before the gate, but for change 52's GateFirst); after
// raise_displacement's barriers it reads the particle's new coordinates from `moved` (coordinate
// thread c's at moved[c]) and writes its entry of the gathered array as the evaluation's gather
// would (cuda::place_ranked), so the evaluation has no gather kernel (a launch and a read of the
// positions a step: 22 us at 1M particles on an H100). In rank order (change 58) the slot is the
// rank: the entries are written coalesced.
template <StateOrder O>
struct Placing {
  std::size_t own = 0, particle = 0;
  bool places = false;
  uint32_t rank = 0, type = 0;
  __device__ Placing(const cuda::RankOrder& to, std::size_t n) {
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
  __device__ void place(const cuda::RankOrder& to, const double* moved) const {
    if (!places) return;
    double v[3] = {0, 0, 0};
    for (int a = 0; a < D; ++a) v[a] = moved[threadIdx.x * D + a];
    cuda::place_ranked<D>(to, particle, rank, v, type);
  }
};

// The gated kernels of a step load every coordinate they read before the gate's barrier, in one
// batch, and template the dimension (a constant divisor): the kick-drift's thread waited on four
// dependent round trips in a row (the gate, then mass, velocity and force, then the position, which
// nvcc loaded after the velocity's store, then the build's position after the position's store),
// 74 us at 1M particles on an H100 with DRAM 58% busy (performance.md, change 28). A shut gate
// discards what was loaded.

// The kick-drift of a Verlet step behind the step gate (step_gate.h): the gate (step_gate_shut: the
// kernel returns with the state as it was), then the kick-drift, then each particle's squared
// displacement from the build's positions into the gate, and its new position into the list's
// rank order (Placing). The state: StateOrder (kGather also copies the mass and the build's
// position into rank order).
// GateFirst (change 52: a step queued past the expected rebuild, which the gate most likely shuts):
// the gate is read before the loads, so that a shut step costs its read, not the state's (~50 us
// at 1M particles); the other steps load first (change 28).
template <int D, bool GateFirst, StateOrder O>
__global__ void __launch_bounds__(kGateParticles * 3)
    gated_kick_drift_kernel(GatedState s, double h, int kicks, double dt, DriftBox box, std::size_t n,
                            MdFlags* flags, cuda::GateView gate, cuda::RankOrder to) {
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
                                     MdFlags* flags, cuda::GateView gate, const uint32_t* __restrict__ order) {
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
                                cuda::GateView gate, cuda::RankOrder to) {
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

// BAOAB's O step: v = c1 v + c2 sqrt(kT / m) xi, xi from counter_normal keyed by the step and the
// particle's stable ID (its index in the caller's order), as the host integrator draws it.
__global__ void thermostat_kernel(double* __restrict__ v, const double* __restrict__ mass, double c1,
                                  double c2, double kT, uint64_t seed, uint64_t stream, std::size_t n, int dim) {
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= n * std::size_t(dim)) return;
  const double sigma = c2 * sqrt(kT / mass[k / std::size_t(dim)]);
  v[k] = c1 * v[k] + sigma * counter_normal(seed, stream, k);
}

// thermostat_kernel behind the step gate (the step's first kernel decided; stream = the step), on
// the state of StateOrder O (kCaller or kRank): the noise keyed by the caller's index all the same.
template <int D, StateOrder O>
__global__ void gated_thermostat_kernel(GatedState s, double c1, double c2, double kT, uint64_t seed, std::size_t n,
                                        cuda::GateView gate, const uint32_t* __restrict__ order) {
  static_assert(O != StateOrder::kGather, "the chunk's first kernel is (1)");
  if (step_gate_closed(gate)) return;
  const std::size_t k = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  const bool in = k < n * std::size_t(D);
  if (!in) return;
  const StateSlot<D, O> at(k, in, order);
  const StateArrays<O> a(s);
  const std::size_t w = at.write();
  const double sigma = c2 * sqrt(kT / mass_of(a.mass_in, at.slot, s.mass_value));
  a.v_out[w] = c1 * a.v_in[w] + sigma * counter_normal(seed, gate.step, at.particle * D + std::size_t(at.axis));
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

// ---- FIRE ----

// What one FIRE reduction gives over the particles after an evaluation: P = F.v and sum F^2 over
// every coordinate, and the largest |F_i|^2 with its particle (largest_force's choice: a NaN is
// the largest of all, ties go to the smallest index).
struct ForceSums {
  double power;
  double f2;
  double largest2;
  unsigned long long particle;
};

// The numbers the host reads back per FIRE step.
struct FireScalars {
  ForceSums forces;                 // of the last evaluation, with the velocities now
  double v2;                        // sum v^2 after the kick (the mixing's |v|)
  double energy;                    // the last evaluation's potential energy (its totals[0])
  unsigned long long bad_position;  // min over non-finite coordinates of axis x n + particle; ~0 if none
};

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

struct WrapBox {
  int dim;
  double length[kMaxDim];
  bool periodic[kMaxDim];
};

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

template <class T>
void upload(DeviceBuffer<T>& d, const std::vector<T>& h, cudaStream_t stream) {
  d.reserve(std::max<std::size_t>(h.size(), 1));
  if (!h.empty())
    CF_CUDA_CHECK(cudaMemcpyAsync(d.data(), h.data(), h.size() * sizeof(T), cudaMemcpyHostToDevice, stream));
}

template <class T>
void download(std::vector<T>& h, const T* d, std::size_t count, cudaStream_t stream) {
  h.resize(count);
  if (count) CF_CUDA_CHECK(cudaMemcpyAsync(h.data(), d, count * sizeof(T), cudaMemcpyDeviceToHost, stream));
}

using Clock = std::chrono::steady_clock;

// The engine's device current for a call, the caller's restored after it.
class OnDevice {
 public:
  explicit OnDevice(int device) {
    CF_CUDA_CHECK(cudaGetDevice(&previous_));
    if (previous_ != device) CF_CUDA_CHECK(cudaSetDevice(device));
  }
  ~OnDevice() { cudaSetDevice(previous_); }
  OnDevice(const OnDevice&) = delete;
  OnDevice& operator=(const OnDevice&) = delete;

 private:
  int previous_ = 0;
};

class CudaMdEngine final : public MdEngine {
 public:
  explicit CudaMdEngine(std::unique_ptr<ForceEngine> forces)
      : owner_(std::move(forces)), forces_(dynamic_cast<CudaForceEngine&>(*owner_)), gpu_(forces_.gpu()) {
    const OnDevice on(gpu_.options().device);
    stream_ = static_cast<cudaStream_t>(gpu_.stream());
    try {
      CF_CUDA_CHECK(cudaEventCreate(&chunk_start_));
      CF_CUDA_CHECK(cudaEventCreate(&chunk_end_));
    } catch (...) {
      release();
      throw;
    }
  }
  ~CudaMdEngine() override {
    try {
      const OnDevice on(gpu_.options().device);  // the buffers are freed on their own device
      // Queued kernels may still post into the gate's mapped memory (a run left by an exception
      // before its synchronisation): wait for them before it goes (errors ignored).
      if (stream_) cudaStreamSynchronize(stream_);
      release();
    } catch (...) {
      release();  // a destructor cannot throw
    }
  }

  void set_state(const MdState& state, const std::vector<double>& masses, const ForceField& ff) override {
    const OnDevice on(gpu_.options().device);
    validate_system(state.config.view(), ff);
    validate_masses(masses, state.config.size());
    if (ff.num_types() > 1 && state.config.types.size() != state.config.size())
      throw Error("the state has " + std::to_string(state.config.types.size()) + " types for " +
                  std::to_string(state.config.size()) + " particles");
    at_build_ = false;  // the positions change
    box_ = state.config.box;
    n_ = state.config.size();
    ff_ = ff;
    step_ = state.step;
    time_ = state.time;
    host_types_ = state.config.types;
    upload(positions_, state.config.positions, stream_);
    upload(velocities_, state.velocities.empty() ? std::vector<double>(n_ * box_.dim, 0.0) : state.velocities,
           stream_);
    upload(masses_, masses, stream_);
    uniform_mass_.reset();  // change 60: one mass for all, bit for bit, is passed as a number
    if (!masses.empty() && std::all_of(masses.begin(), masses.end(), [&](double m) {
          return std::memcmp(&m, &masses[0], sizeof m) == 0;
        }))
      uniform_mass_ = masses[0];
    upload(types_, state.config.types, stream_);
    counters_.bytes_to_device += (2 * n_ * box_.dim + n_) * sizeof(double) + n_ * sizeof(uint32_t);
    flags_.reserve(1);
    reset_flags();
    evaluate(true);
    check(step_, step_);
  }

  void advance(int64_t steps, const IntegratorSettings& settings, bool observe) override {
    const OnDevice on(gpu_.options().device);
    const auto t0 = Clock::now();
    // At most kRun steps are queued between two reads of the flags (and of the timing events).
    for (int64_t done = 0; done < steps;) {
      const int64_t k = std::min<int64_t>(steps - done, kRun);
      const bool final_run = done + k == steps;  // its last evaluation is the call's: observed, sampled
      run(k, settings, observe && final_run, final_run);
      done += k;
    }
    counters_.host_wait_seconds += std::chrono::duration<double>(Clock::now() - t0).count();
    gpu_.collect_timing();  // the stage times of the call's last evaluation
    add_stage_sample(counters_, gpu_.stats());
  }

  void get_state(MdState& state) override {
    const OnDevice on(gpu_.options().device);
    const std::size_t nd = n_ * std::size_t(box_.dim);
    state.config.box = box_;
    state.config.types = host_types_;
    download(state.config.positions, positions_.data(), nd, stream_);
    download(state.velocities, velocities_.data(), nd, stream_);
    download(state.forces, gpu_.device_forces(), nd, stream_);
    CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
    counters_.bytes_to_host += 3 * nd * sizeof(double);
    state.step = step_;
    state.time = time_;
  }

  int64_t step() const override { return step_; }
  std::vector<std::pair<const char*, std::size_t>> state_buffers() const override {
    return {{"md: positions", positions_.bytes()},
            {"md: velocities", velocities_.bytes()},
            {"md: masses", masses_.bytes()},
            {"md: types", types_.bytes()},
            {"md: flags", flags_.bytes()},
            {"md: reduction result", scratch_result_.bytes()},
            {"md: FIRE scalars", fire_scalars_.bytes()},
            {"md: FIRE start", fire_start_.bytes()},
            {"md: reduction scratch", reduce_scratch_.bytes()},
            {"md: step gate", gate_.bytes()},
            {"md: chunk state in rank order", ranked_state_.bytes()}};
  }

  Observables observables() override {
    const OnDevice on(gpu_.options().device);
    if (!observed_) {
      evaluate(true);
      check(step_, step_);
    }
    // One reduction and one copy of 8 numbers: kinetic energy, then the engine's totals.
    scratch_result_.reserve(1 + cuda::kCellSums);
    double* result = scratch_result_.data();
    if (n_) {
      auto terms = thrust::make_transform_iterator(thrust::counting_iterator<std::size_t>(0),
                                                   KineticTerm{velocities_.data(), masses_.data(), box_.dim});
      std::size_t bytes = 0;
      CF_CUDA_CHECK(cub::DeviceReduce::Sum(nullptr, bytes, terms, result, n_, stream_));
      reduce_scratch_.reserve(std::max<std::size_t>(bytes, 1));
      CF_CUDA_CHECK(cub::DeviceReduce::Sum(reduce_scratch_.data(), bytes, terms, result, n_, stream_));
    } else {
      CF_CUDA_CHECK(cudaMemsetAsync(result, 0, sizeof(double), stream_));
    }
    CF_CUDA_CHECK(cudaMemcpyAsync(result + 1, gpu_.device_totals(), cuda::kCellSums * sizeof(double),
                                  cudaMemcpyDeviceToDevice, stream_));
    double host[1 + cuda::kCellSums] = {};
    CF_CUDA_CHECK(cudaMemcpyAsync(host, result, sizeof(host), cudaMemcpyDeviceToHost, stream_));
    CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
    counters_.bytes_to_host += sizeof(host);
    Observables o;
    o.kinetic = host[0];
    o.potential = host[1];
    for (int k = 0; k < kVirialComponents; ++k) {
      const int r = virial_row(k), c = virial_col(k);
      if (r >= box_.dim || c >= box_.dim) continue;
      o.virial[r][c] = o.virial[c][r] = host[2 + k];
    }
    return o;
  }

  void reevaluate() override {
    const OnDevice on(gpu_.options().device);
    at_build_ = false;  // the structure may have been restored from other positions (restore_reuse)
    evaluate(true);
    check(step_, step_);
  }
  FireResult minimize(const FireSettings& settings) override {
    const OnDevice on(gpu_.options().device);
    check_fire_settings(settings);
    const std::size_t nd = n_ * std::size_t(box_.dim);
    // The state to come back to when FIRE throws: a copy on the device.
    fire_start_.reserve(std::max<std::size_t>(2 * nd, 1));
    if (nd) {
      CF_CUDA_CHECK(cudaMemcpyAsync(fire_start_.data(), positions_.data(), nd * sizeof(double),
                                    cudaMemcpyDeviceToDevice, stream_));
      CF_CUDA_CHECK(cudaMemcpyAsync(fire_start_.data() + nd, velocities_.data(), nd * sizeof(double),
                                    cudaMemcpyDeviceToDevice, stream_));
    }
    try {
      return fire(settings);
    } catch (...) {
      try {
        try {
          gpu_.check_flags(box_, n_, positions_.data(), ff_);  // clears what the failed evaluation raised
        } catch (const Error&) {
        }
        at_build_ = false;  // the positions change
        if (nd) {
          CF_CUDA_CHECK(cudaMemcpyAsync(positions_.data(), fire_start_.data(), nd * sizeof(double),
                                        cudaMemcpyDeviceToDevice, stream_));
          CF_CUDA_CHECK(cudaMemcpyAsync(velocities_.data(), fire_start_.data() + nd, nd * sizeof(double),
                                        cudaMemcpyDeviceToDevice, stream_));
        }
        evaluate(true);  // the start's forces again, and its energy and virial
        check(step_, step_);
      } catch (...) {  // the start was evaluated before: FIRE's error is the one to report
      }
      throw;
    }
  }

  ForceEngine& forces() override { return forces_; }
  const MdCounters& counters() const override { return counters_; }
  void reset_counters() override { counters_ = MdCounters{}; }

 private:
  static constexpr int64_t kRun = 256;
  static constexpr int64_t kMaxGated = 64;  // steps queued behind the gate between two reads of it

  void release() {
    for (cudaEvent_t e : force_events_) cudaEventDestroy(e);
    force_events_.clear();
    for (cudaEvent_t e : wait_events_) cudaEventDestroy(e);
    wait_events_.clear();
    if (chunk_start_) cudaEventDestroy(chunk_start_);
    if (chunk_end_) cudaEventDestroy(chunk_end_);
    chunk_start_ = chunk_end_ = nullptr;
  }

  // `steps` steps queued back to back, then the flags read (one synchronisation). An error thrown
  // while queueing (an evaluation of positions that diverged) gives way to the flags' diagnosis.
  // Steps before the last go behind the step gate in chunks wherever the force engine can serve
  // them from its pair list (run_gated): one host wait per chunk instead of one per step. A step's
  // closing half kick is deferred into the next step's first kernel, but for the last step's.
  // `sampled`: the last run of an advance() call, whose last evaluation's stage times it samples.
  void run(int64_t steps, const IntegratorSettings& settings, bool observe, bool sampled) {
    const int dim = box_.dim;
    const double dt = settings.dt;
    const int64_t first = step_ + 1;
    drift_share_ = settings.langevin ? 0.5 : 1.0;  // as drift_box's limits below
    CF_CUDA_CHECK(cudaEventRecord(chunk_start_, stream_));
    std::size_t timed = 0;
    waits_ = 0;
    paused_ = false;
    shut_ms_ = 0;
    try {
      for (int64_t k = 0; k < steps;) {
        const bool last = k + 1 == steps;
        if (!last) {
          const GateChunk chunk = gate_chunk(steps - 1 - k);
          if (chunk.count > 0) {
            k += run_gated(chunk, k == 0 ? 1 : 2, settings, timed);
            continue;
          }
        }
        resume();
        if (!settings.langevin) {
          // The previous step's closing half kick (deferred) with this step's opening one, and the drift.
          kick_drift(0.5 * dt, k == 0 ? 1 : 2, dt);
        } else {
          kick(0.5 * dt, k == 0 ? 1 : 2);  // the previous step's closing half kick (deferred) and this one's
          drift(0.5 * dt, 0.5, false);  // two half drifts of at most L / 2: a step of at most L
          const double c1 = std::exp(-settings.friction * dt);
          const double c2 = std::sqrt(1.0 - c1 * c1);
          if (n_) {
            thermostat_kernel<<<blocks_for(n_ * dim), kBlock, 0, stream_>>>(
                velocities_.data(), masses_.data(), c1, c2, settings.kT, settings.seed, uint64_t(step_) + 1, n_, dim);
            CF_CUDA_CHECK_LAUNCH();
          }
          drift(0.5 * dt, 0.5, true);
        }
        step_ += 1;
        time_ = double(step_) * dt;  // not summed: the same after a restart
        // Only the sampled run's last evaluation records its stage events (change 83): its stage
        // times are advance()'s sample (collect_timing), and a build between (`every`) is then keyed
        // as the gated chunks' closing ones, so that their graph serves it.
        timed_evaluation(timed, [&] { evaluate(observe && last, std::nullopt, last && sampled); });
        if (last) kick(0.5 * dt, 1);  // before the last: deferred into the next step's first kernel
        ++k;
      }
    } catch (const Error& e) {
      check(first, step_);  // throws the divergence or the bad pair when one is flagged
      rethrow_with((first == step_ ? "step " + std::to_string(first)
                                   : "steps " + std::to_string(first) + "-" + std::to_string(step_)) + ": ",
                   e);
    }
    resume();
    CF_CUDA_CHECK(cudaEventRecord(chunk_end_, stream_));
    check(first, step_);  // synchronises: the one host wait beyond the search's counts
    float ms = 0;
    double forces_ms = shut_ms_;  // a chunk's timed first evaluation when the gate shut it
    for (std::size_t t = 0; t < timed; ++t) {
      CF_CUDA_CHECK(cudaEventElapsedTime(&ms, force_events_[2 * t], force_events_[2 * t + 1]));
      forces_ms += ms * double(force_weights_[t]);
    }
    double wait_ms = 0;  // the device idle while the host read a gate and queued on: no stage's time
    for (std::size_t w = 0; w < waits_; ++w) {
      CF_CUDA_CHECK(cudaEventElapsedTime(&ms, wait_events_[2 * w], wait_events_[2 * w + 1]));
      wait_ms += ms;
    }
    CF_CUDA_CHECK(cudaEventElapsedTime(&ms, chunk_start_, chunk_end_));
    counters_.steps += steps;
    counters_.force_seconds += 1e-3 * forces_ms;
    counters_.integration_seconds += 1e-3 * std::max(double(ms) - forces_ms - wait_ms, 0.0);
  }

  // A gated chunk's end: the device idles from here (the gate's read) until the host queues more
  // work, which first records the matching resume(). The gap is booked to no stage.
  void pause() {
    while (wait_events_.size() < 2 * (waits_ + 1)) {
      cudaEvent_t ev;
      CF_CUDA_CHECK(cudaEventCreate(&ev));
      wait_events_.push_back(ev);
    }
    CF_CUDA_CHECK(cudaEventRecord(wait_events_[2 * waits_], stream_));
    ++waits_;
    paused_ = true;
  }
  void resume() {
    if (!paused_) return;
    CF_CUDA_CHECK(cudaEventRecord(wait_events_[2 * waits_ - 1], stream_));
    paused_ = false;
  }

  // Runs `queue` between the timing events of evaluation number `timed` (then counted).
  template <class Queue>
  void timed_evaluation(std::size_t& timed, Queue&& queue) {
    while (force_events_.size() < 2 * (timed + 1)) {
      cudaEvent_t ev;
      CF_CUDA_CHECK(cudaEventCreate(&ev));
      force_events_.push_back(ev);
    }
    force_weights_.resize(timed + 1);
    force_weights_[timed] = 1;  // evaluations it stands for (run_gated: a chunk's served ones)
    CF_CUDA_CHECK(cudaEventRecord(force_events_[2 * timed], stream_));
    queue();
    CF_CUDA_CHECK(cudaEventRecord(force_events_[2 * timed + 1], stream_));
    ++timed;
  }

  // How many of the next `most` steps to queue behind the gate: 0 when the force engine cannot
  // serve them from its list, else enough to reach the next rebuild if it comes as far after this
  // build as the last one did (interval_), and one more, so that few queued steps find the gate
  // shut: a shut step still costs its kernels' loads (~60 us at 1M), except the last, the one past
  // the expected rebuild, whose kick-drift reads the gate first (change 52). Change 48: one step past
  // the expected rebuild and at least 2 (two and at least 4 before: ~3.4 shut steps a build at 1M).
  // A chunk that ends before the gate closes costs one more read of the gate. `overshoot`: the
  // chunk's length is the expected one (not cut short by the run's end, `every` or the gate's own
  // bound), so its last step is the one past the expected rebuild.
  struct GateChunk {
    int64_t count = 0;
    bool overshoot = false;
  };
  GateChunk gate_chunk(int64_t most) const {
    const int64_t allowed = std::min(most, gpu_.gate_steps(box_, n_, ff_));
    if (allowed <= 0) return {};
    const int64_t expected = std::clamp<int64_t>(interval_ + 1 - since_build_, 2, kMaxGated);
    return {std::min(allowed, expected), expected <= allowed};
  }

  // `count` steps behind the step gate (step_gate.h), then one read of the gate. Steps the structure
  // served are done; at the step where the gate closed (its drifts done, its evaluation not run),
  // the ordinary evaluation rebuilds and that step is done too. Returns the steps done. Verlet: one
  // gated kick-drift a step (fast mode: the chunk's first step only, the later ones in the previous
  // evaluation's force kernel, change 59); Langevin: the gated kick and half drift, thermostat, half
  // drift. Fast mode runs the chunk on a rank-order copy of the state (StateOrder, change 58).
  int64_t run_gated(const GateChunk& chunk, int first_kicks, const IntegratorSettings& settings,
                    std::size_t& timed) {
    const int64_t count = chunk.count;
    const double dt = settings.dt;
    resume();
    observed_ = false;  // the state moves on: thermo() must evaluate again unless a later step observes
    // The gate zeroed, its closed step kGateOpen: by the last chunk's end (post_gate_kernel, change
    // 81), else here.
    if (!gate_reset_) {
      gate_.reserve(1);
      CF_CUDA_CHECK(cudaMemsetAsync(gate_.data(), 0, sizeof(cuda::StepGate), stream_));
      CF_CUDA_CHECK(cudaMemsetAsync(&gate_.data()->closed, 0xff, sizeof(unsigned long long), stream_));
    }
    gate_reset_ = false;  // until this chunk's end queues the copy that resets it
    const uint64_t first = uint64_t(step_) + 1;
    cuda::GateView view{gate_.data(), first, gpu_.gate_limit()};
    // The host reads the gate's notice or its copy, whichever comes first (change 77; tests may
    // ask for the copy alone, or for both, checked against each other).
    const GpuOptions& options = gpu_.options();
    const bool check_notice = options.gate_notice_check.value_or(false);
    const bool notice_first = options.gate_notice.value_or(true) && !check_notice;
    gate_read_.begin(view, options.gate_notice.value_or(true) || check_notice);
    const double* built = gpu_.device_build_positions();
    const DriftBox box = drift_box(settings.langevin ? 0.5 : 1.0);  // as the ungated steps' drifts
    const unsigned blocks = unsigned((n_ + kGateParticles - 1) / kGateParticles);
    const unsigned threads = unsigned(kGateParticles * box_.dim);
    const uint32_t* types = ff_.num_types() > 1 ? types_.data() : nullptr;
    // The drifts place the positions; a Verlet chunk's evaluations may run the next step's kick-drift.
    const cuda::RankOrder to = gpu_.rank_order(box_, n_, positions_.data(), types, ff_, !settings.langevin);
    const double c1 = std::exp(-settings.friction * dt), c2 = std::sqrt(1.0 - c1 * c1);  // as run()
    // With the forces in rank order (fast mode), the chunk runs on a rank-order copy of the state
    // (StateOrder, change 58), written back at its end.
    const bool ranked = to.forces != nullptr;
    GatedState state{positions_.data(), velocities_.data(), gpu_.device_forces(),
                     uniform_mass_ ? nullptr : masses_.data(), built, nullptr, nullptr, nullptr, nullptr, to.forces,
                     uniform_mass_.value_or(0.0), at_build_};
    at_build_ = false;  // the chunk's drifts move the positions
    if (ranked) {
      const std::size_t nd = n_ * std::size_t(box_.dim);
      ranked_state_.reserve(std::max<std::size_t>(3 * nd + (uniform_mass_ ? 0 : n_), 1));  // mass: change 60
      state.x_ranked = ranked_state_.data();
      state.v_ranked = state.x_ranked + nd;
      state.built_ranked = state.v_ranked + nd;
      if (!uniform_mass_) state.mass_ranked = state.built_ranked + nd;
    } else {
      ranked_state_.release();  // lean: none (a fast-mode system before may have left it)
    }
    // Verlet on the rank-order copy: every gated evaluation but the chunk's last runs the next step's
    // kick-drift in its force kernel (change 59), so only the chunk's first step has a kick-drift kernel.
    const bool fused = ranked && !settings.langevin;
    const cuda::NextKickDrift then{state.x_ranked, state.v_ranked, state.mass_ranked, state.built_ranked,
                                   to.order, 0.5 * dt, dt, box, flags_.data(), state.mass_value};
    bool gathered = false;  // the chunk's first kernel copied the state into rank order
    auto steps = [&] {
      for (int64_t j = 0; j < count; ++j) {
        view.step = first + uint64_t(j);
        const int kicks = j == 0 ? first_kicks : 2;
        const bool past_expected = chunk.overshoot && j == count - 1;  // gate first (change 52)
        const StateOrder order = !ranked ? StateOrder::kCaller : j == 0 ? StateOrder::kGather : StateOrder::kRank;
        with_state_order(order, [&](auto o) {
          constexpr StateOrder O = decltype(o)::value;
          cuda::with_dim(box_.dim, [&](auto dim) {
            constexpr int D = decltype(dim)::value;
            if (!settings.langevin) {
              if (fused && j > 0) return;  // the previous evaluation ran it
              auto kick_drift = [&](auto gate_first) {
                gated_kick_drift_kernel<D, decltype(gate_first)::value, O><<<blocks, threads, 0, stream_>>>(
                    state, 0.5 * dt, kicks, dt, box, n_, flags_.data(), view, to);
              };
              if (past_expected) kick_drift(std::true_type{});
              else kick_drift(std::false_type{});
              CF_CUDA_CHECK_LAUNCH();
            } else {
              auto kick_drift = [&](auto gate_first) {
                gated_langevin_kick_drift_kernel<D, decltype(gate_first)::value, O>
                    <<<blocks, threads, 0, stream_>>>(state, 0.5 * dt, kicks, box, n_, flags_.data(), view, to.order);
              };
              if (past_expected) kick_drift(std::true_type{});
              else kick_drift(std::false_type{});
              CF_CUDA_CHECK_LAUNCH();
              constexpr StateOrder After = O == StateOrder::kCaller ? O : StateOrder::kRank;  // (1) gathered
              gated_thermostat_kernel<D, After><<<blocks_for(n_ * D), kBlock, 0, stream_>>>(
                  state, c1, c2, settings.kT, settings.seed, n_, view, to.order);
              CF_CUDA_CHECK_LAUNCH();
              gated_langevin_drift_kernel<D, After><<<blocks, threads, 0, stream_>>>(state, 0.5 * dt, box, n_,
                                                                                    flags_.data(), view, to);
              CF_CUDA_CHECK_LAUNCH();
            }
          });
        });
        gathered = ranked;
        // Only the chunk's first evaluation is timed (change 46): the two events around each gated
        // evaluation held the device ~1.5 us each between the step's kernels (H100, CUPTI trace:
        // 3.5 and 3.0 us before and after the evaluation against 1.7 between its own two kernels).
        // The chunk's served evaluations are booked at that one's time (they run the same kernels
        // on the same list); the untimed ones the gate shut (kernels that return at once) fall in
        // the integration's time. The timed one is queued right after the host's read of the gate:
        // at small sizes its window may hold a little of the host's launching (at 32k, 41.4 us of
        // forces and 3.8 of integration a step against a ~4 us kick-drift kernel).
        const cuda::NextKickDrift* next = fused && j + 1 < count ? &then : nullptr;
        if (j == 0) {
          std::size_t slot = timed;  // counted below, for every step served
          timed_evaluation(slot, [&] { gpu_.evaluate_gated(box_, n_, positions_.data(), types, ff_, view, next); });
        } else {
          gpu_.evaluate_gated(box_, n_, positions_.data(), types, ff_, view, next);
        }
      }
    };
    try {
      steps();
    } catch (...) {
      try {
        if (gathered) unrank_state(state, to.rank);  // the state as the queued kernels left it, for the diagnosis
      } catch (...) {
      }
      throw;
    }
    if (ranked) unrank_state(state, to.rank);
    pause();
    gate_read_.queue_copy(gate_.data(), stream_);  // control data, like the displacement: not counted
    gate_reset_ = true;
    const cuda::GateReadback::Outcome read = gate_read_.wait(notice_first);
    const uint64_t last = first + uint64_t(count) - 1;
    // The step the gate closed at: the copy's, or where no later kernel closed it, the last step's
    // own displacement past the limit (its shut evaluation posted the notice).
    auto closed_at = [&](const cuda::StepGate& g) {
      return g.closed == cuda::kGateOpen && g.d2[last % 3] > view.limit ? last : g.closed;
    };
    if (read.copy && check_notice) check_gate_notice(closed_at(*read.copy), *read.copy, read.notice);
    // Where the gate closed, the notice's values (the same as the copy's); else the copy's.
    const cuda::StepGate g = read.notice ? *read.notice : *read.copy;
    const bool early = !read.copy;  // the chunk's tail (shut steps, write-back, copy) may still run
    const uint64_t closed = closed_at(g);
    const int64_t served = closed == cuda::kGateOpen ? count : int64_t(closed - first);
    if (closed != cuda::kGateOpen) {
      ++counters_.gate_closings;
      if (early) ++counters_.gate_closings_early;
    }
    // Every step served: the last gated evaluation's forces are the state's, in the caller's order
    // for whatever comes next. (Where the gate closed, the closed step's kick-drift has read them and
    // its evaluation writes new ones.)
    if (served == count && to.forces) {
      resume();  // integration's time, as the kicks
      gpu_.unrank_forces(n_);
    }
    if (served == 0) {  // the timed evaluation was shut: its slot is reused below, so read it now
      // (after its end event: the host may have read the notice or the gate's mapped copy first)
      CF_CUDA_CHECK(cudaEventSynchronize(force_events_[2 * timed + 1]));
      float ms = 0;
      CF_CUDA_CHECK(cudaEventElapsedTime(&ms, force_events_[2 * timed], force_events_[2 * timed + 1]));
      shut_ms_ += ms;
    }
    double served_d2 = 0;
    std::memcpy(&served_d2, &g.served, sizeof served_d2);
    gpu_.settle_gate(served, served_d2);
    if (served > 0) {
      counters_.evaluations += served;
      add_reuse(counters_, gpu_.stats(), served);
      if (gpu_.stats().list_block) counters_.list_block = gpu_.stats().list_block;  // change 76's choice
    }
    since_build_ += served;
    counters_.gated_steps += served;
    if (served > 0) force_weights_[timed++] = served;  // the chunk's one timed evaluation, for all it served
    step_ += served;
    time_ = double(step_) * dt;
    if (served == count) return count;
    step_ += 1;  // the closed step: drifted, to be evaluated
    time_ = double(step_) * dt;
    resume();
    double closed_d2 = 0;  // its displacement, as the gated kick-drift measured it: the check's value
    std::memcpy(&closed_d2, &g.d2[closed % 3], sizeof closed_d2);
    // Its stage events are left out (change 83): advance() samples its last evaluation's stage
    // times (run(): the last step is never gated).
    timed_evaluation(timed, [&] { evaluate(false, closed_d2, false); });
    return served + 1;
  }

  // Runs f with std::integral_constant<StateOrder, o>.
  template <class F>
  static void with_state_order(StateOrder o, F&& f) {
    switch (o) {
      case StateOrder::kCaller: f(std::integral_constant<StateOrder, StateOrder::kCaller>{}); return;
      case StateOrder::kGather: f(std::integral_constant<StateOrder, StateOrder::kGather>{}); return;
      case StateOrder::kRank: f(std::integral_constant<StateOrder, StateOrder::kRank>{}); return;
    }
  }

  // A rank-order chunk's positions and velocities back into the caller's order (change 58).
  void unrank_state(const GatedState& state, const uint32_t* rank) {
    cuda::unrank(rank, state.x_ranked, n_, box_.dim, state.x, stream_);
    cuda::unrank(rank, state.v_ranked, n_, box_.dim, state.v, stream_);
  }

  void kick(double h, int kicks) {
    if (n_ == 0) return;
    kick_kernel<<<blocks_for(n_ * box_.dim), kBlock, 0, stream_>>>(velocities_.data(), gpu_.device_forces(),
                                                                     masses_.data(), h, kicks, n_, box_.dim);
    CF_CUDA_CHECK_LAUNCH();
  }

  void kick_drift(double h, int kicks, double dt) {
    at_build_ = false;
    if (n_ == 0) return;
    kick_drift_kernel<<<blocks_for(n_ * box_.dim), kBlock, 0, stream_>>>(positions_.data(), velocities_.data(),
                                                              gpu_.device_forces(), masses_.data(), h, kicks, dt,
                                                              drift_box(1.0), n_, flags_.data());
    CF_CUDA_CHECK_LAUNCH();
  }

  DriftBox drift_box(double limit) const {
    DriftBox b{};
    b.dim = box_.dim;
    for (int a = 0; a < box_.dim; ++a) {
      b.length[a] = box_.length[a];
      b.periodic[a] = box_.periodic[a];
      b.most[a] = drift_limit(box_, a, ff_.cutoff, limit);
      b.inv_length[a] = box_.periodic[a] ? 1.0 / box_.length[a] : 0.0;  // as cuda/reuse.cu
    }
    return b;
  }

  void drift(double h, double limit, bool wrap) {
    at_build_ = false;
    if (n_ == 0) return;
    drift_kernel<<<blocks_for(n_), kBlock, 0, stream_>>>(positions_.data(), velocities_.data(), h, drift_box(limit),
                                                         wrap, n_, flags_.data());
    CF_CUDA_CHECK_LAUNCH();
  }

  // known_d2: the step gate's displacement at these positions, where it closed (the reuse check's value).
  void evaluate(bool observe, std::optional<double> known_d2 = {}, bool time_stages = true) {
    gpu_.evaluate_resident(box_, n_, positions_.data(), ff_.num_types() > 1 ? types_.data() : nullptr, ff_,
                           Request{observe, observe}, known_d2, time_stages);
    observed_ = observe;
    at_build_ = gpu_.stats().rebuilt;  // the build's positions are the positions now
    ++counters_.evaluations;
    add_reuse(counters_, gpu_.stats());
    if (gpu_.stats().rebuilt) {
      if (since_build_ > 0) interval_ = since_build_ + 1;
      since_build_ = 0;
    } else {
      ++since_build_;
    }
  }

  // FIRE on the state (minimize() restores the start when this throws): md/minimize.h's run_fire,
  // its per-particle arithmetic in kernels, its decisions on the host.
  FireResult fire(const FireSettings& settings) {
    const int dim = box_.dim;
    const std::size_t nd = n_ * std::size_t(dim);
    fire_scalars_.reserve(1);
    CF_CUDA_CHECK(cudaMemsetAsync(fire_scalars_.data(), 0xff, sizeof(FireScalars), stream_));  // no bad position
    if (nd) CF_CUDA_CHECK(cudaMemsetAsync(velocities_.data(), 0, nd * sizeof(double), stream_));
    WrapBox wrap{};
    wrap.dim = dim;
    for (int a = 0; a < dim; ++a) {
      wrap.length[a] = box_.length[a];
      wrap.periodic[a] = box_.periodic[a];
    }

    const FireResult result = run_fire(settings, fire_evaluate(), [&](bool uphill, double dt, double alpha) {
      at_build_ = false;  // the step's drift moves the positions
      // n_ > 0 here: without particles the largest force is 0, converged.
      fire_kick_kernel<<<blocks_for(n_), kBlock, 0, stream_>>>(positions_.data(), velocities_.data(),
                                                               gpu_.device_forces(), masses_.data(), dt, 0.5 * dt,
                                                               uphill, n_, dim);
      CF_CUDA_CHECK_LAUNCH();
      auto speeds = thrust::make_transform_iterator(thrust::counting_iterator<std::size_t>(0),
                                                    SpeedTerm{velocities_.data(), dim});
      std::size_t bytes = 0;
      CF_CUDA_CHECK(cub::DeviceReduce::Sum(nullptr, bytes, speeds, &fire_scalars_.data()->v2, n_, stream_));
      reduce_scratch_.reserve(std::max<std::size_t>(bytes, 1));
      CF_CUDA_CHECK(
          cub::DeviceReduce::Sum(reduce_scratch_.data(), bytes, speeds, &fire_scalars_.data()->v2, n_, stream_));
      fire_drift_kernel<<<blocks_for(n_), kBlock, 0, stream_>>>(positions_.data(), velocities_.data(),
                                                                gpu_.device_forces(), fire_scalars_.data(), alpha,
                                                                dt, settings.max_displacement, wrap, n_);
      CF_CUDA_CHECK_LAUNCH();
      return fire_evaluate();
    });
    if (nd) CF_CUDA_CHECK(cudaMemsetAsync(velocities_.data(), 0, nd * sizeof(double), stream_));
    CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
    return result;
  }

  // One FIRE evaluation at the positions now (energy and virial), its ForceSums with the
  // velocities now, its energy, and the drift's flag (FireScalars): the numbers the host reads per
  // step, with
  // the force engine's flags (one synchronisation). Throws for a pair whose force is not finite
  // and for a position that is not finite (that diagnosis first: an evaluation of such positions
  // may fail on its own).
  FireEvaluation fire_evaluate() {
    FireScalars* d = fire_scalars_.data();
    try {
      evaluate(true);
    } catch (const Error&) {
      throw_if_position_not_finite();
      throw;
    }
    const ForceSums none{0, 0, -1, 0};  // largest_force's answer without particles
    if (n_) {
      auto terms = thrust::make_transform_iterator(thrust::counting_iterator<std::size_t>(0),
                                                   ForceTerm{gpu_.device_forces(), velocities_.data(), box_.dim});
      std::size_t bytes = 0;
      CF_CUDA_CHECK(cub::DeviceReduce::Reduce(nullptr, bytes, terms, &d->forces, n_, CombineForceSums{}, none,
                                              stream_));
      reduce_scratch_.reserve(std::max<std::size_t>(bytes, 1));
      CF_CUDA_CHECK(cub::DeviceReduce::Reduce(reduce_scratch_.data(), bytes, terms, &d->forces, n_,
                                              CombineForceSums{}, none, stream_));
    }
    CF_CUDA_CHECK(
        cudaMemcpyAsync(&d->energy, gpu_.device_totals(), sizeof(double), cudaMemcpyDeviceToDevice, stream_));
    FireScalars host{};
    CF_CUDA_CHECK(cudaMemcpyAsync(&host, d, sizeof host, cudaMemcpyDeviceToHost, stream_));
    try {
      gpu_.check_flags(box_, n_, positions_.data(), ff_);  // synchronises the stream
    } catch (const Error&) {
      throw_if_position_not_finite();
      throw;
    }
    counters_.bytes_to_host += sizeof host;
    if (!n_) host.forces = none;
    if (host.bad_position != ~0ull) throw_position_not_finite(host.bad_position);
    return FireEvaluation{host.energy, largest_of(host.forces), host.forces.power};
  }

  static LargestForce largest_of(const ForceSums& s) {
    return LargestForce{s.largest2 < 0 ? 0.0 : std::sqrt(s.largest2), std::size_t(s.particle)};
  }

  // The error path of FIRE's drift flag: the flag, then the coordinate it names, to the host.
  void throw_if_position_not_finite() {
    unsigned long long key = ~0ull;
    CF_CUDA_CHECK(cudaMemcpyAsync(&key, &fire_scalars_.data()->bad_position, sizeof key, cudaMemcpyDeviceToHost,
                                  stream_));
    CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
    if (key != ~0ull) throw_position_not_finite(key);
  }
  [[noreturn]] void throw_position_not_finite(unsigned long long key) {
    const std::size_t i = std::size_t(key % n_);
    const int axis = int(key / n_);
    double value = 0;
    CF_CUDA_CHECK(cudaMemcpyAsync(&value, positions_.data() + i * std::size_t(box_.dim) + std::size_t(axis),
                                  sizeof value, cudaMemcpyDeviceToHost, stream_));
    CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
    counters_.bytes_to_host += sizeof key + sizeof value;
    throw_fire_position_not_finite(i, axis, value);
  }

  void reset_flags() { CF_CUDA_CHECK(cudaMemsetAsync(flags_.data(), 0xff, sizeof(MdFlags), stream_)); }

  // gate_notice_check (tests): a chunk's notice (the first and only one posted) must be there exactly
  // where its gate closed (`closed`, from the copy), with the copy's values: the closed step, its
  // displacement and the largest one served (change 77).
  static void check_gate_notice(uint64_t closed, const cuda::StepGate& copy,
                                const std::optional<cuda::StepGate>& notice) {
    if (closed == cuda::kGateOpen) {
      if (notice) throw Error("internal error: a gated chunk posted a notice at step " +
                              std::to_string(notice->closed) + ", but its gate did not close");
      return;
    }
    if (!notice)
      throw Error("internal error: the step gate closed at step " + std::to_string(closed) +
                  ", but no kernel posted its notice");
    if (notice->closed != closed || notice->d2[closed % 3] != copy.d2[closed % 3] || notice->served != copy.served)
      throw Error("internal error: the step gate closed at step " + std::to_string(closed) +
                  ", but its notice says step " + std::to_string(notice->closed) + " or other values");
  }

  // Reads the integration's and the force engine's flags (synchronises) and throws for the first
  // that is raised, naming the steps first..last of the call.
  void check(int64_t first, int64_t last) {
    MdFlags f{};
    CF_CUDA_CHECK(cudaMemcpyAsync(&f, flags_.data(), sizeof(f), cudaMemcpyDeviceToHost, stream_));
    const std::string steps = first == last ? "step " + std::to_string(first)
                                            : "steps " + std::to_string(first) + "-" + std::to_string(last);
    try {
      gpu_.check_flags(box_, n_, positions_.data(), ff_);  // synchronises the stream
    } catch (const Error& e) {
      if (f.diverged == ~0ull) rethrow_with(steps + ": ", e);
    }
    if (f.diverged != ~0ull) {
      reset_flags();
      if (cuda::drift_key_particle(f.drift) == f.diverged) {  // the particle's drift (below 2^32 particles)
        double dx;
        const unsigned long long bits = cuda::drift_key_displacement_bits(f.drift);
        std::memcpy(&dx, &bits, sizeof dx);
        char digits[32];  // the key keeps 6 digits: shown as such, not as the truncated double's
        std::snprintf(digits, sizeof digits, "%.6g", dx);
        if (std::isfinite(dx)) dx = std::strtod(digits, nullptr);
        throw Error(steps + ": " + diverged_message(std::size_t(f.diverged), cuda::drift_key_axis(f.drift), dx, NAN,
                                                    box_, ff_.cutoff, drift_share_));
      }
      throw Error(steps + ": particle " + std::to_string(f.diverged) +
                  " moved too far in one drift or left the finite numbers: the integration diverged; lower dt, "
                  "or remove overlaps first");
    }
  }

  std::unique_ptr<ForceEngine> owner_;
  CudaForceEngine& forces_;
  GpuEngine& gpu_;
  cudaStream_t stream_ = nullptr;
  Box box_;
  std::size_t n_ = 0;
  ForceField ff_;
  int64_t step_ = 0;
  double time_ = 0;
  double drift_share_ = 1.0;  // drift_limit's share in the steps last queued: 0.5 under Langevin
  std::vector<uint32_t> host_types_;
  DeviceBuffer<double> positions_, velocities_, masses_;
  DeviceBuffer<uint32_t> types_;
  DeviceBuffer<MdFlags> flags_;
  DeviceBuffer<double> scratch_result_;
  DeviceBuffer<FireScalars> fire_scalars_;
  DeviceBuffer<double> fire_start_;  // positions, then velocities, before minimize()
  DeviceBuffer<double> ranked_state_;  // a gated chunk's state in rank order (change 58): x, v, built, mass
  DeviceBuffer<std::byte> reduce_scratch_;
  bool observed_ = false;
  std::optional<double> uniform_mass_;  // every particle's mass, where they are all the same (change 60)
  bool at_build_ = false;  // the positions are those the structure in use was built from (change 60)
  DeviceBuffer<cuda::StepGate> gate_;
  cuda::GateReadback gate_read_;  // the gate's copy and notice on the host (change 77)
  bool gate_reset_ = false;       // the last chunk's copy reset the gate (change 81)
  int64_t interval_ = 16;    // steps between the last two builds (a guess before there were two)
  int64_t since_build_ = 0;  // evaluations served since the last build
  MdCounters counters_;
  std::vector<cudaEvent_t> force_events_;
  std::vector<int64_t> force_weights_;    // per timed evaluation: the evaluations its time stands for
  std::vector<cudaEvent_t> wait_events_;  // per host turnaround of a run() call's gated chunks: pause, resume
  std::size_t waits_ = 0;                 // turnarounds in the run() call
  bool paused_ = false;                   // a turnaround's resume is still to be recorded
  double shut_ms_ = 0;                    // force-kernel time of the timed evaluations the gate shut, this call
  cudaEvent_t chunk_start_ = nullptr, chunk_end_ = nullptr;
};

}  // namespace

std::unique_ptr<MdEngine> make_cuda_md_engine(std::unique_ptr<ForceEngine> forces) {
  return std::make_unique<CudaMdEngine>(std::move(forces));
}

}  // namespace cellforce
