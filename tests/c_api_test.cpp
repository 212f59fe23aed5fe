// The C API's molecular dynamics (cf_set_integrator, cf_set_state, cf_step, cf_get_state,
// cf_thermo), its thread count and cutoff mode, and its version: the same runs as the C++ API bit
// for bit, and every bad input answered with a status and a message naming it.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cellforce/cellforce.h>
#include <cellforce/cellforce.hpp>

#include <cmath>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "scene/lattice.h"
#include "state/velocities.h"

namespace {

namespace cf = cellforce;
using ::testing::HasSubstr;

struct Destroy {
  void operator()(cf_context* ctx) const { cf_destroy(ctx); }
};
using Handle = std::unique_ptr<cf_context, Destroy>;

Handle create(int dim) {
  cf_context* ctx = nullptr;
  EXPECT_EQ(cf_create(&ctx, dim), CF_OK) << cf_last_error(nullptr);
  return Handle(ctx);
}

// The fcc liquid (256 particles, density 0.8442, T0 1.44), two types alternating.
struct Liquid {
  std::size_t n = 0;
  double edge = 0;
  std::vector<double> x, v, m;
  std::vector<uint32_t> types;
};

Liquid liquid() {
  cf::MdState state;
  state.config = cf::make_lattice(cf::Lattice::kFcc, 4, 0.8442);
  Liquid l;
  l.n = state.config.size();
  l.edge = state.config.box.length[0];
  l.m.assign(l.n, 1.0);
  for (std::size_t i = 0; i < l.n; ++i) l.m[i] = i % 2 ? 1.5 : 1.0;
  cf::initialize_velocities(state, l.m, 1.44, 77, true);
  l.x = state.config.positions;
  l.v = state.velocities;
  for (std::size_t i = 0; i < l.n; ++i) l.types.push_back(uint32_t(i % 2));
  return l;
}

double lj(double r) {
  const double s6 = 1.0 / std::pow(r, 6);
  return 4.0 * (s6 * s6 - s6);
}

}  // namespace

