/* cellforce's C API for a domain-decomposed code: a periodic box cut into two slabs along x, each
 * slab computed as one rank would compute its own particles (cf_compute_local), with its ghosts.
 *
 * The system: 2,048 particles on an fcc lattice at density 0.8442 (LAMMPS's in.lj), each moved by
 * up to 0.1 sigma so that the forces are not zero, Lennard-Jones with sigma = epsilon = 1 cut at
 * rc = 2.5. One call on the whole periodic box gives the reference. Each slab's call gets its own
 * particles first (the locals), then its ghosts: the periodic images of the particles within rc of
 * the slab along x, placed at their image positions. x is open in the slabs' box (the ghosts stand
 * in for its periodic wrap); y and z stay periodic. A local-ghost pair adds half its energy and
 * virial to the local (LAMMPS's newton off), so the two slabs' energies add up to the whole's, and
 * each particle's force, from the one slab that owns it, is its force in the whole system.
 *
 * The program checks the summed energy and virial and every force against the whole-system call
 * (1e-12 relative: both in double, the sums in another order) and exits 1 when a check or a call
 * fails. Build against the installed package: examples/README.md. */
#include <cellforce/cellforce.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

enum { kCells = 8, kN = 4 * kCells * kCells * kCells, kSlabs = 2 };
static const double kDensity = 0.8442, kCutoff = 2.5, kJiggle = 0.1;

