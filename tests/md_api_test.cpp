// Molecular dynamics through the public API (Context::set_state / step / thermo / get_state) on
// every backend here: NVE energy conservation and the Langevin temperature with the bounds of
// md_test.cpp, two runs of one setup bitwise equal, the device-resident CUDA run equal to the CPU
// run to round-off over its first steps, and a diverging run named with its particle and steps.
// The CUDA instances skip where no CUDA device can be used.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cellforce/cellforce.hpp>

#include <cmath>
#include <cstdio>
#include <numeric>
#include <string>
#include <vector>

#ifdef CELLFORCE_HAVE_CUDA
#include "engine.h"  // cuda/engine.h: GpuEngine::unavailable
#endif
#include "core/engine_options.h"
#include "md/md.h"
#include "series.h"
#include "scene/lattice.h"

namespace {

namespace cf = cellforce;
using ::testing::HasSubstr;

struct RunSetup {
  cf::Backend backend = cf::Backend::kCpu;
  cf::Precision precision = cf::Precision::kDouble;
  cf::IntegratorOptions integrator;
  int cells = 5;  // fcc cells per axis at density 0.8442: 4 cells^3 particles
  uint64_t seed = 12345;
};

std::string unavailable(cf::Backend backend) {
#ifdef CELLFORCE_HAVE_CUDA
  if (backend == cf::Backend::kCuda) return cf::GpuEngine::unavailable();
  return {};
#else
  return backend == cf::Backend::kCuda ? "this build has no CUDA" : "";
#endif
}

// A context holding the force-shifted LJ liquid of md_test.cpp with T0 = 1.44 velocities.
cf::Context liquid(const RunSetup& s, std::size_t* n_out = nullptr) {
  cf::MdState state;
  state.config = cf::make_lattice(cf::Lattice::kFcc, s.cells, 0.8442);
  const std::size_t n = state.config.size();
  std::vector<double> masses(n, 1.0);
  cf::initialize_velocities(state, masses, 1.44, s.seed, s.integrator.kind == cf::Integrator::kVerlet);
  cf::Context ctx(3);
  const bool periodic[3] = {true, true, true};
  ctx.set_box(state.config.box.length, periodic);
  ctx.set_cutoff(2.5, cf::CutoffMode::kForceShift);
  ctx.add_type("A", 1.0, 1.0);
  ctx.set_backend(s.backend);
  ctx.set_precision(s.precision);
  ctx.set_integrator(s.integrator);
  ctx.set_state(n, state.config.positions.data(), state.velocities.data(), nullptr, masses.data());
  if (n_out) *n_out = n;
  return ctx;
}

using cftest::rms_about_mean;
using cftest::slope;

class MdApi : public ::testing::TestWithParam<cf::Backend> {
 protected:
  void SetUp() override {
    const std::string why = unavailable(GetParam());
    if (!why.empty()) GTEST_SKIP() << why;
  }
};

// NVE (500 particles, dt 0.005, 20,000 steps, sampled every 20): the bounds of md_test.cpp's
// Nve.EnergyIsConservedInDoubleAndSingle, in double and mixed precision.
TEST_P(MdApi, NveConservesEnergy) {
  if (GetParam() == cf::Backend::kCpu) GTEST_SKIP() << "md_test.cpp runs these bounds on the host integrator";
  for (cf::Precision p : {cf::Precision::kDouble, cf::Precision::kMixed}) {
    SCOPED_TRACE(cf::to_string(p));
    RunSetup s;
    s.backend = GetParam();
    s.precision = p;
    std::size_t n = 0;
    cf::Context ctx = liquid(s, &n);
    std::vector<double> times, energies;
    for (int k = 1; k <= 1000; ++k) {
      ctx.step(20);
      const cf::Thermo t = ctx.thermo();
      times.push_back(0.005 * double(ctx.current_step()));
      energies.push_back(t.total / double(n));
    }
    const double drift = slope(times, energies), rms = rms_about_mean(energies);
    std::printf("NVE %s %s: drift %.3e per particle per unit time, RMS %.3e\n", cf::to_string(GetParam()),
                cf::to_string(p), drift, rms);
    EXPECT_EQ(ctx.current_step(), 20000);
    EXPECT_LT(std::abs(drift), 1e-6);
    EXPECT_LT(rms, 2e-4);
  }
}

// Langevin (BAOAB, gamma 1, kT 1.2, 256 particles): md_test.cpp's bounds on the mean temperature.
TEST_P(MdApi, LangevinHoldsTheTargetTemperature) {
  if (GetParam() == cf::Backend::kCpu) GTEST_SKIP() << "md_test.cpp runs these bounds on the host integrator";
  RunSetup s;
  s.backend = GetParam();
  s.cells = 4;
  s.integrator.kind = cf::Integrator::kLangevin;
  s.integrator.temperature = 1.2;
  s.integrator.friction = 1.0;
  s.integrator.seed = 12345;
  cf::Context ctx = liquid(s);
  ctx.step(2000, false);
  std::vector<double> means;
  for (int b = 0; b < 20; ++b) {
    double sum = 0;
    for (int k = 0; k < 100; ++k) {
      ctx.step(10);
      sum += ctx.thermo().temperature;
    }
    means.push_back(sum / 100);
  }
  const double mean = std::accumulate(means.begin(), means.end(), 0.0) / double(means.size());
  const double err = rms_about_mean(means) / std::sqrt(double(means.size() - 1));
  std::printf("Langevin %s: mean T %.5f (target 1.2), standard error %.5f\n", cf::to_string(GetParam()), mean, err);
  EXPECT_LT(err, 0.01 * 1.2);
  EXPECT_LT(std::abs(mean - 1.2), 3 * err);
}

// The same setup twice gives the same state bit for bit (Langevin: the noise is keyed by step and
// particle, and the force sums have a fixed order); another seed does not.
TEST_P(MdApi, RepeatIsBitwise) {
  auto final_state = [&](uint64_t seed) {
    RunSetup s;
    s.backend = GetParam();
    s.precision = cf::Precision::kMixed;
    s.integrator.kind = cf::Integrator::kLangevin;
    s.integrator.seed = seed;
    std::size_t n = 0;
    cf::Context ctx = liquid(s, &n);
    ctx.step(37, false);
    ctx.step(63);
    std::vector<double> x(3 * n), v(3 * n), f(3 * n);
    ctx.get_state(x.data(), v.data(), f.data());
    x.insert(x.end(), v.begin(), v.end());
    x.insert(x.end(), f.begin(), f.end());
    x.push_back(ctx.thermo().potential);
    return x;
  };
  const std::vector<double> a = final_state(7), b = final_state(7), c = final_state(8);
  EXPECT_TRUE(a == b) << "two runs of one setup differ";
  EXPECT_FALSE(a == c);
}

// The backend's run follows the CPU's (the reference integrator on host arrays) to round-off:
// 50 NVE steps in double, positions within 1e-9 and the energies within 1e-10 relative.
TEST_P(MdApi, FollowsTheCpuRun) {
  RunSetup s;
  s.backend = GetParam();
  std::size_t n = 0;
  cf::Context ctx = liquid(s, &n);
  RunSetup cpu = s;
  cpu.backend = cf::Backend::kCpu;
  cf::Context ref = liquid(cpu);
  ctx.step(50);
  ref.step(50);
  std::vector<double> x(3 * n), y(3 * n);
  ctx.get_state(x.data(), nullptr, nullptr);
  ref.get_state(y.data(), nullptr, nullptr);
  const double edge = cf::make_lattice(cf::Lattice::kFcc, s.cells, 0.8442).box.length[0];
  double worst = 0;
  for (std::size_t k = 0; k < x.size(); ++k) {
    double d = std::abs(x[k] - y[k]);
    d = std::min(d, std::abs(d - edge));  // one wrapped to 0, the other to just below the edge
    worst = std::max(worst, d);
  }
  EXPECT_LT(worst, 1e-9);
  const cf::Thermo a = ctx.thermo(), b = ref.thermo();
  EXPECT_NEAR(a.potential, b.potential, 1e-10 * std::abs(b.potential));
  EXPECT_NEAR(a.kinetic, b.kinetic, 1e-10 * std::abs(b.kinetic));
  EXPECT_NEAR(a.pressure, b.pressure, 1e-9 * std::max(1.0, std::abs(b.pressure)));
}

// An open box (the grid spans the particles' bounds, read on the device for CUDA), with and without
// a skin: the backend's run follows the CPU's to round-off over 50 double steps.
TEST_P(MdApi, OpenBoxFollowsTheCpuRun) {
  for (const double skin : {0.0, 0.3}) {
    SCOPED_TRACE("skin " + std::to_string(skin));
    auto run = [&](cf::Backend backend) {
      cf::MdState state;
      state.config = cf::make_lattice(cf::Lattice::kFcc, 4, 0.8442);
      const std::size_t n = state.config.size();
      std::vector<double> masses(n, 1.0);
      cf::initialize_velocities(state, masses, 1.44, 77);
      cf::Context ctx(3);
      const double lengths[3] = {0, 0, 0};
      const bool periodic[3] = {false, false, false};
      ctx.set_box(lengths, periodic);
      ctx.set_cutoff(2.5, cf::CutoffMode::kForceShift);
      ctx.add_type("A", 1.0, 1.0);
      ctx.set_backend(backend);
      ctx.set_skin(skin);
      ctx.set_state(n, state.config.positions.data(), state.velocities.data(), nullptr, masses.data());
      ctx.step(50);
      std::vector<double> x(3 * n);
      ctx.get_state(x.data(), nullptr, nullptr);
      x.push_back(ctx.thermo().potential);
      return x;
    };
    const std::vector<double> got = run(GetParam()), ref = run(cf::Backend::kCpu);
    ASSERT_EQ(got.size(), ref.size());
    double worst = 0;
    for (std::size_t k = 0; k + 1 < got.size(); ++k) worst = std::max(worst, std::abs(got[k] - ref[k]));
    EXPECT_LT(worst, 1e-9);
    EXPECT_NEAR(got.back(), ref.back(), 1e-10 * std::abs(ref.back()));
  }
}

// dt far too large: the step call that diverged throws, naming the particle and its steps.
TEST_P(MdApi, DivergenceNamesTheParticleAndTheSteps) {
  RunSetup s;
  s.backend = GetParam();
  s.integrator.dt = 0.5;
  cf::Context ctx = liquid(s);
  try {
    ctx.step(200);
    ADD_FAILURE() << "dt = 0.5 did not diverge";
  } catch (const cf::Error& e) {
    const std::string msg = e.message();
    EXPECT_THAT(msg, HasSubstr("particle "));
    EXPECT_THAT(msg, ::testing::AnyOf(HasSubstr("the integration diverged"), HasSubstr("not finite")));
    EXPECT_THAT(msg, HasSubstr("step"));
  }
}

std::string backend_name(const ::testing::TestParamInfo<cf::Backend>& info) { return cf::to_string(info.param); }

INSTANTIATE_TEST_SUITE_P(Backends, MdApi, ::testing::Values(cf::Backend::kCpu, cf::Backend::kCuda), backend_name);

}  // namespace

