// A physics or engine setting changed while a Context holds an MD state: it applies to the state
// from the next step (the state's forces evaluated again under it), so that the run continues as a
// fresh context set up with the new setting continues from the same state (positions, velocities,
// step); or it is refused with a cellforce::Error naming the setting and why, and the state and
// the context are as they were (the run continues as if the call had not been made). Double
// precision, every backend here (the CUDA instances skip without a device).
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cellforce/cellforce.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#ifdef CELLFORCE_HAVE_CUDA
#include <cuda_runtime.h>

#include "backend/engine.h"  // cuda/backend/engine.h: GpuEngine::unavailable
#endif
#include "core/box.h"
#include "core/engine_options.h"
#include "scene/lattice.h"
#include "state/velocities.h"

namespace {

namespace cf = cellforce;
using ::testing::HasSubstr;

// The fcc liquid of md_api_test.cpp (256 particles, density 0.8442, edge 6.72, T0 1.44), with two
// types alternating so that mixing and explicit pairs matter.
struct Start {
  std::size_t n = 0;
  double edge = 0;
  std::vector<double> x, v, m;
  std::vector<uint32_t> types;
};

Start liquid_start() {
  cf::MdState state;
  state.config = cf::make_lattice(cf::Lattice::kFcc, 4, 0.8442);
  Start s;
  s.n = state.config.size();
  s.edge = state.config.box.length[0];
  s.m.assign(s.n, 1.0);
  cf::initialize_velocities(state, s.m, 1.44, 2024, true);
  s.x = state.config.positions;
  s.v = state.velocities;
  for (std::size_t i = 0; i < s.n; ++i) s.types.push_back(uint32_t(i % 2));
  return s;
}

// The backend of the test instance (set by the fixture).
cf::Backend backend = cf::Backend::kCpu;

// How far a run that rebuilt its neighbour structure at another step than its twin may be from it:
// the same bits on the CPU (no skin: every evaluation builds it); with CUDA's automatic skin the
// pair lists' order follows the build, so the sums differ in rounding.
double rebuilt_tolerance() { return backend == cf::Backend::kCpu ? 0.0 : 1e-12; }

// The context before any change: the backend, double, rc 2.5 truncated, types A and B, Verlet dt
// 0.005.
void set_up(cf::Context& ctx, const Start& s) {
  const double box[3] = {s.edge, s.edge, s.edge};
  const bool periodic[3] = {true, true, true};
  ctx.set_box(box, periodic);
  ctx.set_cutoff(2.5, cf::CutoffMode::kTruncate);
  ctx.add_type("A", 1.0, 1.0);
  ctx.add_type("B", 0.9, 0.7);
  ctx.set_backend(backend);
  ctx.set_precision(cf::Precision::kDouble);
  cf::IntegratorOptions o;
  o.dt = 0.005;
  ctx.set_integrator(o);
}

struct Snapshot {
  std::vector<double> x, v, f;
  double potential = 0;
  int64_t step = 0;
};

Snapshot snapshot(cf::Context& ctx, std::size_t n) {
  Snapshot s;
  s.x.resize(3 * n);
  s.v.resize(3 * n);
  s.f.resize(3 * n);
  ctx.get_state(s.x.data(), s.v.data(), s.f.data());
  s.potential = ctx.thermo().potential;
  s.step = ctx.current_step();
  return s;
}

// max |a - b| over the largest |b|: the arrays agree to `tolerance` of their scale.
void expect_close(const std::vector<double>& a, const std::vector<double>& b, double tolerance, const char* what) {
  ASSERT_EQ(a.size(), b.size()) << what;
  double worst = 0, scale = 0;
  for (std::size_t k = 0; k < a.size(); ++k) {
    worst = std::max(worst, std::abs(a[k] - b[k]));
    scale = std::max(scale, std::abs(b[k]));
  }
  EXPECT_LE(worst, tolerance * scale) << what << ": largest difference " << worst << " of " << scale;
}

void expect_same(const Snapshot& a, const Snapshot& b, double tolerance) {
  EXPECT_EQ(a.step, b.step);
  expect_close(a.x, b.x, tolerance, "positions");
  expect_close(a.v, b.v, tolerance, "velocities");
  expect_close(a.f, b.f, tolerance, "forces");
  EXPECT_NEAR(a.potential, b.potential, tolerance * std::abs(b.potential)) << "potential energy";
}

using Change = std::function<void(cf::Context&)>;

// A run of 10 steps, `change`, 5 more, against a fresh context with `fresh` made after set_up and
// given the state at the change: equal at the change and after the 5 steps (1e-12 relative).
// `moves_forces`: the setting changes the forces at the change (a physics setting, whose being
// ignored the comparison must see; an engine setting ignored would have dropped the state).
void expect_applied(const Change& change, const Change& fresh, bool moves_forces = true) {
  const Start s = liquid_start();
  cf::Context a(3);
  set_up(a, s);
  a.set_state(s.n, s.x.data(), s.v.data(), s.types.data(), s.m.data());
  a.step(10);
  const Snapshot at = snapshot(a, s.n);
  change(a);
  cf::Context b(3);
  set_up(b, s);
  fresh(b);
  b.set_state(s.n, at.x.data(), at.v.data(), s.types.data(), s.m.data(), at.step);
  {
    SCOPED_TRACE("at the change");
    expect_same(snapshot(a, s.n), snapshot(b, s.n), 1e-12);
  }
  const Snapshot before_b = snapshot(b, s.n);
  if (moves_forces) {
    EXPECT_FALSE(before_b.f == at.f && before_b.potential == at.potential)
        << "the new setting changes nothing here: the test would not see it ignored";
  }
  a.step(5);
  b.step(5);
  SCOPED_TRACE("5 steps after the change");
  expect_same(snapshot(a, s.n), snapshot(b, s.n), 1e-12);
}

void expect_applied(const Change& change, bool moves_forces = true) { expect_applied(change, change, moves_forces); }

class LiveState : public ::testing::TestWithParam<cf::Backend> {
 protected:
  void SetUp() override {
    backend = GetParam();
#ifdef CELLFORCE_HAVE_CUDA
    if (backend == cf::Backend::kCuda && !cf::GpuEngine::unavailable().empty())
      GTEST_SKIP() << cf::GpuEngine::unavailable();
#else
    if (backend == cf::Backend::kCuda) GTEST_SKIP() << "this build has no CUDA";
#endif
  }
};

}  // namespace

