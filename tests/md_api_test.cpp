// Molecular dynamics through the public API (Context::set_state / step / thermo / get_state) on
// every backend here: NVE energy conservation and the Langevin temperature with the bounds of
// md_test.cpp, two runs of one setup bitwise equal, the device-resident CUDA run equal to the CPU
// run to round-off over its first steps, a diverging run named with its particle and steps, and FIRE
// (Context::minimize) converging like the CPU's, bitwise repeatable, restoring the start when it
// throws, and leaving a state that the dynamics continue from.
// The CUDA instances skip where no CUDA device can be used.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cellforce/cellforce.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <string>
#include <utility>
#include <vector>

#include "backend_here.h"
#include "core/box.h"
#include "core/engine_options.h"
#include "core/random.h"
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
  std::vector<std::pair<std::string, std::string>> options;  // set_option(key, value), in order
  // The units: lengths, energies and masses times these (time then times length sqrt(mass / energy)).
  double length = 1, energy = 1, mass = 1;
};

using cftest::unavailable;

// The MD engine's own statistics (the "run" object of statistics_json(), beside RunStatistics').
nlohmann::json engine_statistics(const cf::Context& ctx) { return nlohmann::json::parse(ctx.statistics_json()).at("run"); }

// A context holding the force-shifted LJ liquid of md_test.cpp with T0 = 1.44 velocities.
cf::Context liquid(const RunSetup& s, std::size_t* n_out = nullptr) {
  cf::MdState state;
  state.config = cf::make_lattice(cf::Lattice::kFcc, s.cells, 0.8442);
  const std::size_t n = state.config.size();
  std::vector<double> masses(n, 1.0);
  cf::initialize_velocities(state, masses, 1.44, s.seed, s.integrator.kind == cf::Integrator::kVerlet);
  const double time = s.length * std::sqrt(s.mass / s.energy);
  for (double& x : state.config.positions) x *= s.length;
  for (double& v : state.velocities) v *= s.length / time;
  for (double& m : masses) m *= s.mass;
  for (double& l : state.config.box.length) l *= s.length;
  cf::IntegratorOptions integrator = s.integrator;
  integrator.dt *= time;
  integrator.temperature *= s.energy;
  integrator.friction /= time;
  cf::Context ctx(3);
  const bool periodic[3] = {true, true, true};
  ctx.set_box(state.config.box.length, periodic);
  ctx.set_cutoff(2.5 * s.length, cf::CutoffMode::kForceShift);
  ctx.add_type("A", s.length, s.energy);
  ctx.set_backend(s.backend);
  ctx.set_precision(s.precision);
  ctx.set_integrator(integrator);
  for (const auto& [key, value] : s.options) ctx.set_option(key, value);
  ctx.set_state(n, state.config.positions.data(), state.velocities.data(), nullptr, masses.data());
  if (n_out) *n_out = n;
  return ctx;
}

using cftest::rms_about_mean;
using cftest::slope;

// The largest coordinate difference between two contexts' positions (n particles in the fcc box of
// edge `edge`: a coordinate wrapped to 0 in one and to just below the edge in the other is close).
double largest_position_difference(cf::Context& a, cf::Context& b, std::size_t n, double edge) {
  std::vector<double> x(3 * n), y(3 * n);
  a.get_state(x.data(), nullptr, nullptr);
  b.get_state(y.data(), nullptr, nullptr);
  double worst = 0;
  for (std::size_t k = 0; k < x.size(); ++k) {
    const double d = std::abs(x[k] - y[k]);
    worst = std::max(worst, std::min(d, std::abs(d - edge)));
  }
  return worst;
}

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

