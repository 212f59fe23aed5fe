// The backends' integration and state-access jobs: an MdEngine holds the MD state (positions,
// velocities, forces, types, masses) where its backend computes (host memory for the CPU; device
// memory for CUDA, for the whole run) and advances it with the integrators of md/md.h (velocity
// Verlet, Langevin BAOAB) and minimises it with FIRE (md/minimize.h). The state crosses to the host
// only when asked for (get_state, observables). One implementation per backend:
// src/backends/cpu_md_engine.cpp and cuda/backend/md_engine.cu.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "backends/force_engine.h"
#include "md/md.h"
#include "md/minimize.h"

namespace cellforce {

// What an output step reads: kinetic energy (reduced where the state lives), and the potential
// energy and virial of the evaluation at the current positions.
struct Observables {
  double kinetic = 0;
  double potential = 0;
  double virial[kMaxDim][kMaxDim] = {};
};

// Time and traffic of the steps since the engine was made or reset_counters() ran.
struct MdCounters {
  int64_t steps = 0;
  int64_t evaluations = 0;
  double force_seconds = 0;        // force evaluations (CUDA: device time; CPU: wall time)
  double integration_seconds = 0;  // kicks, drifts, thermostat (CUDA: device time, less the idle
                                   // while the host reads the step gate; CPU: wall time)
  double host_wait_seconds = 0;    // wall time of advance() calls, host included
  std::size_t bytes_to_host = 0;   // particle data and results copied device -> host (CUDA)
  std::size_t bytes_to_device = 0; // host -> device
  PipelineStats stages;            // stage times (t_*) summed over the evaluations sampled
  int64_t stage_samples = 0;       // evaluations whose stage times are in `stages` (CUDA: the last
                                   // of each advance() call; CPU: every one)
  // Reuse of the neighbour structure (skin > 0), over every evaluation: builds, the largest
  // displacement a reused structure served, and the audit's counts (CPU only).
  int64_t builds = 0;
  int64_t dangerous_builds = 0;  // builds that retired a structure past skin / 2 (check = false)
  double served = 0;
  int64_t gated_steps = 0;  // CUDA: steps the structure served behind the step gate (cuda/search/step_gate.h)
  int64_t list_evaluations = 0;  // CUDA: evaluations that walked pair lists (PipelineStats::listed)
  int64_t graph_builds = 0;  // CUDA: builds whose fixed part a CUDA graph replayed (PipelineStats::graph_build)
  int list_block = 0;  // CUDA: the last nonzero PipelineStats::list_block of a gated chunk; 0: none ran
  int64_t gate_closings = 0;        // CUDA: gated chunks whose gate closed (each followed by a rebuild)
  int64_t gate_closings_early = 0;  // of those, the ones the host read from the notice before the
                                    // chunk's end (cuda/integrate/gate_readback.cuh)
  std::size_t missed_pairs = 0, repeated_pairs = 0;
};

class MdEngine {
 public:
  virtual ~MdEngine() = default;

  // The state to integrate (host arrays, the caller's order; positions wrapped on periodic axes)
  // and each particle's mass (n). Validates it (non-finite coordinates, types, cutoff against the
  // box; masses finite and > 0), stores it where the backend computes and evaluates the forces
  // (with energy and virial) at its positions. Throws cellforce::Error naming the particle.
  virtual void set_state(const MdState& state, const std::vector<double>& masses, const ForceField& ff) = 0;

  // Advances `steps` time steps of `settings` (md/md.h's advance(): forces at the new positions
  // each step); the last step's evaluation also computes energy and virial when `observe`. On a
  // backend whose state lives on a device the host does not wait for the device here except for
  // the counts that size the search's buffers; the kernels' flags are read once at the end, and
  // an integration that diverged or a force that is not finite throws cellforce::Error naming the
  // particle(s) and the steps the call covered.
  virtual void advance(int64_t steps, const IntegratorSettings& settings, bool observe) = 0;

