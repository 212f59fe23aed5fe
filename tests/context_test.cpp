// The C++ Context's contract beyond the numbers: set_cutoff(rc) keeps the cutoff mode, a Context
// moved from throws on every call, the thread-count option, and the version macros.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cellforce/cellforce.hpp>
#include <cellforce/version.h>

#include <omp.h>

#include <cmath>
#include <cstring>
#include <functional>
#include <string>
#include <vector>

#include "oracle.h"

namespace {

namespace cf = cellforce;
using ::testing::HasSubstr;

// The Lennard-Jones energy 4 eps ((s/r)^12 - (s/r)^6) of sigma = epsilon = 1.
double lj(double r) {
  const double s6 = 1.0 / (r * r * r * r * r * r);
  return 4.0 * (s6 * s6 - s6);
}

// Two type-A particles r apart along x in a periodic box of edge 10: the total energy.
double pair_energy(cf::Context& ctx, double r) {
  const double x[6] = {1.0, 2.0, 3.0, 1.0 + r, 2.0, 3.0};
  double f[6], e = 0;
  ctx.compute(2, x, nullptr, {f, nullptr, &e, nullptr});
  return e;
}

cf::Context pair_context() {
  cf::Context ctx(3);
  const double box[3] = {10, 10, 10};
  const bool periodic[3] = {true, true, true};
  ctx.set_box(box, periodic);
  ctx.add_type("A", 1.0, 1.0);
  return ctx;
}

}  // namespace

// set_cutoff(rc) keeps the mode that option cutoff-mode set; set_cutoff(rc, mode) sets it. At r just
// below rc the shifted energy U(r) - U(rc) is ~40x smaller than the truncated U(r).
TEST(ContextCutoff, SetCutoffKeepsTheMode) {
  const double rc = 2.5, r = 2.49;
  const double shifted = lj(r) - lj(rc), truncated = lj(r);
  ASSERT_GT(std::abs(truncated - shifted), 10 * std::abs(shifted));
  cf::Context ctx = pair_context();
  ctx.set_option("cutoff-mode", "shift");
  ctx.set_cutoff(rc);
  EXPECT_NEAR(pair_energy(ctx, r), shifted, 1e-12 * std::abs(shifted));
  ctx.set_cutoff(rc, cf::CutoffMode::kTruncate);
  EXPECT_NEAR(pair_energy(ctx, r), truncated, 1e-12 * std::abs(truncated));
  ctx.set_cutoff(rc);  // still truncated
  EXPECT_NEAR(pair_energy(ctx, r), truncated, 1e-12 * std::abs(truncated));
  ctx.set_cutoff(rc, cf::CutoffMode::kShift);
  ctx.set_cutoff(3.0);  // shifted at the new cutoff
  EXPECT_NEAR(pair_energy(ctx, r), lj(r) - lj(3.0), 1e-12 * std::abs(lj(r) - lj(3.0)));
}