// Units are a choice, not physics: the liquid with lengths in units of 2^-33, energies and masses of
// 2^-70 (so time too is in units of 2^-33: argon's sizes in SI) runs the same 300 steps as in reduced
// units, NVE and Langevin, in every precision, with the backend's default neighbour search (pair
// lists on CUDA): every operation scales by a power of two, so the positions and velocities,
// brought back to reduced units, equal the reduced run's bit for bit, and the potential energy too.
TEST_P(MdApi, UnitsOfArgonInSiRunTheReducedSteps) {
  for (cf::Precision p : {cf::Precision::kDouble, cf::Precision::kMixed, cf::Precision::kSingle})
    for (cf::Integrator kind : {cf::Integrator::kVerlet, cf::Integrator::kLangevin}) {
      SCOPED_TRACE(std::string(cf::to_string(p)) + (kind == cf::Integrator::kVerlet ? " verlet" : " langevin"));
      RunSetup s;
      s.backend = GetParam();
      s.precision = p;
      s.integrator.kind = kind;
      std::size_t n = 0;
      cf::Context ref = liquid(s, &n);
      s.length = 0x1p-33, s.energy = 0x1p-70, s.mass = 0x1p-70;
      cf::Context si = liquid(s);
      ref.step(300);
      si.step(300);
      std::vector<double> x(3 * n), v(3 * n), y(3 * n), w(3 * n);
      ref.get_state(x.data(), v.data(), nullptr);
      si.get_state(y.data(), w.data(), nullptr);
      std::size_t differ = 0;
      for (std::size_t k = 0; k < 3 * n; ++k) differ += (y[k] / s.length != x[k]) + (w[k] != v[k]);
      EXPECT_EQ(differ, 0u) << "of " << 6 * n << " coordinates; e.g. x " << y[0] / s.length << " against " << x[0];
      EXPECT_EQ(si.thermo().potential / s.energy, ref.thermo().potential);
    }
}

