#include "md/md.h"

#include <cmath>
#include <limits>

#include "core/box.h"
#include "core/error.h"
#include "core/random.h"
#include "core/text.h"
#include "md/verlet_step.h"

namespace cellforce {
namespace {

// Moves every particle by h * v, in one pass over the arrays (md/verlet_step.h drift_value). A
// displacement that is not finite or beyond drift_limit (share x the box edge on a periodic axis,
// share x the cutoff on an open one) means the integration diverged: the check compares
// displacements, never raw coordinates, so an unwrapped start is no divergence. With `wrap` (a
// step's last drift) each moved position is then wrapped into [0, L) on periodic axes; one that is
// no longer finite is named.
void drift(MdState& s, double h, double share, bool wrap, double cutoff) {
  const Box& box = s.config.box;
  const int dim = box.dim;
  const std::size_t n = s.config.size();
  DriftAxis axis[kMaxDim];
  for (int a = 0; a < dim; ++a)
    axis[a] = DriftAxis{box.length[a], drift_limit(box, a, cutoff, share),
                        box.periodic[a] ? 1.0 / box.length[a] : 0.0, box.periodic[a]};
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < dim; ++a) {
      const std::size_t k = i * dim + a;
      const double v = s.velocities[k];
      bool bad = false;
      const double x = drift_value(s.config.positions[k], v, h, axis[a], wrap, bad);
      if (bad) {
        const double dx = mul_rn(h, v);
        // A position that left the finite numbers is stored, as the device's drift stores it; a
        // displacement past the limit leaves the particle where it was.
        if (std::abs(dx) <= axis[a].most) s.config.positions[k] = x;
        throw Error(diverged_message(i, a, dx, x, box, cutoff, share));
      }
      s.config.positions[k] = x;
    }
  }
}

}  // namespace

double drift_limit(const Box& box, int axis, double cutoff, double share) {
  return share * (box.periodic[axis] ? box.length[axis] : cutoff);
}

std::string diverged_message(std::size_t particle, int axis, double displacement, double position, const Box& box,
                             double cutoff, double share) {
  const std::string who = "particle " + std::to_string(particle);
  const std::string along = std::string(1, "xyz"[axis]);
  const double most = drift_limit(box, axis, cutoff, share);
  std::string what;
  if (std::abs(displacement) <= most) {  // a finite move from a position that ran out of the doubles
    what = who + " left the finite numbers in one step (" + along +
           (std::isnan(position) ? "" : " = " + format_number(position)) + ")";  // nan: not known
  } else {
    const std::string half = share == 1.0 ? "" : "half ";
    what = who + " moved " + format_number(displacement) + " along " + along + " in one drift, more than " +
           format_number(most) + " (" +
           (box.periodic[axis] ? half + "the box edge" : half + "the cutoff, on an open axis: a longer move can pass "
                                                                 "through a partner without their force acting") +
           (share == 1.0 ? "" : ", for each of a step's two half drifts") + ")";
  }
  return what + ": the integration diverged; lower dt, or remove overlaps first";
}

ThermoValues thermo(const MdState& s, const std::vector<double>& masses, const ForceResult& result,
              bool com_conserved) {
  const int dim = s.config.box.dim;
  ThermoValues t;
  t.kinetic = kinetic_energy(s, masses);
  t.potential = result.energy;
  t.total = t.kinetic + t.potential;
  t.temperature = 2.0 * t.kinetic / degrees_of_freedom(s.config.size(), dim, com_conserved);
  double trace = 0;
  for (int a = 0; a < dim; ++a) trace += result.virial[a][a];
  bool closed = true;
  for (int a = 0; a < dim; ++a) closed = closed && s.config.box.periodic[a];
  t.pressure = closed ? (2.0 * t.kinetic + trace) / (dim * s.config.box.volume())
                      : std::numeric_limits<double>::quiet_NaN();
  return t;
}

void advance(MdState& s, const std::vector<double>& masses, const IntegratorSettings& settings,
             const std::function<void(MdState&)>& compute_forces, double cutoff) {
  const int dim = s.config.box.dim;
  const std::size_t n = s.config.size();
  const double dt = settings.dt;
  auto kick = [&](double h) {
    for (std::size_t i = 0; i < n; ++i)
      for (int a = 0; a < dim; ++a) {
        double& v = s.velocities[i * dim + a];
        v = kick_value(v, s.forces[i * dim + a], masses[i], h, 1);
      }
  };
  kick(0.5 * dt);
  if (settings.langevin) {
    drift(s, 0.5 * dt, 0.5, false, cutoff);  // two half drifts of at most half the limit: a step of at most it
    const double c1 = std::exp(-settings.friction * dt);
    const double c2 = std::sqrt(1.0 - c1 * c1);
    // stream = step number + 1 (stream 0 draws the initial velocities)
    const uint64_t stream = uint64_t(s.step) + 1;
    for (std::size_t i = 0; i < n; ++i) {
      const double sigma = thermostat_sigma(c2, settings.kT, masses[i]);
      for (int a = 0; a < dim; ++a) {
        double& v = s.velocities[i * dim + a];
        v = thermostat_value(v, c1, sigma, counter_normal(settings.seed, stream, i * dim + a));
      }
    }
    drift(s, 0.5 * dt, 0.5, true, cutoff);
  } else {
    drift(s, dt, 1.0, true, cutoff);
  }
  s.step += 1;
  s.time = double(s.step) * dt;  // not summed: the same after a restart
  compute_forces(s);
  kick(0.5 * dt);
}

}  // namespace cellforce
