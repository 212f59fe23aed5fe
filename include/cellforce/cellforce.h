/* cellforce's C API: Lennard-Jones forces, energies and virial of a particle system by the
 * spatial-subdivision cutoff search of GPU Gems 3, chapter 32, on the CPU or a CUDA device.
 *
 * Every call returns a status; CF_OK is 0. On any other status cf_last_error(ctx) says why, naming
 * the parameter, particle or option at fault, and the outputs and the context are left as they
 * were. No call aborts the caller or lets a C++ exception escape. A context is used by one thread
 * at a time.
 *
 * Arrays are in the caller's particle order, row-major: particle i's coordinate a is
 * positions[i * dim + a]. Units are the caller's: lengths as the positions, energies as epsilon,
 * forces energy / length.
 *
 *   cf_context* ctx;
 *   const double box[3] = {10, 10, 10};
 *   const int periodic[3] = {1, 1, 1};
 *   uint32_t a;
 *   if (cf_create(&ctx, 3) != CF_OK) ... cf_last_error(NULL) ...
 *   cf_set_box(ctx, box, periodic);
 *   cf_set_cutoff(ctx, 2.5, "truncate");
 *   cf_add_type(ctx, "A", 1.0, 1.0, &a);
 *   if (cf_compute(ctx, n, positions, NULL, forces, &energy, NULL) != CF_OK)
 *     fprintf(stderr, "%s\n", cf_last_error(ctx));
 *   cf_destroy(ctx);
 */
#ifndef CELLFORCE_CELLFORCE_H
#define CELLFORCE_CELLFORCE_H

#include <stddef.h>
#include <stdint.h>

#include <cellforce/export.hpp>
#include <cellforce/version.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct cf_context cf_context;

typedef enum {
  CF_OK = 0,
  CF_ERROR_INPUT = 1,    /* a bad argument, option or array value */
  CF_ERROR_DEVICE = 2,   /* no usable CUDA device, or a CUDA call failed */
  CF_ERROR_INTERNAL = 3  /* out of memory, or a fault of cellforce itself */
} cf_status;

/* The library's version, "MAJOR.MINOR.PATCH": that of the library loaded (the headers' are the
 * macros CELLFORCE_VERSION_MAJOR, _MINOR and _PATCH of cellforce/version.h). */
CELLFORCE_API const char* cf_version(void);

/* A new context for dim = 2 or 3 in *ctx: no box, cutoff or types yet; defaults: CPU backend,
 * double precision, truncated cutoff, Lorentz-Berthelot mixing, skin auto. On failure *ctx is NULL
 * (when ctx is not) and cf_last_error(NULL) says why. */
CELLFORCE_API cf_status cf_create(cf_context** ctx, int dim);

/* lengths[dim], periodic[dim] (non-zero: the axis wraps). A periodic edge must be finite and > 0
 * (and at least twice the cutoff, checked when computing); the length of an open axis is ignored
 * and may be 0. */
CELLFORCE_API cf_status cf_set_box(cf_context* ctx, const double* lengths, const int* periodic);
/* As cf_set_box; with an MD state the positions on each axis periodic before and after are
 * scaled by the new edge over the old (velocities kept). */
CELLFORCE_API cf_status cf_set_box_scaled(cf_context* ctx, const double* lengths, const int* periodic);

/* Pairs interact only when r < rc; mode: "truncate", "shift" or "force-shift", or NULL to keep the
 * mode (truncate in a new context, or as set by the option cutoff-mode).
 *
 * With an MD state (cf_set_state), cf_set_box, cf_set_cutoff, cf_add_type, cf_set_pair and the
 * options apply to it at once: the state (positions, wrapped into a new box and not scaled;
 * velocities, types, masses, step) is set again under the new physics or on a new engine, its
 * forces evaluated there, as a fresh cf_set_state of it would. A change it cannot take fails
 * naming the setting and leaves the state as it was. */
CELLFORCE_API cf_status cf_set_cutoff(cf_context* ctx, double rc, const char* mode);

/* A particle type; *index (when index is not NULL) receives its index: 0, 1, ... in the order
 * added. sigma and epsilon finite and >= 0; the name printable and not added before. */
CELLFORCE_API cf_status cf_add_type(cf_context* ctx, const char* name, double sigma, double epsilon, uint32_t* index);

