// The public API (include/cellforce): the C++ Context and the C functions against the
// double-precision brute force and analytic pair values, bitwise against `cellforce forces` on the
// same input, backend and precision, and every bad input of the C API answered with a status and a
// message naming the parameter or particle. The device-pointer tests need a CUDA device and skip
// without one.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cellforce/cellforce.h>
#include <cellforce/cellforce.hpp>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#ifdef CELLFORCE_HAVE_CUDA
#include <cuda_runtime.h>

#include "backend/engine.h"  // cuda/backend/engine.h: GpuEngine::unavailable
#endif

#include "cli/forces.h"
#include "core/engine_options.h"
#include "core/grid.h"
#include "core/names.h"
#include "core/option_table.h"
#include "io/configuration_file.h"
#include "io/hdf5.h"
#include "oracle.h"
#include "reference/brute_force.h"
#include "temp_folder.h"

namespace {

using ::testing::HasSubstr;
namespace cf = cellforce;

// A binary Lennard-Jones liquid (A, B; Lorentz-Berthelot with an explicit A-B pair), periodic.
struct Binary {
  cf::Configuration config;
  cf::ForceField ff;
};

Binary binary_liquid(int dim, std::size_t n, uint64_t seed) {
  Binary b;
  const double edge = dim == 3 ? std::cbrt(double(n) / 0.8) : std::sqrt(double(n) / 0.7);
  cftest::RandomSpec spec;
  spec.min_distance = 0.8;
  spec.num_types = 2;
  b.config = cftest::random_configuration(cftest::cube(dim, edge), n, seed, spec);
  b.ff.cutoff = 2.5;
  b.ff.mode = cf::CutoffMode::kForceShift;
  b.ff.types = {{"A", 1.0, 1.0}, {"B", 0.88, 0.5}};
  b.ff.overrides = {{0, 1, 0.8, 1.5}};
  return b;
}

cf::Context context_for(const Binary& b, cf::Backend backend, cf::Precision precision) {
  cf::Context ctx(b.config.box.dim);
  const bool periodic[3] = {b.config.box.periodic[0], b.config.box.periodic[1], b.config.box.periodic[2]};
  ctx.set_box(b.config.box.length, periodic);
  ctx.set_cutoff(b.ff.cutoff, b.ff.mode);
  for (const auto& t : b.ff.types) ctx.add_type(t.name, t.sigma, t.epsilon);
  for (const auto& o : b.ff.overrides) ctx.set_pair(uint32_t(o.a), uint32_t(o.b), o.sigma, o.epsilon);
  ctx.set_backend(backend);
  ctx.set_precision(precision);
  return ctx;
}

// compute() into a ForceResult (the oracle's layout).
cf::ForceResult compute(cf::Context& ctx, const cf::Configuration& c) {
  cf::ForceResult r;
  const int dim = std::min(c.box.dim, 3);
  r.dim = dim;
  r.forces.assign(c.size() * std::size_t(dim), std::nan(""));
  r.energies.assign(c.size(), std::nan(""));
  double w[9] = {};
  ctx.compute(c.size(), c.positions.data(), c.types.data(), {r.forces.data(), r.energies.data(), &r.energy, w});
  for (int a = 0; a < dim; ++a)
    for (int b = 0; b < dim; ++b) r.virial[a][b] = w[a * dim + b];
  return r;
}

std::vector<cf::Backend> backends_here() {
  std::vector<cf::Backend> out = {cf::Backend::kCpu};
#ifdef CELLFORCE_HAVE_CUDA
  if (cf::GpuEngine::unavailable().empty()) out.push_back(cf::Backend::kCuda);
#endif
  return out;
}

// Tolerances against the double brute force: double arithmetic agrees to rounding; float pairs
// to a few float ulps of the largest forces.
double tolerance(cf::Precision p) { return p == cf::Precision::kDouble ? 1e-11 : 2e-5; }

const cf::Precision kPrecisions[] = {cf::Precision::kDouble, cf::Precision::kMixed, cf::Precision::kSingle};

}  // namespace

// ---- the C++ API ----------------------------------------------------------------------------------

// The traversal option's names are accepted and others refused (the rule `auto` follows:
// tests/memory_plan_test.cpp).
TEST(EngineOptions, TraversalOptionNames) {
  cf::Context ctx(3);
  ctx.set_option("traversal", "auto");
  ctx.set_option("traversal", "tile");
  EXPECT_THROW(ctx.set_option("traversal", "block"), cf::Error);
  ctx.set_option("neighbor-list", "true");
  ctx.set_option("neighbor-list", "false");
  EXPECT_THROW(ctx.set_option("neighbor-list", "yes"), cf::Error);
}

// The option table (core/option_table.h) is the one list of set_option's keys: each key finds its
// row, the unknown-key message lists them all, each default is what a new Context takes, and each
// choice's names are accepted in any letter case while others are refused with the list.
TEST(EngineOptions, OneTableOfOptionNames) {
  std::set<std::string> keys;
  for (const cf::OptionSpec& o : cf::kOptions) {
    SCOPED_TRACE(o.key);
    EXPECT_TRUE(keys.insert(o.key).second) << "a key given twice";
    EXPECT_EQ(cf::find_option(o.key), &o);
    EXPECT_EQ(&cf::option_spec(o.id), &o);
    cf::Context ctx(3);
    EXPECT_NO_THROW(ctx.set_option(o.key, o.default_value));
    if (o.kind == cf::OptionKind::kChoice || o.kind == cf::OptionKind::kBoolean) {
      ASSERT_GT(o.names.size, 1u);
      EXPECT_NE(cf::option_name(o.id, o.default_value), nullptr) << "the default is one of the names";
      for (const char* name : o.names) {
        std::string upper(name);
        for (char& c : upper) c = char(std::toupper(static_cast<unsigned char>(c)));
        EXPECT_EQ(cf::option_name(o.id, upper), name);
        if (o.id != cf::OptionId::kBackend) {  // (cuda: taken, but no device to make an engine on here)
          EXPECT_NO_THROW(ctx.set_option(o.key, upper)) << name;
        }
      }
      EXPECT_EQ(cf::option_name(o.id, "none-such"), nullptr);
      EXPECT_THROW(ctx.set_option(o.key, "none-such"), cf::Error);
    }
  }
  EXPECT_EQ(cf::find_option("Backend"), nullptr) << "keys are exact";
  try {
    cf::Context(3).set_option("colour", "blue");
    ADD_FAILURE() << "an unknown key was taken";
  } catch (const cf::Error& e) {
    EXPECT_EQ(e.message(), "unknown option 'colour'; options: " + cf::option_keys());
  }
  EXPECT_EQ(cf::option_keys(), "backend, device, precision, mixing, cutoff-mode, skin, neighbor-check, "
                               "neighbor-every, neighbor-audit, neighbor-list, accumulation, cell-rule, traversal, "
                               "sort, memory, threads");
  // The application's list: each option once, in the order first given; a value given again
  // replaces the first in place; an option not given reads as the table's default.
  cf::OptionList list;
  list.set(cf::OptionId::kSkin, "0.3");
  list.set(cf::OptionId::kBackend, "cpu");
  list.set(cf::OptionId::kSkin, "auto");
  ASSERT_EQ(list.entries().size(), 2u);
  EXPECT_STREQ(list.entries()[0].key(), "skin");
  EXPECT_EQ(list.entries()[0].value, "auto");
  EXPECT_STREQ(list.entries()[1].key(), "backend");
  EXPECT_EQ(list.find(cf::OptionId::kMemory), nullptr);
  EXPECT_EQ(list.value(cf::OptionId::kMemory), "auto");
  EXPECT_EQ(list.value(cf::OptionId::kBackend), "cpu");
}

