/* The consumers' shared input: a jittered simple-cubic lattice of 6^3 particles (spacing 1.12,
 * two types alternating) in a periodic box, from a fixed linear congruential sequence so that
 * C and C++ build the same numbers; and the analytic Lennard-Jones pair values. */
#ifndef CONSUMER_SYSTEM_H
#define CONSUMER_SYSTEM_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>

enum { kCells = 6, kN = kCells * kCells * kCells };
static const double kSpacing = 1.12, kCutoff = 2.5;
/* The MD run's step, length and masses by type. */
static const double kDt = 0.004, kMass[2] = {1.0, 1.5};
enum { kMdSteps = 25 };

static double next_uniform(uint64_t* state) {
  *state = *state * 6364136223846793005ull + 1442695040888963407ull;
  return (double)(*state >> 11) / 9007199254740992.0; /* [0, 1) */
}

static void make_system(double* positions, uint32_t* types, double* box) {
  uint64_t state = 2026;
  size_t i = 0;
  for (int x = 0; x < kCells; ++x)
    for (int y = 0; y < kCells; ++y)
      for (int z = 0; z < kCells; ++z, ++i) {
        const int c[3] = {x, y, z};
        for (int a = 0; a < 3; ++a) positions[3 * i + a] = (c[a] + 0.5) * kSpacing + 0.1 * (next_uniform(&state) - 0.5);
        types[i] = (uint32_t)((x + y + z) % 2);
      }
  box[0] = box[1] = box[2] = kCells * kSpacing;
}

/* Pair energy and F(r)/r of a truncated Lennard-Jones pair. */
static void lj_pair(double r, double sigma, double epsilon, double* energy, double* force_over_r) {
  const double sr6 = pow(sigma / r, 6.0);
  *energy = 4.0 * epsilon * (sr6 * sr6 - sr6);
  *force_over_r = 24.0 * epsilon * (2.0 * sr6 * sr6 - sr6) / (r * r);
}

#endif