/* An explicit pair value replacing the mixing rule for types a and b (either order). */
CELLFORCE_API cf_status cf_set_pair(cf_context* ctx, uint32_t a, uint32_t b, double sigma, double epsilon);

/* A choice by name (the keys as written here; the names in any letter case, "CUDA" as "cuda", as
 * the command line and scene files read them):
 *   backend       cpu | cuda | auto        precision     single | mixed | double
 *   mixing        lorentz-berthelot | geometric
 *   cutoff-mode   truncate | shift | force-shift
 *   skin          auto (the default: none for the force calls; the C++ API's MD state gets pair
 *                 lists with a skin of 0.24 rc on CUDA, 0.18 rc where they run in lean memory) |
 *                 a length >= 0 (Verlet skin of the neighbour structure; 0 rebuilds every call)
 *   device        CUDA device ordinal      accumulation  jacobi | gauss-seidel
 *   cell-rule     tight | chapter          sort          cub | chapter
 *   traversal     auto | warp | thread | tile (CUDA; auto, the default, picks tile or warp)
 *   memory        auto | fast | lean (CUDA pair lists: lean takes ~700 bytes a particle against
 *                 ~1,300, and for its builds' masks up to ~230 more of the memory the device has
 *                 left (builds up to ~2x slower without them); auto, the default, is lean where
 *                 fast would not fit in 90% of the device)
 *   threads       auto | N >= 0 (cf_set_threads) */
CELLFORCE_API cf_status cf_set_option(cf_context* ctx, const char* key, const char* value);

/* The CPU backend's OpenMP threads (its parallel regions run with this many): threads >= 1, or 0
 * for OpenMP's default (omp_get_max_threads() of the calling thread; option threads = auto, a new
 * context's). Other threads of the program keep their own count. */
CELLFORCE_API cf_status cf_set_threads(cf_context* ctx, int threads);

/* Host arrays. positions: n * dim (finite; any periodic image); types: n indices into the types
 * added, or NULL for all type 0; forces: n * dim, written; energy: 1 (total potential energy) or
 * NULL; virial: dim * dim row-major (sum over pairs of r_ij (x) f_ij, r_ij = x_i - x_j by minimum
 * image, f_ij the force on i from j) or NULL. n = 0 is a valid, empty call. Returns when the
 * results are written. */
CELLFORCE_API cf_status cf_compute(cf_context* ctx, size_t n, const double* positions, const uint32_t* types,
                     double* forces, double* energy, double* virial);

/* As cf_compute, with energies: n per-particle energies (half of each pair's energy; they sum to
 * the total), or NULL. */
CELLFORCE_API cf_status cf_compute_energies(cf_context* ctx, size_t n, const double* positions, const uint32_t* types,
                              double* forces, double* energies, double* energy, double* virial);

/* A rank's own particles with its ghosts, for domain-decomposed codes (host arrays, either
 * backend). positions: (n_local + n_ghost) * dim, the locals
 * first, then the ghosts the caller places (other ranks' particles, or periodic images at their
 * image positions); types: as many, or NULL for all type 0. Outputs for the locals only, each
 * optional (forces NULL: an energy-only call): forces n_local * dim; energy 1, the locals' shares
 * (a pair of two locals whole, a pair of a local and a ghost half: LAMMPS's newton off); virial
 * dim * dim row-major, summed as the energy. A pair of two ghosts is never evaluated. An axis the
 * ghosts stand in for is open in the box (cf_set_box); ghosts with every axis periodic are
 * CF_ERROR_INPUT (the minimum image already finds every neighbour there, and a ghost that is an
 * image would count its pairs twice). cellforce.hpp Context::compute_local says more. */
CELLFORCE_API cf_status cf_compute_local(cf_context* ctx, size_t n_local, size_t n_ghost, const double* positions,
                                         const uint32_t* types, double* forces, double* energy, double* virial);
/* As cf_compute_local, with energies: n_local per-particle energies (half of each of a local's
 * pairs), virials: n_local * dim * dim per-particle virials (half of each pair's r_ij (x) f_ij, each
 * dim * dim row-major), each or NULL; with accumulate non-zero every output given is added to
 * instead of overwritten. */
