// Counter-based random numbers shared by the host integrators and the CUDA kernels: each value is
// a hash of (seed, stream, index), so a run draws the same numbers whatever the thread count or
// launch shape, and a restart from step s draws exactly what the uninterrupted run drew after s.
// The index is a particle's stable ID (its position in the caller's order) times dim plus the
// axis, never a position in some sorted order, so reordering particles cannot change a trajectory.
#pragma once

#include <cmath>
#include <cstdint>

#include "core/hd.h"

namespace cellforce {

CF_HD uint64_t splitmix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

// (0, 1) from 53 random bits.
CF_HD double unit_open(uint64_t bits) { return (double(bits >> 11) + 0.5) * 0x1.0p-53; }

// A standard normal value for (seed, stream, index) by Box-Muller. The host's and the device's
// log, sqrt and cos may differ in the last bit: the same numbers to round-off on CPU and GPU,
// bitwise on one of them.
CF_HD double counter_normal(uint64_t seed, uint64_t stream, uint64_t index) {
  const uint64_t key = splitmix64(splitmix64(seed ^ 0xC0FFEEull) ^ splitmix64(stream * 0x632BE59BD9B4E019ull));
  const uint64_t a = splitmix64(key ^ (2 * index));
  const uint64_t b = splitmix64(key ^ (2 * index + 1));
  return std::sqrt(-2.0 * std::log(unit_open(a))) * std::cos(2.0 * 3.14159265358979323846 * unit_open(b));
}

}  // namespace cellforce
