// Checks on an MD state before dynamics start from it (state/stable_start.h).
#include "state/stable_start.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/box.h"
#include "core/error.h"
#include "core/text.h"

namespace cellforce {
void check_step_arithmetic(double dt, const std::vector<double>& masses, const std::vector<uint32_t>& types,
                           const ForceField& ff) {
  if (!std::isfinite(dt * dt))
    throw Error("dt = " + format_number(dt) + " makes the step's arithmetic overflow: dt^2 = " +
                format_number(dt * dt) + " is not a finite number (a step moves a particle by dt v + dt^2 F / 2m); "
                "lower dt");
  for (std::size_t i = 0; i < masses.size(); ++i) {
    const double kick = 0.5 * dt / masses[i], move = kick * dt;
    if (std::isfinite(kick) && std::isfinite(move)) continue;
    std::string type;
    if (i < types.size() && types[i] < ff.types.size()) type = " (type " + quote_excerpt(ff.types[types[i]].name) + ")";
    throw Error("the mass " + format_number(masses[i]) + " of particle " + std::to_string(i) + type +
                " with dt = " + format_number(dt) + " makes the step's arithmetic overflow: " +
                (std::isfinite(kick) ? "dt^2 / 2m = " + format_number(move) : "dt / 2m = " + format_number(kick)) +
                " is not a finite number (a step kicks by dt F / 2m and moves by dt v + dt^2 F / 2m); raise the "
                "mass or lower dt");
  }
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

// Pairs with sigma = 0 or epsilon = 0 do not interact (core/lj.h) and set no length.
double smallest_sigma(const ForceField& ff) {
  double smallest = std::numeric_limits<double>::infinity();
  for (std::size_t a = 0; a < ff.num_types(); ++a)
    for (std::size_t b = a; b < ff.num_types(); ++b)
      if (ff.pair_sigma(a, b) > 0.0 && ff.pair_epsilon(a, b) > 0.0) smallest = std::min(smallest, ff.pair_sigma(a, b));
  return smallest;
}

void check_stable_start(const MdState& s, const std::vector<double>& masses, double dt, const ForceField& ff,
                        const std::string& remedy) {
  check_step_arithmetic(dt, masses, s.config.types, ff);
  const FirstStepKick kick = first_step_kick(s, masses, dt);
  const double limit = 0.1 * smallest_sigma(ff);
  if (kick.displacement <= limit) return;

  // The move is (dt^2 / 2m) |F|: either the step's scale dt^2 / 2m is too large for this particle's
  // mass, so that a force of ordinary size (24 epsilon/sigma, two particles at distance sigma)
  // already moves it too far, or the force is beyond that size (overlapping particles).
  const std::size_t p = kick.particle;
  const uint32_t type = p < s.config.types.size() ? s.config.types[p] : 0;
  double contact = 0;  // the largest pair force at r = sigma among the particle type's pairs
  for (std::size_t b = 0; b < ff.num_types(); ++b)
    if (ff.pair_sigma(type, b) > 0.0 && ff.pair_epsilon(type, b) > 0.0)
      contact = std::max(contact, 24.0 * ff.pair_epsilon(type, b) / ff.pair_sigma(type, b));
  const double scale = 0.5 * dt * dt / masses[p];
  if (scale * contact > limit) {
    const std::string name = type < ff.types.size() ? " (type " + quote_excerpt(ff.types[type].name) + ")" : "";
    throw Error("dt = " + format_6g(dt) + " is too long a step for the mass " + format_6g(masses[p]) + " of particle " +
                std::to_string(p) + name + ": a step moves it by dt^2 |F| / 2m = " + format_6g(scale) +
                " x |F|, so that already the force between two particles at distance sigma (24 epsilon/sigma = " +
                format_6g(contact) + ") would move it by " + format_6g(scale * contact) +
                ", more than 0.1 x the smallest sigma (" + format_6g(limit) + "); with this mass dt must be below " +
                format_6g(std::sqrt(2.0 * limit * masses[p] / contact)) + " (lower dt, or check the mass)");
  }

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
                         format_6g(std::sqrt(nearest2));
  throw Error("the dynamics would not be stable from this start: particle " + std::to_string(i) + " has a force of " +
              format_6g(kick.force) + " (" + neighbour + "), so the first step (dt " + format_6g(dt) +
              ") would move it by dt^2 |F| / 2m = " + format_6g(kick.displacement) +
              ", more than 0.1 x the smallest sigma (" + format_6g(limit) + "); " +
              (remedy.empty() ? "the start has overlapping particles: add a [minimize] section to the scene (FIRE "
                                "brings the largest force below its force_tolerance first), or lower dt"
                              : remedy));
}

}  // namespace cellforce