// Every call on a Context moved from throws cellforce::Error saying so (none crashes); assigning
// a new Context to it makes it usable again.
TEST(ContextMove, EveryCallOnAMovedFromContextThrows) {
  cf::Context source = pair_context();
  cf::Context target(std::move(source));
  EXPECT_EQ(target.dim(), 3);
  EXPECT_EQ(target.num_types(), 1u);
  cf::Context& c = source;  // moved from
  const double x[3] = {1, 1, 1}, box[3] = {10, 10, 10}, m[1] = {1};
  const bool periodic[3] = {true, true, true};
  double f[3], out[3];
  const std::vector<std::pair<const char*, std::function<void()>>> calls = {
      {"dim", [&] { (void)c.dim(); }},
      {"num_types", [&] { (void)c.num_types(); }},
      {"set_box", [&] { c.set_box(box, periodic); }},
      {"set_cutoff", [&] { c.set_cutoff(2.5); }},
      {"set_cutoff with a mode", [&] { c.set_cutoff(2.5, cf::CutoffMode::kShift); }},
      {"set_mixing", [&] { c.set_mixing(cf::Mixing::kGeometric); }},
      {"add_type", [&] { c.add_type("B", 1, 1); }},
      {"set_pair", [&] { c.set_pair(0, 0, 1, 1); }},
      {"set_backend", [&] { c.set_backend(cf::Backend::kCpu); }},
      {"set_precision", [&] { c.set_precision(cf::Precision::kDouble); }},
      {"set_skin", [&] { c.set_skin(0.3); }},
      {"set_option", [&] { c.set_option("threads", "1"); }},
      {"compute", [&] { c.compute(1, x, nullptr, {f, nullptr, nullptr, nullptr}); }},
      {"compute_device", [&] { c.compute_device(1, x, nullptr, {f, nullptr, nullptr, nullptr}); }},
      {"synchronize", [&] { c.synchronize(); }},
      {"count_pairs", [&] { c.count_pairs(1, x, nullptr); }},
      {"statistics", [&] { (void)c.statistics(); }},
      {"compute_brute_force", [&] { c.compute_brute_force(1, x, nullptr, {f, nullptr, nullptr, nullptr}); }},
      {"set_integrator", [&] { c.set_integrator(cf::IntegratorOptions{}); }},
      {"set_state", [&] { c.set_state(1, x, nullptr, nullptr, m); }},
      {"step", [&] { c.step(1); }},
      {"current_step", [&] { (void)c.current_step(); }},
      {"num_particles", [&] { (void)c.num_particles(); }},
      {"get_state", [&] { c.get_state(out, nullptr, nullptr); }},
      {"thermo", [&] { (void)c.thermo(); }},
      {"minimize", [&] { c.minimize(cf::MinimizeOptions{}); }},
      {"neighbor_state", [&] { (void)c.neighbor_state(); }},
      {"restore_neighbor_state", [&] { c.restore_neighbor_state(cf::NeighborState{}); }},
      {"run_statistics", [&] { (void)c.run_statistics(); }},
      {"reset_run_statistics", [&] { c.reset_run_statistics(); }},
      {"backend_name", [&] { (void)c.backend_name(); }},
      {"description", [&] { (void)c.description(); }},
      {"traversal", [&] { (void)c.traversal(); }},
      {"sort", [&] { (void)c.sort(); }},
      {"skin", [&] { (void)c.skin(); }},
      {"neighbor", [&] { (void)c.neighbor(); }},
      {"neighbor_lists", [&] { (void)c.neighbor_lists(); }},
  };
  for (const auto& [name, call] : calls) {
    SCOPED_TRACE(name);
    try {
      call();
      ADD_FAILURE() << "a call on a moved-from Context returned";
    } catch (const cf::Error& e) {
      EXPECT_EQ(e.message(), "this cellforce::Context was moved from: it holds no box, types or engine any more");
    }
  }
  // Move assignment moves from the right-hand side too, and gives the left a context again.
  source = std::move(target);
  EXPECT_EQ(source.num_types(), 1u);
  EXPECT_THROW((void)target.dim(), cf::Error);
  target = cf::Context(2);
  EXPECT_EQ(target.dim(), 2);
}

namespace {

// A random binary LJ liquid of 3,000 particles on a CPU context with `threads` threads.
struct Threaded {
  cf::Configuration config;
  cf::Context ctx{3};
};

void set_up(Threaded& t, const std::string& threads, cf::Precision precision) {
  cftest::RandomSpec spec;
  spec.min_distance = 0.8;
  spec.num_types = 2;
  t.config = cftest::random_configuration(cftest::cube(3, 15.5), 3000, 99, spec);
  const bool periodic[3] = {true, true, true};
  t.ctx.set_box(t.config.box.length, periodic);
  t.ctx.set_cutoff(2.5, cf::CutoffMode::kForceShift);
  t.ctx.add_type("A", 1.0, 1.0);
  t.ctx.add_type("B", 0.88, 0.5);
  t.ctx.set_precision(precision);
  t.ctx.set_option("threads", threads);
}

std::vector<double> results(Threaded& t) {
  const std::size_t n = t.config.size();
  std::vector<double> out(4 * n + 10);
  t.ctx.compute(n, t.config.positions.data(), t.config.types.data(),
                {out.data(), out.data() + 3 * n, out.data() + 4 * n, out.data() + 4 * n + 1});
  return out;
}

}  // namespace

