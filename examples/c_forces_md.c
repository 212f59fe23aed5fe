/* cellforce's C API, host arrays: the forces and energy of one configuration, then a short NVE run.
 *
 * The system is LAMMPS's in.lj: 4,000 particles on an fcc lattice at density 0.8442 in a periodic
 * cube, Lennard-Jones with sigma = epsilon = 1 cut at rc = 2.5, velocities for T = 1.44, velocity
 * Verlet with dt = 0.005. One change: the potential is shifted to zero at rc (cutoff mode "shift";
 * in.lj truncates), which leaves the forces as they are and removes the energy's jumps when pairs
 * cross rc, so that the total energy is conserved to the integrator's accuracy.
 *
 * The program checks what it can know without cellforce: the lattice's energy (a lattice sum),
 * zero forces on a perfect lattice, the temperature it gave the velocities, and that the total
 * energy and momentum are conserved. It exits 1 when a check or a call fails.
 *
 * Build against the installed package: examples/README.md. */
#include <cellforce/cellforce.h>

#include <math.h>
#include <stdio.h>

enum { kCells = 10, kN = 4 * kCells * kCells * kCells, kSteps = 500, kEvery = 50 };
static const double kDensity = 0.8442, kCutoff = 2.5, kTemperature = 1.44, kDt = 0.005;
/* The largest change of the total energy per particle allowed over the run (energy units). */
static const double kDriftTolerance = 5e-4;

/* Every call returns a cf_status; on failure cf_last_error(ctx) names the parameter or particle at
 * fault, and the context is left as it was. */