TEST(Api, ComputeMatchesTheBruteForceOnEveryBackendAndPrecision) {
  for (int dim : {3, 2}) {
    const Binary b = binary_liquid(dim, 900, 7 + uint64_t(dim));
    cf::ForceResult ref;
    cf::brute_force(b.config.view(), b.ff, cf::Request{true, true}, ref);
    for (cf::Backend backend : backends_here())
      for (cf::Precision p : kPrecisions) {
        SCOPED_TRACE(std::string(cf::to_string(backend)) + " " + cf::to_string(p) + " " + std::to_string(dim) + "D");
        cf::Context ctx = context_for(b, backend, p);
        const cf::ForceResult got = compute(ctx, b.config);
        EXPECT_TRUE(cftest::forces_match(ref, got, tolerance(p)));
        EXPECT_TRUE(cftest::energies_match(ref, got, tolerance(p)));
        EXPECT_TRUE(cftest::total_energy_matches(ref, got, tolerance(p)));
        EXPECT_TRUE(cftest::virial_matches(ref, got, tolerance(p)));
        EXPECT_EQ(ctx.backend_name(), cf::to_string(backend));
      }
  }
}

// compute_brute_force is the oracle itself, whatever the context's backend and precision: bitwise
// the double brute force, with its outputs optional as compute()'s and its input checked the same.
TEST(Api, BruteForceIsTheOracleOnEveryBackendAndPrecision) {
  for (int dim : {3, 2}) {
    const Binary b = binary_liquid(dim, 600, 17 + uint64_t(dim));
    cf::ForceResult ref;
    cf::brute_force(b.config.view(), b.ff, cf::Request{true, true}, ref);
    for (cf::Backend backend : backends_here())
      for (cf::Precision p : kPrecisions) {
        SCOPED_TRACE(std::string(cf::to_string(backend)) + " " + cf::to_string(p) + " " + std::to_string(dim) + "D");
        cf::Context ctx = context_for(b, backend, p);
        cf::ForceResult got;
        got.dim = dim;
        got.forces.assign(b.config.size() * std::size_t(dim), std::nan(""));
        got.energies.assign(b.config.size(), std::nan(""));
        double w[9] = {};
        ctx.compute_brute_force(b.config.size(), b.config.positions.data(), b.config.types.data(),
                                {got.forces.data(), got.energies.data(), &got.energy, w});
        for (int r = 0; r < dim; ++r)
          for (int c = 0; c < dim; ++c) got.virial[r][c] = w[r * dim + c];
        EXPECT_TRUE(cftest::bitwise_equal(ref, got));
        std::vector<double> forces_only(b.config.size() * std::size_t(dim));
        ctx.compute_brute_force(b.config.size(), b.config.positions.data(), b.config.types.data(),
                                {forces_only.data()});
        EXPECT_EQ(std::memcmp(forces_only.data(), ref.forces.data(), forces_only.size() * sizeof(double)), 0);
      }
  }
  const Binary b = binary_liquid(3, 300, 3);
  cf::Context ctx = context_for(b, cf::Backend::kCpu, cf::Precision::kDouble);
  std::vector<double> f(900);
  std::vector<double> bad = b.config.positions;
  bad[3 * 7 + 1] = std::nan("");
  const std::string msg = [&] {
    try {
      ctx.compute_brute_force(300, bad.data(), b.config.types.data(), {f.data()});
    } catch (const cf::Error& e) {
      return std::string(e.what());
    }
    return std::string();
  }();
  EXPECT_THAT(msg, HasSubstr("particle 7"));
  cf::Context empty(3);
  EXPECT_THROW(empty.compute_brute_force(300, b.config.positions.data(), nullptr, {f.data()}), cf::Error);
}

// count_pairs reports the search structure it counted on, and statistics() the last call's time by
// stage: cell-ID entries n x 2^dim, every particle's home entry valid, cells at least the cell rule's
// edge, pairs tested at least those within the cutoff (the brute force's count).
TEST(Api, PairCountsDescribeTheSearchStructure) {
  for (int dim : {3, 2}) {
    const Binary b = binary_liquid(dim, 900, 27 + uint64_t(dim));
    const std::size_t n = b.config.size();
    const std::size_t within = cf::brute_force_pairs(b.config.view(), b.ff).size();
    for (cf::Backend backend : backends_here())
      for (const char* rule : {"tight", "chapter"}) {
        SCOPED_TRACE(std::string(cf::to_string(backend)) + " " + rule + " " + std::to_string(dim) + "D");
        cf::Context ctx = context_for(b, backend, cf::Precision::kDouble);
        ctx.set_option("cell-rule", rule);
        std::vector<double> f(n * std::size_t(dim));
        ctx.compute(n, b.config.positions.data(), b.config.types.data(), {f.data()});
        const cf::Statistics st = ctx.statistics();
        for (double t : {st.cell_ids_seconds, st.sort_seconds, st.collision_cells_seconds, st.traversal_seconds,
                         st.accumulate_seconds})
          EXPECT_GE(t, 0.0);
        const cf::PairCounts c = ctx.count_pairs(n, b.config.positions.data(), b.config.types.data());
        EXPECT_EQ(c.within_cutoff, within);
        EXPECT_GE(c.tested, c.within_cutoff);
        EXPECT_EQ(c.entries, n << dim);
        EXPECT_GE(c.valid_entries, n);
        EXPECT_LE(c.valid_entries, c.entries);
        EXPECT_GT(c.collision_cells, 0u);
        EXPECT_GE(c.max_occupancy, 2u);
        const double reach = b.ff.cutoff + ctx.skin();  // the structure's search radius (a skin on CUDA: auto)
        EXPECT_NEAR(c.half_width, reach * std::sqrt(0.5), 1e-5 * reach);
        const cf::CellRule r = *cf::parse_name(rule, cf::kCellRuleNames);
        for (int a = 0; a < 3; ++a) {
          if (a >= dim) {
            EXPECT_EQ(c.grid_cells[a], 1u);
            continue;
          }
          EXPECT_GE(c.grid_cells[a], 1u);
          EXPECT_NEAR(c.cell_edge[a] * c.grid_cells[a], b.config.box.length[a], 1e-9 * b.config.box.length[a]);
          if (c.grid_cells[a] > 1) {
            EXPECT_GE(c.cell_edge[a], cf::min_cell_edge(r, reach, c.half_width));
          }
        }
      }
  }
}

// The automatic skin of force calls follows the cutoff and the box (CUDA: 0.24 rc): a new cutoff
// after the first call makes the engine again, whose structure is then built for rc + 0.24 rc
// (count_pairs' half width (rc + skin) / sqrt(2)), and a box too small for lists leaves no skin.
TEST(Api, ForceCallsSkinFollowsTheCutoffAndTheBox) {
  if (!cf::GpuEngine::unavailable().empty()) GTEST_SKIP() << cf::GpuEngine::unavailable();
  const Binary b = binary_liquid(3, 2000, 41);  // edge 13.6
  cf::Context ctx = context_for(b, cf::Backend::kCuda, cf::Precision::kDouble);
  const std::size_t n = b.config.size();
  std::vector<double> f(n * 3);
  auto half_width = [&] {
    ctx.compute(n, b.config.positions.data(), b.config.types.data(), {f.data()});
    return ctx.count_pairs(n, b.config.positions.data(), b.config.types.data()).half_width;
  };
  EXPECT_NEAR(half_width(), (2.5 + 0.6) * std::sqrt(0.5), 1e-5);
  ctx.set_cutoff(3.0);
  EXPECT_DOUBLE_EQ(ctx.skin(), 0.24 * 3.0);
  EXPECT_NEAR(half_width(), (3.0 + 0.72) * std::sqrt(0.5), 1e-5);
  ctx.set_cutoff(6.0);  // 2 (6 + 1.44) > 13.6: no lists, no skin
  EXPECT_EQ(ctx.skin(), 0.0);
  EXPECT_NEAR(half_width(), 6.0 * std::sqrt(0.5), 1e-5);
}