CELLFORCE_API cf_status cf_compute_local_full(cf_context* ctx, size_t n_local, size_t n_ghost,
                                              const double* positions, const uint32_t* types, double* forces,
                                              double* energies, double* energy, double* virial, double* virials,
                                              int accumulate);

/* As cf_compute, with every pointer a device pointer on the context's CUDA device (the cuda
 * backend, or auto with a device) and the work ordered on `stream` (a cudaStream_t; NULL: the
 * legacy default stream): the results are ready when the stream reaches this call's point. The
 * call returns without waiting for the device or the stream (pointers and physics are checked
 * before anything is queued; an open axis, a skin with the displacement check and the neighbour
 * audit make it wait). The arrays are checked on the device: a non-finite coordinate, a type index
 * out of range or a pair whose force is not finite is reported by the next cf_synchronize (or
 * cf_compute, which synchronises first), and the outputs since the last cf_synchronize are then
 * not to be used. The results are bitwise those of cf_compute on the same input. */
CELLFORCE_API cf_status cf_compute_device(cf_context* ctx, size_t n, const double* positions, const uint32_t* types,
                            double* forces, double* energy, double* virial, void* stream);

/* Arrays as the caller holds them (cellforce.hpp Positions and Types; the enumerations are int-sized
 * for every C compiler, their last values no element type): positions are n rows of
 * `stride` elements (0: dim; 4 for xyz padded to four) of `scalar`, the first dim of each used;
 * types (or NULL) are n elements of `index`. The results are those of the packed double and
 * uint32_t arrays of the same values. A stride below dim, an unknown scalar or index, and (host
 * arrays) a negative int32 type are CF_ERROR_INPUT naming them. */
typedef enum cf_scalar { CF_FLOAT64 = 0, CF_FLOAT32 = 1, CF_SCALAR_INT_SIZED = 0x7fffffff } cf_scalar;
typedef enum cf_index { CF_UINT32 = 0, CF_INT32 = 1, CF_INDEX_INT_SIZED = 0x7fffffff } cf_index;
CELLFORCE_API cf_status cf_compute_layout(cf_context* ctx, size_t n, const void* positions, cf_scalar scalar,
                                          size_t stride, const void* types, cf_index index, double* forces,
                                          double* energies, double* energy, double* virial);
/* As cf_compute_layout with device pointers, as cf_compute_device. */
CELLFORCE_API cf_status cf_compute_device_layout(cf_context* ctx, size_t n, const void* positions, cf_scalar scalar,
                                                 size_t stride, const void* types, cf_index index, double* forces,
                                                 double* energies, double* energy, double* virial, void* stream);

/* Waits for the cf_compute_device calls queued so far; CF_ERROR_INPUT (with cf_last_error naming
 * the particle or pair) when their kernels found bad input. CF_OK at once when none is pending. */
CELLFORCE_API cf_status cf_synchronize(cf_context* ctx);

/* Every statistic of the context as one JSON object (cellforce.hpp Context::statistics_json
 * documents its keys), NUL-terminated into `buffer` of `capacity` bytes; *length (if not NULL)
 * receives the text's length without the NUL. With buffer NULL only the length is given;
 * a buffer too small for it is CF_ERROR_INPUT (nothing written; *length says what is needed). */
CELLFORCE_API cf_status cf_statistics_json(cf_context* ctx, char* buffer, size_t capacity, size_t* length);

/* ---- molecular dynamics: a state held where the backend computes (on the GPU with cuda) ---- */

/* The integrator of the steps: kind "verlet" (NVE, velocity Verlet) or "langevin" (NVT, BAOAB);
 * dt: the time step (finite, > 0; time units); temperature: Langevin's kT (finite, >= 0; energy);
 * friction: Langevin's gamma (finite, > 0; 1 / time); seed: Langevin's noise, keyed by (seed, step,
 * particle, axis). temperature and friction are not read for "verlet". Takes effect at the next
 * step; a new context has verlet with dt 0.005. */
CELLFORCE_API cf_status cf_set_integrator(cf_context* ctx, const char* kind, double dt, double temperature,
                                          double friction, uint64_t seed);