#define CHECK(call)                                                                \
  do {                                                                             \
    if ((call) != CF_OK) {                                                         \
      fprintf(stderr, "c_forces_md: %s failed: %s\n", #call, cf_last_error(ctx));  \
      cf_destroy(ctx);                                                             \
      return 1;                                                                    \
    }                                                                              \
  } while (0)

/* The fcc lattice (4 particles per cubic cell of edge a) and, from a fixed random sequence,
 * velocities with zero total momentum scaled to kTemperature = 2 KE / (3 (N - 1)). */
static void make_system(double a, double* x, double* v) {
  static const double basis[4][3] = {{0, 0, 0}, {0.5, 0.5, 0}, {0.5, 0, 0.5}, {0, 0.5, 0.5}};
  unsigned long long seed = 87287;
  double mean[3] = {0, 0, 0}, v2 = 0;
  int i = 0;
  for (int cx = 0; cx < kCells; ++cx)
    for (int cy = 0; cy < kCells; ++cy)
      for (int cz = 0; cz < kCells; ++cz)
        for (int b = 0; b < 4; ++b, ++i) {
          const int c[3] = {cx, cy, cz};
          for (int k = 0; k < 3; ++k) {
            x[3 * i + k] = (c[k] + basis[b][k]) * a;
            seed = seed * 6364136223846793005ull + 1442695040888963407ull;
            v[3 * i + k] = (double)(seed >> 11) / 9007199254740992.0 - 0.5;
            mean[k] += v[3 * i + k] / kN;
          }
        }
  for (i = 0; i < 3 * kN; ++i) v2 += (v[i] - mean[i % 3]) * (v[i] - mean[i % 3]);
  const double scale = sqrt(kTemperature * 3 * (kN - 1) / v2); /* unit masses: 2 KE = sum v^2 */
  for (i = 0; i < 3 * kN; ++i) v[i] = (v[i] - mean[i % 3]) * scale;
}

/* The lattice's energy without cellforce: every fcc site sees the same neighbours, so the total is
 * N/2 times the sum of the pair energies of one site with the sites within rc. */
static double lattice_energy(double a) {
  static const double basis[4][3] = {{0, 0, 0}, {0.5, 0.5, 0}, {0.5, 0, 0.5}, {0, 0.5, 0.5}};
  double sum = 0;
  for (int i = -3; i <= 3; ++i)
    for (int j = -3; j <= 3; ++j)
      for (int k = -3; k <= 3; ++k)
        for (int b = 0; b < 4; ++b) {
          const double d[3] = {(i + basis[b][0]) * a, (j + basis[b][1]) * a, (k + basis[b][2]) * a};
          const double r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
          if (r2 == 0 || r2 >= kCutoff * kCutoff) continue;
          const double s6 = 1 / (r2 * r2 * r2), c6 = 1 / pow(kCutoff, 6); /* shifted: U(rc) = 0 */
          sum += 4 * (s6 * s6 - s6) - 4 * (c6 * c6 - c6);
        }
  return 0.5 * kN * sum;
}

int main(void) {
  static double x[3 * kN], v[3 * kN], f[3 * kN], masses[kN];
  const double a = cbrt(4 / kDensity); /* the cubic cell's edge */
  make_system(a, x, v);
  for (int i = 0; i < kN; ++i) masses[i] = 1.0;

  /* A context holds the physics (box, cutoff, types) and the engine; the types are added in order,
   * the first is type 0, and all particles are type 0 when the types array is NULL. */
  cf_context* ctx = NULL;
  if (cf_create(&ctx, 3) != CF_OK) {
    fprintf(stderr, "c_forces_md: cf_create failed: %s\n", cf_last_error(NULL));
    return 1;
  }
  const double box[3] = {kCells * a, kCells * a, kCells * a};
  const int periodic[3] = {1, 1, 1};
  CHECK(cf_set_box(ctx, box, periodic));
  CHECK(cf_set_cutoff(ctx, kCutoff, "shift"));  /* U(r) - U(rc) for r < rc, else 0 */
  CHECK(cf_add_type(ctx, "A", 1.0, 1.0, NULL)); /* sigma, epsilon */
  CHECK(cf_set_option(ctx, "backend", "auto")); /* a CUDA device when one can be used, else the CPU */

  /* 1. Forces, total energy and virial of one configuration (the virial: 3 x 3, row-major). */
  double energy = 0, virial[9], largest_force = 0;
  CHECK(cf_compute(ctx, kN, x, NULL, f, &energy, virial));
  for (int i = 0; i < 3 * kN; ++i) largest_force = fmax(largest_force, fabs(f[i]));
  const double expected = lattice_energy(a);
  printf("cellforce %s: %d particles, box %.6f, rc %.1f\n", cf_version(), kN, box[0], kCutoff);
  printf("lattice energy/particle %.12f (lattice sum %.12f), largest force component %.1e\n", energy / kN,
         expected / kN, largest_force);
  if (fabs(energy - expected) > 1e-10 * fabs(expected) || largest_force > 1e-9) {
    fprintf(stderr, "c_forces_md: check failed: energy %.17g against %.17g (1e-10 relative), largest force "
            "%.3g (a perfect lattice's is 0: 1e-9 allowed)\n", energy, expected, largest_force);
    cf_destroy(ctx);
    return 1;
  }

  /* 2. Molecular dynamics: the context keeps the state (on the GPU with cuda) and steps it; the host
   * reads it back only when asked (cf_thermo, cf_get_state). */
  CHECK(cf_set_integrator(ctx, "verlet", kDt, 0.0, 0.0, 0)); /* temperature, friction, seed: Langevin's */
  CHECK(cf_set_state(ctx, kN, x, v, NULL, masses, 0));       /* also evaluates the forces there */
  double ke, pe, temp, press, e0 = 0, drift = 0;
  printf("%6s %10s %12s %12s %12s %10s\n", "step", "temp", "ke/atom", "pe/atom", "etot/atom", "press");
  for (int step = 0; step <= kSteps; step += kEvery) {
    if (step > 0) CHECK(cf_step(ctx, kEvery)); /* the last step of each call computes the energy */
    CHECK(cf_thermo(ctx, &ke, &pe, &temp, &press));
    printf("%6d %10.6f %12.8f %12.8f %12.8f %10.6f\n", step, temp, ke / kN, pe / kN, (ke + pe) / kN, press);
    if (step == 0) e0 = ke + pe;
    drift = fmax(drift, fabs(ke + pe - e0) / kN);
    if (step == 0 && fabs(temp - kTemperature) > 1e-12 * kTemperature) {
      fprintf(stderr, "c_forces_md: check failed: temperature %.17g, the velocities were given %g\n", temp,
              kTemperature);
      cf_destroy(ctx);
      return 1;
    }
  }
  CHECK(cf_get_state(ctx, kN, x, v, f)); /* positions (wrapped into the box), velocities, forces */
  double momentum[3] = {0, 0, 0};
  for (int i = 0; i < 3 * kN; ++i) momentum[i % 3] += v[i]; /* unit masses */
  const double p = fmax(fabs(momentum[0]), fmax(fabs(momentum[1]), fabs(momentum[2])));
  printf("energy conserved: largest |etot - etot(0)| per particle %.1e (tolerance %.0e)\n", drift,
         kDriftTolerance);
  printf("momentum conserved: largest component of the total %.0e (tolerance 1e-9)\n", p);
  cf_destroy(ctx);
  if (drift > kDriftTolerance || p > 1e-9) {
    fprintf(stderr, "c_forces_md: check failed: total energy drifted %.3g per particle, momentum %.3g\n", drift, p);
    return 1;
  }
  return 0;
}