  // FIRE (md/minimize.h's minimize_fire, its algorithm and contract) on the state now, in place:
  // every evaluation computes energy and virial; on return the state holds the final positions,
  // their forces and zero velocities (step and time unchanged). Throws cellforce::Error for
  // settings out of range, a force or position that is not finite (naming the particle), and,
  // with require_convergence, no convergence within max_steps (naming the particle with the
  // largest force). After a throw the state is the one before the call, its forces evaluated
  // again (as reevaluate() does). On a device backend the particles stay on the device.
  virtual FireResult minimize(const FireSettings& settings) = 0;

  // New positions for the state where it lives (n x dim, the state's n; wrapped on periodic axes
  // by the caller): validated as set_state validates them, stored (on a device backend an upload
  // of the positions alone) and the forces evaluated at them (with energy and virial); velocities,
  // step and time kept. On a throw the state is the one before the call, its forces evaluated again.
  virtual void set_positions(const std::vector<double>& positions) = 0;
  // New velocities for the state where it lives (n x dim, finite: the caller checks them); nothing
  // else changes and nothing is evaluated.
  virtual void set_velocities(const std::vector<double>& velocities) = 0;

  // The state now, into `state` (positions, velocities, forces; step and time): a download on a
  // device backend.
  virtual void get_state(MdState& state) = 0;
  // The state's arrays where they live, read in place: positions, velocities and forces (n x dim
  // each, the caller's order), host pointers on the CPU and device pointers on a device backend
  // (`device`: its ordinal; -1 for host memory), complete when this returns (a device backend
  // waits for its stream). The pointers hold until the state changes (a step, set_*, minimize,
  // reevaluate); the caller reads them again after any call.
  struct StateArrays {
    const double* positions = nullptr;
    const double* velocities = nullptr;
    const double* forces = nullptr;
    int device = -1;
  };
  virtual StateArrays state_arrays() = 0;
  virtual int64_t step() const = 0;
  // Bytes the state and the integrator's working arrays hold where the backend computes, by array
  // (names: string literals), and their sum.
  virtual std::vector<std::pair<const char*, std::size_t>> state_buffers() const = 0;
  std::size_t state_bytes() const {
    std::size_t b = 0;
    for (const auto& [name, bytes] : state_buffers()) b += bytes;
    return b;
  }

  // Kinetic energy now, potential energy and virial at the current positions: those of the last
  // evaluation when it computed them, else from one more evaluation (which computes them).
  virtual Observables observables() = 0;

  // Evaluates the forces (with energy and virial) at the current positions again: after the
  // force engine's structure was restored (restore_reuse), so that the state's forces come from it.
  virtual void reevaluate() = 0;

  // The external force (md/md.h) every later evaluation of the state's forces adds (none: an
  // empty one); the state's forces now are not changed (reevaluate() does that). The caller has
  // checked its size against the state's and, on the CPU, that it holds no device array.
  virtual void set_external_force(const ExternalForce& external) = 0;

  // The force engine underneath (description, reuse state for checkpoints, stage statistics).
  virtual ForceEngine& forces() = 0;

  virtual const MdCounters& counters() const = 0;
  virtual void reset_counters() = 0;
};

// The engine of `choice`'s backend (auto resolved as make_force_engine does).
std::unique_ptr<MdEngine> make_md_engine(const EngineChoice& choice);
std::unique_ptr<MdEngine> make_cpu_md_engine(std::unique_ptr<ForceEngine> forces);
#ifdef CELLFORCE_HAVE_CUDA
std::unique_ptr<MdEngine> make_cuda_md_engine(const EngineChoice& choice);  // its own CudaForceEngine
#endif

// Adds one evaluation's statistics: its stage times to c.stages (one more sample), its build or
// reuse to the reuse figures.
void add_stage_sample(MdCounters& c, const PipelineStats& s);
void add_reuse(MdCounters& c, const PipelineStats& s, int64_t evaluations = 1);

// Throws cellforce::Error naming the first particle whose mass is not finite and > 0.
void validate_masses(const std::vector<double>& masses, std::size_t n);

}  // namespace cellforce
