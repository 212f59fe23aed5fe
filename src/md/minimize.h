// Starting from overlaps: the FIRE minimiser that removes them before the dynamics (the check that
// refuses dynamics whose first step would throw a particle out of its neighbourhood is
// state/stable_start.h's check_stable_start).
//
// FIRE (Bitzek, Koskinen, Gaehler, Moseler, Gumbsch, PRL 97, 170201 (2006)) with the FIRE 2.0
// refinements of Guenole et al. (Comput. Mater. Sci. 175, 109584 (2020)): semi-implicit Euler
// steps (v += dt F/m, then the velocity mixing, then x += dt v); on an uphill step (P = F.v <= 0)
// dt is halved (not below 0.02 x the initial dt), alpha reset, the positions stepped back by half
// a step and the velocities zeroed; dt grows and alpha shrinks only after n_delay downhill steps
// in a row, and the first n_delay steps never shrink dt (the "initial delay"). On top of that, no
// particle moves more than max_displacement in one step's drift: a particle whose velocity would
// carry it further has its velocity scaled down to that length (so x and v stay consistent, as
// LAMMPS's nve/limit does); an uphill step's step back retracts at most half of the previous
// drift, so positions between two force evaluations differ by at most 1.5 x max_displacement.
// This cap is what makes a start from overlaps safe: a pair at r = 0.01 sigma has a force of
// ~5e27 epsilon/sigma, and the pair simply walks apart by max_displacement a step.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "core/force_field.h"
#include "md/md.h"

namespace cellforce {

struct FireSettings {
  double force_tolerance = 100.0;  // converged when max_i |F_i| < this (energy / length)
  int64_t max_steps = 10000;       // steps (force evaluations after the first) at most
  double dt = 0.001;               // initial time step
  double dt_max = 0.01;            // largest time step (>= dt; the scene's default is 10 x dt)
  double max_displacement = 0.1;   // no particle moves further in one step (length units)
  double alpha_start = 0.1;        // initial velocity-mixing factor
  double f_alpha = 0.99;           // alpha *= f_alpha after each downhill step beyond n_delay
  double f_inc = 1.1;              // dt *= f_inc (up to dt_max) after each downhill step beyond n_delay
  double f_dec = 0.5;              // dt *= f_dec on an uphill step
  int64_t n_delay = 5;             // downhill steps in a row before dt may grow
  // Not converging within max_steps throws cellforce::Error naming the particle with the largest
  // force; false returns the result with converged = false instead.
  bool require_convergence = true;
};

struct FireResult {
  int64_t steps = 0;  // FIRE steps taken (force evaluations: steps + 1)
  double initial_energy = 0, final_energy = 0;        // potential energy, total
  double initial_max_force = 0, final_max_force = 0;  // max_i |F_i|
  std::size_t initial_max_force_particle = 0, final_max_force_particle = 0;
  bool converged = false;  // final_max_force < force_tolerance
};

// Sets state.forces (n x dim) at state's positions and returns the total potential energy.
using ForceEnergyFunction = std::function<double(MdState&)>;

// The largest per-particle force magnitude |F_i| of state.forces and its particle (0, 0 when
// there is no particle).
struct LargestForce {
  double magnitude = 0;
  std::size_t particle = 0;
};
LargestForce largest_force(const MdState& state);

// Throws cellforce::Error for settings out of range (names the setting and its value).
void check_fire_settings(const FireSettings& settings);

// FIRE's decisions between steps, made from one number per step, the power P = F.v at the step's
// start: the time step, the mixing factor and the count of downhill steps. minimize_fire and the
// device backends' FIRE (MdEngine::minimize) share it, so that they take the same decisions.
class FireSchedule {
 public:
  explicit FireSchedule(const FireSettings& settings);
  // Takes step `step` (0, 1, ...) whose power is `power` (a NaN counts as uphill): grows dt and
  // shrinks alpha after n_delay downhill steps in a row; on an uphill step scales dt by f_dec
  // (not below 0.02 x the initial dt; never within the first n_delay steps) and resets alpha.
  // Returns true for an uphill step: the caller steps the positions back by 0.5 x dt() (the new
  // dt) and sets the velocities to zero before the kick.
  bool take_step(double power, int64_t step);
  double dt() const { return dt_; }
  double alpha() const { return alpha_; }

 private:
  FireSettings s_;
  double dt_min_;  // Guenole et al.'s dt_min = 0.02 dt_MD
  double dt_, alpha_;
  int64_t downhill_ = 0;  // downhill steps in a row (P > 0)
};

// FIRE's errors, one wording for every implementation: a force that is not finite (naming its
// particle), a position that is not finite (particle, axis, value), and no convergence within
// `steps` (naming the particle with the largest force and that force).
[[noreturn]] void throw_fire_force_not_finite(std::size_t particle);
[[noreturn]] void throw_fire_position_not_finite(std::size_t particle, int axis, double value);
[[noreturn]] void throw_fire_not_converged(int64_t steps, const LargestForce& largest, double tolerance);

// What FIRE reads after each force evaluation: the potential energy, the largest |F_i| and
// P = F.v with the velocities at that point.
struct FireEvaluation {
  double energy = 0;
  LargestForce largest;
  double power = 0;
};
// Moves the state by one FIRE step (step back by 0.5 dt and zero the velocities when `uphill`;
// kick, mix with `alpha`, cap, drift, wrap), evaluates the forces there and returns what FIRE reads.
using FireStep = std::function<FireEvaluation(bool uphill, double dt, double alpha)>;

// FIRE's loop, shared by every implementation: from the evaluation at the start, steps until the
// largest force is below the tolerance or max_steps pass, the decisions made by FireSchedule and
// the moves by `step`. Throws for a force that is not finite and, with require_convergence, when
// it does not converge. The caller checks the settings and zeroes the velocities before and after.
FireResult run_fire(const FireSettings& settings, const FireEvaluation& start, const FireStep& step);

// Minimises the potential energy with FIRE until max_i |F_i| < settings.force_tolerance.
// masses: per particle. Positions are wrapped into the box on periodic axes after every step.
// On return state holds the final positions, their forces, and zero velocities (the run then
// draws its own); step and time are left alone. Throws cellforce::Error for settings out of range
// and, unless require_convergence is false, when max_steps pass without converging (naming the
// particle with the largest force and that force; state then holds the last positions and forces).
FireResult minimize_fire(MdState& state, const std::vector<double>& masses, const FireSettings& settings,
                         const ForceEnergyFunction& compute_forces);

}  // namespace cellforce