// 50 Verlet steps through the C API and through the C++ API, CPU, double: the same bits in every
// array and every thermo value.
TEST(CApiMd, VerletRunIsTheCppRunBitwise) {
  const Liquid l = liquid();
  const double box[3] = {l.edge, l.edge, l.edge};

  Handle c = create(3);
  const int periodic[3] = {1, 1, 1};
  ASSERT_EQ(cf_set_box(c.get(), box, periodic), CF_OK);
  ASSERT_EQ(cf_set_cutoff(c.get(), 2.5, "force-shift"), CF_OK);
  ASSERT_EQ(cf_add_type(c.get(), "A", 1.0, 1.0, nullptr), CF_OK);
  ASSERT_EQ(cf_add_type(c.get(), "B", 0.9, 0.7, nullptr), CF_OK);
  ASSERT_EQ(cf_set_option(c.get(), "backend", "cpu"), CF_OK);
  ASSERT_EQ(cf_set_integrator(c.get(), "verlet", 0.004, 0, 0, 0), CF_OK) << cf_last_error(c.get());
  ASSERT_EQ(cf_set_state(c.get(), l.n, l.x.data(), l.v.data(), l.types.data(), l.m.data(), 100), CF_OK)
      << cf_last_error(c.get());
  ASSERT_EQ(cf_step(c.get(), 20), CF_OK) << cf_last_error(c.get());
  ASSERT_EQ(cf_step(c.get(), 30), CF_OK);
  std::vector<double> cx(3 * l.n), cv(3 * l.n), cfo(3 * l.n);
  ASSERT_EQ(cf_get_state(c.get(), l.n, cx.data(), cv.data(), cfo.data()), CF_OK) << cf_last_error(c.get());
  double ck = 0, cp = 0, ct = 0, cpr = 0;
  ASSERT_EQ(cf_thermo(c.get(), &ck, &cp, &ct, &cpr), CF_OK);

  cf::Context cpp(3);
  const bool p3[3] = {true, true, true};
  cpp.set_box(box, p3);
  cpp.set_cutoff(2.5, cf::CutoffMode::kForceShift);
  cpp.add_type("A", 1.0, 1.0);
  cpp.add_type("B", 0.9, 0.7);
  cpp.set_backend(cf::Backend::kCpu);
  cf::IntegratorOptions o;
  o.dt = 0.004;
  cpp.set_integrator(o);
  cpp.set_state(l.n, l.x.data(), l.v.data(), l.types.data(), l.m.data(), 100);
  cpp.step(20);
  cpp.step(30);
  std::vector<double> x(3 * l.n), v(3 * l.n), f(3 * l.n);
  cpp.get_state(x.data(), v.data(), f.data());
  const cf::Thermo t = cpp.thermo();

  EXPECT_EQ(cpp.current_step(), 150);
  EXPECT_TRUE(cx == x) << "positions differ";
  EXPECT_TRUE(cv == v) << "velocities differ";
  EXPECT_TRUE(cfo == f) << "forces differ";
  EXPECT_EQ(std::memcmp(&ck, &t.kinetic, sizeof ck), 0);
  EXPECT_EQ(std::memcmp(&cp, &t.potential, sizeof cp), 0);
  EXPECT_EQ(std::memcmp(&ct, &t.temperature, sizeof ct), 0);
  EXPECT_EQ(std::memcmp(&cpr, &t.pressure, sizeof cpr), 0);
  EXPECT_GT(ck, 0);
  EXPECT_LT(cp, 0);

  // Every output may be NULL; one array alone is the same as with the others.
  std::vector<double> only(3 * l.n);
  EXPECT_EQ(cf_get_state(c.get(), l.n, nullptr, nullptr, nullptr), CF_OK);
  EXPECT_EQ(cf_get_state(c.get(), l.n, nullptr, only.data(), nullptr), CF_OK);
  EXPECT_TRUE(only == v);
  // The state in place (host memory on the CPU): the arrays get_state copies.
  const double *px = nullptr, *pv = nullptr, *pf = nullptr;
  int device = 7;
  ASSERT_EQ(cf_state_view(c.get(), &px, &pv, &pf, &device), CF_OK) << cf_last_error(c.get());
  EXPECT_EQ(device, -1);
  EXPECT_TRUE(std::vector<double>(px, px + 3 * l.n) == cx);
  EXPECT_TRUE(std::vector<double>(pv, pv + 3 * l.n) == cv);
  EXPECT_TRUE(std::vector<double>(pf, pf + 3 * l.n) == cfo);
  EXPECT_EQ(cf_state_view(c.get(), nullptr, nullptr, nullptr, nullptr), CF_OK);
  EXPECT_EQ(cf_thermo(c.get(), nullptr, nullptr, nullptr, nullptr), CF_OK);
  double t_only = 0;
  EXPECT_EQ(cf_thermo(c.get(), nullptr, nullptr, &t_only, nullptr), CF_OK);
  EXPECT_EQ(t_only, ct);
}