// Two particles at r = 1.5 (sigma 1.1, epsilon 0.7), truncated: the analytic force, energy and
// virial, through the C++ and the C API alike.
TEST(Api, TwoParticlesGiveTheAnalyticPairValues) {
  const double r = 1.5, sigma = 1.1, eps = 0.7;
  const double sr6 = std::pow(sigma / r, 6);
  const double energy = 4 * eps * (sr6 * sr6 - sr6);
  const double force = 24 * eps * (2 * sr6 * sr6 - sr6) / r;  // on particle 0 along x_0 - x_1
  const double pos[6] = {2.0, 3.0, 3.0, 3.5, 3.0, 3.0};      // x_0 - x_1 = -1.5 along x
  const double box[3] = {10, 10, 10};
  for (cf::Backend backend : backends_here()) {
    SCOPED_TRACE(cf::to_string(backend));
    cf::Context ctx(3);
    const bool periodic[3] = {true, true, true};
    ctx.set_box(box, periodic);
    ctx.set_cutoff(3.0);
    ctx.add_type("A", sigma, eps);
    ctx.set_backend(backend);
    double f[6], e = 0, w[9];
    ctx.compute(2, pos, nullptr, {f, nullptr, &e, w});
    EXPECT_NEAR(e, energy, 1e-14 * std::abs(energy));
    EXPECT_NEAR(f[0], -force, 1e-13 * std::abs(force));
    EXPECT_NEAR(f[3], force, 1e-13 * std::abs(force));
    EXPECT_EQ(f[1], 0.0);
    EXPECT_NEAR(w[0], r * force, 1e-13 * std::abs(r * force));  // (-r)(-F) along x
    EXPECT_EQ(w[4], 0.0);

    cf_context* c = nullptr;
    ASSERT_EQ(cf_create(&c, 3), CF_OK) << cf_last_error(nullptr);
    const int pbc[3] = {1, 1, 1};
    ASSERT_EQ(cf_set_box(c, box, pbc), CF_OK);
    ASSERT_EQ(cf_set_cutoff(c, 3.0, "truncate"), CF_OK);
    uint32_t index = 99;
    ASSERT_EQ(cf_add_type(c, "A", sigma, eps, &index), CF_OK);
    EXPECT_EQ(index, 0u);
    ASSERT_EQ(cf_set_option(c, "backend", cf::to_string(backend)), CF_OK) << cf_last_error(c);
    double fc[6], ec = 0, wc[9];
    ASSERT_EQ(cf_compute(c, 2, pos, nullptr, fc, &ec, wc), CF_OK) << cf_last_error(c);
    EXPECT_EQ(std::memcmp(f, fc, sizeof f), 0) << "the C API differs from the C++ API";
    EXPECT_EQ(std::memcmp(&e, &ec, sizeof e), 0);
    EXPECT_EQ(std::memcmp(w, wc, sizeof w), 0);
    EXPECT_STREQ(cf_last_error(c), "");
    cf_destroy(c);
  }
}

// The binary liquid in SI units (lengths times 3.4e-10 m, energies times 1.65e-21 J: argon's) through
// the C API, on every backend and precision: its forces times L / E, energies / E and virial / E
// match the double brute force of the liquid in reduced units with the tolerance of reduced units.
// A float precision that cannot hold the pair's constants (epsilon times 1e40) is refused with
// CF_ERROR_INPUT naming the type, epsilon and the precision; double computes it.
TEST(CApi, SiUnitsGiveTheReducedForcesInEveryPrecision) {
  const double L = 3.4e-10, E = 1.65e-21;
  const Binary b = binary_liquid(3, 900, 11);
  cf::ForceResult ref;
  cf::brute_force(b.config.view(), b.ff, cf::Request{true, true}, ref);
  std::vector<double> pos = b.config.positions;
  for (double& x : pos) x *= L;
  const double box[3] = {b.config.box.length[0] * L, b.config.box.length[1] * L, b.config.box.length[2] * L};
  const int pbc[3] = {1, 1, 1};
  auto make = [&](cf::Backend backend, cf::Precision p, double energy) {
    cf_context* c = nullptr;
    EXPECT_EQ(cf_create(&c, 3), CF_OK) << cf_last_error(nullptr);
    EXPECT_EQ(cf_set_box(c, box, pbc), CF_OK) << cf_last_error(c);
    EXPECT_EQ(cf_set_cutoff(c, b.ff.cutoff * L, "force-shift"), CF_OK) << cf_last_error(c);
    for (const auto& t : b.ff.types) EXPECT_EQ(cf_add_type(c, t.name.c_str(), t.sigma * L, t.epsilon * energy, nullptr), CF_OK) << cf_last_error(c);
    for (const auto& o : b.ff.overrides)
      EXPECT_EQ(cf_set_pair(c, uint32_t(o.a), uint32_t(o.b), o.sigma * L, o.epsilon * energy), CF_OK) << cf_last_error(c);
    EXPECT_EQ(cf_set_option(c, "backend", cf::to_string(backend)), CF_OK) << cf_last_error(c);
    EXPECT_EQ(cf_set_option(c, "precision", cf::to_string(p)), CF_OK) << cf_last_error(c);
    return c;
  };
  const std::size_t n = b.config.size();
  for (cf::Backend backend : backends_here())
    for (cf::Precision p : kPrecisions) {
      SCOPED_TRACE(std::string(cf::to_string(backend)) + " " + cf::to_string(p));
      cf_context* c = make(backend, p, E);
      cf::ForceResult got;
      got.dim = 3;
      got.forces.resize(3 * n);
      got.energies.resize(n);
      double w[9];
      ASSERT_EQ(cf_compute(c, n, pos.data(), b.config.types.data(), got.forces.data(), &got.energy, w), CF_OK)
          << cf_last_error(c);
      cf_destroy(c);
      for (double& f : got.forces) f *= L / E;
      got.energy /= E;
      for (int a = 0; a < 3; ++a)
        for (int k = 0; k < 3; ++k) got.virial[a][k] = w[a * 3 + k] / E;
      EXPECT_TRUE(cftest::forces_match(ref, got, tolerance(p)));
      EXPECT_TRUE(cftest::total_energy_matches(ref, got, tolerance(p)));
      EXPECT_TRUE(cftest::virial_matches(ref, got, tolerance(p)));

      cf_context* huge = make(backend, p, E * 1e61);  // epsilon ~ 1e40
      std::vector<double> f(3 * n);
      const int status = cf_compute(huge, n, pos.data(), b.config.types.data(), f.data(), nullptr, nullptr);
      if (p == cf::Precision::kDouble) {
        EXPECT_EQ(status, CF_OK) << cf_last_error(huge);
      } else {
        EXPECT_EQ(status, CF_ERROR_INPUT);
        EXPECT_THAT(cf_last_error(huge), HasSubstr("type 'A'"));
        EXPECT_THAT(cf_last_error(huge), HasSubstr("epsilon"));
        EXPECT_THAT(cf_last_error(huge), HasSubstr(std::string(cf::to_string(p)) + " precision"));
      }
      cf_destroy(huge);
    }
}

// A sigma far from the particles' spacing (1e4, the liquid's unit spacing left as it was) makes
// the force of two particles 1 apart overflow float: in single and mixed precision the error names
// the pair, the distance in sigmas, sigma and its type, and F/r against the precision's range, not
// only the particles (F/r = 48 eps sigma^12 / r^14 ~ 4.8e49); double evaluates the pair (F = 48 eps
// sigma^12 / r^13 - 24 eps sigma^6 / r^7, to 1e-13).
TEST(Api, AFloatForceBeyondRangeNamesSigma) {
  const double pos[6] = {2.0, 3.0, 3.0, 3.0, 3.0, 3.0};
  const double box[3] = {10, 10, 10};
  const bool periodic[3] = {true, true, true};
  for (cf::Backend backend : backends_here())
    for (cf::Precision p : kPrecisions) {
      SCOPED_TRACE(std::string(cf::to_string(backend)) + " " + cf::to_string(p));
      cf::Context ctx(3);
      ctx.set_box(box, periodic);
      ctx.set_cutoff(2.5);
      ctx.add_type("A", 1e4, 1.0);
      ctx.set_backend(backend);
      ctx.set_precision(p);
      double f[6] = {};
      if (p == cf::Precision::kDouble) {
        ctx.compute(2, pos, nullptr, {f, nullptr, nullptr, nullptr});
        const double want = 48 * std::pow(1e4, 12) - 24 * std::pow(1e4, 6);  // r = 1
        EXPECT_NEAR(f[3], want, 1e-13 * want);
        continue;
      }
      try {
        ctx.compute(2, pos, nullptr, {f, nullptr, nullptr, nullptr});
        ADD_FAILURE() << "the float evaluation was accepted";
      } catch (const cf::Error& e) {
        const std::string msg = e.what();
        EXPECT_THAT(msg, HasSubstr("particles 0 and 1 are too close (r = 1, 1e-04 sigma with sigma 10000 of type 'A')"));
        EXPECT_THAT(msg, HasSubstr("F/r ~ 4.8"));
        EXPECT_THAT(msg, HasSubstr("e+49, is beyond " + std::string(cf::to_string(p)) + " precision's float range"));
        EXPECT_THAT(msg, HasSubstr("else correct sigma of type 'A'"));
      }
    }
}

