// cellforce's C++ API: Lennard-Jones forces, energies and virial of a particle system by the
// spatial-subdivision cutoff search of GPU Gems 3, chapter 32, on the CPU or a CUDA device.
//
//   cellforce::Context ctx(3);
//   const double box[3] = {10, 10, 10};
//   const bool periodic[3] = {true, true, true};
//   ctx.set_box(box, periodic);
//   ctx.set_cutoff(2.5, cellforce::CutoffMode::kTruncate);
//   ctx.add_type("A", 1.0, 1.0);
//   std::vector<double> forces(3 * n);
//   double energy;
//   ctx.compute(n, positions.data(), nullptr, {forces.data(), nullptr, &energy, nullptr});
//
// Units are the caller's: lengths as the positions, energies as epsilon, forces energy/length.
// Arrays are in the caller's particle order, row-major: particle i's coordinate a is
// positions[i * dim + a]. Every failing call throws cellforce::Error, whose message names the
// parameter, particle or option at fault; a failed call leaves the outputs unwritten and the
// context as it was. A Context is not thread-safe: one thread at a time.
//
// ABI: every name here lies in the inline namespace cellforce::v<MAJOR> (CELLFORCE_ABI_NAMESPACE,
// version.h), which a program writes as cellforce::; a program built against another major version
// fails to link. No function the library exports takes or returns a standard type whose layout
// _GLIBCXX_USE_CXX11_ABI decides: the calls that take or return std::string are inline here, over
// calls that take std::string_view or return the library's const char*, so that programs built with
// either string ABI use the library.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <cellforce/error.hpp>
#include <cellforce/export.hpp>
#include <cellforce/options.hpp>
#include <cellforce/version.h>