TEST_P(LiveState, ABoxChangeAppliesUnscaledAndWrapped) {
  // Longer edges: the positions stay where they are (wrapped into the new box: the same numbers).
  expect_applied([](cf::Context& c) {
    const Start s = liquid_start();
    const double box[3] = {s.edge * 1.1, s.edge, s.edge * 1.05};
    const bool periodic[3] = {true, true, true};
    c.set_box(box, periodic);
  });
  // An axis made open.
  expect_applied([](cf::Context& c) {
    const Start s = liquid_start();
    const double box[3] = {s.edge, s.edge, 0};
    const bool periodic[3] = {true, true, false};
    c.set_box(box, periodic);
  });
}

// A box change with scaled positions: each coordinate on an axis periodic before and after is
// multiplied by the new edge over the old, the velocities kept; an axis made open keeps its
// coordinates. The run continues as a fresh context given the scaled state, and the scaled
// positions are the old ones times the factors (wrapped: the factors < 1 keep them in the box).
TEST_P(LiveState, ABoxChangeWithScaledPositionsIsAnAffineChange) {
  const Start s = liquid_start();
  const double factor[3] = {0.99, 1.02, 1.0};
  cf::Context a(3);
  set_up(a, s);
  a.set_state(s.n, s.x.data(), s.v.data(), s.types.data(), s.m.data());
  a.step(10);
  const Snapshot at = snapshot(a, s.n);
  const double box[3] = {s.edge * factor[0], s.edge * factor[1], 0};
  const bool periodic[3] = {true, true, false};  // z made open: its coordinates stay
  a.set_box(box, periodic, true);
  std::vector<double> x = at.x;
  for (std::size_t k = 0; k < x.size(); ++k) x[k] *= factor[k % 3];
  const Snapshot moved = snapshot(a, s.n);
  for (std::size_t k = 0; k < x.size(); ++k) {
    if (k % 3 != 1 || x[k] < box[1]) {  // y may wrap
      EXPECT_EQ(moved.x[k], x[k]) << "coordinate " << k;
    }
  }
  cf::Context b(3);
  set_up(b, s);
  b.set_box(box, periodic);
  b.set_state(s.n, x.data(), at.v.data(), s.types.data(), s.m.data(), at.step);
  {
    SCOPED_TRACE("at the change");
    expect_same(moved, snapshot(b, s.n), rebuilt_tolerance());
  }
  EXPECT_FALSE(moved.f == at.f) << "the scaled box changed no force: the test would not see it ignored";
  a.step(5);
  b.step(5);
  SCOPED_TRACE("5 steps after the change");
  expect_same(snapshot(a, s.n), snapshot(b, s.n), rebuilt_tolerance());
}