// The box, the particle count and the types may change between calls: each call equals a fresh
// context's, and the brute force.
TEST(Api, BoxAndParticleCountMayChangeBetweenCalls) {
  for (cf::Backend backend : backends_here()) {
    SCOPED_TRACE(cf::to_string(backend));
    const Binary small = binary_liquid(3, 500, 31), large = binary_liquid(3, 1400, 32);
    cf::Context ctx = context_for(small, backend, cf::Precision::kDouble);
    for (const Binary* b : {&small, &large, &small}) {
      const bool periodic[3] = {true, true, true};
      ctx.set_box(b->config.box.length, periodic);
      const cf::ForceResult got = compute(ctx, b->config);
      cf::Context fresh = context_for(*b, backend, cf::Precision::kDouble);
      EXPECT_TRUE(cftest::bitwise_equal(compute(fresh, b->config), got));
      cf::ForceResult ref;
      cf::brute_force(b->config.view(), b->ff, cf::Request{true, true}, ref);
      EXPECT_TRUE(cftest::forces_match(ref, got, 1e-11));
    }
  }
}

// Only what is asked for is written; n = 0 is a valid, empty call.
TEST(Api, OptionalOutputsAndEmptyCalls) {
  const Binary b = binary_liquid(3, 300, 5);
  for (cf::Backend backend : backends_here()) {
    SCOPED_TRACE(cf::to_string(backend));
    cf::Context ctx = context_for(b, backend, cf::Precision::kDouble);
    std::vector<double> f(b.config.size() * 3);
    ctx.compute(b.config.size(), b.config.positions.data(), b.config.types.data(), {f.data()});
    const cf::ForceResult all = compute(ctx, b.config);
    EXPECT_EQ(std::memcmp(f.data(), all.forces.data(), f.size() * sizeof(double)), 0);
    double e = 1.0, w[9];
    std::fill(std::begin(w), std::end(w), 1.0);
    ctx.compute(0, nullptr, nullptr, {nullptr, nullptr, &e, w});
    EXPECT_EQ(e, 0.0);
    for (double v : w) EXPECT_EQ(v, 0.0);
  }
}

// ---- bitwise equal to `cellforce forces` ------------------------------------------------------------

using ApiVsForcesCommand = cftest::TempFolder;

TEST_F(ApiVsForcesCommand, ApiResultsAreBitwiseTheForcesFile) {
  const Binary b = binary_liquid(3, 800, 11);
  const std::string xyz = path("in.xyz");
  cf::write_extxyz(xyz, b.config, {"A", "B"});
  for (cf::Backend backend : backends_here())
    for (cf::Precision p : kPrecisions) {
      SCOPED_TRACE(std::string(cf::to_string(backend)) + " " + cf::to_string(p));
      cf::ForcesArgs args;
      args.input = xyz;
      args.out = path("out.h5");
      args.overwrite = true;
      args.cutoff = b.ff.cutoff;
      args.mode = b.ff.mode;
      args.types = {"A:1.0:1.0", "B:0.88:0.5"};
      args.pairs = {"A:B:0.8:1.5"};
      args.engine.set(cf::OptionId::kBackend, cf::to_string(backend));
      args.engine.set(cf::OptionId::kPrecision, cf::to_string(p));
      args.quiet = true;
      ASSERT_EQ(cf::run_forces(args), 0);
      cf::h5::File f = cf::h5::File::open_read(args.out);
      const auto forces = cf::h5::read_doubles(f.id(), "forces", args.out).values;
      const auto energies = cf::h5::read_doubles(f.id(), "energies", args.out).values;
      const auto energy = cf::h5::read_doubles(f.id(), "energy", args.out).values;
      const auto virial = cf::h5::read_doubles(f.id(), "virial", args.out).values;

      // The same input as the file holds it (the API reads the coordinates the XYZ file gives).
      const cf::ConfigurationFile input = cf::read_configuration(xyz);
      cf::Context ctx = context_for(b, backend, p);
      const cf::ForceResult got = compute(ctx, input.config);
      ASSERT_EQ(forces.size(), got.forces.size());
      EXPECT_EQ(std::memcmp(forces.data(), got.forces.data(), forces.size() * sizeof(double)), 0);
      EXPECT_EQ(std::memcmp(energies.data(), got.energies.data(), energies.size() * sizeof(double)), 0);
      ASSERT_EQ(energy.size(), 1u);
      EXPECT_EQ(std::memcmp(&energy[0], &got.energy, sizeof(double)), 0);
      ASSERT_EQ(virial.size(), 9u);
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) EXPECT_EQ(std::memcmp(&virial[std::size_t(r * 3 + c)], &got.virial[r][c], 8), 0);
    }
}

// ---- the C API: every bad input gives a status and a message -----------------------------------------

namespace {

// A ready 3D context (box 8, rc 2.5, one type) on the CPU.
cf_context* ready_context() {
  cf_context* c = nullptr;
  EXPECT_EQ(cf_create(&c, 3), CF_OK);
  const double box[3] = {8, 8, 8};
  const int pbc[3] = {1, 1, 1};
  EXPECT_EQ(cf_set_box(c, box, pbc), CF_OK);
  EXPECT_EQ(cf_set_cutoff(c, 2.5, nullptr), CF_OK);
  EXPECT_EQ(cf_add_type(c, "A", 1.0, 1.0, nullptr), CF_OK);
  return c;
}

struct Expect {
  cf_status status;
  std::string message;  // a piece of cf_last_error
};

void expect(cf_status got, const cf_context* c, const Expect& e) {
  EXPECT_EQ(got, e.status) << cf_last_error(c);
  EXPECT_THAT(std::string(cf_last_error(c)), HasSubstr(e.message));
}

}  // namespace

