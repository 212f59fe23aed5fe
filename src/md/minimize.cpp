#include "md/minimize.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "core/box.h"
#include "core/error.h"
#include "core/text.h"
#include "md/fire_step.h"

namespace cellforce {
namespace {

// Positions into [0, L) on periodic axes. Every FIRE step moves a particle by at most
// 1.5 x max_displacement (half a step back, then one forward), so a coordinate that is not
// finite here means the forces were not.
void wrap_positions(MdState& s) {
  const Box& box = s.config.box;
  const int dim = box.dim;
  const std::size_t n = s.config.size();
  for (int a = 0; a < dim; ++a) {
    const double length = box.length[a];
    for (std::size_t i = 0; i < n; ++i) {
      double& x = s.config.positions[i * std::size_t(dim) + std::size_t(a)];
      if (!std::isfinite(x)) throw_fire_position_not_finite(i, a, x);
      if (box.periodic[a]) x = wrap_coordinate(x, length);
    }
  }
}

}  // namespace

void check_fire_settings(const FireSettings& s) {
  auto positive = [](double v, const char* name) {
    if (!(v > 0) || !std::isfinite(v))
      throw Error(std::string("FIRE: ") + name + " must be a finite number > 0, got " + format_6g(v));
  };
  positive(s.force_tolerance, "force_tolerance");
  positive(s.dt, "dt");
  positive(s.dt_max, "dt_max");
  positive(s.max_displacement, "max_displacement");
  positive(s.alpha_start, "alpha_start");
  positive(s.f_alpha, "f_alpha");
  positive(s.f_inc, "f_inc");
  positive(s.f_dec, "f_dec");
  if (s.dt_max < s.dt)
    throw Error("FIRE: dt_max (" + format_6g(s.dt_max) + ") must be at least dt (" + format_6g(s.dt) + ")");
  if (s.alpha_start >= 1) throw Error("FIRE: alpha_start must be below 1, got " + format_6g(s.alpha_start));
  if (s.f_alpha > 1) throw Error("FIRE: f_alpha must be at most 1, got " + format_6g(s.f_alpha));
  if (s.f_inc < 1) throw Error("FIRE: f_inc must be at least 1, got " + format_6g(s.f_inc));
  if (s.f_dec >= 1) throw Error("FIRE: f_dec must be below 1, got " + format_6g(s.f_dec));
  if (s.max_steps < 0) throw Error("FIRE: max_steps must be at least 0, got " + std::to_string(s.max_steps));
  if (s.n_delay < 0) throw Error("FIRE: n_delay must be at least 0, got " + std::to_string(s.n_delay));
}

FireSchedule::FireSchedule(const FireSettings& settings)
    : s_(settings), dt_min_(0.02 * settings.dt), dt_(settings.dt), alpha_(settings.alpha_start) {}

bool FireSchedule::take_step(double power, int64_t step) {
  if (power > 0) {
    if (++downhill_ > s_.n_delay) {
      dt_ = std::min(dt_ * s_.f_inc, s_.dt_max);
      alpha_ *= s_.f_alpha;
    }
    return false;
  }
  downhill_ = 0;
  if (step >= s_.n_delay) {  // the initial delay: the first n_delay steps keep dt
    if (dt_ * s_.f_dec >= dt_min_) dt_ *= s_.f_dec;
    alpha_ = s_.alpha_start;
  }
  return true;
}

void throw_fire_force_not_finite(std::size_t particle) {
  throw Error("FIRE: the force on particle " + std::to_string(particle) + " is not finite");
}

void throw_fire_position_not_finite(std::size_t particle, int axis, double value) {
  throw Error("FIRE: particle " + std::to_string(particle) + " has a non-finite position (" +
              std::string(1, "xyz"[axis]) + " = " + format_6g(value) + "): its force was not finite");
}

void throw_fire_not_converged(int64_t steps, const LargestForce& largest, double tolerance) {
  throw Error("FIRE did not converge in " + std::to_string(steps) + " steps: particle " +
              std::to_string(largest.particle) + " still has the largest force, |F| = " + format_6g(largest.magnitude) +
              " (tolerance " + format_6g(tolerance) + "); raise max_steps or force_tolerance");
}

LargestForce largest_force(const MdState& s) {
  const std::size_t dim = std::size_t(s.config.box.dim);
  LargestForce out;
  double largest2 = -1;
  for (std::size_t i = 0; i < s.config.size(); ++i) {
    double f2 = 0;
    for (std::size_t a = 0; a < dim; ++a) f2 += s.forces[i * dim + a] * s.forces[i * dim + a];
    if (!(f2 <= largest2)) {  // a NaN is the largest of all
      largest2 = f2;
      out.particle = i;
      if (std::isnan(f2)) break;
    }
  }
  out.magnitude = largest2 < 0 ? 0.0 : std::sqrt(largest2);
  return out;
}

FireResult run_fire(const FireSettings& settings, const FireEvaluation& start, const FireStep& step) {
  FireResult result;
  FireEvaluation now = start;
  result.initial_energy = now.energy;
  result.initial_max_force = now.largest.magnitude;
  result.initial_max_force_particle = now.largest.particle;
  FireSchedule schedule(settings);
  int64_t k = 0;
  for (; k < settings.max_steps && !(now.largest.magnitude < settings.force_tolerance); ++k) {
    if (!std::isfinite(now.largest.magnitude)) throw_fire_force_not_finite(now.largest.particle);
    const bool uphill = schedule.take_step(now.power, k);
    now = step(uphill, schedule.dt(), schedule.alpha());
  }
  result.steps = k;
  result.final_energy = now.energy;
  result.final_max_force = now.largest.magnitude;
  result.final_max_force_particle = now.largest.particle;
  result.converged = now.largest.magnitude < settings.force_tolerance;
  if (!result.converged && settings.require_convergence)
    throw_fire_not_converged(k, now.largest, settings.force_tolerance);
  return result;
}

FireResult minimize_fire(MdState& s, const std::vector<double>& masses, const FireSettings& settings,
                         const ForceEnergyFunction& compute_forces) {
  check_fire_settings(settings);
  const std::size_t n = s.config.size();
  const std::size_t dim = std::size_t(s.config.box.dim);
  const std::size_t nd = n * dim;
  if (masses.size() != n)
    throw Error("FIRE: " + std::to_string(masses.size()) + " masses for " + std::to_string(n) + " particles");

  s.velocities.assign(nd, 0.0);
  auto evaluate = [&] {  // the velocities are zero or unchanged since the step: P from them
    FireEvaluation e;
    e.energy = compute_forces(s);
    e.largest = largest_force(s);
    for (std::size_t k = 0; k < nd; ++k) e.power += s.forces[k] * s.velocities[k];
    return e;
  };
  const FireResult result = run_fire(settings, evaluate(), [&](bool uphill, double dt, double alpha) {
    double* x = s.config.positions.data();
    double* v = s.velocities.data();
    const double* f = s.forces.data();
    const int d = int(dim);
    // Uphill: back by half a step (with the new dt), where the climb began, and start from rest.
    // Then the semi-implicit Euler step: kick, mix the velocity towards the force direction, cap,
    // drift (md/fire_step.h, per particle).
    for (std::size_t i = 0; i < n; ++i) {
      if (uphill) fire_step_back(x + i * dim, v + i * dim, 0.5 * dt, d);
      fire_kick(v + i * dim, f + i * dim, dt, masses[i], d);
    }
    double v2 = 0, f2 = 0;
    for (std::size_t k = 0; k < nd; ++k) {
      v2 += v[k] * v[k];
      f2 += f[k] * f[k];
    }
    double mix = 0;
    const bool mixes = fire_mix_factor(alpha, v2, f2, mix);
    for (std::size_t i = 0; i < n; ++i) {
      if (mixes) fire_mix(v + i * dim, f + i * dim, alpha, mix, d);
      fire_cap(v + i * dim, dt, settings.max_displacement, d);
      fire_drift(x + i * dim, v + i * dim, dt, d);
    }
    wrap_positions(s);
    return evaluate();
  });
  std::fill(s.velocities.begin(), s.velocities.end(), 0.0);
  return result;
}

}  // namespace cellforce