// Jacobi accumulation sums in a fixed order: 1 and 2 threads give the same bits, in every
// precision. The description names the engine's thread count, which follows the option; auto and 0
// are OpenMP's default of the calling thread; the caller's own count is left as it was.
TEST(ContextThreads, OneAndTwoThreadsGiveTheSameBits) {
  for (cf::Precision p : {cf::Precision::kDouble, cf::Precision::kMixed, cf::Precision::kSingle}) {
    Threaded one, two;
    set_up(one, "1", p);
    set_up(two, "2", p);
    const int before = omp_get_max_threads();
    const std::vector<double> a = results(one), b = results(two);
    EXPECT_EQ(omp_get_max_threads(), before);
    ASSERT_EQ(a.size(), b.size());
    EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(double)), 0) << "1 and 2 threads differ";
    EXPECT_EQ(one.ctx.description(), "CPU, 1 OpenMP thread");
    EXPECT_EQ(two.ctx.description(), "CPU, 2 OpenMP threads");
  }
  cf::Context ctx(3);
  ctx.set_option("threads", "7");
  EXPECT_EQ(ctx.description(), "CPU, 7 OpenMP threads");
  const std::string automatic = "CPU, " + std::to_string(omp_get_max_threads()) +
                                (omp_get_max_threads() == 1 ? " OpenMP thread" : " OpenMP threads");
  ctx.set_option("threads", "AUTO");
  EXPECT_EQ(ctx.description(), automatic);
  ctx.set_option("threads", "3");
  ctx.set_option("threads", "0");
  EXPECT_EQ(ctx.description(), automatic);
}

// A thread count that is not one is refused naming the option and the value; the count stays.
TEST(ContextThreads, BadCountsAreNamed) {
  cf::Context ctx(3);
  ctx.set_option("threads", "3");
  const std::pair<const char*, const char*> bad[] = {
      {"-1", "option threads: -1 is not a thread count: expected N >= 1, or 0 or auto for OpenMP's default"},
      {"two", "option threads: 'two' is not an integer"},
      {"1.5", "option threads: '1.5' is not an integer"},
      {"", "option threads: '' is not an integer"},
      {"99999999999", "option threads: "},
  };
  for (const auto& [value, message] : bad) {
    SCOPED_TRACE(value);
    try {
      ctx.set_option("threads", value);
      ADD_FAILURE() << "taken";
    } catch (const cf::Error& e) {
      EXPECT_THAT(e.message(), HasSubstr(message));
    }
    EXPECT_EQ(ctx.description(), "CPU, 3 OpenMP threads");
  }
}

// The macros of the headers are the library's version (they come from one project version).
TEST(Version, MacrosAreTheLibrarysVersion) {
  const std::string macros = std::to_string(CELLFORCE_VERSION_MAJOR) + "." + std::to_string(CELLFORCE_VERSION_MINOR) +
                             "." + std::to_string(CELLFORCE_VERSION_PATCH);
  EXPECT_EQ(std::string(cf::version()), macros);
  EXPECT_STREQ(CELLFORCE_VERSION_STRING, cf::version());
}

// set_backend(backend) keeps the device the option chose: the CUDA engine is then asked for device
// 57, which does not exist, and the call names it (a device reset to 0 would compute).
TEST(ContextBackend, SetBackendKeepsTheDevice) {
#ifdef CELLFORCE_HAVE_CUDA
  cf::Context probe(3);
  probe.set_backend(cf::Backend::kAuto);
  if (probe.backend_name() != "cuda") GTEST_SKIP() << "no CUDA device here";
  cf::Context ctx = pair_context();
  ctx.set_cutoff(2.5);
  ctx.set_option("device", "57");
  ctx.set_backend(cf::Backend::kCpu);
  EXPECT_TRUE(std::isfinite(pair_energy(ctx, 1.5)));  // the CPU has no device
  try {
    ctx.set_backend(cf::Backend::kCuda);
    pair_energy(ctx, 1.5);
    ADD_FAILURE() << "device 57 was not asked for";
  } catch (const cf::Error& e) {
    EXPECT_THAT(std::string(e.what()), HasSubstr("device 57 does not exist"));
  }
#else
  GTEST_SKIP() << "this build has no CUDA";
#endif
}