TEST(CApi, BadInputGivesAStatusAndAMessageNamingIt) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  // Creation.
  expect(cf_create(nullptr, 3), nullptr, {CF_ERROR_INPUT, "ctx"});
  cf_context* none = reinterpret_cast<cf_context*>(0x1);
  expect(cf_create(&none, 4), nullptr, {CF_ERROR_INPUT, "dimension 4"});
  EXPECT_EQ(none, nullptr);
  // A null context on every call.
  expect(cf_set_cutoff(nullptr, 2.5, nullptr), nullptr, {CF_ERROR_INPUT, "context is a null pointer"});
  expect(cf_compute(nullptr, 0, nullptr, nullptr, nullptr, nullptr, nullptr), nullptr,
         {CF_ERROR_INPUT, "context is a null pointer"});
  cf_destroy(nullptr);

  cf_context* c = nullptr;
  ASSERT_EQ(cf_create(&c, 3), CF_OK);
  const double pos[12] = {1, 1, 1, 2.2, 1, 1, 5, 5, 5, 6, 6.1, 5};
  double f[12];
  // Computing before the physics is complete.
  expect(cf_compute(c, 4, pos, nullptr, f, nullptr, nullptr), c, {CF_ERROR_INPUT, "no box"});
  // The box.
  const int pbc[3] = {1, 1, 1};
  const double good_box[3] = {8, 8, 8};
  expect(cf_set_box(c, nullptr, pbc), c, {CF_ERROR_INPUT, "box lengths is a null pointer"});
  expect(cf_set_box(c, good_box, nullptr), c, {CF_ERROR_INPUT, "box periodic is a null pointer"});
  const double nan_box[3] = {8, nan, 8};
  expect(cf_set_box(c, nan_box, pbc), c, {CF_ERROR_INPUT, "box edge y is nan"});
  const double negative_box[3] = {8, 8, -1};
  expect(cf_set_box(c, negative_box, pbc), c, {CF_ERROR_INPUT, "box edge z is -1"});
  const double open_box[3] = {0, 8, 8};
  const int open_x[3] = {0, 1, 1};
  EXPECT_EQ(cf_set_box(c, open_box, open_x), CF_OK) << "an open axis' length is ignored";
  ASSERT_EQ(cf_set_box(c, good_box, pbc), CF_OK);
  // The cutoff.
  expect(cf_compute(c, 4, pos, nullptr, f, nullptr, nullptr), c, {CF_ERROR_INPUT, "no cutoff"});
  expect(cf_set_cutoff(c, nan, nullptr), c, {CF_ERROR_INPUT, "cutoff is nan"});
  expect(cf_set_cutoff(c, -2.5, nullptr), c, {CF_ERROR_INPUT, "cutoff is -2.5"});
  expect(cf_set_cutoff(c, 2.5, "smooth"), c, {CF_ERROR_INPUT, "cutoff mode 'smooth' is not one of truncate"});
  ASSERT_EQ(cf_set_cutoff(c, 2.5, "shift"), CF_OK);
  // Types.
  expect(cf_compute(c, 4, pos, nullptr, f, nullptr, nullptr), c, {CF_ERROR_INPUT, "no particle types"});
  expect(cf_add_type(c, "A", -1.0, 1.0, nullptr), c, {CF_ERROR_INPUT, "sigma of type 'A' is -1"});
  expect(cf_add_type(c, "A", 1.0, nan, nullptr), c, {CF_ERROR_INPUT, "epsilon of type 'A' is nan"});
  expect(cf_add_type(c, nullptr, 1.0, 1.0, nullptr), c, {CF_ERROR_INPUT, "type name is a null pointer"});
  expect(cf_add_type(c, "", 1.0, 1.0, nullptr), c, {CF_ERROR_INPUT, "empty name"});
  ASSERT_EQ(cf_add_type(c, "A", 1.0, 1.0, nullptr), CF_OK);
  expect(cf_add_type(c, "A", 1.0, 1.0, nullptr), c, {CF_ERROR_INPUT, "type 'A' is already added"});
  expect(cf_set_pair(c, 0, 3, 1.0, 1.0), c, {CF_ERROR_INPUT, "type index 3 is out of range (1 types)"});
  expect(cf_set_pair(c, 0, 0, -0.5, 1.0), c, {CF_ERROR_INPUT, "sigma of pair 'A'-'A' is -0.5"});
  // Options.
  expect(cf_set_option(c, "colour", "blue"), c, {CF_ERROR_INPUT, "unknown option 'colour'"});
  expect(cf_set_option(c, "precision", "quad"), c,
         {CF_ERROR_INPUT, "option precision: 'quad' is not one of single, mixed or double"});
  expect(cf_set_option(c, "backend", "opencl"), c, {CF_ERROR_INPUT, "is not one of auto, cpu or cuda"});
  expect(cf_set_option(c, "skin", "-0.3"), c, {CF_ERROR_INPUT, "skin -0.3"});
  expect(cf_set_option(c, "skin", "thick"), c, {CF_ERROR_INPUT, "option skin: 'thick' is not auto or a number"});
  expect(cf_set_option(c, "skin", "1e400"), c, {CF_ERROR_INPUT, "option skin: '1e400' is out of range"});
  expect(cf_set_option(c, "device", "99999999999"), c, {CF_ERROR_INPUT, "option device: '99999999999' is out of range"});
  expect(cf_set_option(c, "device", "-1"), c, {CF_ERROR_INPUT, "device -1"});
  expect(cf_set_option(c, "memory", "tiny"), c,
         {CF_ERROR_INPUT, "option memory: 'tiny' is not one of auto, fast or lean"});
  ASSERT_EQ(cf_set_option(c, "memory", "lean"), CF_OK);
  ASSERT_EQ(cf_set_option(c, "memory", "auto"), CF_OK);
  expect(cf_set_option(c, nullptr, "x"), c, {CF_ERROR_INPUT, "option key is a null pointer"});
  expect(cf_set_option(c, "mixing", nullptr), c, {CF_ERROR_INPUT, "value of option mixing is a null pointer"});
  ASSERT_EQ(cf_set_option(c, "mixing", "geometric"), CF_OK);
  // Arrays.
  double nan_pos[12];
  std::memcpy(nan_pos, pos, sizeof pos);
  nan_pos[7] = nan;  // particle 2, y
  expect(cf_compute(c, 4, nan_pos, nullptr, f, nullptr, nullptr), c, {CF_ERROR_INPUT, "particle 2"});
  expect(cf_compute(c, 4, nullptr, nullptr, f, nullptr, nullptr), c, {CF_ERROR_INPUT, "positions is a null pointer"});
  expect(cf_compute(c, 4, pos, nullptr, nullptr, nullptr, nullptr), c, {CF_ERROR_INPUT, "forces is a null pointer"});
  const uint32_t types[4] = {0, 0, 1, 0};
  expect(cf_compute(c, 4, pos, types, f, nullptr, nullptr), c, {CF_ERROR_INPUT, "particle 2"});
  EXPECT_THAT(std::string(cf_last_error(c)), HasSubstr("type"));
  const double small_box[3] = {8, 4.5, 8};
  ASSERT_EQ(cf_set_box(c, small_box, pbc), CF_OK);
  expect(cf_compute(c, 4, pos, nullptr, f, nullptr, nullptr), c, {CF_ERROR_INPUT, "exceeds half the periodic box edge y"});
  ASSERT_EQ(cf_set_box(c, good_box, pbc), CF_OK);
  // A coincident pair names both particles.
  const double same[6] = {1, 1, 1, 1, 1, 1};
  expect(cf_compute(c, 2, same, nullptr, f, nullptr, nullptr), c, {CF_ERROR_INPUT, "particles 0 and 1"});
  // Device pointers on the CPU backend.
  expect(cf_compute_device(c, 4, pos, nullptr, f, nullptr, nullptr, nullptr), c,
         {CF_ERROR_INPUT, "needs the cuda backend"});
  // n = 0 is a valid, empty call; a failed call left the outputs alone and the context usable.
  double e = 5;
  EXPECT_EQ(cf_compute(c, 0, nullptr, nullptr, nullptr, &e, nullptr), CF_OK) << cf_last_error(c);
  EXPECT_EQ(e, 0.0);
  EXPECT_STREQ(cf_last_error(c), "");
  EXPECT_EQ(cf_compute(c, 4, pos, nullptr, f, &e, nullptr), CF_OK) << cf_last_error(c);
  EXPECT_TRUE(std::isfinite(e));
  cf_destroy(c);
}