// cf_set_positions and cf_set_velocities are Context::set_positions and set_velocities: the same
// bits after them and after 10 more steps; a count other than the state's is named.
TEST(CApiMd, NewPositionsAndVelocitiesAreTheCppCalls) {
  const Liquid l = liquid();
  const double box[3] = {l.edge, l.edge, l.edge};
  Handle c = create(3);
  const int periodic[3] = {1, 1, 1};
  ASSERT_EQ(cf_set_box(c.get(), box, periodic), CF_OK);
  ASSERT_EQ(cf_set_cutoff(c.get(), 2.5, "truncate"), CF_OK);
  ASSERT_EQ(cf_add_type(c.get(), "A", 1.0, 1.0, nullptr), CF_OK);
  ASSERT_EQ(cf_add_type(c.get(), "B", 0.9, 0.7, nullptr), CF_OK);
  ASSERT_EQ(cf_set_option(c.get(), "backend", "cpu"), CF_OK);
  ASSERT_EQ(cf_set_integrator(c.get(), "verlet", 0.004, 0, 0, 0), CF_OK);
  ASSERT_EQ(cf_set_state(c.get(), l.n, l.x.data(), l.v.data(), l.types.data(), l.m.data(), 0), CF_OK);
  cf::Context cpp(3);
  const bool p3[3] = {true, true, true};
  cpp.set_box(box, p3);
  cpp.set_cutoff(2.5, cf::CutoffMode::kTruncate);
  cpp.add_type("A", 1.0, 1.0);
  cpp.add_type("B", 0.9, 0.7);
  cpp.set_backend(cf::Backend::kCpu);
  cf::IntegratorOptions o;
  o.dt = 0.004;
  cpp.set_integrator(o);
  cpp.set_state(l.n, l.x.data(), l.v.data(), l.types.data(), l.m.data(), 0);
  std::vector<double> x = l.x, v = l.v;
  for (std::size_t k = 0; k < x.size(); ++k) x[k] += 0.01 * std::cos(double(k)), v[k] *= 0.5;
  ASSERT_EQ(cf_set_positions(c.get(), l.n, x.data()), CF_OK) << cf_last_error(c.get());
  ASSERT_EQ(cf_set_velocities(c.get(), l.n, v.data()), CF_OK) << cf_last_error(c.get());
  cpp.set_positions(l.n, x.data());
  cpp.set_velocities(l.n, v.data());
  for (int round = 0; round < 2; ++round) {
    std::vector<double> cx(3 * l.n), cv(3 * l.n), cfo(3 * l.n), px(3 * l.n), pv(3 * l.n), pf(3 * l.n);
    ASSERT_EQ(cf_get_state(c.get(), l.n, cx.data(), cv.data(), cfo.data()), CF_OK);
    cpp.get_state(px.data(), pv.data(), pf.data());
    EXPECT_TRUE(cx == px && cv == pv && cfo == pf) << "round " << round;
    ASSERT_EQ(cf_step(c.get(), 10), CF_OK);
    cpp.step(10);
  }
  // cf_set_box_scaled is set_box with scale_positions.
  const double bigger[3] = {l.edge * 1.01, l.edge * 1.01, l.edge * 1.01};
  const bool p3b[3] = {true, true, true};
  ASSERT_EQ(cf_set_box_scaled(c.get(), bigger, periodic), CF_OK) << cf_last_error(c.get());
  cpp.set_box(bigger, p3b, true);
  std::vector<double> cx(3 * l.n), px(3 * l.n);
  ASSERT_EQ(cf_get_state(c.get(), l.n, cx.data(), nullptr, nullptr), CF_OK);
  cpp.get_state(px.data(), nullptr, nullptr);
  EXPECT_TRUE(cx == px) << "scaled positions differ";
  EXPECT_EQ(cf_set_positions(c.get(), l.n + 1, x.data()), CF_ERROR_INPUT);
  EXPECT_THAT(std::string(cf_last_error(c.get())), HasSubstr("257 particles given for a state of 256"));
  EXPECT_EQ(cf_set_velocities(c.get(), l.n, nullptr), CF_ERROR_INPUT);
  EXPECT_THAT(std::string(cf_last_error(c.get())), HasSubstr("velocities is a null pointer"));
}