namespace cellforce {
inline namespace CELLFORCE_ABI_NAMESPACE {

// The library's version, "MAJOR.MINOR.PATCH": that of the library loaded, which a program built
// against this header finds in CELLFORCE_VERSION_MAJOR, _MINOR and _PATCH (cellforce/version.h).
CELLFORCE_API const char* version();

// Where a compute call writes. Host pointers for compute(), device pointers (on the context's
// device) for compute_device(). Only forces is required; the others are computed only when given
// (energy and virial cost arithmetic, and are left out of the kernels when nobody reads them).
struct Outputs {
  double* forces = nullptr;    // n x dim: the force on each particle (energy / length)
  double* energies = nullptr;  // n: each particle's share of the potential energy (half of each
                               // of its pairs' energies); they sum to *energy
  double* energy = nullptr;    // 1: the total potential energy
  double* virial = nullptr;    // dim x dim, row-major: sum over pairs of r_ij (x) f_ij, with
                               // r_ij = x_i - x_j by minimum image and f_ij the force on i from j
};

// Where compute_local writes: host pointers, each computed only when given (any may be null: with
// forces null, an energy-only call). Every array is for the locals only, in the caller's order.
struct LocalOutputs {
  double* forces = nullptr;    // n_local x dim: the force on each local from every partner, locals
                               // and ghosts (the ghosts' forces are not given)
  double* energies = nullptr;  // n_local: each local's share, half of each of its pairs' energies
  double* energy = nullptr;    // 1: the locals' shares summed (a pair of two locals whole, a pair of
                               // a local and a ghost half: LAMMPS's newton off, so that the ranks
                               // owning either side of a pair count it once between them)
  double* virial = nullptr;    // dim x dim, row-major: the locals' virial shares summed, as energy
  double* virials = nullptr;   // n_local x dim x dim, each row-major: each local's share, half of
                               // r_ij (x) f_ij of each of its pairs; they sum to *virial
  bool accumulate = false;     // add into the arrays (all of them, energy and virial too) instead
                               // of overwriting them: sums over calls, e.g. over a rank's regions
};

// A caller's particle arrays as it holds them, for the compute calls that take a layout: positions
// in float64 or float32, each particle's row `stride` elements after the last (dim for packed xyz;
// 4 for xyz padded to four, as OpenMM and many GPU codes store them; 0 means dim), and types as
// uint32 or int32 (null: all type 0). The engine computes on float64 copies of the coordinates (a
// float32 coordinate converts exactly) and uint32 types, so the results are bitwise those of the
// packed float64 and uint32 arrays holding the same values. Host arrays for compute(), device
// arrays (on the context's device) for compute_device(); rows in the caller's particle order.
struct Positions {
  const void* data = nullptr;        // n rows of `stride` elements of `scalar`, the first dim used:
                                     // coordinates in length units, any periodic image
  Scalar scalar = Scalar::kFloat64;
  std::size_t stride = 0;            // elements from one particle's row to the next (>= dim); 0: dim
};
struct Types {
  const void* data = nullptr;        // n indices into the types added; null: all type 0
  Index index = Index::kUInt32;
};

// Pair counts of a configuration (count_pairs()), and the search structure they were counted on
// (stages 1-3 of the spatial subdivision: the grid, each particle's cell-ID entries, the
// collision cells).
struct PairCounts {
  std::size_t tested = 0;         // candidate pairs the traversal tested
  std::size_t within_cutoff = 0;  // pairs with r < rc (each once)
  uint32_t grid_cells[3] = {1, 1, 1};  // cells per axis (1 on axes beyond dim)
  double cell_edge[3] = {0, 0, 0};     // a cell's edge per axis (length)
  double half_width = 0;               // h, the half-width of each particle's box (length)
  std::size_t entries = 0;             // cell-ID entries, n x 2^dim
  std::size_t valid_entries = 0;       // of those, the ones in a cell (home and phantom entries)
  std::size_t collision_cells = 0;     // cells holding a home entry and at least one other entry
  std::size_t max_occupancy = 0;       // most entries in one collision cell
};

// Timings and sizes of the last compute call.
struct Statistics {
  double pipeline_seconds = 0;  // the engine's stages, without host <-> device copies (device
                                // stream time on CUDA)
  // pipeline_seconds by stage: cell IDs (with the count of valid entries), sort, collision cells,
  // traversal (the pairs' forces; CUDA: with staging the occupants) and accumulation.
  double cell_ids_seconds = 0, sort_seconds = 0, collision_cells_seconds = 0, traversal_seconds = 0,
         accumulate_seconds = 0;
  double transfer_seconds = 0;  // host <-> device copies (CUDA, compute() only)
  std::size_t builds = 0;       // neighbour structures built so far (stages 1-3)
  bool rebuilt = true;          // whether the last call built one (false: reused, skin > 0)
  std::size_t buffer_bytes = 0; // memory the engine holds for its stages (device memory on CUDA)
};

// ---- molecular dynamics ----

enum class Integrator : uint8_t {
  kVerlet,    // NVE, velocity Verlet: v += dt/2 F/m; x += dt v; F(x); v += dt/2 F/m
  kLangevin,  // NVT, BAOAB (Leimkuhler & Matthews): v += dt/2 F/m; x += dt/2 v;
              // v = c1 v + sqrt((1 - c1^2) kT/m) xi, c1 = exp(-gamma dt); x += dt/2 v; F(x); v += dt/2 F/m
};

struct IntegratorOptions {
  Integrator kind = Integrator::kVerlet;
  double dt = 0.005;         // time units
  double temperature = 1.0;  // Langevin: kT (energy units)
  double friction = 1.0;     // Langevin: gamma (1 / time)
  uint64_t seed = 1;         // Langevin noise: counter-based, keyed by (seed, step, particle, axis)
};

// Thermodynamics at the current step.
struct Thermo {
  double kinetic = 0, potential = 0, total = 0;
  double temperature = 0;  // 2 KE / degrees of freedom: dim (n - 1) for Verlet (momentum
                           // conserved), dim n for Langevin
  double pressure = 0;     // (2 KE + trace W) / (dim V); NaN when an axis is open
  double virial[9] = {};   // dim x dim, row-major (as Outputs::virial)
};

// The MD state's arrays where they live (Context::state_view): on the host with the cpu backend,
// on the context's CUDA device with cuda; the state's particle order, row-major n x dim.
struct StateView {
  const double* positions = nullptr;   // wrapped into the box on periodic axes (length)
  const double* velocities = nullptr;  // length / time
  const double* forces = nullptr;      // at the positions: the pair forces and any external force
  std::size_t n = 0;
  int dim = 3;
  int device = -1;  // the CUDA device's ordinal; -1: host memory
};

// FIRE energy minimisation (Bitzek et al. 2006) of the state's positions.
struct MinimizeOptions {
  double force_tolerance = 100.0;  // converged when every |F_i| < this
  int64_t max_steps = 10000;
  double dt = 0.001, dt_max = 0.01;
  double max_displacement = 0.1;   // per step and particle
};
struct MinimizeResult {
  int64_t steps = 0;
  double initial_energy = 0, final_energy = 0;
  double initial_max_force = 0, final_max_force = 0;
  std::size_t final_max_force_particle = 0;
};

// Where the time of the steps went, and what crossed between host and device, since the state was
// set or reset_run_statistics() ran. The engine's own statistics (stage times per evaluation, pair
// lists, the step gate, memory by buffer) are in statistics_json()'s "run" object, beside these.
struct RunStatistics {
  int64_t steps = 0, evaluations = 0;
  double force_seconds = 0;        // force evaluations (CUDA: device time, with the step gate's
                                   // shut evaluations, whose kernels return at once)
  double integration_seconds = 0;  // kicks, drifts, thermostat (CUDA: device time; the device's
                                   // idle while the host reads the step gate is in neither)
  double step_call_seconds = 0;    // wall time inside step()
  std::size_t bytes_to_host = 0, bytes_to_device = 0;  // particle data and results (CUDA)
  // Neighbour structure (skin > 0): builds over all evaluations, the largest displacement a reused
  // structure served.
  int64_t builds = 0;
  double largest_served_displacement = 0;
  // Builds that retired a structure (after neighbor-every evaluations) when a particle had moved
  // more than skin / 2 since its build: LAMMPS's dangerous builds, whose structure's evaluations may
  // have missed pairs. Possible only with neighbor-check false; a rebuild for a changed box, count
  // or cutoff is not measured. Always 0 with the check on.
  int64_t dangerous_builds = 0;
  // With neighbor-audit: pairs within the cutoff that a reused structure missed or repeated.
  std::size_t missed_pairs = 0, repeated_pairs = 0;
  // Memory held now (device memory with cuda, host memory on the CPU): the force engine's stage
  // buffers (as of the last sampled evaluation) and the MD state (positions, velocities, masses,
  // types and the integrator's and minimiser's working arrays).
  std::size_t buffer_bytes = 0, state_bytes = 0;
};

// The neighbour structure in use (skin > 0), for a bitwise restart: the positions it was built
// from (n x dim; empty when none) and the evaluations it has served.
struct NeighborState {
  std::vector<double> build_positions;
  int64_t served = 0;
};

class CELLFORCE_API Context {
 public:
  // An empty context for 2 or 3 dimensions: no box, cutoff or types yet; CPU backend, double
  // precision, Lorentz-Berthelot mixing, skin auto.
  explicit Context(int dim = 3);
  ~Context();
  Context(Context&&) noexcept;
  Context& operator=(Context&&) noexcept;
  Context(const Context&) = delete;
  Context& operator=(const Context&) = delete;

  // ---- the physics (may change between compute calls, and while an MD state exists) ----
  // With an MD state (set_state), each change below applies to it at once, as a fresh set_state of
  // the state now (positions, velocities, types, masses, step) under the new physics would: its
  // forces are evaluated again, and the next step starts from them. A change the state cannot take
  // (a cutoff beyond half a periodic edge for the new box, a pair whose force is not finite under
  // it) throws naming the setting, and leaves the state and the context as they were.
  //
  // lengths[dim], periodic[dim]: edge lengths and which axes wrap. A periodic edge must be finite
  // and > 0 (and at least twice the cutoff, checked when computing); the length of an open axis
  // is ignored and may be 0 (particles may lie anywhere along it). An MD state's positions are not
  // scaled: they are wrapped into the new box on its periodic axes.
  void set_box(const double* lengths, const bool* periodic);
  // As set_box; with an MD state and `scale_positions`, each coordinate on an axis periodic before
  // and after is multiplied by the new edge over the old (an affine change of the box, as a
  // barostat makes it), velocities kept; without, the positions stay and are wrapped.
  void set_box(const double* lengths, const bool* periodic, bool scale_positions);
  // Pairs interact only when r < rc (strict). The first form keeps the cutoff mode (truncate in a
  // new context, or as set by option cutoff-mode); the second sets it too (options.hpp).
  void set_cutoff(double rc);
  void set_cutoff(double rc, CutoffMode mode);
  void set_mixing(Mixing mixing);
  // A particle type; returns its index (0, 1, ... in the order added). sigma and epsilon finite
  // and >= 0; names printable and unique.
  uint32_t add_type(std::string_view name, double sigma, double epsilon);
  // An explicit pair value that replaces the mixing rule for types a and b (either order).
  void set_pair(uint32_t a, uint32_t b, double sigma, double epsilon);

  // ---- the engine (a change takes effect at the next compute call) ----
  // With an MD state, a change of any engine setting below (set_option's too, but cutoff-mode and
  // mixing, which are physics) carries the state (positions, velocities, types, masses, step; the
  // integrator is the context's) into a new engine made with it, whose forces are evaluated there:
  // the next step runs on the new engine, as after a fresh set_state of the state now; the run
  // statistics and the neighbour structure start afresh. The new engine is made beside the old one
  // (with cuda: both on the device for a moment); when it cannot be made (no CUDA device, no memory
  // for it), the call throws naming the setting, and the state stays on the old engine.
  // set_backend(backend) keeps the device (0 in a new context, or as set by option device).
  void set_backend(Backend backend);
  void set_backend(Backend backend, int device);
  void set_precision(Precision precision);
  // Verlet skin of the neighbour structure (length): stages 1-3 are built for rc + skin and reused
  // while no particle has moved more than skin / 2; 0 rebuilds on every call. The default is auto
  // (option skin = auto): the MD state (set_state, step, minimize) on CUDA with Jacobi accumulation
  // gets pair lists with a skin of 0.24 rc (0.18 rc where the lists run in lean memory: option
  // memory) where rc + skin fits in half of every periodic edge, and so do the force calls compute
  // and compute_device (whose rebuilds the device decides: see compute_device); otherwise (the
  // CPU) no skin. A rule of the backend, the box, the particle count and the device's memory, not a
  // timing: skin() and neighbor() say what it chose.
  void set_skin(double skin);
  // Every choice by name, as the C API and scene files write them (keys as written here, names in
  // any letter case: "CUDA" is "cuda"):
  //   backend       cpu | cuda | auto
  //   device        CUDA device ordinal, 0, 1, ...
  //   precision     single | mixed | double
  //   mixing        lorentz-berthelot | geometric
  //   cutoff-mode   truncate | shift | force-shift
  //   skin          auto (the default) | a length >= 0 (set_skin)
  //   neighbor-check  true | false (rebuild when a particle moved more than skin / 2; default true)
  //   neighbor-every  N >= 0 (a structure serves at most N evaluations; 0: no limit)
  //   neighbor-audit  true | false (count pairs a reused structure misses; slow, CPU diagnostics)
  //   neighbor-list   true | false (CUDA, skin > 0, Jacobi: each build records every particle's
  //                   partners within rc + skin and the evaluations it serves walk those lists;
  //                   default false; it applies to a skin given as a length: skin auto chooses
  //                   lists itself)
  //   accumulation  jacobi | gauss-seidel
  //   cell-rule     tight | chapter
  //   traversal     auto | warp | thread | tile   (CUDA: warp per cell, the chapter's thread per
  //                                           cell, block per 32-occupant tile of a cell; auto, the
  //                                           default: tile for few cells per SM, else warp)
  //   sort          cub | chapter            (CUDA)
  //   memory        auto | fast | lean       (CUDA pair lists: lean keeps no staged occupants,
  //                                           holds the sort's arrays in the dead list's room and
  //                                           keeps the build's masks only in the memory the device
  //                                           has left: ~700 against ~1,300 bytes a particle, up to
  //                                           ~930 with every mask; builds up to ~2x slower where
  //                                           the masks find no room; auto, the default: lean where
  //                                           fast would not fit in 90% of the device; lean memory
  //                                           makes an automatic skin 0.18 rc instead of 0.24 rc)
  //   threads       auto (the default) | N >= 0 (the CPU backend: OpenMP threads of the engine's
  //                 parallel regions; 0 and auto: OpenMP's default, omp_get_max_threads(); other
  //                 threads of the program keep their own count)
  void set_option(std::string_view key, std::string_view value);

  // ---- computing ----
  // Host arrays. positions: n x dim (any periodic image; finite); types: n indices into the types
  // added, or null for all type 0. Returns when the results are written; on CUDA it copies the
  // arrays to the device and back. n = 0 is a valid, empty call (energy and virial 0).
  void compute(std::size_t n, const double* positions, const uint32_t* types, const Outputs& out);
  // Device arrays on the context's CUDA device (positions, types and every output pointer).
  // The work is ordered after what `stream` (a cudaStream_t; null: the legacy default stream)
  // already holds, and the results are ready when the stream reaches this call's point: work the
  // caller queues on `stream` afterwards sees them. Needs the cuda backend (or auto with a
  // device). The call does not wait for the device or the stream: it checks the pointers and the
  // physics on the host (and throws for them before queueing anything), queues the work and
  // returns. The arrays are checked on the device; a coordinate that is not finite, a type index
  // out of range or a pair whose force is not finite is raised as cellforce::Error by the next
  // synchronize() (or the next compute() or count_pairs(), which synchronise first), and the
  // outputs of the calls since the last synchronize() are then not to be used. With a skin and pair
  // lists (the default on CUDA) and every axis periodic, the device decides each call's rebuild
  // (one CUDA graph a call, run on `stream`) and the host waits for nothing, once the first calls
  // have built the structure; until then, and with an open axis, lean memory, neighbor-every or
  // the audit, the host decides: it waits for the displacement check (8 bytes a call), for the
  // particles' bounds with an open axis and for the list's size when the structure is built.
  // Results are bitwise those of compute() on the same input and backend, call by call, where the
  // calls bring the same positions in the same order (the same rebuilds), until a pair list
  // outgrows the room kept for it (1/4 more than the last list); from there on they are exact
  // (the cells serve until the list is built again into a larger array) but not bitwise.
  void compute_device(std::size_t n, const double* positions, const uint32_t* types, const Outputs& out,
                      void* stream = nullptr);
  // compute() and compute_device() for arrays as the caller holds them (Positions, Types: float32
  // or float64 coordinates, a row stride, int32 or uint32 types), with the same results as the
  // packed float64 and uint32 arrays of the same values. Besides what those calls check: a stride
  // below dim, a negative int32 type (host arrays: named here; device arrays: by synchronize(), as
  // any type out of range). compute_device converts the coordinates on the device, ordered after
  // the work `stream` holds as every compute_device call is, into an array of the engine's (n x dim
  // doubles) unless they are packed float64 already.
  void compute(std::size_t n, const Positions& positions, const Types& types, const Outputs& out);
  void compute_device(std::size_t n, const Positions& positions, const Types& types, const Outputs& out,
                      void* stream = nullptr);
  // Forces, energies and virials of a rank's own particles with its ghosts, for domain-decomposed
  // codes (host arrays, either backend). positions: (n_local + n_ghost) x dim, the locals first
  // (particles 0 .. n_local - 1), then the ghosts, which the caller places: other ranks' particles,
  // or periodic images at their image positions. types: as many, or null for all type 0. Outputs
  // (LocalOutputs) are for the locals only; a pair of two ghosts is never evaluated.
  // The box: an axis the ghosts stand in for (the caller's decomposition, or the periodic images
  // it places itself) is given as open (set_box with periodic false); on an axis left periodic the
  // pairs, ghosts' too, take the minimum image, so a ghost must not be an image of a particle
  // across it (its pairs would count twice). Ghosts with every axis periodic are refused: each
  // local then finds every neighbour by the minimum image already. Beside compute()'s checks
  // (null positions, a non-finite coordinate, a type out of range: each named by particle, index
  // into the whole array), a ghost count with every axis periodic is named. The cuda backend walks
  // the collision cells for these calls (the tile form, whatever the traversal option; a build for
  // one makes no pair list, so a compute() that reuses its structure walks the cells too).
  void compute_local(std::size_t n_local, std::size_t n_ghost, const double* positions, const uint32_t* types,
                     const LocalOutputs& out);
  // count_pairs() for a compute_local call: the pairs tested and within the cutoff, no pair of two
  // ghosts among them.
  PairCounts count_pairs_local(std::size_t n_local, std::size_t n_ghost, const double* positions,
                               const uint32_t* types);
  // Waits for the compute_device calls queued so far and throws cellforce::Error for the first
  // problem their kernels found (naming the particle, or both particles of a pair); afterwards
  // statistics() describes the last of them. Returns at once when none is pending. Changing the
  // backend or an engine option drops what pending calls found unchecked.
  void synchronize();
  // Pairs tested and within the cutoff for host arrays (an extra pass on CUDA; it counts as one
  // more use of a reused structure). The tested pairs are the collision cells' candidates, also
  // where pair lists serve the evaluations (a list holds the pairs within rc + skin at its build).
  PairCounts count_pairs(std::size_t n, const double* positions, const uint32_t* types);
  Statistics statistics() const;
  // The outputs of compute() for host arrays by the brute force: every pair under the minimum
  // image, in double precision, on the host, O(n^2) and with no grid, whatever the backend and
  // precision: the oracle the engines are tested against, for checking their results (slow beyond
  // some 10^4 particles). Needs the box, cutoff and types as compute() does; statistics() stays.
  void compute_brute_force(std::size_t n, const double* positions, const uint32_t* types, const Outputs& out);

  // ---- molecular dynamics (the state stays where the backend computes: on the GPU with cuda) ----
  void set_integrator(const IntegratorOptions& options);
  // Host arrays: positions and velocities n x dim (velocities may be null: all zero), types n (or
  // null: all type 0), masses n (finite, > 0). Positions on periodic axes are wrapped into the box.
  // Uploads the state, evaluates the forces at it, and sets the step counter (time = step x dt).
  // Later changes of the physics or the engine apply to the state (set_box, set_cutoff, ...).
  // With skin auto, a box or cutoff for which the rule chooses otherwise than for the state before
  // makes a new MD engine: its run statistics and neighbour structure start afresh.
  void set_state(std::size_t n, const double* positions, const double* velocities, const uint32_t* types,
                 const double* masses, int64_t step = 0);
  // Advances `count` steps. With the cuda backend the host queues them and waits only for the
  // counts that size the neighbour search's buffers and for the skin's displacement check: once
  // per step, or, with pair lists (skin auto's choice on CUDA), once per chunk of steps (the step
  // gate decides the rebuilds on the device, on the same steps); the device's flags are read once
  // at the end,
  // and a diverged integration or a force that is not finite throws naming the particle and the
  // steps of this call. `observe`: the last step also computes energy and virial (for thermo()).
  void step(int64_t count, bool observe = true);
  int64_t current_step() const;
  bool has_state() const;  // whether set_state has given the context an MD state
  // The MD state's particle count (throws when there is no state).
  std::size_t num_particles() const;
  // New positions or velocities (host arrays, n x dim, n the state's count) for the state where it
  // lives: with cuda the array alone is uploaded (set_positions keeps the positions before beside
  // them on the device until the forces at the new ones are known to be finite: n x dim doubles
  // more for the call). set_positions wraps them into the box as
  // set_state does and evaluates the forces at them (velocities, step and time kept); a position
  // that is not finite, or a pair whose force is not finite, throws naming the particle(s) and
  // leaves the state as it was. set_velocities (finite) changes nothing else.
  void set_positions(std::size_t n, const double* positions);
  void set_velocities(std::size_t n, const double* velocities);
  // An external force on every particle, added to the pair forces at each evaluation of the MD
  // state's forces (each step, and set_state, set_positions, thermo() when it evaluates again)
  // before anything reads them, as LAMMPS's fix external does; it has no energy or virial of its
  // own (thermo() reports the pair potential's). One at a time (setting one replaces the last),
  // kept across set_state and changes of the physics or engine until clear_external_force(); a
  // state's forces are evaluated again when it is set or cleared. minimize() refuses to run while
  // one is set (its energy is unknown). With cuda an array is added behind the step gate too (its
  // chunks then run the kick-drift as a kernel of its own, not in the force kernel), while with a
  // callback the steps are not served behind the gate (the host calls it each step): fewer steps a
  // second.
  //  - set_external_forces: a host array, n x dim (n the state's count, or that of the next
  //    set_state), finite (a value that is not is named by particle and axis), copied where the
  //    state lives.
  //  - set_external_forces_device (cuda): the caller's device array, n x dim, read at every
  //    evaluation, kept by the caller (change it between step() calls, which return when the device
  //    is done: the next step's evaluation reads the change; the forces the state holds keep the
  //    value they were evaluated with), on the context's device: a state moved to another device
  //    or backend is refused while it is set. Its values are not checked (a value that is not
  //    finite shows as a diverged drift naming the particle).
  //  - set_external_force_callback: `callback(user, step, n, dim, positions, forces, stream)` at
  //    every evaluation, after the pair forces: it adds its forces into `forces` (n x dim, the
  //    state's order) from `positions` (n x dim, wrapped), both where the state lives (device
  //    arrays with cuda, `stream` the context's cudaStream_t, on which it queues its work or
  //    which it synchronises; host arrays and a null stream on the CPU); `step` is the step the
  //    positions belong to (a step's positions evaluated again, by thermo(), call it again). It
  //    must not throw, nor call this context. A null callback clears.
  using ExternalForceFn = void (*)(void* user, int64_t step, std::size_t n, int dim, const double* positions,
                                   double* forces, void* stream);
  void set_external_forces(std::size_t n, const double* forces);
  void set_external_forces_device(std::size_t n, const double* forces);
  void set_external_force_callback(ExternalForceFn callback, void* user);
  void clear_external_force();
  // The state now into host arrays (n x dim each; any may be null); a download with cuda.
  void get_state(double* positions, double* velocities, double* forces);
  // The state where it lives, to read without a copy (StateView). With cuda the host waits for the
  // context's stream first, so that the arrays are complete. The arrays change with every call that
  // changes the state (step, set_positions and set_velocities write into them, minimize, thermo()
  // when it evaluates again); the pointers may move: the forces' on the CPU alternate between two
  // arrays from one evaluation to the next, and a new set_state, a change of backend, device,
  // engine option, physics or box may give the state new arrays (the old ones freed). Read the view
  // again after any call on the context. Not to be written through.
  StateView state_view();
  // Thermodynamics now: a reduction on the device and 8 numbers copied back with cuda (one more
  // force evaluation when the last step did not observe).
  Thermo thermo();
  // FIRE on the state's positions (velocities are left zero; refused while an external force is
  // set); throws naming the particle with the
  // largest force when it does not converge within max_steps, and then leaves the state as it was.
  // Runs where the state lives: with cuda, kernels on the device, the host reading 56 bytes of
  // sums per FIRE step for its step-size decisions (one synchronisation per step).
  MinimizeResult minimize(const MinimizeOptions& options);
  NeighborState neighbor_state();
  // After set_state: rebuild the structure from the positions it was built from, set its count,
  // and evaluate the current forces with it (as the uninterrupted run had them: a bitwise restart).
  void restore_neighbor_state(const NeighborState& state);
  RunStatistics run_statistics() const;
  void reset_run_statistics();
  // Every statistic as one JSON object (the C API's cf_statistics_json): {"version": ...,
  // "call": statistics() by the names of Statistics' fields, "run": null without an MD state, else
  // run_statistics() by the names of RunStatistics' fields and the engine's own:
  //   stage_samples, stage_seconds {cell_ids, sort, collision_cells, traversal, accumulate, check,
  //     total}: per evaluation, averaged over stage_samples evaluations (CUDA: the last of each
  //     step() call), in seconds;
  //   memory [{"name", "bytes"}]: buffer_bytes + state_bytes by buffer (the MD state's arrays named
  //     "md: ..."), those that hold any, largest first;
  //   gated_steps: CUDA steps run behind the step gate (queued in chunks, the rebuild decided on the
  //     device); gate_closings, gate_closings_early: runs of gated steps that ended in a rebuild, and
  //     of those the ones whose rebuild the host queued before the run's end;
  //   list_evaluations: evaluations that walked CUDA pair lists, not the cells; list_pairs,
  //     list_slots: the last sampled list's pairs (within rc + skin, once from each side) and the
  //     entries its layout holds, padding included; list_mask_words, list_mask_words_held: its
  //     build's count-pass masks, the words all units take and those the device had room for;
  //     graph_builds: builds whose fixed part ran as one replayed CUDA graph; list_block: threads a
  //     block of the force kernels that ran the next step's kick-drift (0: none ran).
  // Keys are added, never renamed or removed, within a major version.
  std::string statistics_json() const { return text(Text::kStatisticsJson); }

  // ---- what the context is ----
  // A Context that was moved from (std::move) holds nothing: every call on it but assignment and
  // destruction throws cellforce::Error saying so.
  int dim() const;
  std::size_t num_types() const;
  // The backend in use, "cpu" or "cuda" (auto resolved; this creates the engine when needed), a
  // description (device or threads, algorithm), and the CUDA traversal and sort ("-" on the CPU).
  std::string backend_name() { return text(Text::kBackendName); }
  std::string description() { return text(Text::kDescription); }
  std::string traversal() { return text(Text::kTraversal); }
  std::string sort() { return text(Text::kSort); }
  // The skin in effect (the automatic one resolved for the box, backend and lists' memory mode; 0:
  // none) and the neighbour structure in words, e.g. "skin 0.6 (auto: 0.24 rc), pair lists",
  // "skin 0.45 (auto: 0.18 rc, lean memory), pair lists" or "none, stages 1-3 every evaluation
  // (auto: no skin on the cpu)". For the MD state when there is one (as set_state resolved it),
  // else for force calls on the current box (auto: none).
  double skin();
  std::string neighbor() { return text(Text::kNeighbor); }
  // Whether the evaluations walk pair lists (CUDA, a skin with lists, Jacobi accumulation, rc + skin
  // within half of every periodic edge); a list the engine declines at a build (too crowded for the
  // device's memory) is counted by RunStatistics::list_evaluations, not here.
  bool neighbor_lists();

  struct Impl;  // the engine and the physics it is given

 private:
  // The library's side of the calls that return text: the text, held by the context until the next
  // such call. (The exported functions return no std::string: its layout is the caller's
  // _GLIBCXX_USE_CXX11_ABI's.)
  enum class Text : uint8_t { kBackendName, kDescription, kTraversal, kSort, kNeighbor, kStatisticsJson };
  const char* text(Text which) const;
  // The library's side of neighbor_state() and restore_neighbor_state(): the build positions
  // (`coordinates` doubles, held by the context until the next call) and the evaluations served.
  const double* held_neighbor_state(std::size_t* coordinates, int64_t* served);
  void restore_neighbor_arrays(const double* build_positions, std::size_t coordinates, int64_t served);

  Impl& self() const;  // *impl_, or cellforce::Error for a Context moved from
  std::unique_ptr<Impl> impl_;
};

inline NeighborState Context::neighbor_state() {
  NeighborState state;
  std::size_t coordinates = 0;
  const double* positions = held_neighbor_state(&coordinates, &state.served);
  state.build_positions.assign(positions, positions + coordinates);
  return state;
}
inline void Context::restore_neighbor_state(const NeighborState& state) {
  restore_neighbor_arrays(state.build_positions.data(), state.build_positions.size(), state.served);
}

}  // namespace CELLFORCE_ABI_NAMESPACE
}  // namespace cellforce