namespace {

// A state the engine refuses (two particles at one position) leaves no half-set state behind:
// step() asks for set_state again, and a good state then runs.
TEST_P(MdApi, RefusedStateLeavesNoHalfSetState) {
  cf::Context ctx(3);
  const double box[3] = {10, 10, 10};
  const bool periodic[3] = {true, true, true};
  ctx.set_box(box, periodic);
  ctx.set_cutoff(2.5);
  ctx.add_type("A", 1.0, 1.0);
  ctx.set_backend(GetParam());
  const double same[6] = {1, 1, 1, 1, 1, 1}, masses[2] = {1, 1};
  try {
    ctx.set_state(2, same, nullptr, nullptr, masses);
    ADD_FAILURE() << "a coincident pair was accepted";
  } catch (const cf::Error& e) {
    EXPECT_THAT(e.message(), HasSubstr("particles 0 and 1"));
  }
  try {
    ctx.step(1);
    ADD_FAILURE() << "step() ran without a state";
  } catch (const cf::Error& e) {
    EXPECT_THAT(e.message(), HasSubstr("set_state"));
  }
  const double apart[6] = {1, 1, 1, 2.2, 1, 1};
  ctx.set_state(2, apart, nullptr, nullptr, masses);
  ctx.step(10);
  EXPECT_EQ(ctx.current_step(), 10);
  EXPECT_TRUE(std::isfinite(ctx.thermo().total));
}

}  // namespace
