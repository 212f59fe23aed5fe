/* The C API as a C program uses it: two particles against the analytic pair values, then a
 * lattice whose forces, energy and virial it prints (%.17g) for comparison with consumer_cpp. */
#include <cellforce/cellforce.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "system.h"

#define CHECK(call)                                                           \
  do {                                                                        \
    if ((call) != CF_OK) {                                                    \
      fprintf(stderr, "consumer_c: %s failed: %s\n", #call, cf_last_error(ctx)); \
      return 1;                                                               \
    }                                                                         \
  } while (0)

int main(void) {
  cf_context* ctx = NULL;
  if (cf_create(&ctx, 3) != CF_OK) {
    fprintf(stderr, "consumer_c: cf_create: %s\n", cf_last_error(NULL));
    return 1;
  }
  const int periodic[3] = {1, 1, 1};
  double box[3];
  static double positions[3 * kN], forces[3 * kN];
  static uint32_t types[kN];
  make_system(positions, types, box);
  CHECK(cf_set_box(ctx, box, periodic));
  CHECK(cf_set_cutoff(ctx, kCutoff, "truncate"));
  uint32_t a, b;
  CHECK(cf_add_type(ctx, "A", 1.0, 1.0, &a));
  CHECK(cf_add_type(ctx, "B", 0.9, 0.6, &b));
  if (a != 0 || b != 1) {
    fprintf(stderr, "consumer_c: type indices %u %u, expected 0 1\n", a, b);
    return 1;
  }

  /* Two A particles 1.3 apart along y: the analytic values. */
  const double pair[6] = {1.0, 1.0, 1.0, 1.0, 2.3, 1.0};
  double f2[6], e2 = 0, w2[9];
  CHECK(cf_compute(ctx, 2, pair, NULL, f2, &e2, w2));
  double e_ref, fr_ref;
  lj_pair(1.3, 1.0, 1.0, &e_ref, &fr_ref);
  const double f_ref = -fr_ref * 1.3; /* on particle 0: (x0 - x1) = -1.3 along y */
  if (fabs(e2 - e_ref) > 1e-13 * fabs(e_ref) || fabs(f2[1] - f_ref) > 1e-13 * fabs(f_ref) ||
      fabs(f2[4] + f_ref) > 1e-13 * fabs(f_ref) || fabs(w2[4] - fr_ref * 1.69) > 1e-13 * fabs(fr_ref)) {
    fprintf(stderr, "consumer_c: pair energy %.17g force %.17g virial %.17g; expected %.17g %.17g %.17g\n", e2,
            f2[1], w2[4], e_ref, f_ref, fr_ref * 1.69);
    return 1;
  }

  double energy = 0, virial[9];
  CHECK(cf_compute(ctx, kN, positions, types, forces, &energy, virial));
  double net[3] = {0, 0, 0};
  for (int i = 0; i < kN; ++i)
    for (int k = 0; k < 3; ++k) net[k] += forces[3 * i + k];
  for (int k = 0; k < 3; ++k)
    if (fabs(net[k]) > 1e-9) {
      fprintf(stderr, "consumer_c: the forces do not sum to zero (%.3g along axis %d)\n", net[k], k);
      return 1;
    }
  printf("cellforce %s\nheaders %d.%d.%d\nenergy %.17g\n", cf_version(), CELLFORCE_VERSION_MAJOR,
         CELLFORCE_VERSION_MINOR, CELLFORCE_VERSION_PATCH, energy);
  for (int k = 0; k < 9; ++k) printf("virial %d %.17g\n", k, virial[k]);
  for (int i = 0; i < 3 * kN; ++i) printf("force %d %.17g\n", i, forces[i]);

  /* Molecular dynamics: kMdSteps Verlet steps from the lattice at rest. */
  static double masses[kN], x[3 * kN], v[3 * kN];
  for (int i = 0; i < kN; ++i) masses[i] = kMass[types[i]];
  CHECK(cf_set_integrator(ctx, "verlet", kDt, 0.0, 0.0, 0));
  CHECK(cf_set_state(ctx, kN, positions, NULL, types, masses, 0));
  CHECK(cf_step(ctx, kMdSteps));
  CHECK(cf_get_state(ctx, kN, x, v, NULL));
  double kinetic, potential, temperature, pressure;
  CHECK(cf_thermo(ctx, &kinetic, &potential, &temperature, &pressure));
  printf("md kinetic %.17g potential %.17g temperature %.17g pressure %.17g\n", kinetic, potential, temperature,
         pressure);
  for (int i = 0; i < 3 * kN; ++i) printf("md %d %.17g %.17g\n", i, x[i], v[i]);
  cf_destroy(ctx);
  return 0;
}