// Langevin through the C API: the C++ run of the same seed, bit for bit; another seed differs.
TEST(CApiMd, LangevinRunIsTheCppRunBitwise) {
  const Liquid l = liquid();
  const double box[3] = {l.edge, l.edge, l.edge};
  auto c_run = [&](uint64_t seed) {
    Handle c = create(3);
    const int periodic[3] = {1, 1, 1};
    EXPECT_EQ(cf_set_box(c.get(), box, periodic), CF_OK);
    EXPECT_EQ(cf_set_cutoff(c.get(), 2.5, nullptr), CF_OK);
    EXPECT_EQ(cf_add_type(c.get(), "A", 1.0, 1.0, nullptr), CF_OK);
    EXPECT_EQ(cf_add_type(c.get(), "B", 0.9, 0.7, nullptr), CF_OK);
    EXPECT_EQ(cf_set_integrator(c.get(), "Langevin", 0.005, 1.2, 2.0, seed), CF_OK) << cf_last_error(c.get());
    EXPECT_EQ(cf_set_state(c.get(), l.n, l.x.data(), nullptr, l.types.data(), l.m.data(), 0), CF_OK);
    EXPECT_EQ(cf_step(c.get(), 25), CF_OK);
    std::vector<double> x(3 * l.n);
    EXPECT_EQ(cf_get_state(c.get(), l.n, x.data(), nullptr, nullptr), CF_OK);
    return x;
  };
  cf::Context cpp(3);
  const bool p3[3] = {true, true, true};
  cpp.set_box(box, p3);
  cpp.set_cutoff(2.5);
  cpp.add_type("A", 1.0, 1.0);
  cpp.add_type("B", 0.9, 0.7);
  cf::IntegratorOptions o;
  o.kind = cf::Integrator::kLangevin;
  o.dt = 0.005;
  o.temperature = 1.2;
  o.friction = 2.0;
  o.seed = 5;
  cpp.set_integrator(o);
  cpp.set_state(l.n, l.x.data(), nullptr, l.types.data(), l.m.data());
  cpp.step(25);
  std::vector<double> x(3 * l.n);
  cpp.get_state(x.data(), nullptr, nullptr);
  EXPECT_TRUE(c_run(5) == x);
  EXPECT_FALSE(c_run(6) == x);
}