TEST_P(LiveState, ABoxChangeWrapsThePositionsIntoTheNewBox) {
  // Edges shorter than the lattice's (by less than a lattice plane's spacing, so that no pair
  // overlaps): the particles beyond the new edge are wrapped into the box, not scaled.
  const Start s = liquid_start();
  cf::Context ctx(3);
  set_up(ctx, s);
  ctx.set_state(s.n, s.x.data(), s.v.data(), s.types.data(), s.m.data());
  const double edge = s.edge - 0.3;
  const double box[3] = {edge, edge, edge};
  const bool periodic[3] = {true, true, true};
  ctx.set_box(box, periodic);
  std::vector<double> x(3 * s.n);
  ctx.get_state(x.data(), nullptr, nullptr);
  for (std::size_t k = 0; k < x.size(); ++k) EXPECT_EQ(x[k], cf::wrap_coordinate(s.x[k], edge)) << k;
}

TEST_P(LiveState, ACutoffChangeApplies) {
  expect_applied([](cf::Context& c) { c.set_cutoff(2.0); });
  expect_applied([](cf::Context& c) { c.set_cutoff(2.2, cf::CutoffMode::kForceShift); });
  expect_applied([](cf::Context& c) { c.set_option("cutoff-mode", "shift"); });
}

TEST_P(LiveState, ATypeChangeApplies) {
  expect_applied([](cf::Context& c) { c.set_mixing(cf::Mixing::kGeometric); });
  expect_applied([](cf::Context& c) { c.set_option("mixing", "geometric"); });
  expect_applied([](cf::Context& c) { c.set_pair(0, 1, 0.95, 1.3); });
  expect_applied([](cf::Context& c) { c.set_pair(1, 1, 0.85, 0.5); });
}

// An added type changes no force; the state takes it (a later set_pair may use it).
TEST_P(LiveState, AnAddedTypeKeepsTheRun) {
  const Start s = liquid_start();
  cf::Context a(3), b(3);
  for (cf::Context* c : {&a, &b}) {
    set_up(*c, s);
    c->set_state(s.n, s.x.data(), s.v.data(), s.types.data(), s.m.data());
    c->step(10);
  }
  EXPECT_EQ(a.add_type("C", 1.1, 0.9), 2u);
  a.step(5);
  b.step(5);
  expect_same(snapshot(a, s.n), snapshot(b, s.n), rebuilt_tolerance());
}

TEST_P(LiveState, AnEngineChangeCarriesTheState) {
  expect_applied([](cf::Context& c) { c.set_precision(cf::Precision::kMixed); });
  expect_applied([](cf::Context& c) { c.set_option("precision", "single"); });
  expect_applied([](cf::Context& c) { c.set_skin(0.3); }, false);
  expect_applied([](cf::Context& c) { c.set_option("accumulation", "gauss-seidel"); }, false);
  expect_applied([](cf::Context& c) { c.set_option("cell-rule", "chapter"); }, false);
  expect_applied(
      [](cf::Context& c) {
        c.set_skin(0.4);
        c.set_option("neighbor-every", "3");
      },
      false);
}

// Settings that change the engine but no number: the run goes on as without them, on a new engine.
TEST_P(LiveState, AnEngineChangeKeepsTheSteps) {
  const Start s = liquid_start();
  const Change changes[] = {
      [](cf::Context& c) { c.set_option("threads", "1"); },
      [](cf::Context& c) { c.set_option("backend", cf::to_string(backend)); },
      [](cf::Context& c) { c.set_backend(backend); },
      [](cf::Context& c) { c.set_option("skin", "auto"); },
      [](cf::Context& c) { c.set_option("neighbor-check", "false"); },
      [](cf::Context& c) { c.set_option("sort", "chapter"); },
  };
  for (const Change& change : changes) {
    cf::Context a(3), b(3);
    for (cf::Context* c : {&a, &b}) {
      set_up(*c, s);
      c->set_state(s.n, s.x.data(), s.v.data(), s.types.data(), s.m.data());
      c->step(10);
    }
    change(a);
    EXPECT_EQ(a.current_step(), 10);
    a.step(5);
    b.step(5);
    expect_same(snapshot(a, s.n), snapshot(b, s.n), rebuilt_tolerance());
  }
}