// Choice names are read in any letter case, as the command line and scene files read them.
TEST(Api, NamesInAnyLetterCase) {
  cf::Context ctx(3);
  ctx.set_option("backend", "CPU");
  EXPECT_EQ(ctx.backend_name(), "cpu");
  ctx.set_option("backend", "Auto");
  ctx.set_option("backend", "cpu");
  EXPECT_EQ(ctx.backend_name(), "cpu");
  EXPECT_NO_THROW(ctx.set_option("precision", "Double"));
  EXPECT_NO_THROW(ctx.set_option("skin", "AUTO"));
  EXPECT_NO_THROW(ctx.set_option("neighbor-check", "True"));
  // The keys are as documented: a key in another case is unknown.
  EXPECT_THROW(ctx.set_option("Backend", "cpu"), cf::Error);

  cf_context* c = nullptr;
  ASSERT_EQ(cf_create(&c, 3), CF_OK);
  EXPECT_EQ(cf_set_option(c, "backend", "Cpu"), CF_OK) << cf_last_error(c);
  EXPECT_EQ(cf_set_option(c, "cutoff-mode", "FORCE-SHIFT"), CF_OK) << cf_last_error(c);
  EXPECT_EQ(cf_set_cutoff(c, 2.5, "Shift"), CF_OK) << cf_last_error(c);
  EXPECT_EQ(cf_set_option(c, "backend", "gpu"), CF_ERROR_INPUT);
  EXPECT_THAT(cf_last_error(c), HasSubstr("'gpu' is not one of auto, cpu or cuda"));
  cf_destroy(c);
}

TEST(CApi, FailedComputeLeavesTheOutputsUnwritten) {
  cf_context* c = ready_context();
  const double pos[6] = {1, 1, 1, std::nan(""), 1, 1};
  double f[6] = {7, 7, 7, 7, 7, 7}, e = 7, w[9] = {7, 7, 7, 7, 7, 7, 7, 7, 7};
  EXPECT_EQ(cf_compute(c, 2, pos, nullptr, f, &e, w), CF_ERROR_INPUT);
  for (double v : f) EXPECT_EQ(v, 7.0);
  EXPECT_EQ(e, 7.0);
  for (double v : w) EXPECT_EQ(v, 7.0);
  cf_destroy(c);
}

TEST(CApi, TheCudaBackendWithoutADeviceIsADeviceError) {
#ifdef CELLFORCE_HAVE_CUDA
  if (cf::GpuEngine::unavailable().empty()) GTEST_SKIP() << "a CUDA device can be used here";
#endif
  cf_context* c = ready_context();
  ASSERT_EQ(cf_set_option(c, "backend", "cuda"), CF_OK);
  const double pos[3] = {1, 1, 1};
  double f[3];
  EXPECT_EQ(cf_compute(c, 1, pos, nullptr, f, nullptr, nullptr), CF_ERROR_DEVICE);
  EXPECT_THAT(std::string(cf_last_error(c)), ::testing::AnyOf(HasSubstr("without CUDA"), HasSubstr("no CUDA device")));
  cf_destroy(c);
}

// ---- device pointers --------------------------------------------------------------------------------

#ifdef CELLFORCE_HAVE_CUDA
namespace {

template <class T>
T* device_copy(const std::vector<T>& host, cudaStream_t stream = nullptr) {
  T* d = nullptr;
  EXPECT_EQ(cudaMalloc(reinterpret_cast<void**>(&d), std::max<std::size_t>(host.size(), 1) * sizeof(T)), cudaSuccess);
  EXPECT_EQ(cudaMemcpyAsync(d, host.data(), host.size() * sizeof(T), cudaMemcpyHostToDevice, stream), cudaSuccess);
  return d;
}

template <class T>
std::vector<T> host_copy(const T* d, std::size_t n) {
  std::vector<T> h(n);
  EXPECT_EQ(cudaMemcpy(h.data(), d, n * sizeof(T), cudaMemcpyDeviceToHost), cudaSuccess);
  return h;
}

}  // namespace

// Device pointers give bitwise what host pointers give, on the default stream and on a user
// stream whose pending work (the upload of the positions) the call must wait for.
TEST(ApiDevice, DevicePointersAreBitwiseTheHostResults) {
  if (!cf::GpuEngine::unavailable().empty()) GTEST_SKIP() << cf::GpuEngine::unavailable();
  for (int dim : {3, 2})
    for (cf::Precision p : kPrecisions) {
      SCOPED_TRACE(std::string(cf::to_string(p)) + " " + std::to_string(dim) + "D");
      const Binary b = binary_liquid(dim, 2000, 40 + uint64_t(dim));
      cf::Context ctx = context_for(b, cf::Backend::kCuda, p);
      const cf::ForceResult host = compute(ctx, b.config);
      const std::size_t n = b.config.size(), nd = n * std::size_t(dim);

      cudaStream_t stream = nullptr;
      ASSERT_EQ(cudaStreamCreateWithFlags(&stream, cudaStreamNonBlocking), cudaSuccess);
      // Pending work on the stream: the positions arrive by an asynchronous copy from pinned
      // memory queued just before the call.
      double* pinned = nullptr;
      ASSERT_EQ(cudaMallocHost(reinterpret_cast<void**>(&pinned), nd * sizeof(double)), cudaSuccess);
      std::memcpy(pinned, b.config.positions.data(), nd * sizeof(double));
      double *d_pos = nullptr, *d_f = nullptr, *d_e = nullptr, *d_energy = nullptr, *d_w = nullptr;
      ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_pos), nd * sizeof(double)), cudaSuccess);
      ASSERT_EQ(cudaMemsetAsync(d_pos, 0xff, nd * sizeof(double), stream), cudaSuccess);  // NaNs until the copy
      ASSERT_EQ(cudaMemcpyAsync(d_pos, pinned, nd * sizeof(double), cudaMemcpyHostToDevice, stream), cudaSuccess);
      uint32_t* d_types = device_copy(b.config.types, stream);
      ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_f), nd * sizeof(double)), cudaSuccess);
      ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_e), n * sizeof(double)), cudaSuccess);
      ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_energy), sizeof(double)), cudaSuccess);
      ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_w), 9 * sizeof(double)), cudaSuccess);
      ctx.compute_device(n, d_pos, d_types, {d_f, d_e, d_energy, d_w}, stream);
      ASSERT_EQ(cudaStreamSynchronize(stream), cudaSuccess);

      cf::ForceResult dev;
      dev.dim = dim;
      dev.forces = host_copy(d_f, nd);
      dev.energies = host_copy(d_e, n);
      dev.energy = host_copy(d_energy, 1)[0];
      const std::vector<double> w = host_copy(d_w, std::size_t(dim * dim));
      for (int r = 0; r < dim; ++r)
        for (int c = 0; c < dim; ++c) dev.virial[r][c] = w[std::size_t(r * dim + c)];
      EXPECT_TRUE(cftest::bitwise_equal(host, dev));

      // The C API on the default stream.
      cf_context* c = nullptr;
      ASSERT_EQ(cf_create(&c, dim), CF_OK);
      const double lengths[3] = {b.config.box.length[0], b.config.box.length[1], b.config.box.length[2]};
      const int pbc[3] = {1, 1, 1};
      ASSERT_EQ(cf_set_box(c, lengths, pbc), CF_OK);
      ASSERT_EQ(cf_set_cutoff(c, b.ff.cutoff, "force-shift"), CF_OK);
      ASSERT_EQ(cf_add_type(c, "A", 1.0, 1.0, nullptr), CF_OK);
      ASSERT_EQ(cf_add_type(c, "B", 0.88, 0.5, nullptr), CF_OK);
      ASSERT_EQ(cf_set_pair(c, 0, 1, 0.8, 1.5), CF_OK);
      ASSERT_EQ(cf_set_option(c, "backend", "cuda"), CF_OK);
      ASSERT_EQ(cf_set_option(c, "precision", cf::to_string(p)), CF_OK);
      ASSERT_EQ(cudaMemset(d_f, 0, nd * sizeof(double)), cudaSuccess);
      ASSERT_EQ(cf_compute_device(c, n, d_pos, d_types, d_f, d_energy, d_w, nullptr), CF_OK) << cf_last_error(c);
      ASSERT_EQ(cudaDeviceSynchronize(), cudaSuccess);
      const std::vector<double> fc = host_copy(d_f, nd);
      EXPECT_EQ(std::memcmp(fc.data(), host.forces.data(), nd * sizeof(double)), 0);
      const double ec = host_copy(d_energy, 1)[0];
      EXPECT_EQ(std::memcmp(&ec, &host.energy, sizeof ec), 0);
      cf_destroy(c);

      for (void* ptr : {static_cast<void*>(d_pos), static_cast<void*>(d_types), static_cast<void*>(d_f),
                        static_cast<void*>(d_e), static_cast<void*>(d_energy), static_cast<void*>(d_w)})
        cudaFree(ptr);
      cudaFreeHost(pinned);
      cudaStreamDestroy(stream);
    }
}

