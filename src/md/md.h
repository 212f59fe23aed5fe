// Molecular dynamics on top of a force backend: the integrators (velocity Verlet for NVE; Langevin
// BAOAB for NVT) and the thermodynamic observables of the state (state/md_state.h; its initial
// velocities and kinetic energy in state/velocities.h).
//
// Random numbers (initial velocities, Langevin noise) are counter-based: each value is a hash of
// (seed, step, particle, axis), so a run is reproducible for a seed whatever the thread count,
// and a restart from step s draws exactly what the uninterrupted run drew after s.
#pragma once

#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "core/random.h"
#include "core/system.h"
#include "state/md_state.h"
#include "state/velocities.h"

namespace cellforce {

// counter_normal(seed, stream, index) (core/random.h) draws the numbers: stream 0 the initial
// velocities, stream step + 1 the Langevin noise of that step, index particle * dim + axis.

struct ThermoValues {
  double kinetic = 0, potential = 0, total = 0;
  double temperature = 0;  // 2 KE / degrees of freedom
  double pressure = 0;     // (2 KE + trace W) / (dim V); NaN when an axis is open (no volume)
};
ThermoValues thermo(const MdState& state, const std::vector<double>& masses, const ForceResult& result,
              bool com_conserved = true);

// A force added to every particle's pair force at each evaluation of the MD state's forces (the
// API's set_external_forces and set_external_force_callback), before anything reads them: one of
// a host array (n x dim, copied where the state lives), the caller's device array (n x dim, read
// at each evaluation; CUDA), or a callback that adds its forces itself (positions and forces where
// the state lives, the state's order; `stream` the engine's cudaStream_t on CUDA, null on the CPU;
// `step` the step whose positions they are). No energy or virial of its own.
using ExternalForceCallback = void (*)(void* user, int64_t step, std::size_t n, int dim, const double* positions,
                                 double* forces, void* stream);
struct ExternalForce {
  std::vector<double> values;
  const double* device = nullptr;
  ExternalForceCallback callback = nullptr;
  void* user = nullptr;
  bool any() const { return !values.empty() || device != nullptr || callback != nullptr; }
};

struct IntegratorSettings {
  bool langevin = false;
  double dt = 0.005;
  double kT = 1.0;        // Langevin target temperature
  double friction = 1.0;  // Langevin gamma
  uint64_t seed = 1;
};

// The longest displacement one drift may make along `axis` before the integration counts as
// diverged: `share` x the box edge on a periodic axis (beyond it the particle's image is
// ambiguous) and `share` x the cutoff on an open axis (a particle that moves farther than the
// cutoff in one step can pass a partner without their force ever acting: a collision the
// integration cannot resolve). share: 1 for velocity Verlet's drift, 0.5 for each of a Langevin
// step's two half drifts. The CPU's drift and the CUDA engine's kernels both take it from here.
double drift_limit(const Box& box, int axis, double cutoff, double share);

// The message of a drift that failed drift_limit, or whose new position is no longer finite
// (`position`; NaN where it is not known), naming the particle, the axis, the displacement and the
// limit.
std::string diverged_message(std::size_t particle, int axis, double displacement, double position,
                             const Box& box, double cutoff, double share);

// One time step. `compute_forces(state)` must set state.forces at state's positions.
//   NVE, velocity Verlet:  v += dt/2 F/m; x += dt v; F(x); v += dt/2 F/m
//   Langevin, BAOAB (Leimkuhler & Matthews): v += dt/2 F/m; x += dt/2 v;
//     v = c1 v + sqrt((1 - c1^2) kT/m) xi, c1 = exp(-gamma dt); x += dt/2 v; F(x); v += dt/2 F/m
// Positions are wrapped into the box on periodic axes after the drift. Throws cellforce::Error
// naming the particle when its displacement in one drift is not finite or beyond drift_limit (the
// box edge on a periodic axis, the cutoff on an open one), or its position is no longer finite (the
// integration diverged). Positions given outside the box are no divergence: the check looks at
// displacements only. cutoff: the force field's (the MD engines pass it; infinite leaves open axes
// unchecked but for finite numbers).
void advance(MdState& state, const std::vector<double>& masses, const IntegratorSettings& settings,
             const std::function<void(MdState&)>& compute_forces,
             double cutoff = std::numeric_limits<double>::infinity());

}  // namespace cellforce
