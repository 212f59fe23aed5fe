#include "md/minimize.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

#include "core/box.h"
#include "core/error.h"

namespace cellforce {
namespace {

std::string number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

void check_settings(const FireSettings& s) {
  auto positive = [](double v, const char* name) {
    if (!(v > 0) || !std::isfinite(v))
      throw Error(std::string("FIRE: ") + name + " must be a finite number > 0, got " + number(v));
  };
  positive(s.force_tolerance, "force_tolerance");
  positive(s.dt, "dt");
  positive(s.dt_max, "dt_max");
  positive(s.max_displacement, "max_displacement");
  positive(s.alpha_start, "alpha_start");
  positive(s.f_alpha, "f_alpha");
  positive(s.f_inc, "f_inc");
  positive(s.f_dec, "f_dec");
  if (s.dt_max < s.dt) throw Error("FIRE: dt_max (" + number(s.dt_max) + ") must be at least dt (" + number(s.dt) + ")");
  if (s.alpha_start >= 1) throw Error("FIRE: alpha_start must be below 1, got " + number(s.alpha_start));
  if (s.f_alpha > 1) throw Error("FIRE: f_alpha must be at most 1, got " + number(s.f_alpha));
  if (s.f_inc < 1) throw Error("FIRE: f_inc must be at least 1, got " + number(s.f_inc));
  if (s.f_dec >= 1) throw Error("FIRE: f_dec must be below 1, got " + number(s.f_dec));
  if (s.max_steps < 0) throw Error("FIRE: max_steps must be at least 0, got " + std::to_string(s.max_steps));
  if (s.n_delay < 0) throw Error("FIRE: n_delay must be at least 0, got " + std::to_string(s.n_delay));
}

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
      if (!std::isfinite(x))
        throw Error("FIRE: particle " + std::to_string(i) + " has a non-finite position (" +
                    std::string(1, "xyz"[a]) + " = " + number(x) + "): its force was not finite");
      if (box.periodic[a]) x = wrap_coordinate(x, length);
    }
  }
}

}  // namespace

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

FireResult minimize_fire(MdState& s, const std::vector<double>& masses, const FireSettings& settings,
                         const ForceEnergyFunction& compute_forces) {
  check_settings(settings);
  const std::size_t n = s.config.size();
  const std::size_t dim = std::size_t(s.config.box.dim);
  const std::size_t nd = n * dim;
  if (masses.size() != n)
    throw Error("FIRE: " + std::to_string(masses.size()) + " masses for " + std::to_string(n) + " particles");

  FireResult result;
  s.velocities.assign(nd, 0.0);
  double energy = compute_forces(s);
  LargestForce fmax = largest_force(s);
  result.initial_energy = energy;
  result.initial_max_force = fmax.magnitude;
  result.initial_max_force_particle = fmax.particle;

  const double dt_min = 0.02 * settings.dt;  // Guenole et al.'s dt_min = 0.02 dt_MD
  double dt = settings.dt;
  double alpha = settings.alpha_start;
  int64_t downhill = 0;  // downhill steps in a row (P > 0)
  int64_t step = 0;
  for (; step < settings.max_steps && !(fmax.magnitude < settings.force_tolerance); ++step) {
    if (!std::isfinite(fmax.magnitude))
      throw Error("FIRE: the force on particle " + std::to_string(fmax.particle) + " is not finite");
    double power = 0;
    for (std::size_t k = 0; k < nd; ++k) power += s.forces[k] * s.velocities[k];
    if (power > 0) {
      if (++downhill > settings.n_delay) {
        dt = std::min(dt * settings.f_inc, settings.dt_max);
        alpha *= settings.f_alpha;
      }
    } else {
      downhill = 0;
      if (step >= settings.n_delay) {  // the initial delay: the first n_delay steps keep dt
        if (dt * settings.f_dec >= dt_min) dt *= settings.f_dec;
        alpha = settings.alpha_start;
      }
      // Back by half a step (with the new dt), where the climb began, and start from rest.
      for (std::size_t k = 0; k < nd; ++k) s.config.positions[k] -= 0.5 * dt * s.velocities[k];
      std::fill(s.velocities.begin(), s.velocities.end(), 0.0);
    }

    // Semi-implicit Euler: kick, mix the velocity towards the force direction, cap, drift.
    for (std::size_t i = 0; i < n; ++i) {
      const double h = dt / masses[i];
      for (std::size_t a = 0; a < dim; ++a) s.velocities[i * dim + a] += h * s.forces[i * dim + a];
    }
    double v2 = 0, f2 = 0;
    for (std::size_t k = 0; k < nd; ++k) {
      v2 += s.velocities[k] * s.velocities[k];
      f2 += s.forces[k] * s.forces[k];
    }
    if (f2 > 0 && std::isfinite(v2)) {
      const double mix = alpha * std::sqrt(v2) / std::sqrt(f2);
      for (std::size_t k = 0; k < nd; ++k) s.velocities[k] = (1 - alpha) * s.velocities[k] + mix * s.forces[k];
    }
    for (std::size_t i = 0; i < n; ++i) {
      double* v = &s.velocities[i * dim];
      double largest = 0;  // |v| as largest component x norm of the scaled vector: no overflow
      for (std::size_t a = 0; a < dim; ++a) largest = std::max(largest, std::abs(v[a]));
      if (largest > 0) {
        double u2 = 0;
        for (std::size_t a = 0; a < dim; ++a) u2 += (v[a] / largest) * (v[a] / largest);
        const double step_length = dt * largest * std::sqrt(u2);
        if (step_length > settings.max_displacement) {
          const double scale = settings.max_displacement / step_length;
          for (std::size_t a = 0; a < dim; ++a) v[a] *= scale;
        }
      }
      for (std::size_t a = 0; a < dim; ++a) s.config.positions[i * dim + a] += dt * v[a];
    }
    wrap_positions(s);
    energy = compute_forces(s);
    fmax = largest_force(s);
  }

  result.steps = step;
  result.final_energy = energy;
  result.final_max_force = fmax.magnitude;
  result.final_max_force_particle = fmax.particle;
  result.converged = fmax.magnitude < settings.force_tolerance;
  if (!result.converged && settings.require_convergence)
    throw Error("FIRE did not converge in " + std::to_string(step) + " steps: particle " +
                std::to_string(fmax.particle) + " still has the largest force, |F| = " + number(fmax.magnitude) +
                " (tolerance " + number(settings.force_tolerance) + "); raise max_steps or force_tolerance");
  std::fill(s.velocities.begin(), s.velocities.end(), 0.0);
  return result;
}