// Each bad input: a status, and cf_last_error naming the parameter; the context as it was.
TEST(CApiMd, BadInputIsNamed) {
  EXPECT_EQ(cf_set_integrator(nullptr, "verlet", 0.005, 1, 1, 1), CF_ERROR_INPUT);
  EXPECT_STREQ(cf_last_error(nullptr), "the context is a null pointer");
  const double one[3] = {1, 1, 1}, mass[1] = {1};
  double out[3];
  EXPECT_EQ(cf_set_state(nullptr, 1, one, nullptr, nullptr, mass, 0), CF_ERROR_INPUT);
  EXPECT_EQ(cf_step(nullptr, 1), CF_ERROR_INPUT);
  EXPECT_EQ(cf_get_state(nullptr, 1, out, nullptr, nullptr), CF_ERROR_INPUT);
  EXPECT_EQ(cf_thermo(nullptr, out, nullptr, nullptr, nullptr), CF_ERROR_INPUT);
  const double* view = nullptr;
  EXPECT_EQ(cf_state_view(nullptr, &view, nullptr, nullptr, nullptr), CF_ERROR_INPUT);
  EXPECT_EQ(cf_set_threads(nullptr, 1), CF_ERROR_INPUT);
  EXPECT_STREQ(cf_last_error(nullptr), "the context is a null pointer");

  const Liquid l = liquid();
  const double box[3] = {l.edge, l.edge, l.edge};
  const int periodic[3] = {1, 1, 1};
  Handle h = create(3);
  cf_context* c = h.get();
  ASSERT_EQ(cf_set_box(c, box, periodic), CF_OK);
  ASSERT_EQ(cf_set_cutoff(c, 2.5, "truncate"), CF_OK);
  ASSERT_EQ(cf_add_type(c, "A", 1.0, 1.0, nullptr), CF_OK);

  EXPECT_EQ(cf_set_integrator(c, "nose-hoover", 0.005, 1, 1, 1), CF_ERROR_INPUT);
  EXPECT_STREQ(cf_last_error(c), "integrator kind 'nose-hoover' is not one of verlet or langevin");
  EXPECT_EQ(cf_set_integrator(c, nullptr, 0.005, 1, 1, 1), CF_ERROR_INPUT);
  EXPECT_STREQ(cf_last_error(c), "integrator kind is a null pointer");
  EXPECT_EQ(cf_set_integrator(c, "verlet", -1, 1, 1, 1), CF_ERROR_INPUT);
  EXPECT_THAT(cf_last_error(c), HasSubstr("dt is -1"));
  EXPECT_EQ(cf_set_integrator(c, "langevin", 0.005, 1, 0, 1), CF_ERROR_INPUT);
  EXPECT_THAT(cf_last_error(c), HasSubstr("friction is 0"));

  // No state yet.
  EXPECT_EQ(cf_step(c, 1), CF_ERROR_INPUT);
  EXPECT_THAT(cf_last_error(c), HasSubstr("no MD state"));
  EXPECT_EQ(cf_get_state(c, 0, nullptr, nullptr, nullptr), CF_ERROR_INPUT);
  EXPECT_THAT(cf_last_error(c), HasSubstr("no MD state"));
  EXPECT_EQ(cf_thermo(c, out, nullptr, nullptr, nullptr), CF_ERROR_INPUT);
  EXPECT_THAT(cf_last_error(c), HasSubstr("no MD state"));
  EXPECT_EQ(cf_state_view(c, &view, nullptr, nullptr, nullptr), CF_ERROR_INPUT);
  EXPECT_THAT(cf_last_error(c), HasSubstr("no MD state"));
  EXPECT_EQ(view, nullptr);  // left unwritten

  EXPECT_EQ(cf_set_state(c, l.n, nullptr, nullptr, nullptr, l.m.data(), 0), CF_ERROR_INPUT);
  EXPECT_STREQ(cf_last_error(c), "positions is a null pointer (256 particles)");
  EXPECT_EQ(cf_set_state(c, l.n, l.x.data(), nullptr, nullptr, nullptr, 0), CF_ERROR_INPUT);
  EXPECT_STREQ(cf_last_error(c), "masses is a null pointer (256 particles)");
  EXPECT_EQ(cf_set_state(c, l.n, l.x.data(), nullptr, nullptr, l.m.data(), -3), CF_ERROR_INPUT);
  EXPECT_STREQ(cf_last_error(c), "step -3: expected a step >= 0");
  std::vector<uint32_t> bad_types(l.n, 0);
  bad_types[17] = 4;
  EXPECT_EQ(cf_set_state(c, l.n, l.x.data(), nullptr, bad_types.data(), l.m.data(), 0), CF_ERROR_INPUT);
  EXPECT_THAT(cf_last_error(c), HasSubstr("particle 17 has type index 4"));

  ASSERT_EQ(cf_set_state(c, l.n, l.x.data(), l.v.data(), nullptr, l.m.data(), 0), CF_OK);
  EXPECT_EQ(cf_step(c, -1), CF_ERROR_INPUT);
  EXPECT_STREQ(cf_last_error(c), "step count -1: expected >= 0");
  std::vector<double> x(3 * (l.n + 1), -7.0);
  EXPECT_EQ(cf_get_state(c, l.n + 1, x.data(), nullptr, nullptr), CF_ERROR_INPUT);
  EXPECT_STREQ(cf_last_error(c), "cf_get_state: n is 257 but the MD state holds 256 particles");
  EXPECT_EQ(x[0], -7.0) << "a refused call wrote its output";
  EXPECT_EQ(cf_get_state(c, 3, x.data(), nullptr, nullptr), CF_ERROR_INPUT);
  EXPECT_STREQ(cf_last_error(c), "cf_get_state: n is 3 but the MD state holds 256 particles");
  EXPECT_EQ(cf_get_state(c, l.n, x.data(), nullptr, nullptr), CF_OK);
  EXPECT_STREQ(cf_last_error(c), "");
  EXPECT_EQ(std::memcmp(x.data(), l.x.data(), 3 * l.n * sizeof(double)), 0) << "the lattice is inside the box";

  EXPECT_EQ(cf_set_threads(c, -2), CF_ERROR_INPUT);
  EXPECT_STREQ(cf_last_error(c),
               "option threads: -2 is not a thread count: expected N >= 1, or 0 or auto for OpenMP's default");
}