#define CHECK(ctx, call)                                                              \
  do {                                                                                \
    if ((call) != CF_OK) {                                                            \
      fprintf(stderr, "ghost_particles: %s failed: %s\n", #call, cf_last_error(ctx)); \
      return 1;                                                                       \
    }                                                                                 \
  } while (0)

/* The fcc lattice of edge a per cubic cell, each site moved by up to kJiggle per axis (a fixed
 * random sequence), wrapped into [0, L). */
static void make_positions(double a, double length, double* x) {
  static const double basis[4][3] = {{0, 0, 0}, {0.5, 0.5, 0}, {0.5, 0, 0.5}, {0, 0.5, 0.5}};
  unsigned long long seed = 4747;
  int i = 0;
  for (int cx = 0; cx < kCells; ++cx)
    for (int cy = 0; cy < kCells; ++cy)
      for (int cz = 0; cz < kCells; ++cz)
        for (int b = 0; b < 4; ++b, ++i) {
          const int c[3] = {cx, cy, cz};
          for (int k = 0; k < 3; ++k) {
            seed = seed * 6364136223846793005ull + 1442695040888963407ull;
            const double u = (double)(seed >> 11) / 9007199254740992.0; /* [0, 1) */
            double v = (c[k] + basis[b][k]) * a + kJiggle * (2 * u - 1);
            if (v < 0) v += length;
            if (v >= length) v -= length;
            x[3 * i + k] = v;
          }
        }
}

/* Slab s's call: its particles with lo <= x < hi first, then the images x + k L (k = -1, 0, 1) of
 * every particle that fall within rc below lo or above hi. Returns the total count; *n_local gets
 * the locals', owner[j] the whole system's index of entry j. */
static size_t slab_particles(const double* x, double length, int s, double* out, int* owner, size_t* n_local) {
  const double lo = length * s / kSlabs, hi = s + 1 == kSlabs ? length : length * (s + 1) / kSlabs;
  size_t m = 0;
  for (int i = 0; i < kN; ++i)
    if (x[3 * i] >= lo && x[3 * i] < hi) {
      out[3 * m] = x[3 * i], out[3 * m + 1] = x[3 * i + 1], out[3 * m + 2] = x[3 * i + 2];
      owner[m++] = i;
    }
  *n_local = m;
  for (int i = 0; i < kN; ++i)
    for (int k = -1; k <= 1; ++k) {
      const double xi = x[3 * i] + k * length;
      if ((xi >= lo - kCutoff && xi < lo) || (xi >= hi && xi < hi + kCutoff)) {
        out[3 * m] = xi, out[3 * m + 1] = x[3 * i + 1], out[3 * m + 2] = x[3 * i + 2];
        owner[m++] = i;
      }
    }
  return m;
}

/* A context with the box (x periodic or open), the cutoff and one type. */
static cf_context* make_context(double length, int x_periodic) {
  cf_context* ctx = NULL;
  if (cf_create(&ctx, 3) != CF_OK) {
    fprintf(stderr, "ghost_particles: cf_create failed: %s\n", cf_last_error(NULL));
    return NULL;
  }
  const double box[3] = {length, length, length};
  const int periodic[3] = {x_periodic, 1, 1};
  if (cf_set_box(ctx, box, periodic) != CF_OK || cf_set_cutoff(ctx, kCutoff, "truncate") != CF_OK ||
      cf_add_type(ctx, "A", 1.0, 1.0, NULL) != CF_OK) {
    fprintf(stderr, "ghost_particles: setting up the context failed: %s\n", cf_last_error(ctx));
    cf_destroy(ctx);
    return NULL;
  }
  return ctx;
}

static int run(cf_context* whole, cf_context* slab, double length, double* x, double* f, double* buffer,
               double* f_local, int* owner) {
  /* The reference: the whole periodic system in one call. */
  double energy = 0, virial[9];
  CHECK(whole, cf_compute(whole, kN, x, NULL, f, &energy, virial));
  printf("cellforce %s: %d particles, box %.6f, rc %.1f, %d slabs along x\n", cf_version(), kN, length, kCutoff,
         kSlabs);
  printf("whole periodic system: energy/particle %.12f\n", energy / kN);

  /* Each slab as a rank: its locals' forces, and its share of the energy and virial. */
  double sum_energy = 0, sum_virial[9] = {0}, worst_force = 0, largest_force = 0;
  for (int s = 0; s < kSlabs; ++s) {
    size_t n_local = 0;
    const size_t n = slab_particles(x, length, s, buffer, owner, &n_local);
    double e = 0, w[9];
    CHECK(slab, cf_compute_local(slab, n_local, n - n_local, buffer, NULL, f_local, &e, w));
    printf("slab %d: %zu locals, %zu ghosts, energy %.9f\n", s, n_local, n - n_local, e);
    sum_energy += e;
    for (int k = 0; k < 9; ++k) sum_virial[k] += w[k];
    for (size_t j = 0; j < 3 * n_local; ++j) {
      const double ref = f[3 * owner[j / 3] + j % 3];
      worst_force = fmax(worst_force, fabs(f_local[j] - ref));
    }
  }
  double worst_virial = 0, largest_virial = 0;
  for (int k = 0; k < 9; ++k) {
    worst_virial = fmax(worst_virial, fabs(sum_virial[k] - virial[k]));
    largest_virial = fmax(largest_virial, fabs(virial[k]));
  }
  for (int i = 0; i < 3 * kN; ++i) largest_force = fmax(largest_force, fabs(f[i]));
  printf("slabs summed: energy/particle %.12f (whole %.12f)\n", sum_energy / kN, energy / kN);
  printf("check: energy %.1e, virial %.1e, forces %.1e relative (tolerance 1e-12)\n",
         fabs(sum_energy - energy) / fabs(energy), worst_virial / largest_virial, worst_force / largest_force);
  if (fabs(sum_energy - energy) > 1e-12 * fabs(energy) || worst_virial > 1e-12 * largest_virial ||
      worst_force > 1e-12 * largest_force) {
    fprintf(stderr, "ghost_particles: check failed: the slabs do not sum to the whole system\n");
    return 1;
  }
  return 0;
}

int main(void) {
  const double a = cbrt(4 / kDensity), length = kCells * a;
  /* A slab's entries: its locals and its ghosts (at most all particles once more per side). */
  double* x = malloc(sizeof(double) * 3 * kN);
  double* f = malloc(sizeof(double) * 3 * kN);
  double* buffer = malloc(sizeof(double) * 9 * kN);
  double* f_local = malloc(sizeof(double) * 3 * kN);
  int* owner = malloc(sizeof(int) * 3 * kN);
  cf_context* whole = make_context(length, 1);
  cf_context* slab = make_context(length, 0); /* x open: the ghosts stand in for its wrap */
  int rc = 1;
  if (x && f && buffer && f_local && owner && whole && slab) {
    make_positions(a, length, x);
    rc = run(whole, slab, length, x, f, buffer, f_local, owner);
  } else if (!(x && f && buffer && f_local && owner)) {
    fprintf(stderr, "ghost_particles: out of memory\n");
  }
  cf_destroy(whole);
  cf_destroy(slab);
  free(x), free(f), free(buffer), free(f_local), free(owner);
  return rc;
}