// The backend's run follows the CPU's (the reference integrator on host arrays) to round-off:
// 50 NVE steps in double, positions within 1e-9 and the energies within 1e-10 relative; with the
// default skin (auto: pair lists on CUDA) and with none (the cells on every step).
TEST_P(MdApi, FollowsTheCpuRun) {
  for (const char* skin : {"auto", "0"}) {
    SCOPED_TRACE(std::string("skin ") + skin);
    RunSetup s;
    s.backend = GetParam();
    s.options = {{"skin", skin}};
    std::size_t n = 0;
    cf::Context ctx = liquid(s, &n);
    RunSetup cpu = s;
    cpu.backend = cf::Backend::kCpu;
    cf::Context ref = liquid(cpu);
    ctx.step(50);
    ref.step(50);
    const double edge = cf::make_lattice(cf::Lattice::kFcc, s.cells, 0.8442).box.length[0];
    EXPECT_LT(largest_position_difference(ctx, ref, n, edge), 1e-9);
    const cf::Thermo a = ctx.thermo(), b = ref.thermo();
    EXPECT_NEAR(a.potential, b.potential, 1e-10 * std::abs(b.potential));
    EXPECT_NEAR(a.kinetic, b.kinetic, 1e-10 * std::abs(b.kinetic));
    EXPECT_NEAR(a.pressure, b.pressure, 1e-9 * std::max(1.0, std::abs(b.pressure)));
  }
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

// The step gate (cuda/search/step_gate.h): with pair lists a step() call queues its steps in chunks and
// the device decides the rebuilds. One call of 300 steps against 300 calls of one step (the last
// step of a call is never gated, so those decide every rebuild on the host): the same builds and,
// bit for bit, the same positions, velocities and forces; and the gate served most steps. Verlet
// and Langevin (BAOAB: the gated kick and half drift, thermostat, half drift); also with
// neighbor-every, which bounds each chunk, and in double precision.
TEST_P(MdApi, GatedStepsEqualStepByStep) {
  if (GetParam() == cf::Backend::kCpu) GTEST_SKIP() << "the step gate is the CUDA engine's";
  struct Case {
    cf::Precision precision;
    const char* every;
    bool langevin;
  };
  for (const Case c : {Case{cf::Precision::kMixed, "0", false}, Case{cf::Precision::kMixed, "7", false},
                       Case{cf::Precision::kDouble, "0", false}, Case{cf::Precision::kMixed, "0", true},
                       Case{cf::Precision::kDouble, "7", true}}) {
    SCOPED_TRACE(std::string(cf::to_string(c.precision)) + ", neighbor-every " + c.every +
                 (c.langevin ? ", Langevin" : ", Verlet"));
    auto run = [&](bool one_call, cf::RunStatistics* st, nlohmann::json* engine) {
      RunSetup s;
      s.backend = GetParam();
      s.precision = c.precision;
      if (c.langevin) {
        s.integrator.kind = cf::Integrator::kLangevin;
        s.integrator.temperature = 1.44;
        s.integrator.friction = 1.0;
        s.integrator.seed = 99;
      }
      s.cells = 8;  // 2,048 particles, edge 13.4 > 2 (rc + skin)
      s.options = {{"skin", "0.3"}, {"neighbor-list", "true"}, {"neighbor-every", c.every}};
      std::size_t n = 0;
      cf::Context ctx = liquid(s, &n);
      ctx.reset_run_statistics();
      if (one_call) {
        ctx.step(300, false);
      } else {
        for (int k = 0; k < 300; ++k) ctx.step(1, false);
      }
      *st = ctx.run_statistics();
      *engine = engine_statistics(ctx);
      std::vector<double> x(3 * n), v(3 * n), f(3 * n);
      ctx.get_state(x.data(), v.data(), f.data());
      x.insert(x.end(), v.begin(), v.end());
      x.insert(x.end(), f.begin(), f.end());
      return x;
    };
    cf::RunStatistics gated, stepwise;
    nlohmann::json gated_engine, stepwise_engine;
    const std::vector<double> a = run(true, &gated, &gated_engine), b = run(false, &stepwise, &stepwise_engine);
    EXPECT_TRUE(a == b) << "the gated run differs from the step-by-step run";
    EXPECT_EQ(gated.builds, stepwise.builds);
    EXPECT_GE(gated.builds, 5) << "too few rebuilds to exercise the gate's closing";
    EXPECT_EQ(stepwise_engine.at("gated_steps"), 0);
    const int64_t gated_steps = gated_engine.at("gated_steps");
    EXPECT_GT(gated_steps, 200) << "the gate served few steps";
    EXPECT_LE(gated_steps, 299);
    EXPECT_EQ(gated.largest_served_displacement, stepwise.largest_served_displacement);
    // Both runs' builds but the first few of the system replayed the build's graph.
    const int64_t gated_graphs = gated_engine.at("graph_builds"), stepwise_graphs = stepwise_engine.at("graph_builds");
    EXPECT_GE(gated_graphs, gated.builds - 4);
    EXPECT_GE(stepwise_graphs, stepwise.builds - 4);
    EXPECT_LE(gated_graphs, gated.builds);
  }
}

// skin = auto, the context's default: the MD state of the in.lj-sized liquid (2,048 particles,
// edge 13.4 > 2 (rc + 0.6)) gets pair lists with a skin of 0.24 rc = 0.6 on CUDA and no skin on the
// CPU, as core/reuse.h's rule says; the CUDA run walks the lists on every evaluation and builds
// less often than it evaluates, and follows the run without a skin (the same pairs, summed in
// another order) to round-off over 50 double steps. Force calls take the same rule.
TEST_P(MdApi, SkinAutoIsTheBackendsRule) {
  const bool cuda = GetParam() == cf::Backend::kCuda;
  RunSetup s;
  s.backend = GetParam();
  s.cells = 8;
  std::size_t n = 0;
  cf::Context ctx = liquid(s, &n);
  EXPECT_EQ(ctx.skin(), cuda ? 0.24 * 2.5 : 0.0);
  EXPECT_EQ(ctx.neighbor(), cuda ? "skin 0.6 (auto: 0.24 rc), pair lists"
                                 : "none, stages 1-3 every evaluation (auto: no skin on the cpu)");
  RunSetup lean = s;  // lists in lean memory (asked for here; auto takes it where fast would not fit): 0.18 rc
  lean.options = {{"memory", "lean"}};
  cf::Context lean_ctx = liquid(lean);
  EXPECT_EQ(lean_ctx.skin(), cuda ? 0.18 * 2.5 : 0.0);
  EXPECT_EQ(lean_ctx.neighbor(), cuda ? "skin 0.45 (auto: 0.18 rc, lean memory), pair lists"
                                      : "none, stages 1-3 every evaluation (auto: no skin on the cpu)");
  RunSetup plain = s;
  plain.options = {{"skin", "0"}};
  cf::Context ref = liquid(plain);
  EXPECT_EQ(ref.skin(), 0.0);
  ctx.step(50);
  ref.step(50);
  const cf::RunStatistics st = ctx.run_statistics();
  EXPECT_EQ(engine_statistics(ctx).at("list_evaluations"), cuda ? st.evaluations : 0);
  if (cuda) {
    EXPECT_GE(st.builds, 1);
    EXPECT_LT(st.builds, st.evaluations) << "the lists were never reused";
  }
  const double edge = cf::make_lattice(cf::Lattice::kFcc, s.cells, 0.8442).box.length[0];
  EXPECT_LT(largest_position_difference(ctx, ref, n, edge), 1e-9);
  EXPECT_NEAR(ctx.thermo().potential, ref.thermo().potential, 1e-10 * std::abs(ref.thermo().potential));

  cf::Context forces(3);  // the same system without an MD state: the force calls' structure
  const double box[3] = {edge, edge, edge};
  const bool periodic[3] = {true, true, true};
  forces.set_box(box, periodic);
  forces.set_cutoff(2.5, cf::CutoffMode::kForceShift);
  forces.add_type("A", 1.0, 1.0);
  forces.set_backend(s.backend);
  const double rule = cuda ? 0.24 * 2.5 : 0.0;  // the rule of steps
  EXPECT_EQ(forces.skin(), rule);
  EXPECT_EQ(forces.neighbor(), cuda ? "skin 0.6 (auto: 0.24 rc), pair lists"
                                    : "none, stages 1-3 every evaluation (auto: no skin on the cpu)");
  forces.set_option("neighbor-list", "true");  // for a skin given as a length; auto chooses itself
  EXPECT_EQ(forces.skin(), rule);
  forces.set_skin(0.3);
  EXPECT_EQ(forces.skin(), 0.3);
  EXPECT_EQ(forces.neighbor(), cuda ? "skin 0.3, pair lists" : "skin 0.3, cells reused");
  forces.set_option("neighbor-list", "false");
  EXPECT_EQ(forces.neighbor(), "skin 0.3, cells reused");
  forces.set_option("skin", "auto");
  EXPECT_EQ(forces.skin(), rule);
}

// statistics_json()'s run memory: the engine's stage buffers and the MD state's arrays, by buffer, largest
// first, adding up to buffer_bytes + state_bytes (a consistency check: both come from the same
// buffers; a buffer the engine leaves out of its list is missing from both). The oracle for the
// sizes: the state's positions and velocities hold n x 3 doubles (exactly on the CPU, where they are
// vectors; at least on CUDA, whose buffers may keep room they grew to); on CUDA with pair lists
// (skin auto) the list's entries hold 4 bytes for each of its slots (list_slots) and its lengths 4
// bytes a particle.
TEST_P(MdApi, MemoryByBufferAddsUp) {
  const bool cuda = GetParam() == cf::Backend::kCuda;
  RunSetup s;
  s.backend = GetParam();
  s.cells = 8;
  std::size_t n = 0;
  cf::Context ctx = liquid(s, &n);
  ctx.step(20);
  const cf::RunStatistics st = ctx.run_statistics();
  const nlohmann::json engine = engine_statistics(ctx);
  std::vector<std::pair<std::string, std::size_t>> memory;
  for (const nlohmann::json& buffer : engine.at("memory")) memory.emplace_back(buffer.at("name"), buffer.at("bytes"));
  ASSERT_FALSE(memory.empty());
  std::size_t sum = 0;
  std::vector<std::string> names;
  for (std::size_t k = 0; k < memory.size(); ++k) {
    const auto& [name, bytes] = memory[k];
    SCOPED_TRACE(name);
    EXPECT_GT(bytes, 0u);
    if (k) {
      EXPECT_LE(bytes, memory[k - 1].second) << "not largest first";
    }
    sum += bytes;
    names.push_back(name);
  }
  EXPECT_EQ(sum, st.buffer_bytes + st.state_bytes);
  std::sort(names.begin(), names.end());
  EXPECT_EQ(std::adjacent_find(names.begin(), names.end()), names.end()) << "a name twice";
  auto bytes_of = [&](const std::string& name) -> std::size_t {
    for (const auto& [buffer, bytes] : memory)
      if (buffer == name) return bytes;
    ADD_FAILURE() << "no buffer named " << name;
    return 0;
  };
  const std::size_t coordinates = 3 * n * sizeof(double);
  if (cuda) {
    EXPECT_GE(bytes_of("md: positions"), coordinates);
    EXPECT_GE(bytes_of("md: velocities"), coordinates);
    const std::size_t list_slots = engine.at("list_slots");
    ASSERT_GT(list_slots, 0u) << "skin auto gives CUDA pair lists";
    EXPECT_GE(bytes_of("list: entries"), 4 * list_slots);
    EXPECT_GE(bytes_of("list: lengths"), 4 * n);
  } else {
    EXPECT_EQ(bytes_of("md: positions"), coordinates);
    EXPECT_EQ(bytes_of("md: velocities"), coordinates);
    EXPECT_EQ(bytes_of("md: forces"), coordinates);
    EXPECT_EQ(bytes_of("md: masses"), n * sizeof(double));
  }
}

// Dangerous builds (LAMMPS's term): with neighbor-check false a structure serves `every` evaluations
// whatever the particles do, and a build that retires one after a particle moved more than skin / 2
// since its build is counted. The oracle: the state read every `every` steps (the rebuild steps)
// and the largest minimum-image displacement between consecutive reads, computed here. With the
// check on there are none, although builds then follow displacements past skin / 2 (those rebuild
// before the structure serves them: counting them would be the bug that half catches).
TEST_P(MdApi, DangerousBuildsAreCounted) {
  constexpr int kEvery = 8, kChunks = 25;
  constexpr double kSkin = 0.3;
  for (const bool check : {false, true}) {
    SCOPED_TRACE(check ? "neighbor-check true" : "neighbor-check false");
    RunSetup s;
    s.backend = GetParam();
    s.options = {{"skin", "0.3"}, {"neighbor-check", check ? "true" : "false"},
                 {"neighbor-every", std::to_string(kEvery)}};
    std::size_t n = 0;
    cf::Context ctx = liquid(s, &n);
    const double edge = cf::make_lattice(cf::Lattice::kFcc, s.cells, 0.8442).box.length[0];
    std::vector<double> then(3 * n), now(3 * n);
    ctx.get_state(then.data(), nullptr, nullptr);
    ctx.reset_run_statistics();
    int64_t expected = 0;
    for (int c = 0; c < kChunks; ++c) {
      ctx.step(kEvery, false);
      ctx.get_state(now.data(), nullptr, nullptr);
      double worst = 0;
      for (std::size_t i = 0; i < n; ++i) {
        double d2 = 0;
        for (int a = 0; a < 3; ++a) {
          const double d = cf::minimum_image(now[3 * i + a] - then[3 * i + a], edge, 1.0 / edge);
          d2 += d * d;
        }
        worst = std::max(worst, d2);
      }
      if (worst > 0.25 * kSkin * kSkin) ++expected;
      then = now;
    }
    const cf::RunStatistics st = ctx.run_statistics();
    std::printf("dangerous builds %s, check %s: %lld of %lld builds (oracle %lld of %d)\n",
                cf::to_string(GetParam()), check ? "on" : "off", (long long)st.dangerous_builds,
                (long long)st.builds, (long long)expected, kChunks);
    if (!check) {
      EXPECT_GT(expected, 2) << "the run never drifted past skin / 2 between builds: the count is not exercised";
      EXPECT_LT(expected, kChunks) << "every build dangerous: the count is not exercised";
      EXPECT_EQ(st.builds, kChunks);
      EXPECT_EQ(st.dangerous_builds, expected);
    } else {
      EXPECT_EQ(st.dangerous_builds, 0);
    }
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

// Two particles 10 apart along x (beyond the cutoff 2.5: no force) in a box periodic along x and
// z (edge 20) and open along y, particle 1 moving at `vx`, `vy`; dt = 2^-7, so that dt v is exact.
cf::Context drifting_pair(cf::Backend backend, double vx, double vy, bool langevin) {
  cf::Context ctx(3);
  const double lengths[3] = {20, 0, 20};
  const bool periodic[3] = {true, false, true};
  ctx.set_box(lengths, periodic);
  ctx.set_cutoff(2.5, cf::CutoffMode::kForceShift);
  ctx.add_type("A", 1.0, 1.0);
  ctx.set_backend(backend);
  cf::IntegratorOptions integrator;
  integrator.dt = 0.0078125;
  if (langevin) {
    integrator.kind = cf::Integrator::kLangevin;
    integrator.temperature = 0;  // no noise: each half drift moves by dt/2 x (the decayed) velocity
    integrator.friction = 1e-9;
  }
  ctx.set_integrator(integrator);
  const double x[6] = {1, 1, 1, 11, 1, 1}, v[6] = {0, 0, 0, vx, vy, 0}, m[2] = {1, 1};
  ctx.set_state(2, x, v, nullptr, m);
  return ctx;
}

// On an open axis a drift longer than the cutoff is a divergence (a particle that far in one step
// can pass a partner without their force acting), named with the particle, axis, displacement and
// limit as on a periodic axis, whose limit stays the box edge; a run that blows up on an open axis
// is named so, not left to end at the grid's cell limit.
TEST_P(MdApi, AnOpenAxisDriftLongerThanTheCutoffIsADivergence) {
  const cf::Backend backend = GetParam();
  auto message = [&](double vx, double vy, bool langevin) {
    cf::Context ctx = drifting_pair(backend, vx, vy, langevin);
    try {
      ctx.step(1);
    } catch (const cf::Error& e) {
      return e.message();
    }
    return std::string();
  };
  EXPECT_EQ(message(0, 384, false),  // dt v = 3 along the open y
            "step 1: particle 1 moved 3 along y in one drift, more than 2.5 (the cutoff, on an open axis: a longer "
            "move can pass through a partner without their force acting): the integration diverged; lower dt, or "
            "remove overlaps first");
  EXPECT_EQ(message(0, -384, true),  // dt/2 v = 1.5 in the Langevin step's first half drift
            "step 1: particle 1 moved -1.5 along y in one drift, more than 1.25 (half the cutoff, on an open axis: a "
            "longer move can pass through a partner without their force acting, for each of a step's two half "
            "drifts): the integration diverged; lower dt, or remove overlaps first");
  EXPECT_EQ(message(384, 0, false), "") << "3 along the periodic x is within its limit, the edge 20";
  cf::Context ctx = drifting_pair(backend, 0, 300, false);  // dt v = 2.34375: within the cutoff
  ctx.step(1);
  double x[6];
  ctx.get_state(x, nullptr, nullptr);
  EXPECT_EQ(x[4], 1 + 2.34375);
}

// A dt or a mass whose step overflows the doubles is named where it enters (set_integrator,
// set_state), not left to a divergence blamed on overlaps.
TEST(MdApiSteps, ADtOrAMassThatOverflowsTheStepIsNamed) {
  cf::Context ctx = drifting_pair(cf::Backend::kCpu, 0, 0, false);
  cf::IntegratorOptions huge;
  huge.dt = 1e300;
  try {
    ctx.set_integrator(huge);
    ADD_FAILURE() << "dt = 1e300 was accepted";
  } catch (const cf::Error& e) {
    EXPECT_THAT(e.message(), HasSubstr("dt = 1e+300 makes the step's arithmetic overflow: dt^2 = inf"));
    EXPECT_THAT(e.message(), ::testing::Not(HasSubstr("overlap")));
  }
  const double x[6] = {1, 1, 1, 11, 1, 1}, m[2] = {1, 1e-320};  // dt / 2m = 0.0039 / 1e-320 overflows
  try {
    ctx.set_state(2, x, nullptr, nullptr, m);
    ADD_FAILURE() << "mass 1e-320 was accepted at dt 2^-7";
  } catch (const cf::Error& e) {
    EXPECT_THAT(e.message(), HasSubstr("the mass 1e-320 of particle 1 (type 'A') with dt = 0.0078125 makes the "
                                       "step's arithmetic overflow: dt / 2m = inf"));
  }
}

// ---- FIRE (Context::minimize; CUDA: kernels on the device) ----

// 256 particles of the fcc lattice at density 0.8442 (4 cells), each moved by up to 0.1 sigma per
// axis at random, then particles 0, 100 and 200 put at r = 0.6, 0.8 and 0.9 from their nearest
// neighbours: a largest force of ~4e4 epsilon/sigma (measured), so that FIRE's displacement cap
// binds on its first steps. Zero velocities; `velocity` > 0 gives every coordinate that value
// instead (for the tests that the state is restored).
cf::Context overlapping_lattice(cf::Backend backend, std::size_t* n_out = nullptr, double velocity = 0) {
  cf::Configuration c = cf::make_lattice(cf::Lattice::kFcc, 4, 0.8442);
  const std::size_t n = c.size();
  const double edge = c.box.length[0];
  auto image = [&](double d) { return d - edge * std::rint(d / edge); };
  for (std::size_t k = 0; k < c.positions.size(); ++k) {
    const double u = cf::unit_open(cf::splitmix64(uint64_t(k) + 1)) - 0.5;  // (-0.5, 0.5)
    c.positions[k] = cf::wrap_coordinate(c.positions[k] + 0.2 * u, edge);
  }
  const std::pair<std::size_t, double> close[] = {{0, 0.6}, {100, 0.8}, {200, 0.9}};
  for (const auto& [p, r] : close) {
    std::size_t q = p;
    double best = INFINITY;
    for (std::size_t j = 0; j < n; ++j) {
      double r2 = 0;
      for (int a = 0; a < 3; ++a) r2 += std::pow(image(c.positions[3 * p + a] - c.positions[3 * j + a]), 2);
      if (j != p && r2 < best) best = r2, q = j;
    }
    for (int a = 0; a < 3; ++a) {
      const double d = image(c.positions[3 * p + a] - c.positions[3 * q + a]);
      c.positions[3 * p + a] = cf::wrap_coordinate(c.positions[3 * q + a] + d * r / std::sqrt(best), edge);
    }
  }
  const std::vector<double> masses(n, 1.0), velocities(3 * n, velocity);
  cf::Context ctx(3);
  const bool periodic[3] = {true, true, true};
  ctx.set_box(c.box.length, periodic);
  ctx.set_cutoff(2.5, cf::CutoffMode::kForceShift);
  ctx.add_type("A", 1.0, 1.0);
  ctx.set_backend(backend);
  ctx.set_state(n, c.positions.data(), velocities.data(), nullptr, masses.data());
  if (n_out) *n_out = n;
  return ctx;
}

// max_i |F_i| of n x 3 forces, summed as md/minimize.h's largest_force sums it.
double largest_force(const std::vector<double>& f) {
  double largest2 = 0;
  for (std::size_t i = 0; i < f.size() / 3; ++i)
    largest2 = std::max(largest2, f[3 * i] * f[3 * i] + f[3 * i + 1] * f[3 * i + 1] + f[3 * i + 2] * f[3 * i + 2]);
  return std::sqrt(largest2);
}

struct Minimized {
  cf::MinimizeResult result;
  std::vector<double> positions, velocities, forces;
  double potential = 0;  // thermo() after the minimisation
};

Minimized minimize_overlapping_lattice(cf::Backend backend, const cf::MinimizeOptions& options) {
  std::size_t n = 0;
  cf::Context ctx = overlapping_lattice(backend, &n);
  Minimized m;
  m.result = ctx.minimize(options);
  m.positions.resize(3 * n);
  m.velocities.resize(3 * n);
  m.forces.resize(3 * n);
  ctx.get_state(m.positions.data(), m.velocities.data(), m.forces.data());
  m.potential = ctx.thermo().potential;
  return m;
}

// FIRE through the API to |F| < 1e-4 from the overlapping lattice: the backend converges and leaves
// the final positions with their forces (largest below the tolerance and equal to the result's to
// 4 ulps: the same per-particle sum) and zero velocities; thermo() reports the result's energy;
// two runs are bitwise equal; the final energy is the CPU run's to 1e-9 relative. The backends do
// the same arithmetic per particle (md/fire_step.h), but their force and reduction sums differ in
// order, so their trajectories part at round-off and may end at slightly different points of the
// same minimum, which they reach with every |F_i| < 1e-4. Measured on the CPU: that end lies
// 1.4e-8 (1e-11 relative) above the end at |F_i| < 1e-6, and a start moved by 1e-7 ends 1e-14
// relative from the unmoved one, in as many steps; 1e-9 leaves a factor 100. The step counts
// may differ where an uphill decision (the sign of P) flips at round-off: within 20% of the CPU's.
TEST_P(MdApi, MinimizeConvergesAndFollowsTheCpu) {
  cf::MinimizeOptions options;
  options.force_tolerance = 1e-4;
  options.max_steps = 20000;
  const Minimized a = minimize_overlapping_lattice(GetParam(), options);
  const Minimized b = minimize_overlapping_lattice(GetParam(), options);
  const Minimized cpu =
      GetParam() == cf::Backend::kCpu ? a : minimize_overlapping_lattice(cf::Backend::kCpu, options);
  std::printf("FIRE %s: %lld steps, E %.10g -> %.10g, max |F| %.3g -> %.3g (particle %zu); cpu: %lld steps, E %.10g\n",
              cf::to_string(GetParam()), (long long)a.result.steps, a.result.initial_energy, a.result.final_energy,
              a.result.initial_max_force, a.result.final_max_force, a.result.final_max_force_particle,
              (long long)cpu.result.steps, cpu.result.final_energy);
  EXPECT_GT(a.result.initial_max_force, 1e4) << "the start has no close pair: the test measures little";
  EXPECT_GT(a.result.steps, 0);
  EXPECT_LT(a.result.final_max_force, options.force_tolerance);
  EXPECT_LT(largest_force(a.forces), options.force_tolerance);
  EXPECT_DOUBLE_EQ(largest_force(a.forces), a.result.final_max_force);
  EXPECT_EQ(a.velocities, std::vector<double>(a.velocities.size(), 0.0));
  EXPECT_NEAR(a.potential, a.result.final_energy, 1e-12 * std::abs(a.result.final_energy));
  EXPECT_LT(a.result.final_energy, a.result.initial_energy);

  EXPECT_TRUE(a.positions == b.positions) << "two minimisations of one start differ";
  EXPECT_TRUE(a.forces == b.forces);
  EXPECT_EQ(a.result.steps, b.result.steps);
  EXPECT_EQ(a.result.final_energy, b.result.final_energy);

  EXPECT_LT(cpu.result.final_max_force, options.force_tolerance);
  EXPECT_NEAR(a.result.initial_energy, cpu.result.initial_energy, 1e-12 * std::abs(cpu.result.initial_energy));
  EXPECT_NEAR(a.result.final_energy, cpu.result.final_energy, 1e-9 * std::abs(cpu.result.final_energy));
  EXPECT_NEAR(double(a.result.steps), double(cpu.result.steps), 0.2 * double(cpu.result.steps));
}

// A minimisation that throws (here: no convergence in 3 steps) names the particle and leaves the
// state it started from: positions, velocities and forces as before the call, bitwise; the run
// then steps from it.
TEST_P(MdApi, MinimizeThatThrowsLeavesTheStartingState) {
  std::size_t n = 0;
  cf::Context ctx = overlapping_lattice(GetParam(), &n, 0.25);
  std::vector<double> x(3 * n), v(3 * n), f(3 * n);
  ctx.get_state(x.data(), v.data(), f.data());
  cf::MinimizeOptions options;
  options.max_steps = 3;
  try {
    ctx.minimize(options);
    ADD_FAILURE() << "3 FIRE steps converged from the overlapping lattice";
  } catch (const cf::Error& e) {
    EXPECT_THAT(e.message(), HasSubstr("did not converge in 3 steps: particle "));
  }
  std::vector<double> x2(3 * n), v2(3 * n), f2(3 * n);
  ctx.get_state(x2.data(), v2.data(), f2.data());
  EXPECT_TRUE(x2 == x) << "positions changed";
  EXPECT_TRUE(v2 == v) << "velocities changed";
  EXPECT_TRUE(f2 == f) << "the forces are not the starting positions' any more";
  EXPECT_EQ(ctx.current_step(), 0);
  options.max_displacement = -1;
  try {
    ctx.minimize(options);
    ADD_FAILURE() << "max_displacement -1 was accepted";
  } catch (const cf::Error& e) {
    EXPECT_THAT(e.message(), HasSubstr("max_displacement must be a finite number > 0"));
  }
}

// After FIRE to the CLI's default tolerance (|F| < 100) the run steps on from the engine's state
// (velocities zero, forces up to 100 left; the step counter where it was): 2000 NVE steps at
// dt 0.005 turn potential into kinetic energy (~0.17 per particle), and the total energy, after
// a first jump (the first steps' large forces: measured 2.8e-4 per particle on the CPU; bound
// 1e-3), holds md_test.cpp's bounds: RMS about its mean below 2e-4 per particle (measured ~5e-6)
// and a drift below 1e-5 per particle per unit time over 10 time units.
TEST_P(MdApi, NveAfterMinimizeConservesEnergy) {
  std::size_t n = 0;
  cf::Context ctx = overlapping_lattice(GetParam(), &n);
  const cf::MinimizeResult r = ctx.minimize(cf::MinimizeOptions{});
  EXPECT_LT(r.final_max_force, 100.0);
  EXPECT_EQ(ctx.current_step(), 0);
  const cf::Thermo start = ctx.thermo();
  EXPECT_EQ(start.kinetic, 0.0);
  std::vector<double> times, energies;
  for (int k = 1; k <= 100; ++k) {
    ctx.step(20);
    times.push_back(0.005 * double(ctx.current_step()));
    energies.push_back((ctx.thermo().total - start.total) / double(n));
  }
  const double jump = energies.front(), drift = slope(times, energies), rms = rms_about_mean(energies);
  const double kinetic = ctx.thermo().kinetic / double(n);
  std::printf("NVE after FIRE %s (%lld steps): kinetic 0 -> %.4g, first jump %.3e, RMS %.3e, drift %.3e "
              "(per particle)\n",
              cf::to_string(GetParam()), (long long)r.steps, kinetic, jump, rms, drift);
  EXPECT_EQ(ctx.current_step(), 2000);
  EXPECT_GT(kinetic, 0.05) << "the residual forces did not move anything: the test measures little";
  EXPECT_LT(std::abs(jump), 1e-3);
  EXPECT_LT(rms, 2e-4);
  EXPECT_LT(std::abs(drift), 1e-5);
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