// cf_set_threads: 1 and 2 threads give the same bits (Jacobi), 0 is OpenMP's default.
TEST(CApiMd, ThreadsFollowTheCall) {
  const Liquid l = liquid();
  const double box[3] = {l.edge, l.edge, l.edge};
  const int periodic[3] = {1, 1, 1};
  std::vector<std::vector<double>> forces;
  for (int threads : {1, 2, 0}) {
    Handle h = create(3);
    ASSERT_EQ(cf_set_box(h.get(), box, periodic), CF_OK);
    ASSERT_EQ(cf_set_cutoff(h.get(), 2.5, NULL), CF_OK);
    ASSERT_EQ(cf_add_type(h.get(), "A", 1.0, 1.0, nullptr), CF_OK);
    ASSERT_EQ(cf_set_threads(h.get(), threads), CF_OK) << cf_last_error(h.get());
    ASSERT_EQ(cf_set_state(h.get(), l.n, l.x.data(), l.v.data(), nullptr, l.m.data(), 0), CF_OK);
    ASSERT_EQ(cf_step(h.get(), 10), CF_OK);
    ASSERT_EQ(cf_set_threads(h.get(), threads == 1 ? 2 : 1), CF_OK);  // the state is kept
    ASSERT_EQ(cf_step(h.get(), 10), CF_OK);
    forces.emplace_back(3 * l.n);
    ASSERT_EQ(cf_get_state(h.get(), l.n, nullptr, nullptr, forces.back().data()), CF_OK);
  }
  EXPECT_TRUE(forces[0] == forces[1]);
  EXPECT_TRUE(forces[0] == forces[2]);
}

// cf_set_cutoff with a NULL mode keeps the mode that option cutoff-mode set: at r just below rc the
// energy is the shifted U(r) - U(rc), not the truncated U(r).
TEST(CApiCutoff, NullModeKeepsTheMode) {
  Handle h = create(3);
  cf_context* c = h.get();
  const double box[3] = {10, 10, 10};
  const int periodic[3] = {1, 1, 1};
  ASSERT_EQ(cf_set_box(c, box, periodic), CF_OK);
  ASSERT_EQ(cf_add_type(c, "A", 1.0, 1.0, nullptr), CF_OK);
  ASSERT_EQ(cf_set_option(c, "cutoff-mode", "shift"), CF_OK);
  ASSERT_EQ(cf_set_cutoff(c, 2.5, NULL), CF_OK);
  const double r = 2.49, x[6] = {1, 2, 3, 1 + r, 2, 3};
  double f[6], e = 0;
  ASSERT_EQ(cf_compute(c, 2, x, NULL, f, &e, NULL), CF_OK);
  const double shifted = lj(r) - lj(2.5);
  EXPECT_NEAR(e, shifted, 1e-12 * std::abs(shifted));
  ASSERT_EQ(cf_set_cutoff(c, 2.5, "truncate"), CF_OK);
  ASSERT_EQ(cf_compute(c, 2, x, NULL, f, &e, NULL), CF_OK);
  EXPECT_NEAR(e, lj(r), 1e-12 * std::abs(lj(r)));
}

// cf_version is the headers' version.
TEST(CApiVersion, MacrosAreTheLibrarysVersion) {
  const std::string macros = std::to_string(CELLFORCE_VERSION_MAJOR) + "." + std::to_string(CELLFORCE_VERSION_MINOR) +
                             "." + std::to_string(CELLFORCE_VERSION_PATCH);
  EXPECT_EQ(std::string(cf_version()), macros);
}