// Host pointers given to the device call are refused, naming the parameter, before any copy.
TEST(ApiDevice, HostPointersAreRefused) {
  if (!cf::GpuEngine::unavailable().empty()) GTEST_SKIP() << cf::GpuEngine::unavailable();
  cf_context* c = ready_context();
  ASSERT_EQ(cf_set_option(c, "backend", "cuda"), CF_OK);
  std::vector<double> pos = {1, 1, 1, 3, 1, 1};
  double* d_pos = device_copy(pos);
  double* d_f = device_copy(std::vector<double>(6, 0.0));
  double host_f[6], host_energy = 0;
  EXPECT_EQ(cf_compute_device(c, 2, pos.data(), nullptr, d_f, nullptr, nullptr, nullptr), CF_ERROR_INPUT);
  EXPECT_THAT(std::string(cf_last_error(c)), HasSubstr("positions is not a device pointer"));
  EXPECT_EQ(cf_compute_device(c, 2, d_pos, nullptr, host_f, nullptr, nullptr, nullptr), CF_ERROR_INPUT);
  EXPECT_THAT(std::string(cf_last_error(c)), HasSubstr("forces is not a device pointer"));
  EXPECT_EQ(cf_compute_device(c, 2, d_pos, nullptr, d_f, &host_energy, nullptr, nullptr), CF_ERROR_INPUT);
  EXPECT_THAT(std::string(cf_last_error(c)), HasSubstr("energy is not a device pointer"));
  EXPECT_EQ(cf_compute_device(c, 2, d_pos, nullptr, d_f, nullptr, nullptr, nullptr), CF_OK) << cf_last_error(c);
  cudaFree(d_pos);
  cudaFree(d_f);
  cf_destroy(c);
}

// A bad particle in device arrays is named as for host arrays, by the synchronisation that
// follows the call (the call itself returns without waiting for the device): a coordinate that is
// not finite (with its axis), then a type index out of range. A later clean call reports nothing.
TEST(ApiDevice, BadDeviceInputIsNamedBySynchronize) {
  if (!cf::GpuEngine::unavailable().empty()) GTEST_SKIP() << cf::GpuEngine::unavailable();
  cf_context* c = ready_context();
  ASSERT_EQ(cf_set_option(c, "backend", "cuda"), CF_OK);
  EXPECT_EQ(cf_synchronize(c), CF_OK);  // nothing pending
  std::vector<double> pos = {1, 1, 1, 3, 1, 1, 5, 5, std::nan(""), 6, 6, 6};
  double* d_pos = device_copy(pos);
  double* d_f = device_copy(std::vector<double>(12, 7.0));
  EXPECT_EQ(cf_compute_device(c, 4, d_pos, nullptr, d_f, nullptr, nullptr, nullptr), CF_OK) << cf_last_error(c);
  EXPECT_EQ(cf_synchronize(c), CF_ERROR_INPUT);
  EXPECT_THAT(std::string(cf_last_error(c)), HasSubstr("particle 2 has a non-finite z coordinate"));
  EXPECT_EQ(cf_synchronize(c), CF_OK);  // reported once

  pos[8] = 5;
  const std::vector<uint32_t> types = {0, 5, 0, 0};
  double* d_pos2 = device_copy(pos);
  uint32_t* d_types = device_copy(types);
  EXPECT_EQ(cf_compute_device(c, 4, d_pos2, d_types, d_f, nullptr, nullptr, nullptr), CF_OK) << cf_last_error(c);
  // cf_compute synchronises first, so it reports the device call's problem.
  double host_f[12];
  EXPECT_EQ(cf_compute(c, 4, pos.data(), nullptr, host_f, nullptr, nullptr), CF_ERROR_INPUT);
  EXPECT_THAT(std::string(cf_last_error(c)), HasSubstr("particle 1 has type index 5 but there are 1 types"));

  // Clean input afterwards: no stale flag, and the forces are those of the host call.
  EXPECT_EQ(cf_compute_device(c, 4, d_pos2, nullptr, d_f, nullptr, nullptr, nullptr), CF_OK) << cf_last_error(c);
  EXPECT_EQ(cf_synchronize(c), CF_OK) << cf_last_error(c);
  EXPECT_EQ(cf_compute(c, 4, pos.data(), nullptr, host_f, nullptr, nullptr), CF_OK) << cf_last_error(c);
  const std::vector<double> dev_f = host_copy(d_f, 12);
  EXPECT_EQ(std::memcmp(dev_f.data(), host_f, sizeof host_f), 0);
  for (void* p : {static_cast<void*>(d_pos), static_cast<void*>(d_pos2), static_cast<void*>(d_types),
                  static_cast<void*>(d_f)})
    cudaFree(p);
  cf_destroy(c);
}

// A gate on a stream: a host function that holds the stream until the test opens it (or, should
// the call under test wait for the stream, until a timeout, which the test then reports).
struct Gate {
  std::atomic<bool> open{false};
  std::atomic<bool> timed_out{false};
  static void CUDART_CB hold(void* p) {
    auto* g = static_cast<Gate*>(p);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    while (!g->open.load()) {
      if (std::chrono::steady_clock::now() > deadline) {
        g->timed_out = true;
        return;
      }
      std::this_thread::sleep_for(std::chrono::microseconds(100));
    }
  }
};