namespace {

// `change` throws an Error whose message has each of `texts`, and the run then continues as an
// untouched copy of it does: bit for bit, or as rebuilt_tolerance() where the engine had taken the
// change and got the state before back (`rebuilt`).
void expect_refused(const Change& change, const std::vector<std::string>& texts, bool rebuilt = false) {
  const Start s = liquid_start();
  cf::Context a(3), b(3);
  for (cf::Context* c : {&a, &b}) {
    set_up(*c, s);
    c->set_state(s.n, s.x.data(), s.v.data(), s.types.data(), s.m.data());
    c->step(10);
  }
  const Snapshot before = snapshot(a, s.n);
  const std::string description = a.description();
  try {
    change(a);
    ADD_FAILURE() << "the change was taken";
  } catch (const cf::Error& e) {
    std::printf("refused: %s\n", e.message().c_str());
    for (const std::string& text : texts) EXPECT_THAT(e.message(), HasSubstr(text));
  }
  expect_same(snapshot(a, s.n), before, rebuilt ? rebuilt_tolerance() : 0.0);
  EXPECT_EQ(a.description(), description);
  a.step(5);
  b.step(5);
  expect_same(snapshot(a, s.n), snapshot(b, s.n), rebuilt ? rebuilt_tolerance() : 0.0);
}

}  // namespace

TEST_P(LiveState, AChangeTheStateCannotTakeIsRefused) {
  expect_refused(
      [](cf::Context& c) {
        const double box[3] = {4.0, 10, 10};
        const bool periodic[3] = {true, true, true};
        c.set_box(box, periodic);
      },
      {"set_box", "the MD state cannot take it", "cutoff 2.5 exceeds half the periodic box edge x = 4"});
  expect_refused([](cf::Context& c) { c.set_cutoff(3.5); },
                 {"set_cutoff 3.5", "the MD state cannot take it", "cutoff 3.5 exceeds half the periodic box edge x"});
  // A pair whose force overflows at the state's positions: found by the engine after it took the
  // new force field, which then gets the state before back.
  expect_refused([](cf::Context& c) { c.set_pair(0, 1, 1e30, 1.0); },
                 {"set_pair (0, 1)", "the MD state cannot take it", "particles "}, true);
}

TEST_P(LiveState, AnEngineThatCannotBeMadeIsRefused) {
#ifdef CELLFORCE_HAVE_CUDA
  GTEST_SKIP() << "this build has CUDA: a cuda backend may be made here";
#else
  expect_refused([](cf::Context& c) { c.set_backend(cf::Backend::kCuda); },
                 {"backend cuda", "the MD state cannot move to an engine with it", "built without CUDA"});
  expect_refused([](cf::Context& c) { c.set_option("backend", "cuda"); }, {"backend cuda"});
#endif
}

// New positions and velocities act on the state where it lives: the run continues as a fresh
// context given the same state (positions moved off the trajectory, velocities reversed, the same
// step) continues, at the change and 5 steps later (bitwise on the CPU; with cuda to
// rebuilt_tolerance, the skin's structure of the run against one built at the change); with cuda only the new array crosses to the
// device (the run statistics count its bytes alone) and nothing comes back.
TEST_P(LiveState, NewPositionsAndVelocitiesActOnTheStateWhereItLives) {
  const Start s = liquid_start();
  cf::Context a(3);
  set_up(a, s);
  a.set_state(s.n, s.x.data(), s.v.data(), s.types.data(), s.m.data());
  a.step(10);
  const Snapshot at = snapshot(a, s.n);
  std::vector<double> x = at.x, v = at.v;
  for (std::size_t k = 0; k < x.size(); ++k) {
    x[k] += 0.02 * std::sin(0.7 * double(k));  // off the trajectory: other forces
    v[k] = -v[k];
  }
  x[0] += s.edge;  // another periodic image: wrapped as set_state wraps it
  a.reset_run_statistics();
  a.set_positions(s.n, x.data());
  a.set_velocities(s.n, v.data());
  const cf::RunStatistics st = a.run_statistics();
  EXPECT_EQ(st.bytes_to_host, 0u);
  EXPECT_EQ(st.bytes_to_device, backend == cf::Backend::kCuda ? 2 * s.n * 3 * sizeof(double) : 0u);
  cf::Context b(3);
  set_up(b, s);
  b.set_state(s.n, x.data(), v.data(), s.types.data(), s.m.data(), at.step);
  const Snapshot moved = snapshot(a, s.n);
  {
    SCOPED_TRACE("at the change");  // with cuda a's forces come from its reused lists, b's built anew
    expect_same(moved, snapshot(b, s.n), rebuilt_tolerance());
  }
  EXPECT_FALSE(moved.f == at.f) << "the new positions changed no force: the test would not see them ignored";
  a.step(5);
  b.step(5);
  SCOPED_TRACE("5 steps after the change");
  expect_same(snapshot(a, s.n), snapshot(b, s.n), rebuilt_tolerance());
}