// cf_statistics_json and Context::statistics_json: every statistic as JSON, the same text from C
// and C++, "run" null without a state and the run statistics' values with one; a buffer too small
// is refused with the length needed.
TEST(CApiStatistics, JsonHoldsEveryStatistic) {
  const Liquid l = liquid();
  const double box[3] = {l.edge, l.edge, l.edge};
  Handle c = create(3);
  const int periodic[3] = {1, 1, 1};
  ASSERT_EQ(cf_set_box(c.get(), box, periodic), CF_OK);
  ASSERT_EQ(cf_set_cutoff(c.get(), 2.5, "truncate"), CF_OK);
  ASSERT_EQ(cf_add_type(c.get(), "A", 1.0, 1.0, nullptr), CF_OK);
  ASSERT_EQ(cf_add_type(c.get(), "B", 0.9, 0.7, nullptr), CF_OK);
  ASSERT_EQ(cf_set_option(c.get(), "backend", "cpu"), CF_OK);
  auto text = [&] {
    std::size_t length = 0;
    EXPECT_EQ(cf_statistics_json(c.get(), nullptr, 0, &length), CF_OK) << cf_last_error(c.get());
    std::string out(length + 1, '\0');
    EXPECT_EQ(cf_statistics_json(c.get(), out.data(), out.size(), nullptr), CF_OK) << cf_last_error(c.get());
    out.resize(length);
    return out;
  };
  std::vector<double> f(3 * l.n);
  ASSERT_EQ(cf_compute(c.get(), l.n, l.x.data(), l.types.data(), f.data(), nullptr, nullptr), CF_OK);
  nlohmann::json doc = nlohmann::json::parse(text());
  EXPECT_TRUE(doc["run"].is_null());
  EXPECT_EQ(doc["version"], cellforce::version());
  EXPECT_EQ(doc["call"]["builds"].get<std::size_t>(), 1u);
  EXPECT_TRUE(doc["call"]["rebuilt"].get<bool>());
  EXPECT_GT(doc["call"]["buffer_bytes"].get<std::size_t>(), 0u);

  ASSERT_EQ(cf_set_integrator(c.get(), "verlet", 0.004, 0, 0, 0), CF_OK);
  ASSERT_EQ(cf_set_state(c.get(), l.n, l.x.data(), l.v.data(), l.types.data(), l.m.data(), 0), CF_OK);
  ASSERT_EQ(cf_step(c.get(), 12), CF_OK);
  doc = nlohmann::json::parse(text());
  const nlohmann::json& run = doc["run"];
  ASSERT_TRUE(run.is_object());
  EXPECT_EQ(run["steps"].get<int64_t>(), 12);
  EXPECT_EQ(run["evaluations"].get<int64_t>(), 13);  // set_state's and one a step
  EXPECT_GT(run["force_seconds"].get<double>(), 0.0);
  EXPECT_GT(run["state_bytes"].get<std::size_t>(), 0u);
  std::size_t memory = 0;
  for (const nlohmann::json& m : run["memory"]) memory += m["bytes"].get<std::size_t>();
  EXPECT_EQ(memory, run["buffer_bytes"].get<std::size_t>() + run["state_bytes"].get<std::size_t>());
  EXPECT_TRUE(run["stage_seconds"].contains("traversal"));
  // Every statistic by name: RunStatistics' fields and the engine's own, which no public struct
  // carries (keys are added, never removed, within a major version).
  std::vector<std::string> keys;
  for (const auto& [key, value] : run.items()) keys.push_back(key);
  EXPECT_THAT(keys, ::testing::UnorderedElementsAre(
                        "steps", "evaluations", "force_seconds", "integration_seconds", "step_call_seconds",
                        "bytes_to_host", "bytes_to_device", "stage_samples", "stage_seconds", "builds",
                        "largest_served_displacement", "dangerous_builds", "gated_steps", "list_evaluations",
                        "buffer_bytes", "state_bytes", "memory", "list_pairs", "list_slots", "missed_pairs",
                        "repeated_pairs", "list_mask_words", "list_mask_words_held", "graph_builds", "list_block",
                        "gate_closings", "gate_closings_early"));
  std::vector<std::string> stages;
  for (const auto& [key, value] : run["stage_seconds"].items()) stages.push_back(key);
  EXPECT_THAT(stages, ::testing::UnorderedElementsAre("cell_ids", "sort", "collision_cells", "traversal", "accumulate",
                                                      "check", "total"));
  EXPECT_EQ(run["stage_samples"].get<int64_t>(), 13);  // every CPU evaluation is sampled

  std::size_t length = 0;
  char small[8] = "unset";
  EXPECT_EQ(cf_statistics_json(c.get(), small, sizeof small, &length), CF_ERROR_INPUT);
  EXPECT_STREQ(small, "unset");
  EXPECT_GT(length, sizeof small);
  EXPECT_THAT(std::string(cf_last_error(c.get())),
              HasSubstr("a buffer of 8 bytes cannot hold the " + std::to_string(length + 1) + " bytes"));
}
