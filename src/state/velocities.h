// Velocities of an MD state: the Maxwell-Boltzmann start, the centre-of-mass momentum, the kinetic
// energy and the degrees of freedom its temperature counts.
//
// The initial velocities are counter-based random numbers (core/random.h counter_normal, stream
// 0, index particle * dim + axis): the same for a seed whatever the thread count.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "state/md_state.h"

namespace cellforce {

// Degrees of freedom of the kinetic temperature: dim (n - 1) when the centre-of-mass momentum
// is removed and conserved (NVE), dim n under a Langevin thermostat (which does not conserve
// it); at least 1.
double degrees_of_freedom(std::size_t n, int dim, bool com_conserved = true);

// Maxwell-Boltzmann velocities at temperature kT (energy units), centre-of-mass momentum removed,
// then scaled so that the kinetic temperature (with the degrees of freedom of com_conserved) is
// exactly kT. masses: per particle.
void initialize_velocities(MdState& state, const std::vector<double>& masses, double kT, uint64_t seed,
                           bool com_conserved = true);

// Removes the centre-of-mass momentum (mass-weighted).
void remove_com_momentum(MdState& state, const std::vector<double>& masses);

double kinetic_energy(const MdState& state, const std::vector<double>& masses);

}  // namespace cellforce