FirstStepKick first_step_kick(const MdState& s, const std::vector<double>& masses, double dt) {
  const std::size_t dim = std::size_t(s.config.box.dim);
  FirstStepKick out;
  out.displacement = -1;
  for (std::size_t i = 0; i < s.config.size(); ++i) {
    double f2 = 0;
    for (std::size_t a = 0; a < dim; ++a) f2 += s.forces[i * dim + a] * s.forces[i * dim + a];
    const double f = std::sqrt(f2);
    const double d = 0.5 * dt * dt * f / masses[i];
    if (!(d <= out.displacement)) {  // a NaN is the largest of all
      out = FirstStepKick{d, i, f};
      if (std::isnan(d)) break;
    }
  }
  if (out.displacement < 0) out = FirstStepKick{};
  return out;
}

double smallest_sigma(const ForceField& ff) {
  double smallest = std::numeric_limits<double>::infinity();
  for (std::size_t a = 0; a < ff.num_types(); ++a)
    for (std::size_t b = a; b < ff.num_types(); ++b) smallest = std::min(smallest, ff.pair_sigma(a, b));
  return smallest;
}

void check_stable_start(const MdState& s, const std::vector<double>& masses, double dt, const ForceField& ff,
                        const std::string& remedy) {
  const FirstStepKick kick = first_step_kick(s, masses, dt);
  const double limit = 0.1 * smallest_sigma(ff);
  if (kick.displacement <= limit) return;

  // The nearest neighbour of the particle (minimum image on periodic axes): usually the overlap.
  const Box& box = s.config.box;
  const std::size_t dim = std::size_t(box.dim);
  const std::size_t i = kick.particle;
  std::size_t nearest = i;
  double nearest2 = std::numeric_limits<double>::infinity();
  for (std::size_t j = 0; j < s.config.size(); ++j) {
    if (j == i) continue;
    double r2 = 0;
    for (std::size_t a = 0; a < dim; ++a) {
      const double inv = box.periodic[a] ? 1.0 / box.length[a] : 0.0;
      const double d = separation(s.config.positions[i * dim + a], s.config.positions[j * dim + a],
                                  box.length[a], inv);
      r2 += d * d;
    }
    if (r2 < nearest2) nearest2 = r2, nearest = j;
  }
  const std::string neighbour =
      nearest == i ? "it has no neighbour"
                   : "its nearest neighbour is particle " + std::to_string(nearest) + " at distance " +
                         number(std::sqrt(nearest2));
  throw Error("the dynamics would not be stable from this start: particle " + std::to_string(i) + " has a force of " +
              number(kick.force) + " (" + neighbour + "), so the first step (dt " + number(dt) +
              ") would move it by dt^2 |F| / 2m = " + number(kick.displacement) + ", more than 0.1 x the smallest sigma (" +
              number(limit) + "); " +
              (remedy.empty() ? "the start has overlapping particles: add a [minimize] section to the scene (FIRE "
                                "brings the largest force below its force_tolerance first), or lower dt"
                              : remedy));
}

}  // namespace cellforce