// The test: a device call on a user stream that holds pending work returns before that
// work ends (the stream is still busy when the call returns), and once the stream is synchronised
// its results are bitwise those of the host call. The positions themselves arrive behind the gate.
// On a fresh context (its buffers allocated in the call) and again with them in place, for
// Jacobi and Gauss-Seidel accumulation, without a skin (each call builds its structure; a first
// build of pair lists waits for their size: DecidedCallsReturnBeforeThePendingWorkOfTheirStream
// has the skin). A context destroyed with its work still queued waits for it (stream-ordered
// buffers are not freed under running kernels: memcheck runs this test).
TEST(ApiDevice, DeviceCallReturnsBeforeThePendingWorkOfItsStream) {
  if (!cf::GpuEngine::unavailable().empty()) GTEST_SKIP() << cf::GpuEngine::unavailable();
  for (const char* accumulation : {"jacobi", "gauss-seidel"}) {
    SCOPED_TRACE(accumulation);
    const Binary b = binary_liquid(3, 4000, 77);
    cf::Context ctx = context_for(b, cf::Backend::kCuda, cf::Precision::kMixed);
    ctx.set_option("accumulation", accumulation);
    ctx.set_skin(0.0);
    cf::Context reference = context_for(b, cf::Backend::kCuda, cf::Precision::kMixed);
    reference.set_option("accumulation", accumulation);
    reference.set_skin(0.0);
    const cf::ForceResult host = compute(reference, b.config);
    const std::size_t n = b.config.size(), nd = n * 3;
    cudaStream_t stream = nullptr;
    ASSERT_EQ(cudaStreamCreateWithFlags(&stream, cudaStreamNonBlocking), cudaSuccess);
    double* pinned = nullptr;
    ASSERT_EQ(cudaMallocHost(reinterpret_cast<void**>(&pinned), nd * sizeof(double)), cudaSuccess);
    std::memcpy(pinned, b.config.positions.data(), nd * sizeof(double));
    double *d_pos = nullptr, *d_f = nullptr, *d_energy = nullptr, *d_w = nullptr;
    ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_pos), nd * sizeof(double)), cudaSuccess);
    ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_f), nd * sizeof(double)), cudaSuccess);
    ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_energy), sizeof(double)), cudaSuccess);
    ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_w), 9 * sizeof(double)), cudaSuccess);
    uint32_t* d_types = device_copy(b.config.types);
    {  // Every kernel of the device path loaded once, ungated: with lazy module loading a first
       // launch may synchronise the context, which is no part of what is tested here.
      cf::Context warm = context_for(b, cf::Backend::kCuda, cf::Precision::kMixed);
      warm.set_option("accumulation", accumulation);
      warm.set_skin(0.0);
      ASSERT_EQ(cudaMemcpy(d_pos, pinned, nd * sizeof(double), cudaMemcpyHostToDevice), cudaSuccess);
      warm.compute_device(n, d_pos, d_types, {d_f, nullptr, d_energy, d_w}, nullptr);
      warm.synchronize();
    }
    ASSERT_EQ(cudaDeviceSynchronize(), cudaSuccess);

    for (int call = 0; call < 2; ++call) {
      SCOPED_TRACE(call == 0 ? "fresh context" : "buffers in place");
      Gate gate;
      ASSERT_EQ(cudaMemsetAsync(d_pos, 0xff, nd * sizeof(double), stream), cudaSuccess);  // NaNs until the copy
      ASSERT_EQ(cudaLaunchHostFunc(stream, &Gate::hold, &gate), cudaSuccess);
      ASSERT_EQ(cudaMemcpyAsync(d_pos, pinned, nd * sizeof(double), cudaMemcpyHostToDevice, stream), cudaSuccess);
      ctx.compute_device(n, d_pos, d_types, {d_f, nullptr, d_energy, d_w}, stream);
      const cudaError_t busy = cudaStreamQuery(stream);
      gate.open = true;
      ASSERT_EQ(cudaStreamSynchronize(stream), cudaSuccess);
      EXPECT_FALSE(gate.timed_out) << "compute_device waited for the stream's pending work";
      EXPECT_EQ(busy, cudaErrorNotReady) << "the stream had finished when compute_device returned";
      ctx.synchronize();
      cf::ForceResult dev;
      dev.dim = 3;
      dev.forces = host_copy(d_f, nd);
      dev.energies = host.energies;  // not asked of the device call
      dev.energy = host_copy(d_energy, 1)[0];
      const std::vector<double> w = host_copy(d_w, 9);
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) dev.virial[r][c] = w[std::size_t(r * 3 + c)];
      EXPECT_TRUE(cftest::bitwise_equal(host, dev));
    }
    {  // A context destroyed while its call still waits behind the gate: the destructor waits.
      Gate gate;
      ASSERT_EQ(cudaLaunchHostFunc(stream, &Gate::hold, &gate), cudaSuccess);
      auto doomed = std::make_unique<cf::Context>(context_for(b, cf::Backend::kCuda, cf::Precision::kMixed));
      doomed->set_skin(0.0);
      doomed->compute_device(n, d_pos, d_types, {d_f, nullptr, d_energy, d_w}, stream);
      std::thread opener([&] {
        std::this_thread::sleep_for(std::chrono::milliseconds(200));
        gate.open = true;
      });
      doomed.reset();
      opener.join();
      EXPECT_EQ(cudaStreamSynchronize(stream), cudaSuccess);
      EXPECT_FALSE(gate.timed_out);
    }
    for (void* p : {static_cast<void*>(d_pos), static_cast<void*>(d_types), static_cast<void*>(d_f),
                    static_cast<void*>(d_energy), static_cast<void*>(d_w)})
      cudaFree(p);
    cudaFreeHost(pinned);
    cudaStreamDestroy(stream);
  }
}

// With the defaults (on CUDA a skin and pair lists: the rule of steps), once the first calls have
// built the structure, every call returns before the pending work of its stream, those where the
// device rebuilds the structure too, and its results are bitwise those of a host call on the same
// positions in the same order (the host decides the same rebuilds). 30 calls, each moving every
// particle by its own step (components within +-0.03, so that the largest displacement passes
// skin / 2 = 0.3 every few calls); from call 10 on, each call's positions arrive behind a gate.
TEST(ApiDevice, DecidedCallsReturnBeforeThePendingWorkOfTheirStream) {
  if (!cf::GpuEngine::unavailable().empty()) GTEST_SKIP() << cf::GpuEngine::unavailable();
  const Binary b = binary_liquid(3, 4000, 78);
  cf::Context ctx = context_for(b, cf::Backend::kCuda, cf::Precision::kMixed);
  cf::Context reference = context_for(b, cf::Backend::kCuda, cf::Precision::kMixed);
  ASSERT_GT(ctx.skin(), 0.0);
  const std::size_t n = b.config.size(), nd = n * 3;
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-0.03, 0.03);
  std::vector<double> step(nd);
  for (double& v : step) v = u(rng);
  cudaStream_t stream = nullptr;
  ASSERT_EQ(cudaStreamCreateWithFlags(&stream, cudaStreamNonBlocking), cudaSuccess);
  double* pinned = nullptr;
  ASSERT_EQ(cudaMallocHost(reinterpret_cast<void**>(&pinned), nd * sizeof(double)), cudaSuccess);
  double *d_pos = nullptr, *d_f = nullptr, *d_energy = nullptr, *d_w = nullptr;
  ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_pos), nd * sizeof(double)), cudaSuccess);
  ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_f), nd * sizeof(double)), cudaSuccess);
  ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_energy), sizeof(double)), cudaSuccess);
  ASSERT_EQ(cudaMalloc(reinterpret_cast<void**>(&d_w), 9 * sizeof(double)), cudaSuccess);
  uint32_t* d_types = device_copy(b.config.types);
  int gated_rebuilds = 0;
  for (int k = 0; k < 30; ++k) {
    SCOPED_TRACE("call " + std::to_string(k));
    cf::Configuration c = b.config;
    for (std::size_t i = 0; i < nd; ++i) {
      const double length = c.box.length[i % 3];
      double x = c.positions[i] + k * step[i];
      x -= length * std::floor(x / length);
      c.positions[i] = x < length ? x : 0.0;
    }
    std::memcpy(pinned, c.positions.data(), nd * sizeof(double));
    const bool gated = k >= 10;
    Gate gate;
    if (gated) {
      ASSERT_EQ(cudaMemsetAsync(d_pos, 0xff, nd * sizeof(double), stream), cudaSuccess);  // NaNs until the copy
      ASSERT_EQ(cudaLaunchHostFunc(stream, &Gate::hold, &gate), cudaSuccess);
    }
    ASSERT_EQ(cudaMemcpyAsync(d_pos, pinned, nd * sizeof(double), cudaMemcpyHostToDevice, stream), cudaSuccess);
    ctx.compute_device(n, d_pos, d_types, {d_f, nullptr, d_energy, d_w}, stream);
    const cudaError_t busy = cudaStreamQuery(stream);
    gate.open = true;
    ASSERT_EQ(cudaStreamSynchronize(stream), cudaSuccess);
    if (gated) {
      EXPECT_FALSE(gate.timed_out) << "compute_device waited for the stream's pending work";
      EXPECT_EQ(busy, cudaErrorNotReady) << "the stream had finished when compute_device returned";
    }
    ctx.synchronize();
    if (gated && ctx.statistics().rebuilt) ++gated_rebuilds;
    const cf::ForceResult host = compute(reference, c);
    EXPECT_EQ(ctx.statistics().rebuilt, reference.statistics().rebuilt);
    EXPECT_TRUE(host_copy(d_f, nd) == host.forces);
    EXPECT_EQ(host_copy(d_energy, 1)[0], host.energy);
    const std::vector<double> w = host_copy(d_w, 9);
    for (int r = 0; r < 3; ++r)
      for (int col = 0; col < 3; ++col) EXPECT_EQ(w[std::size_t(r * 3 + col)], host.virial[r][col]);
  }
  EXPECT_GE(gated_rebuilds, 2) << "too few rebuilds behind the gate to test the device's decision";
  for (void* p : {static_cast<void*>(d_pos), static_cast<void*>(d_types), static_cast<void*>(d_f),
                  static_cast<void*>(d_energy), static_cast<void*>(d_w)})
    cudaFree(p);
  cudaFreeHost(pinned);
  cudaStreamDestroy(stream);
}
#endif