/* The MD state, from host arrays: positions n * dim (finite; wrapped into the box on periodic
 * axes); velocities n * dim (length / time) or NULL for all zero; types n indices into the types
 * added, or NULL for all type 0; masses n (finite, > 0); step >= 0 (time = step * dt). Needs the
 * box, cutoff and types; evaluates the forces at the positions. */
CELLFORCE_API cf_status cf_set_state(cf_context* ctx, size_t n, const double* positions, const double* velocities,
                                     const uint32_t* types, const double* masses, int64_t step);

/* Advances the state count >= 0 steps; the last one also computes the energy and virial for
 * cf_thermo. */
CELLFORCE_API cf_status cf_step(cf_context* ctx, int64_t count);

/* New positions or velocities (n * dim, n the state's count) for the state where it lives
 * (cellforce.hpp Context::set_positions, set_velocities): positions are wrapped into the box and
 * the forces evaluated at them; velocities, step and time are kept. */
CELLFORCE_API cf_status cf_set_positions(cf_context* ctx, size_t n, const double* positions);
CELLFORCE_API cf_status cf_set_velocities(cf_context* ctx, size_t n, const double* velocities);

/* An external force added to the pair forces at every evaluation of the MD state's forces (each
 * step; set_state, set_positions; cf_thermo when it evaluates again), with no energy or virial of
 * its own; one at a time, kept until cf_clear_external_force (cellforce.hpp
 * Context::set_external_forces says more). cf_set_external_forces: a host array n * dim (copied);
 * cf_set_external_forces_device: the caller's device array n * dim (cuda backend), read at every
 * evaluation; cf_set_external_force_callback: fn(user, step, n, dim, positions, forces, stream) adds
 * its forces into `forces` at every evaluation, both arrays where the state lives (device arrays on
 * `stream`, the context's cudaStream_t, with cuda; host arrays and NULL on the CPU); fn NULL clears. */
typedef void (*cf_external_force_fn)(void* user, int64_t step, size_t n, int dim, const double* positions,
                                     double* forces, void* stream);
CELLFORCE_API cf_status cf_set_external_forces(cf_context* ctx, size_t n, const double* forces);
CELLFORCE_API cf_status cf_set_external_forces_device(cf_context* ctx, size_t n, const double* forces);
CELLFORCE_API cf_status cf_set_external_force_callback(cf_context* ctx, cf_external_force_fn fn, void* user);
CELLFORCE_API cf_status cf_clear_external_force(cf_context* ctx);

/* The state now into host arrays of n * dim each, n the state's particle count (another n is an
 * error): positions (wrapped into the box), velocities and forces; any may be NULL. */
CELLFORCE_API cf_status cf_get_state(cf_context* ctx, size_t n, double* positions, double* velocities,
                                     double* forces);

/* The state where it lives, read without a copy (Context::state_view): pointers to positions
 * (length, wrapped into the box on periodic axes), velocities (length / time) and forces (energy /
 * length), n x dim doubles each, row-major in the state's particle order, on the host with the cpu
 * backend or on CUDA device *device (-1: host) with cuda, complete when this returns; any output
 * may be NULL. Read again after any call on the context (the arrays change, and may move); never
 * written through. Without an MD state: CF_ERROR_INPUT, the outputs unwritten. */
CELLFORCE_API cf_status cf_state_view(cf_context* ctx, const double** positions, const double** velocities,
                                      const double** forces, int* device);

/* Thermodynamics now: kinetic and potential energy, temperature (2 KE / degrees of freedom:
 * dim (n - 1) for verlet, dim n for langevin) and pressure ((2 KE + trace W) / (dim V); NaN when
 * an axis is open); any pointer may be NULL. */
CELLFORCE_API cf_status cf_thermo(cf_context* ctx, double* kinetic, double* potential, double* temperature,
                                  double* pressure);

/* Why the last call on ctx failed ("" after a success); with ctx NULL, why the last cf_create of
 * this thread failed. The text stays valid until the next call on ctx. */
CELLFORCE_API const char* cf_last_error(const cf_context* ctx);

/* Frees the context; NULL is ignored. As with free(), the pointer is invalid afterwards: passing
 * it to any cf_ function again, cf_destroy included (a double destroy), is undefined behaviour. */
CELLFORCE_API void cf_destroy(cf_context* ctx);

#ifdef __cplusplus
}
#endif

#endif /* CELLFORCE_CELLFORCE_H */
