// The pair list's rank order on the device: a particle's entry in the arrays the list force kernel
// gathers its partners from (double, or fixed point for float pairs in a periodic box), and the one
// arithmetic that writes an entry, shared by the gather (search/rank_order.cu), a gated step's
// drift that places the positions itself (integrate/gated_steps.cu) and the force kernel that runs
// the next step's kick-drift (forces/list_forces.cu).
#pragma once

#include <cstddef>
#include <cstdint>
#include <type_traits>

#include "core/box.h"
#include "core/grid.h"
#include "search/cells.cuh"       // DeviceFlags
#include "search/list_build.h"   // fixed_coordinate
#include "search/rank_order.h"

namespace cellforce::cuda {

// A particle's position (wrapped into the box on periodic axes) and type, in rank order: what the
// force kernel gathers for each partner in double precision, or where an axis is open.
struct alignas(32) RankedParticle {
  double x, y, z;
  uint32_t type;
  uint32_t unused;
};

// The same in fixed point, for float pairs in a box periodic on every axis with edges up to 2^8
// cutoffs (fixed_point_serves: the single and mixed precisions' usual case): coordinate a as the
// integer nearest x_a / L_a * 2^32, modulo 2^32 (a wrapped x_a that rounds to 2^32 is 0, the same
// point). The difference of two such integers, read as a signed 32-bit integer, is the
// minimum-image separation in units of L_a / 2^32 (for |d| < L_a / 2, which lists guarantee:
// rc + skin <= L / 2): exact but for the two quantisations, each at most L_a / 2^33 (1.2e-8 at
// L = 107, 5.7e-8 at L = 490, the 100M in.lj box), and two float roundings (fixed_separation), the
// minimum image costing nothing. Half the bytes of RankedParticle and no double arithmetic per pair.
struct alignas(16) FixedParticle {
  uint32_t x, y, z;
  uint32_t type;
};

// Particle i (position v, type t) as rank p's entry of the gathered array: wrapped into the box on
// periodic axes, then stored in double (RankedParticle) or fixed point (FixedParticle, every axis
// periodic: fixed_point_serves). The one arithmetic of the gather and of a gated drift's placing. A
// non-finite coordinate is flagged as the device input check does (the particle and axis named at
// the next check of the flags): a pair with it has a NaN r^2, which fails every cutoff test, so the
// force kernel would drop its pairs without a word, and it has no fixed-point value.
template <int D, class Particle>
__device__ __forceinline__ void store_ranked(Particle* __restrict__ ranked, std::size_t p, const Grid& g,
                                             const double v[3], uint32_t t, uint32_t num_types, std::size_t i,
                                             DeviceFlags* flags) {
  double x[3] = {0, 0, 0};
  for (int a = 0; a < D; ++a) {
    x[a] = g.inv_length[a] != 0.0 ? wrap_coordinate(v[a], g.length[a]) : v[a];
    if (!isfinite(x[a])) atomicMin(&flags->bad_coordinate, static_cast<unsigned long long>(i) << 32 | unsigned(a));
  }
  const uint32_t type = t < num_types ? t : 0u;
  if constexpr (std::is_same_v<Particle, FixedParticle>) {
    uint32_t u[3] = {0, 0, 0};
    for (int a = 0; a < D; ++a) u[a] = fixed_coordinate(x[a], g.inv_length[a]);
    ranked[p] = FixedParticle{u[0], u[1], u[2], type};
  } else {
    ranked[p] = RankedParticle{x[0], x[1], x[2], type, 0u};
  }
}

// A gated drift's placing (RankOrder): particle i, now at v, into its rank's entry.
template <int D>
__device__ __forceinline__ void place_ranked(const RankOrder& to, std::size_t i, uint32_t p, const double v[3],
                                             uint32_t t) {
  if (to.fixed) store_ranked<D>(static_cast<FixedParticle*>(to.particles), p, to.grid, v, t, to.num_types, i, to.flags);
  else store_ranked<D>(static_cast<RankedParticle*>(to.particles), p, to.grid, v, t, to.num_types, i, to.flags);
}

}  // namespace cellforce::cuda
