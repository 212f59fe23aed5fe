// An external force on the MD state (Context::set_external_forces, set_external_forces_device,
// set_external_force_callback; C cf_set_external_*): a force-shifted LJ liquid with an external
// force is stepped by the library and by this file's own velocity Verlet loop, whose forces are the
// double brute force's (Context::compute_brute_force) plus the same external force. The two
// trajectories agree to round-off over 20 steps on every backend, for a constant array (host or
// device) and for a callback whose force depends on the positions (a harmonic tether), which is
// called once per evaluation with the step its positions belong to. Bad input is named, minimize()
// is refused, and the force is kept across a new engine and dropped by clear_external_force.
// The CUDA instances skip where no CUDA device can be used.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cellforce/cellforce.h>
#include <cellforce/cellforce.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#ifdef CELLFORCE_HAVE_CUDA
#include <cuda_runtime.h>
#endif
#include "backend_here.h"
#include "core/random.h"
#include "md/md.h"
#include "scene/lattice.h"

namespace {

namespace cf = cellforce;
using ::testing::HasSubstr;

using cftest::unavailable;

constexpr double kDt = 0.005;
constexpr int kSteps = 20;

// 256 particles of an fcc liquid at density 0.8442 with T0 = 1.44 velocities, force-shifted LJ at
// rc 2.5, masses 1 and 2 by turns.
struct Liquid {
  cf::MdState state;
  std::vector<double> masses;
  std::size_t n = 0;
  Liquid() {
    state.config = cf::make_lattice(cf::Lattice::kFcc, 4, 0.8442);
    n = state.config.size();
    masses.assign(n, 1.0);
    for (std::size_t i = 1; i < n; i += 2) masses[i] = 2.0;
    cf::initialize_velocities(state, masses, 1.44, 4711, true);
  }
  double edge() const { return state.config.box.length[0]; }
};

void set_physics(cf::Context& ctx, const Liquid& l) {
  const bool periodic[3] = {true, true, true};
  ctx.set_box(l.state.config.box.length, periodic);
  ctx.set_cutoff(2.5, cf::CutoffMode::kForceShift);
  ctx.add_type("A", 1.0, 1.0);
}

cf::Context context(const Liquid& l, cf::Backend backend) {
  cf::Context ctx(3);
  set_physics(ctx, l);
  ctx.set_backend(backend);
  ctx.set_precision(cf::Precision::kDouble);
  cf::IntegratorOptions verlet;
  verlet.dt = kDt;
  ctx.set_integrator(verlet);
  return ctx;
}

void set_state(cf::Context& ctx, const Liquid& l) {
  ctx.set_state(l.n, l.state.config.positions.data(), l.state.velocities.data(), nullptr, l.masses.data());
}

// A constant external force: components normal with deviation 1, drawn per particle and axis.
std::vector<double> constant_force(std::size_t n) {
  std::vector<double> f(3 * n);
  for (std::size_t k = 0; k < f.size(); ++k) f[k] = cf::counter_normal(99, 0, k);
  return f;
}

// A harmonic tether of every particle to the plane x = L / 2 (k = 0.7): F_x = -k (x - L/2).
struct Tether {
  double edge = 0;
  double k = 0.7;
  void add(std::size_t n, const double* x, double* f) const {
    for (std::size_t i = 0; i < n; ++i) f[3 * i] -= k * (x[3 * i] - 0.5 * edge);
  }
};

// The oracle: velocity Verlet (v += dt/2 F/m; x += dt v, wrapped; F = brute force + external;
// v += dt/2 F/m) in double on the host, the forces by the brute force of a CPU context.
struct Trajectory {
  std::vector<double> x, v, f;
};
Trajectory oracle(const Liquid& l, const std::function<void(const std::vector<double>&, std::vector<double>&)>& external) {
  cf::Context brute(3);
  set_physics(brute, l);
  brute.set_backend(cf::Backend::kCpu);
  Trajectory t{l.state.config.positions, l.state.velocities, std::vector<double>(3 * l.n)};
  auto forces = [&] {
    brute.compute_brute_force(l.n, t.x.data(), nullptr, {t.f.data()});
    external(t.x, t.f);
  };
  forces();
  const double L = l.edge();
  for (int s = 0; s < kSteps; ++s) {
    for (std::size_t k = 0; k < t.x.size(); ++k) {
      t.v[k] += 0.5 * kDt * t.f[k] / l.masses[k / 3];
      t.x[k] += kDt * t.v[k];
      t.x[k] -= L * std::floor(t.x[k] / L);
    }
    forces();
    for (std::size_t k = 0; k < t.x.size(); ++k) t.v[k] += 0.5 * kDt * t.f[k] / l.masses[k / 3];
  }
  return t;
}

Trajectory state_of(cf::Context& ctx, std::size_t n) {
  Trajectory t{std::vector<double>(3 * n), std::vector<double>(3 * n), std::vector<double>(3 * n)};
  ctx.get_state(t.x.data(), t.v.data(), t.f.data());
  return t;
}

// Largest difference of positions (a coordinate wrapped to 0 in one and just below L in the
// other is close), velocities and forces.
void expect_close(const Trajectory& ref, const Trajectory& got, double edge, double tol) {
  double dx = 0, dv = 0, df = 0;
  for (std::size_t k = 0; k < ref.x.size(); ++k) {
    const double d = std::abs(ref.x[k] - got.x[k]);
    dx = std::max(dx, std::min(d, std::abs(d - edge)));
    dv = std::max(dv, std::abs(ref.v[k] - got.v[k]));
    df = std::max(df, std::abs(ref.f[k] - got.f[k]));
  }
  EXPECT_LE(dx, tol) << "positions";
  EXPECT_LE(dv, tol) << "velocities";
  EXPECT_LE(df, 100 * tol) << "forces";  // forces near contact are ~100 times the velocities
}

// Round-off of 20 double steps of a liquid (the library's cell search and Verlet arithmetic
// against the brute force and this loop's: seen 1e-14); a missing or doubled external force moves
// the particles by ~F dt^2 steps^2 / m ~ 1e-2.
constexpr double kTol = 1e-10;

void add_constant(const std::vector<double>& c, std::vector<double>& f) {
  for (std::size_t k = 0; k < f.size(); ++k) f[k] += c[k];
}

class ExternalForce : public ::testing::TestWithParam<cf::Backend> {
 protected:
  void SetUp() override {
    if (const std::string why = unavailable(GetParam()); !why.empty()) GTEST_SKIP() << why;
  }
};

// A host array, set before the state and after it: the oracle's trajectory either way; the pair
// potential alone in thermo(); on CUDA most steps served behind the step gate, the force added
// into the chunk's rank order (memory fast) or the caller's order (memory lean).
TEST_P(ExternalForce, HostArrayFollowsTheOracle) {
  const Liquid l;
  const std::vector<double> c = constant_force(l.n);
  const Trajectory ref = oracle(l, [&](const std::vector<double>&, std::vector<double>& f) { add_constant(c, f); });
  for (const int run : {0, 1, 2}) {
    const bool before = run == 0, lean = run == 2;
    if (lean && GetParam() != cf::Backend::kCuda) continue;
    SCOPED_TRACE(before ? "set before the state" : lean ? "on the state, lean memory" : "set on the state");
    cf::Context ctx = context(l, GetParam()), plain = context(l, GetParam());
    if (lean) ctx.set_option("memory", "lean");
    if (before) ctx.set_external_forces(l.n, c.data());
    set_state(ctx, l);
    set_state(plain, l);
    if (!before) ctx.set_external_forces(l.n, c.data());
    EXPECT_NEAR(ctx.thermo().potential, plain.thermo().potential, 1e-12 * std::abs(plain.thermo().potential))
        << "the external force has no energy";
    ctx.step(kSteps);
    expect_close(ref, state_of(ctx, l.n), l.edge(), kTol);
    const nlohmann::json stats = nlohmann::json::parse(ctx.statistics_json()).at("run");
    if (GetParam() == cf::Backend::kCuda) {
      EXPECT_GE(stats.at("gated_steps").get<int64_t>(), kSteps / 2);
    }
  }
}

// A callback (the tether) on host arrays on the CPU and on device arrays with CUDA (this test's
// callback copies them to the host and back on the stream it is given): the oracle's trajectory,
// called for each evaluation with its step.
struct CallbackRecord {
  Tether tether;
  std::vector<int64_t> steps;
  bool device = false;
  void* stream = nullptr;
  std::size_t n = 0;
};

void tether_callback(void* user, int64_t step, std::size_t n, int dim, const double* positions, double* forces,
                     void* stream) {
  auto* r = static_cast<CallbackRecord*>(user);
  r->steps.push_back(step);
  r->n = n;
  r->stream = stream;
  if (dim != 3) return;
  if (!r->device) {
    r->tether.add(n, positions, forces);
    return;
  }
#ifdef CELLFORCE_HAVE_CUDA
  const auto s = static_cast<cudaStream_t>(stream);
  std::vector<double> x(3 * n), f(3 * n);
  cudaMemcpyAsync(x.data(), positions, x.size() * sizeof(double), cudaMemcpyDeviceToHost, s);
  cudaMemcpyAsync(f.data(), forces, f.size() * sizeof(double), cudaMemcpyDeviceToHost, s);
  cudaStreamSynchronize(s);
  r->tether.add(n, x.data(), f.data());
  cudaMemcpyAsync(forces, f.data(), f.size() * sizeof(double), cudaMemcpyHostToDevice, s);
  cudaStreamSynchronize(s);
#endif
}

TEST_P(ExternalForce, CallbackFollowsTheOracle) {
  const Liquid l;
  CallbackRecord record;
  record.tether.edge = l.edge();
  record.device = GetParam() == cf::Backend::kCuda;
  const Trajectory ref = oracle(l, [&](const std::vector<double>& x, std::vector<double>& f) {
    record.tether.add(l.n, x.data(), f.data());
  });
  cf::Context ctx = context(l, GetParam());
  set_state(ctx, l);
  ctx.set_external_force_callback(&tether_callback, &record);
  ctx.step(kSteps);
  expect_close(ref, state_of(ctx, l.n), l.edge(), kTol);
  // Once when set (the state's forces evaluated again, step 0), then once a step.
  std::vector<int64_t> expected{0};
  for (int64_t s = 1; s <= kSteps; ++s) expected.push_back(s);
  EXPECT_EQ(record.steps, expected);
  EXPECT_EQ(record.n, l.n);
  EXPECT_EQ(record.stream == nullptr, GetParam() == cf::Backend::kCpu);
  EXPECT_EQ(nlohmann::json::parse(ctx.statistics_json()).at("run").at("gated_steps").get<int64_t>(), 0)
      << "a callback's steps are not gated";
  // A null callback clears it: no more calls.
  ctx.set_external_force_callback(nullptr, &record);
  ctx.step(3);
  EXPECT_EQ(record.steps.size(), expected.size());
}

// The force stays through a change that makes a new engine (an engine option), and goes with
// clear_external_force: the state then runs as one that never had it.
TEST_P(ExternalForce, KeptAcrossANewEngineUntilCleared) {
  const Liquid l;
  const std::vector<double> c = constant_force(l.n);
  const Trajectory ref = oracle(l, [&](const std::vector<double>&, std::vector<double>& f) { add_constant(c, f); });
  cf::Context ctx = context(l, GetParam());
  ctx.set_external_forces(l.n, c.data());
  set_state(ctx, l);
  ctx.step(kSteps / 2);
  ctx.set_option("skin", "0.35");  // another engine for the state (its run statistics start afresh)
  ctx.step(kSteps / 2);
  EXPECT_EQ(ctx.run_statistics().steps, kSteps / 2) << "the option made a new engine";
  expect_close(ref, state_of(ctx, l.n), l.edge(), kTol);

  cf::Context plain = context(l, GetParam());
  cf::Context cleared = context(l, GetParam());
  set_state(plain, l);
  cleared.set_external_forces(l.n, c.data());
  set_state(cleared, l);
  cleared.clear_external_force();
  plain.step(kSteps);
  cleared.step(kSteps);
  expect_close(state_of(plain, l.n), state_of(cleared, l.n), l.edge(), 1e-12);
}

// Bad input, each named; minimize() refused while a force is set.
TEST_P(ExternalForce, BadInputIsNamed) {
  const Liquid l;
  std::vector<double> c = constant_force(l.n);
  cf::Context ctx = context(l, GetParam());
  set_state(ctx, l);
  auto message = [](const std::function<void()>& f) {
    try {
      f();
    } catch (const cf::Error& e) {
      return e.message();
    }
    return std::string("(no error)");
  };
  EXPECT_EQ(message([&] { ctx.set_external_forces(l.n - 1, c.data()); }),
            "set_external_forces: 255 particles given for a state of 256");
  c[3 * 7 + 1] = std::nan("");
  EXPECT_EQ(message([&] { ctx.set_external_forces(l.n, c.data()); }),
            "set_external_forces: particle 7 has a non-finite external force (nan) along axis 1");
  c[3 * 7 + 1] = 0.5;
  EXPECT_THAT(message([&] { ctx.set_external_forces(l.n, nullptr); }), HasSubstr("external forces is a null pointer"));
  ctx.set_external_forces(l.n, c.data());
  EXPECT_EQ(message([&] { ctx.minimize({}); }),
            "minimize: an external force is set, and FIRE needs the energy, which it does not give; "
            "clear_external_force first");
  // A state of another count while the array is set.
  std::vector<double> x(l.state.config.positions.begin(), l.state.config.positions.end() - 3), m(l.n - 1, 1.0);
  EXPECT_EQ(message([&] { ctx.set_state(l.n - 1, x.data(), nullptr, nullptr, m.data()); }),
            "set_state: 255 particles, but the external force set holds 256 (set one for 255, or "
            "clear_external_force)");
  ctx.clear_external_force();
  ctx.set_state(l.n - 1, x.data(), nullptr, nullptr, m.data());
  EXPECT_EQ(ctx.num_particles(), l.n - 1);
  if (GetParam() == cf::Backend::kCpu) {
    EXPECT_EQ(message([&] { ctx.set_external_forces_device(l.n - 1, c.data()); }),
              "set_external_forces_device: the cpu backend holds the state in host memory; use set_external_forces");
  } else {
    EXPECT_EQ(message([&] { ctx.set_external_forces_device(l.n - 1, c.data()); }),
              "set_external_forces_device: external forces is not a device pointer (use set_external_forces for a "
              "host array)");
  }
}

INSTANTIATE_TEST_SUITE_P(Backends, ExternalForce, ::testing::Values(cf::Backend::kCpu, cf::Backend::kCuda),
                         [](const ::testing::TestParamInfo<cf::Backend>& i) {
                           return std::string(i.param == cf::Backend::kCuda ? "cuda" : "cpu");
                         });

// The caller's device array: the host array's trajectory bitwise (the same addition on the device),
// and read at every evaluation (changed between step() calls, the next step's forces have the change).
TEST(ExternalForceDevice, DeviceArrayIsTheHostArray) {
#ifdef CELLFORCE_HAVE_CUDA
  if (const std::string why = unavailable(cf::Backend::kCuda); !why.empty()) GTEST_SKIP() << why;
  const Liquid l;
  const std::vector<double> c = constant_force(l.n);
  double* d = nullptr;
  ASSERT_EQ(cudaMalloc(&d, c.size() * sizeof(double)), cudaSuccess);
  ASSERT_EQ(cudaMemcpy(d, c.data(), c.size() * sizeof(double), cudaMemcpyHostToDevice), cudaSuccess);
  cf::Context host = context(l, cf::Backend::kCuda), device = context(l, cf::Backend::kCuda);
  set_state(host, l);
  set_state(device, l);
  host.set_external_forces(l.n, c.data());
  device.set_external_forces_device(l.n, d);
  host.step(kSteps);
  device.step(kSteps);
  const Trajectory a = state_of(host, l.n), b = state_of(device, l.n);
  EXPECT_EQ(a.x, b.x);
  EXPECT_EQ(a.v, b.v);
  EXPECT_EQ(a.f, b.f);
  // A new value in the array (3c): the next evaluation reads it, so the forces after one more
  // step are the pair forces at its positions (the brute force) plus 3c.
  std::vector<double> triple(c);
  for (double& v : triple) v *= 3;
  ASSERT_EQ(cudaMemcpy(d, triple.data(), c.size() * sizeof(double), cudaMemcpyHostToDevice), cudaSuccess);
  device.step(1);
  const Trajectory after = state_of(device, l.n);
  cf::Context brute(3);
  set_physics(brute, l);
  brute.set_backend(cf::Backend::kCpu);
  std::vector<double> pair(3 * l.n);
  brute.compute_brute_force(l.n, after.x.data(), nullptr, {pair.data()});
  double worst = 0;
  for (std::size_t k = 0; k < pair.size(); ++k) worst = std::max(worst, std::abs(after.f[k] - pair[k] - triple[k]));
  EXPECT_LE(worst, 1e-8);
  // The state cannot move to the CPU while it takes a device array: refused, the state kept.
  try {
    device.set_backend(cf::Backend::kCpu);
    ADD_FAILURE() << "the state moved to the CPU with a device array as its external force";
  } catch (const cf::Error& e) {
    EXPECT_THAT(e.message(), HasSubstr("the external force is a device array on CUDA device 0"));
  }
  device.step(1);
  device.clear_external_force();
  device.set_backend(cf::Backend::kCpu);
  device.step(1);
  cudaFree(d);
#else
  GTEST_SKIP() << "this build has no CUDA";
#endif
}

// The C API: cf_set_external_forces and the callback are the C++ calls (bitwise, CPU).
TEST(ExternalForceCApi, MatchesTheCppCalls) {
  const Liquid l;
  const std::vector<double> c = constant_force(l.n);
  cf::Context cpp = context(l, cf::Backend::kCpu);
  set_state(cpp, l);
  cpp.set_external_forces(l.n, c.data());
  cpp.step(5);
  cf_context* ctx = nullptr;
  ASSERT_EQ(cf_create(&ctx, 3), CF_OK);
  const int periodic[3] = {1, 1, 1};
  ASSERT_EQ(cf_set_box(ctx, l.state.config.box.length, periodic), CF_OK) << cf_last_error(ctx);
  ASSERT_EQ(cf_set_cutoff(ctx, 2.5, "force-shift"), CF_OK) << cf_last_error(ctx);
  ASSERT_EQ(cf_add_type(ctx, "A", 1.0, 1.0, nullptr), CF_OK) << cf_last_error(ctx);
  ASSERT_EQ(cf_set_option(ctx, "backend", "cpu"), CF_OK) << cf_last_error(ctx);
  ASSERT_EQ(cf_set_integrator(ctx, "verlet", kDt, 1.0, 1.0, 1), CF_OK) << cf_last_error(ctx);
  ASSERT_EQ(cf_set_state(ctx, l.n, l.state.config.positions.data(), l.state.velocities.data(), nullptr,
                         l.masses.data(), 0),
            CF_OK)
      << cf_last_error(ctx);
  ASSERT_EQ(cf_set_external_forces(ctx, l.n, c.data()), CF_OK) << cf_last_error(ctx);
  ASSERT_EQ(cf_step(ctx, 5), CF_OK) << cf_last_error(ctx);
  std::vector<double> x(3 * l.n), v(3 * l.n);
  ASSERT_EQ(cf_get_state(ctx, l.n, x.data(), v.data(), nullptr), CF_OK);
  const Trajectory want = state_of(cpp, l.n);
  EXPECT_EQ(x, want.x);
  EXPECT_EQ(v, want.v);
  EXPECT_EQ(cf_set_external_forces(ctx, l.n + 1, c.data()), CF_ERROR_INPUT);
  EXPECT_THAT(cf_last_error(ctx), HasSubstr("257 particles given for a state of 256"));
  EXPECT_EQ(cf_set_external_forces_device(ctx, l.n, c.data()), CF_ERROR_INPUT);
  CallbackRecord record;
  record.tether.edge = l.edge();
  ASSERT_EQ(cf_set_external_force_callback(ctx, &tether_callback, &record), CF_OK) << cf_last_error(ctx);
  ASSERT_EQ(cf_step(ctx, 2), CF_OK);
  EXPECT_EQ(record.steps, (std::vector<int64_t>{5, 6, 7}));
  ASSERT_EQ(cf_clear_external_force(ctx), CF_OK);
  ASSERT_EQ(cf_step(ctx, 1), CF_OK);
  EXPECT_EQ(record.steps.size(), 3u);
  cf_destroy(ctx);
}

}  // namespace