// Positions the state cannot take (a wrong count, a non-finite coordinate, two particles on one
// point) and non-finite velocities are refused naming the cause; the run then continues as an
// untouched twin's (bitwise on the CPU; with cuda a refused evaluation may have rebuilt the
// structure from the same positions, which moves later builds: rebuilt_tolerance).
TEST_P(LiveState, NewPositionsTheStateCannotTakeAreRefused) {
  const Start s = liquid_start();
  cf::Context a(3), twin(3);
  for (cf::Context* c : {&a, &twin}) {
    set_up(*c, s);
    c->set_state(s.n, s.x.data(), s.v.data(), s.types.data(), s.m.data());
    c->step(5);
  }
  const Snapshot at = snapshot(a, s.n);
  auto message = [&](const std::function<void()>& call) {
    try {
      call();
    } catch (const cf::Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_THAT(message([&] { a.set_positions(s.n - 1, at.x.data()); }), HasSubstr("255 particles given for a state of 256"));
  std::vector<double> bad = at.x;
  bad[3 * 17 + 1] = std::nan("");
  EXPECT_THAT(message([&] { a.set_positions(s.n, bad.data()); }), HasSubstr("particle 17"));
  bad = at.x;
  for (int c = 0; c < 3; ++c) bad[3 * 9 + std::size_t(c)] = bad[3 * 8 + std::size_t(c)];  // 8 and 9 on one point
  EXPECT_THAT(message([&] { a.set_positions(s.n, bad.data()); }), HasSubstr("particles 8 and 9"));
  std::vector<double> v = at.v;
  v[3 * 4 + 2] = std::numeric_limits<double>::infinity();
  EXPECT_THAT(message([&] { a.set_velocities(s.n, v.data()); }), HasSubstr("particle 4 has a non-finite velocity"));
  EXPECT_THAT(message([&] { a.set_velocities(s.n, nullptr); }), HasSubstr("velocities is a null pointer"));
  expect_same(snapshot(a, s.n), snapshot(twin, s.n), rebuilt_tolerance());
  a.step(5);
  twin.step(5);
  expect_same(snapshot(a, s.n), snapshot(twin, s.n), rebuilt_tolerance());
}

// The state view is the state where it lives, read in place: host memory on the CPU, the context's
// device with cuda; bitwise what get_state downloads, after set_state and after steps; nothing crosses
// to the host for it (the run statistics count no bytes); no state, no view.
TEST_P(LiveState, TheStateViewIsTheStateInPlace) {
  const Start s = liquid_start();
  cf::Context a(3);
  set_up(a, s);
  EXPECT_THROW(a.state_view(), cf::Error);
  a.set_state(s.n, s.x.data(), s.v.data(), s.types.data(), s.m.data());
  for (const int steps : {0, 7, 3}) {
    SCOPED_TRACE("after " + std::to_string(steps) + " more steps");
    a.step(steps);
    const Snapshot want = snapshot(a, s.n);
    a.reset_run_statistics();
    const cf::StateView view = a.state_view();
    EXPECT_EQ(a.run_statistics().bytes_to_host, 0u);
    ASSERT_EQ(view.n, s.n);
    ASSERT_EQ(view.dim, 3);
    const std::size_t count = s.n * 3;
    std::vector<double> x(count), v(count), f(count);
    if (backend == cf::Backend::kCpu) {
      EXPECT_EQ(view.device, -1);
      std::copy(view.positions, view.positions + count, x.begin());
      std::copy(view.velocities, view.velocities + count, v.begin());
      std::copy(view.forces, view.forces + count, f.begin());
    } else {
#ifdef CELLFORCE_HAVE_CUDA
      EXPECT_EQ(view.device, 0);
      for (const auto& [from, to] : {std::pair{view.positions, &x}, {view.velocities, &v}, {view.forces, &f}}) {
        cudaPointerAttributes where{};
        ASSERT_EQ(cudaPointerGetAttributes(&where, from), cudaSuccess);
        EXPECT_EQ(where.type, cudaMemoryTypeDevice);
        ASSERT_EQ(cudaMemcpy(to->data(), from, count * sizeof(double), cudaMemcpyDeviceToHost), cudaSuccess);
      }
#endif
    }
    EXPECT_EQ(x, want.x);
    EXPECT_EQ(v, want.v);
    EXPECT_EQ(f, want.f);
  }
}

INSTANTIATE_TEST_SUITE_P(Backends, LiveState, ::testing::Values(cf::Backend::kCpu, cf::Backend::kCuda),
                         [](const ::testing::TestParamInfo<cf::Backend>& param_info) { return cf::to_string(param_info.param); });
