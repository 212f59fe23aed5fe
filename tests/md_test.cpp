// Molecular dynamics: NVE energy conservation (drift and fluctuation against stated bounds, in
// double and single precision), the Langevin thermostat's temperature against its target within
// the statistical error, initial velocities, and reproducibility for a seed.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numeric>

#include "cpu/engine.h"
#include "md/md.h"
#include "series.h"
#include "scene/lattice.h"

namespace {

using namespace cellforce;

struct Trace {
  std::vector<double> times, energies, temperatures;  // per sample; energies per particle
};

// An LJ liquid of 4 cells^3 particles (fcc at density 0.8442, T0 = 1.44, rc 2.5 force-shifted
// by default), run for `steps`, sampled every `every` steps.
Trace simulate(Precision precision, bool langevin, double dt, int64_t steps, int64_t every, double kT = 1.44,
               CutoffMode mode = CutoffMode::kForceShift, uint64_t seed = 12345, int cells = 5) {
  MdState s;
  s.config = make_lattice(Lattice::kFcc, cells, 0.8442);
  const std::size_t n = s.config.size();
  std::vector<double> masses(n, 1.0);
  ForceField ff;
  ff.cutoff = 2.5;
  ff.mode = mode;
  CpuOptions options;
  options.precision = precision;
  CpuEngine engine(options);
  const SystemView view = s.config.view();
  ForceResult result;
  initialize_velocities(s, masses, 1.44, seed);
  IntegratorSettings settings;
  settings.langevin = langevin;
  settings.dt = dt;
  settings.kT = kT;
  settings.friction = 1.0;
  settings.seed = seed;
  bool observe = true;
  auto compute = [&](MdState& st) {
    engine.evaluate(view, ff, Request{observe, observe}, result);
    st.forces = result.forces;
  };
  compute(s);
  Trace run;
  for (int64_t k = 1; k <= steps; ++k) {
    observe = k % every == 0;
    advance(s, masses, settings, compute);
    if (observe) {
      const ThermoValues t = thermo(s, masses, result, !langevin);
      run.times.push_back(s.time);
      run.energies.push_back(t.total / double(n));
      run.temperatures.push_back(t.temperature);
    }
  }
  return run;
}

using cftest::rms_about_mean;
using cftest::slope;

// NVE, force-shifted LJ liquid (500 particles), dt 0.005, 20,000 steps (t = 100): the total
// energy per particle drifts by less than 1e-6 per unit time and fluctuates (RMS) by less than
// 2e-4, in double and in single precision (the fastest). Measured on the development machine:
// drift -4.0e-8 (double) and 1.5e-7 (single), RMS 7.9e-5 in both (the test prints its numbers).
TEST(Nve, EnergyIsConservedInDoubleAndSingle) {
  for (Precision p : {Precision::kDouble, Precision::kSingle}) {
    SCOPED_TRACE(to_string(p));
    const Trace r = simulate(p, false, 0.005, 20000, 20);
    const double drift = slope(r.times, r.energies);
    const double rms = rms_about_mean(r.energies);
    std::printf("NVE %s: drift %.3e per particle per unit time, RMS fluctuation %.3e per particle\n",
                to_string(p), drift, rms);
    EXPECT_LT(std::abs(drift), 1e-6);
    EXPECT_LT(rms, 2e-4);
  }
}

// The same bounds fail for plain truncation (the force jumps at rc), so they measure something.
TEST(Nve, BoundsDetectTheTruncationJump) {
  const Trace r = simulate(Precision::kDouble, false, 0.005, 5000, 20, 1.44, CutoffMode::kTruncate);
  const double rms = rms_about_mean(r.energies);
  std::printf("NVE truncate: RMS fluctuation %.3e per particle\n", rms);
  EXPECT_GT(rms, 2e-4);
}

// Langevin (BAOAB, gamma 1) at kT = 1.2 from T0 = 1.44, 256 particles: after 2,000 steps of
// equilibration, the mean kinetic temperature (dim N degrees of freedom) over 20,000 steps is
// within 3 standard errors (block averages of 1,000 steps) of the target, and the standard error
// itself is below 1% of it.
TEST(Langevin, MeanTemperatureIsTheTarget) {
  const double kT = 1.2;
  const Trace r = simulate(Precision::kDouble, true, 0.005, 22000, 10, kT, CutoffMode::kForceShift, 12345, 4);
  const std::size_t skip = 200, block = 100;  // samples: every 10 steps
  std::vector<double> means;
  for (std::size_t b = skip; b + block <= r.temperatures.size(); b += block)
    means.push_back(std::accumulate(r.temperatures.begin() + long(b), r.temperatures.begin() + long(b + block), 0.0) /
                    double(block));
  const double mean = std::accumulate(means.begin(), means.end(), 0.0) / double(means.size());
  const double err = rms_about_mean(means) / std::sqrt(double(means.size() - 1));
  std::printf("Langevin: mean T %.5f (target %.5f), standard error %.5f over %zu blocks\n", mean, kT, err,
              means.size());
  EXPECT_LT(err, 0.01 * kT);
  EXPECT_LT(std::abs(mean - kT), 3 * err);
}

TEST(InitialVelocities, ExactTemperatureAndNoDrift) {
  MdState s;
  s.config = make_lattice(Lattice::kFcc, 4, 0.8442);
  std::vector<double> masses(s.config.size());
  for (std::size_t i = 0; i < masses.size(); ++i) masses[i] = 1.0 + double(i % 3);
  initialize_velocities(s, masses, 1.7, 9);
  double p[3] = {0, 0, 0};
  for (std::size_t i = 0; i < masses.size(); ++i)
    for (int a = 0; a < 3; ++a) p[a] += masses[i] * s.velocities[3 * i + a];
  for (double c : p) EXPECT_NEAR(c, 0.0, 1e-12);
  const double T = 2 * kinetic_energy(s, masses) / degrees_of_freedom(masses.size(), 3);
  EXPECT_NEAR(T, 1.7, 1e-12);
}

// The counter-based normals have mean 0 and variance 1 (10^6 draws: 5 standard errors).
TEST(CounterNormal, StandardNormal) {
  double sum = 0, sum2 = 0;
  const int n = 1000000;
  for (int k = 0; k < n; ++k) {
    const double x = counter_normal(77, uint64_t(k / 1000), uint64_t(k % 1000));
    sum += x;
    sum2 += x * x;
  }
  EXPECT_NEAR(sum / n, 0.0, 5.0 / std::sqrt(double(n)));
  EXPECT_NEAR(sum2 / n, 1.0, 5.0 * std::sqrt(2.0 / n));
}

// The same seed gives the same trajectory bit for bit; another seed does not.
TEST(Langevin, ReproducibleForASeed) {
  const Trace a = simulate(Precision::kDouble, true, 0.005, 200, 50, 1.0);
  const Trace b = simulate(Precision::kDouble, true, 0.005, 200, 50, 1.0);
  const Trace c = simulate(Precision::kDouble, true, 0.005, 200, 50, 1.0, CutoffMode::kForceShift, 999);
  EXPECT_EQ(a.energies, b.energies);
  EXPECT_NE(a.energies, c.energies);
}

}  // namespace
