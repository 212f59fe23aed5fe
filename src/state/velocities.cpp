// Velocities of an MD state (state/velocities.h).
#include "state/velocities.h"

#include <algorithm>
#include <cmath>

#include "core/random.h"

namespace cellforce {

double degrees_of_freedom(std::size_t n, int dim, bool com_conserved) {
  return std::max(1.0, double(dim) * (double(n) - (com_conserved ? 1.0 : 0.0)));
}

void remove_com_momentum(MdState& s, const std::vector<double>& masses) {
  const int dim = s.config.box.dim;
  const std::size_t n = s.config.size();
  if (n == 0) return;
  double p[3] = {0, 0, 0}, mtotal = 0;
  for (std::size_t i = 0; i < n; ++i) {
    mtotal += masses[i];
    for (int a = 0; a < dim; ++a) p[a] += masses[i] * s.velocities[i * dim + a];
  }
  for (std::size_t i = 0; i < n; ++i)
    for (int a = 0; a < dim; ++a) s.velocities[i * dim + a] -= p[a] / mtotal;
}

double kinetic_energy(const MdState& s, const std::vector<double>& masses) {
  const int dim = s.config.box.dim;
  double ke = 0;
  for (std::size_t i = 0; i < s.config.size(); ++i) {
    double v2 = 0;
    for (int a = 0; a < dim; ++a) v2 += s.velocities[i * dim + a] * s.velocities[i * dim + a];
    ke += 0.5 * masses[i] * v2;
  }
  return ke;
}

void initialize_velocities(MdState& s, const std::vector<double>& masses, double kT, uint64_t seed,
                           bool com_conserved) {
  const int dim = s.config.box.dim;
  const std::size_t n = s.config.size();
  s.velocities.assign(n * std::size_t(dim), 0.0);
  for (std::size_t i = 0; i < n; ++i)
    for (int a = 0; a < dim; ++a)
      s.velocities[i * dim + a] = std::sqrt(kT / masses[i]) * counter_normal(seed, /*stream=*/0, i * dim + a);
  remove_com_momentum(s, masses);
  const double ke = kinetic_energy(s, masses);
  const double target = 0.5 * degrees_of_freedom(n, dim, com_conserved) * kT;
  const double scale = ke > 0 ? std::sqrt(target / ke) : 0.0;
  for (double& v : s.velocities) v *= scale;
}

}  // namespace cellforce
