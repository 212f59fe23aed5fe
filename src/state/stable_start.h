// Checks on an MD state before dynamics start from it: that the time step's arithmetic stays finite
// for the particles' masses, and that the first step would not throw a particle out of its
// neighbourhood (an overlap, or a dt too long for a mass). The API's set_state and set_integrator
// make the first check; `cellforce run` makes the second before any output is written.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "core/force_field.h"
#include "state/md_state.h"

namespace cellforce {

// Refuses a time step whose arithmetic overflows for these masses: a step kicks by (dt / 2m) F and
// moves a particle by dt v + dt^2 F / 2m, so dt^2 and, for every particle's mass m, dt / 2m and
// dt^2 / 2m must be finite numbers. Throws cellforce::Error naming dt, or the particle, its type
// (ff's name for types[i]) and its mass. Called where dt and the masses enter: the API's
// set_state and set_integrator (so `cellforce run` meets it before any output), and
// check_stable_start.
void check_step_arithmetic(double dt, const std::vector<double>& masses, const std::vector<uint32_t>& types,
                           const ForceField& ff);

// The first time step's displacement due to the force alone, dt^2 |F_i| / (2 m_i): velocity
// Verlet and BAOAB both move a particle by dt v + dt^2 F / (2 m) in a step.
struct FirstStepKick {
  double displacement = 0;  // the largest over the particles
  std::size_t particle = 0;
  double force = 0;         // |F| of that particle
};
FirstStepKick first_step_kick(const MdState& state, const std::vector<double>& masses, double dt);

// The smallest pair sigma of the force field over the pairs that interact (sigma and epsilon > 0;
// explicit pairs included); infinity when none does.
double smallest_sigma(const ForceField& ff);

// Refuses to start dynamics from state.forces when the first step would move a particle by more
// than 0.1 x the smallest sigma, or when the step's arithmetic overflows (check_step_arithmetic).
// The cause it names is the factor of dt^2 |F| / 2m that is out of range: where even the force of
// a pair at distance sigma (24 epsilon/sigma) would move the particle too far, dt and its mass
// (with the dt that mass allows); otherwise the force, an overlap: the particle, its force, its
// nearest neighbour (minimum image) and their distance, the displacement, and what to do (a
// [minimize] section, or a lower dt; `remedy`, when given, replaces that advice). Lattice starts
// (forces ~0) and random starts with a minimum distance of ~0.8 sigma (forces up to ~1e3) pass at
// dt 0.005 (the limit there is ~8e3).
void check_stable_start(const MdState& state, const std::vector<double>& masses, double dt,
                        const ForceField& ff, const std::string& remedy = "");

}  // namespace cellforce
