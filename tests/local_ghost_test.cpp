// Local and ghost particles (Context::compute_local, C cf_compute_local): a periodic liquid cut into
// slabs along x, each slab's call given its own particles as locals and, as ghosts, the periodic
// images of the particles within rc of it (x open for the slab call, the other axes periodic).
// Summed over the slabs, the forces, energy and virial are the whole periodic system's by the
// double brute force; each local's energy and virial share are its whole-system shares; the
// shares sum to the totals; no pair of two ghosts is evaluated. Every bad input is named.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cellforce/cellforce.h>
#include <cellforce/cellforce.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <tuple>
#include <vector>


#include "backend_here.h"
#include "core/engine_options.h"
#include "core/force_field.h"
#include "core/lj.h"
#include "cpu/engine.h"
#include "oracle.h"
#include "reference/brute_force.h"

namespace {

using ::testing::HasSubstr;
namespace cf = cellforce;

using cftest::usable_backends;
std::string cuda_missing() { return cftest::unavailable(cf::Backend::kCuda); }
const char* name_of(cf::Backend b) { return b == cf::Backend::kCuda ? "cuda" : "cpu"; }

struct Liquid {
  cf::Configuration config;  // periodic on every axis, positions in [0, L)
  cf::ForceField ff;
};

// 3D: in.lj's liquid density 0.8442, one type, rc 2.5 truncated, 2,048 particles placed at random
// no closer than 0.85 sigma. 2D: a binary mixture (explicit A-B pair) with force shift.
Liquid liquid(int dim) {
  Liquid l;
  cftest::RandomSpec spec;
  spec.min_distance = 0.85;
  l.ff.cutoff = 2.5;
  if (dim == 3) {
    const std::size_t n = 2048;
    l.config = cftest::random_configuration(cftest::cube(3, std::cbrt(double(n) / 0.8442)), n, 47, spec);
    l.ff.types = {{"A", 1.0, 1.0}};
  } else {
    const std::size_t n = 1200;
    spec.num_types = 2;
    l.config = cftest::random_configuration(cftest::cube(2, std::sqrt(double(n) / 0.7)), n, 48, spec);
    l.ff.mode = cf::CutoffMode::kForceShift;
    l.ff.types = {{"A", 1.0, 1.0}, {"B", 0.88, 0.5}};
    l.ff.overrides = {{0, 1, 0.8, 1.5}};
  }
  return l;
}

// One slab's call: its particles (locals) first, then the ghosts; whole[k] is the whole system's
// index of entry k. The box is the whole's with x open.
struct Slab {
  cf::Configuration config;
  std::size_t n_local = 0;
  std::vector<std::size_t> whole;
};

// Slab s holds the particles with lo_s <= x < hi_s; its ghosts are the images x + k L (k = -1, 0,
// 1) of every particle that fall within rc of the slab on either side. With the slab's width + 2 rc
// below L no local is its own ghost and no particle has two ghost images on one side.
std::vector<Slab> cut_into_slabs(const cf::Configuration& c, double rc, int slabs) {
  const std::size_t d = std::size_t(c.box.dim), n = c.size();
  const double L = c.box.length[0];
  std::vector<Slab> out(static_cast<std::size_t>(slabs));
  for (int s = 0; s < slabs; ++s) {
    Slab& slab = out[std::size_t(s)];
    const double lo = L * s / slabs, hi = s + 1 == slabs ? L : L * (s + 1) / slabs;
    slab.config.box = c.box;
    slab.config.box.periodic[0] = false;
    auto add = [&](std::size_t i, double x) {
      slab.config.positions.push_back(x);
      for (std::size_t a = 1; a < d; ++a) slab.config.positions.push_back(c.positions[i * d + a]);
      slab.config.types.push_back(c.types[i]);
      slab.whole.push_back(i);
    };
    for (std::size_t i = 0; i < n; ++i)
      if (c.positions[i * d] >= lo && c.positions[i * d] < hi) add(i, c.positions[i * d]);
    slab.n_local = slab.whole.size();
    for (std::size_t i = 0; i < n; ++i)
      for (int k = -1; k <= 1; ++k) {
        const double x = c.positions[i * d] + k * L;
        if ((x >= lo - rc && x < lo) || (x >= hi && x < hi + rc)) add(i, x);
      }
  }
  return out;
}

cf::Context context_for(const Liquid& l, const cf::Box& box, cf::Precision precision,
                        cf::Backend backend = cf::Backend::kCpu) {
  cf::Context ctx(box.dim);
  const bool periodic[3] = {box.periodic[0], box.periodic[1], box.periodic[2]};
  ctx.set_box(box.length, periodic);
  ctx.set_cutoff(l.ff.cutoff, l.ff.mode);
  for (const auto& t : l.ff.types) ctx.add_type(t.name, t.sigma, t.epsilon);
  for (const auto& o : l.ff.overrides) ctx.set_pair(uint32_t(o.a), uint32_t(o.b), o.sigma, o.epsilon);
  ctx.set_backend(backend);
  ctx.set_precision(precision);
  return ctx;
}

// Each particle's virial share (half of r_ij (x) f_ij of each of its pairs; n x dim x dim) in
// double from the brute force's pair list: the oracle of the per-particle virials.
std::vector<double> virial_shares(const Liquid& l) {
  const cf::Configuration& c = l.config;
  const std::size_t d = std::size_t(c.box.dim);
  const std::vector<cf::LJParams<double>> table = cf::make_pair_table<double>(l.ff);
  std::vector<double> w(c.size() * d * d, 0.0);
  for (const auto& [i, j] : cf::brute_force_pairs(c.view(), l.ff)) {
    double r[3] = {0, 0, 0}, r2 = 0;
    for (std::size_t a = 0; a < d; ++a) {
      const double L = c.box.length[a];
      r[a] = c.positions[i * d + a] - c.positions[j * d + a];
      r[a] -= L * std::rint(r[a] / L);
      r2 += r[a] * r[a];
    }
    const cf::LJParams<double>& p = table[c.types[i] * l.ff.num_types() + c.types[j]];
    double fr = 0, e = 0;
    const double rc2 = l.ff.cutoff * l.ff.cutoff;
    switch (l.ff.mode) {
      case cf::CutoffMode::kTruncate: cf::lj_pair<cf::CutoffMode::kTruncate, false>(r2, rc2, p, fr, e); break;
      case cf::CutoffMode::kShift: cf::lj_pair<cf::CutoffMode::kShift, false>(r2, rc2, p, fr, e); break;
      case cf::CutoffMode::kForceShift: cf::lj_pair<cf::CutoffMode::kForceShift, false>(r2, rc2, p, fr, e); break;
    }
    for (std::size_t a = 0; a < d; ++a)
      for (std::size_t b = 0; b < d; ++b) {
        w[i * d * d + a * d + b] += 0.5 * fr * r[a] * r[b];
        w[j * d * d + a * d + b] += 0.5 * fr * r[a] * r[b];
      }
  }
  return w;
}

double largest_abs(const std::vector<double>& v) {
  double m = 0;
  for (const double x : v) m = std::max(m, std::abs(x));
  return m;
}

// Largest |got - ref| over the entries, relative to the largest |ref|.
double relative_error(const std::vector<double>& ref, const std::vector<double>& got) {
  double worst = 0;
  for (std::size_t k = 0; k < ref.size(); ++k) worst = std::max(worst, std::abs(got[k] - ref[k]));
  return worst / largest_abs(ref);
}

// What the slabs' calls gave, put back in the whole system's order (each particle is a local of
// exactly one slab) and summed over slabs.
struct Summed {
  std::vector<double> forces, energies, virials;
  double energy = 0;
  std::vector<double> virial;  // dim x dim
};

// Runs compute_local for every slab. Within each call, the locals' energy and virial shares must
// sum to its totals (1e-12 relative: the library sums the same doubles in index order).
Summed run_slabs(cf::Context& ctx, const std::vector<Slab>& slabs, std::size_t n, std::size_t d) {
  Summed s;
  s.forces.assign(n * d, std::nan(""));
  s.energies.assign(n, std::nan(""));
  s.virials.assign(n * d * d, std::nan(""));
  s.virial.assign(d * d, 0.0);
  for (const Slab& slab : slabs) {
    const std::size_t nl = slab.n_local, ng = slab.config.size() - nl;
    std::vector<double> f(nl * d), e(nl), w(nl * d * d), total_w(d * d);
    double energy = 0;
    ctx.compute_local(nl, ng, slab.config.positions.data(), slab.config.types.data(),
                      cf::LocalOutputs{f.data(), e.data(), &energy, total_w.data(), w.data(), false});
    double e_sum = 0, e_abs = 0;
    std::vector<double> w_sum(d * d, 0.0);
    for (std::size_t k = 0; k < nl; ++k) {
      const std::size_t i = slab.whole[k];
      std::copy_n(&f[k * d], d, &s.forces[i * d]);
      s.energies[i] = e[k];
      std::copy_n(&w[k * d * d], d * d, &s.virials[i * d * d]);
      e_sum += e[k];
      e_abs += std::abs(e[k]);
      for (std::size_t c = 0; c < d * d; ++c) w_sum[c] += w[k * d * d + c];
    }
    EXPECT_LE(std::abs(e_sum - energy), 1e-12 * e_abs) << "the locals' energies sum to the slab's energy";
    EXPECT_LE(relative_error(total_w, w_sum), 1e-12) << "the locals' virials sum to the slab's virial";
    s.energy += energy;
    for (std::size_t c = 0; c < d * d; ++c) s.virial[c] += total_w[c];
  }
  return s;
}

using SlabParam = std::tuple<cf::Backend, int, cf::Precision>;

class LocalGhostSlabs : public ::testing::TestWithParam<SlabParam> {
 protected:
  void SetUp() override {
    if (std::get<0>(GetParam()) != cf::Backend::kCuda) return;
    if (const std::string why = cuda_missing(); !why.empty()) GTEST_SKIP() << why;
  }
};

// Tolerances against the double brute force, relative to the largest value of each quantity
// (force components, per-particle energies, per-particle virial components, virial components;
// the total energy to the sum of |e_i|). Double: 1e-12, rounding of sums in another order (seen:
// 2e-14). Single and mixed evaluate each pair in float, with coordinates staged relative to the
// cell centre in two floats (hi + lo: r_ij to double's accuracy), so each pair's F/r and energy
// carry some ten float roundings, ~6e-7 of the pair's size; a local's ~45 pairs (2D: ~15), of
// sizes up to the largest net force near contact (0.85 sigma), err by ~1e-6 of the largest value
// (seen: 1.0e-6 for forces, 0.8e-6 for energies and virials, in both). 1e-5 holds that with a
// margin of ten. A pair missed or counted twice (a ghost's pair, a lost image) is found exactly by
// the pair counts below and the double instances, whatever its size.
double tolerance(cf::Precision p) { return p == cf::Precision::kDouble ? 1e-12 : 1e-5; }

TEST_P(LocalGhostSlabs, SumToTheWholePeriodicSystem) {
  const auto [backend, dim, precision] = GetParam();
  const Liquid l = liquid(dim);
  const std::size_t n = l.config.size(), d = std::size_t(dim);
  cf::ForceResult ref;
  cf::brute_force(l.config.view(), l.ff, cf::Request{true, true}, ref);
  const std::vector<double> ref_w = virial_shares(l);
  std::vector<double> ref_virial(d * d);
  for (std::size_t a = 0; a < d; ++a)
    for (std::size_t b = 0; b < d; ++b) ref_virial[a * d + b] = ref.virial[a][b];

  const std::vector<Slab> slabs = cut_into_slabs(l.config, l.ff.cutoff, 4);
  cf::Context ctx = context_for(l, slabs[0].config.box, precision, backend);
  const Summed got = run_slabs(ctx, slabs, n, d);
  const double tol = tolerance(precision);
  const double e_abs = [&] {
    double s = 0;
    for (const double e : ref.energies) s += std::abs(e);
    return s;
  }();
  EXPECT_LE(relative_error(ref.forces, got.forces), tol) << "forces";
  EXPECT_LE(relative_error(ref.energies, got.energies), tol) << "per-particle energies";
  EXPECT_LE(relative_error(ref_w, got.virials), tol) << "per-particle virials";
  EXPECT_LE(std::abs(got.energy - ref.energy), tol * e_abs) << "energy " << got.energy << " vs " << ref.energy;
  EXPECT_LE(relative_error(ref_virial, got.virial), tol) << "virial";
  // The ghosts matter: without them the slabs' forces would be far off at their faces.
  EXPECT_GT(slabs[0].config.size() - slabs[0].n_local, slabs[0].n_local / 2);
}

// count_pairs_local on a slab: the pairs within the cutoff are the brute force's pairs of the slab
// call that hold a local (none of two ghosts, though the slab has many); the candidates tested are
// fewer than those of the same particles all taken as locals.
TEST_P(LocalGhostSlabs, NoPairOfTwoGhostsIsEvaluated) {
  const auto [backend, dim, precision] = GetParam();
  const Liquid l = liquid(dim);
  const std::vector<Slab> slabs = cut_into_slabs(l.config, l.ff.cutoff, 4);
  cf::Context ctx = context_for(l, slabs[0].config.box, precision, backend);
  for (const Slab& slab : slabs) {
    const std::size_t nl = slab.n_local, n = slab.config.size();
    std::size_t with_local = 0, ghost_pairs = 0;
    for (const auto& [i, j] : cf::brute_force_pairs(slab.config.view(), l.ff)) (i < nl ? with_local : ghost_pairs) += 1;
    const cf::PairCounts local = ctx.count_pairs_local(nl, n - nl, slab.config.positions.data(), slab.config.types.data());
    const cf::PairCounts all = ctx.count_pairs_local(n, 0, slab.config.positions.data(), slab.config.types.data());
    EXPECT_GT(ghost_pairs, 100u) << "the slab's ghosts have pairs among themselves";
    EXPECT_EQ(local.within_cutoff, with_local);
    EXPECT_EQ(all.within_cutoff, with_local + ghost_pairs);
    EXPECT_LT(local.tested, all.tested);
  }
}

std::string slab_name(const ::testing::TestParamInfo<SlabParam>& info) {
  const auto [backend, dim, precision] = info.param;
  return std::string(backend == cf::Backend::kCuda ? "cuda" : "cpu") + "_" + std::to_string(dim) + "d_" +
         cf::to_string(precision);
}

INSTANTIATE_TEST_SUITE_P(Backends, LocalGhostSlabs,
                         ::testing::Combine(::testing::Values(cf::Backend::kCpu, cf::Backend::kCuda),
                                            ::testing::Values(3, 2),
                                            ::testing::Values(cf::Precision::kDouble, cf::Precision::kMixed,
                                                              cf::Precision::kSingle)),
                         slab_name);

// The engine's own pair recorder on a slab: exactly the brute force's pairs that hold a local.
TEST(LocalGhost, VisitedPairsAreThePairsWithALocal) {
  for (const int dim : {3, 2}) {
    const Liquid l = liquid(dim);
    for (const Slab& slab : cut_into_slabs(l.config, l.ff.cutoff, 3)) {
      std::vector<cftest::Pair> expected;
      for (const auto& p : cf::brute_force_pairs(slab.config.view(), l.ff))
        if (p.first < slab.n_local) expected.push_back(p);
      cf::CpuEngine engine;
      EXPECT_TRUE(cftest::pair_sets_equal(expected, engine.visited_pairs(slab.config.view(), l.ff, slab.n_local)))
          << dim << "D";
    }
  }
}

// Without ghosts, on the periodic box, compute_local is compute() with per-particle virials: on the
// CPU the same forces bitwise (the same traversal), on CUDA to rounding (compute walks pair lists,
// compute_local the cells' tiles: sums in another order), energy and virial to rounding (summed
// per particle instead of per cell), per-particle virials as the oracle's. Then compute() again
// on CUDA, on the structure compute_local built (no pair list: the cells serve it).
TEST(LocalGhost, WithoutGhostsItIsComputeWithPerParticleVirials) {
  for (const cf::Backend backend : usable_backends())
    for (const int dim : {3, 2}) {
      SCOPED_TRACE(std::string(name_of(backend)) + " " + std::to_string(dim) + "D");
      const Liquid l = liquid(dim);
      const std::size_t n = l.config.size(), d = std::size_t(dim);
      cf::Context ctx = context_for(l, l.config.box, cf::Precision::kDouble, backend);
      std::vector<double> f(n * d), f_local(n * d), f_after(n * d), w(d * d), w_local(d * d), shares(n * d * d);
      double e = 0, e_local = 0;
      ctx.compute(n, l.config.positions.data(), l.config.types.data(), {f.data(), nullptr, &e, w.data()});
      ctx.compute_local(n, 0, l.config.positions.data(), l.config.types.data(),
                        {f_local.data(), nullptr, &e_local, w_local.data(), shares.data()});
      if (backend == cf::Backend::kCpu) EXPECT_EQ(f, f_local);
      else EXPECT_LE(relative_error(f, f_local), 1e-12);
      EXPECT_NEAR(e_local, e, 1e-12 * std::abs(e));
      EXPECT_LE(relative_error(w, w_local), 1e-12);
      EXPECT_LE(relative_error(virial_shares(l), shares), 1e-12);
      if (backend != cf::Backend::kCuda) continue;
      // compute() on a structure that compute_local built (a fresh context: the call's build makes
      // no pair list), reused: the cells serve it.
      cf::Context fresh = context_for(l, l.config.box, cf::Precision::kDouble, backend);
      fresh.compute_local(n, 0, l.config.positions.data(), l.config.types.data(), {f_local.data()});
      fresh.compute(n, l.config.positions.data(), l.config.types.data(), {f_after.data()});
      EXPECT_FALSE(fresh.statistics().rebuilt) << "compute() reused compute_local's structure";
      EXPECT_LE(relative_error(f, f_after), 1e-12);
    }
}

// Energy-only calls (forces null) added over the slabs with accumulate give the whole system's
// energy and virial; forces accumulated twice are twice the forces.
TEST(LocalGhost, AccumulatedEnergyOnlyCallsSumOverSlabs) {
  for (const cf::Backend backend : usable_backends()) {
    SCOPED_TRACE(name_of(backend));
    const Liquid l = liquid(3);
    cf::ForceResult ref;
    cf::brute_force(l.config.view(), l.ff, cf::Request{true, true}, ref);
    const std::vector<Slab> slabs = cut_into_slabs(l.config, l.ff.cutoff, 4);
    cf::Context ctx = context_for(l, slabs[0].config.box, cf::Precision::kDouble, backend);
    double energy = 0;
    std::vector<double> virial(9, 0.0);
    cf::LocalOutputs out;
    out.energy = &energy;
    out.virial = virial.data();
    out.accumulate = true;
    for (const Slab& s : slabs)
      ctx.compute_local(s.n_local, s.config.size() - s.n_local, s.config.positions.data(), s.config.types.data(), out);
    double e_abs = 0;
    for (const double e : ref.energies) e_abs += std::abs(e);
    EXPECT_LE(std::abs(energy - ref.energy), 1e-12 * e_abs);
    std::vector<double> ref_virial(9);
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) ref_virial[std::size_t(a * 3 + b)] = ref.virial[a][b];
    EXPECT_LE(relative_error(ref_virial, virial), 1e-12);

    const Slab& s = slabs[1];
    std::vector<double> once(s.n_local * 3), twice(s.n_local * 3, 0.0);
    ctx.compute_local(s.n_local, s.config.size() - s.n_local, s.config.positions.data(), s.config.types.data(),
                      {once.data()});
    cf::LocalOutputs add;
    add.forces = twice.data();
    add.accumulate = true;
    for (int k = 0; k < 2; ++k)
      ctx.compute_local(s.n_local, s.config.size() - s.n_local, s.config.positions.data(), s.config.types.data(), add);
    for (std::size_t k = 0; k < once.size(); ++k) ASSERT_EQ(twice[k], 2.0 * once[k]) << "entry " << k;
  }
}

// Gauss-Seidel accumulation (passes by cell type) takes ghosts as Jacobi does; so does a CUDA
// engine set to another traversal form (ghosts always take the tile form, whose tiles the
// structure's build did not make) and with a skin (the structure reused from call to call where
// the particles moved less than half of it).
TEST(LocalGhost, GaussSeidelSlabsSumToTheWholeSystem) {
  const Liquid l = liquid(3);
  cf::ForceResult ref;
  cf::brute_force(l.config.view(), l.ff, cf::Request{true, true}, ref);
  const std::vector<Slab> slabs = cut_into_slabs(l.config, l.ff.cutoff, 4);
  for (const cf::Backend backend : usable_backends()) {
    cf::Context ctx = context_for(l, slabs[0].config.box, cf::Precision::kDouble, backend);
    ctx.set_option("accumulation", "gauss-seidel");
    const Summed got = run_slabs(ctx, slabs, l.config.size(), 3);
    EXPECT_LE(relative_error(ref.forces, got.forces), 1e-12) << name_of(backend);
    EXPECT_LE(relative_error(ref.energies, got.energies), 1e-12) << name_of(backend);
    EXPECT_LE(relative_error(virial_shares(l), got.virials), 1e-12) << name_of(backend);
  }
  if (!cuda_missing().empty()) GTEST_SKIP() << "the CUDA cases: " << cuda_missing();
  for (const char* form : {"thread", "warp"}) {
    cf::Context ctx = context_for(l, slabs[0].config.box, cf::Precision::kDouble, cf::Backend::kCuda);
    ctx.set_option("traversal", form);
    ctx.set_option("skin", "0.3");
    const Summed got = run_slabs(ctx, slabs, l.config.size(), 3);
    EXPECT_LE(relative_error(ref.forces, got.forces), 1e-12) << form;
    EXPECT_LE(relative_error(ref.energies, got.energies), 1e-12) << form;
    EXPECT_LE(relative_error(virial_shares(l), got.virials), 1e-12) << form;
    // The same slab twice: the second call reuses the structure, with the same results bitwise.
    const Slab& s = slabs[2];
    std::vector<double> first(s.n_local * 3), again(s.n_local * 3);
    ctx.compute_local(s.n_local, s.config.size() - s.n_local, s.config.positions.data(), s.config.types.data(),
                      {first.data()});
    EXPECT_TRUE(ctx.statistics().rebuilt) << form;
    ctx.compute_local(s.n_local, s.config.size() - s.n_local, s.config.positions.data(), s.config.types.data(),
                      {again.data()});
    EXPECT_FALSE(ctx.statistics().rebuilt) << form;
    EXPECT_EQ(first, again) << form;
  }
}

// ---- bad input: each named ---------------------------------------------------------------------

struct Small {
  Liquid l = liquid(3);
  std::vector<Slab> slabs = cut_into_slabs(l.config, l.ff.cutoff, 4);
  const Slab& s = slabs[0];
  std::size_t ghosts() const { return s.config.size() - s.n_local; }
};

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const cf::Error& e) {
    return e.message();
  }
  return "(no error)";
}

TEST(LocalGhostErrors, NullPositions) {
  Small t;
  cf::Context ctx = context_for(t.l, t.s.config.box, cf::Precision::kDouble);
  std::vector<double> f(t.s.n_local * 3);
  EXPECT_EQ(error_of([&] { ctx.compute_local(t.s.n_local, t.ghosts(), nullptr, nullptr, {f.data()}); }),
            "positions is a null pointer (" + std::to_string(t.s.config.size()) + " particles)");
  // No particle at all: nothing to read, energy 0.
  double e = 1;
  ctx.compute_local(0, 0, nullptr, nullptr, {nullptr, nullptr, &e});
  EXPECT_EQ(e, 0.0);
}

TEST(LocalGhostErrors, GhostsWithEveryAxisPeriodic) {
  Small t;
  cf::Context ctx = context_for(t.l, t.l.config.box, cf::Precision::kDouble);
  std::vector<double> f(t.s.n_local * 3);
  const std::string message = error_of([&] {
    ctx.compute_local(t.s.n_local, t.ghosts(), t.s.config.positions.data(), t.s.config.types.data(), {f.data()});
  });
  EXPECT_EQ(message, "compute_local: " + std::to_string(t.ghosts()) +
                         " ghost particles, but every axis of the box is periodic: give the axes the ghosts "
                         "stand in for as open (set_box with periodic false there); on a periodic axis the "
                         "minimum image already finds each local's neighbours, and a ghost that is an image "
                         "would count its pairs twice");
  // Without ghosts the periodic box is right.
  EXPECT_NO_THROW(ctx.compute_local(t.s.n_local, 0, t.s.config.positions.data(), t.s.config.types.data(), {f.data()}));
}

TEST(LocalGhostErrors, NotFiniteCoordinateOfAGhost) {
  Small t;
  cf::Context ctx = context_for(t.l, t.s.config.box, cf::Precision::kDouble);
  std::vector<double> x = t.s.config.positions, f(t.s.n_local * 3);
  const std::size_t ghost = t.s.n_local + 3;
  x[ghost * 3 + 1] = std::nan("");
  EXPECT_EQ(error_of([&] { ctx.compute_local(t.s.n_local, t.ghosts(), x.data(), t.s.config.types.data(), {f.data()}); }),
            "particle " + std::to_string(ghost) + " has a non-finite y coordinate (nan)");
}

TEST(LocalGhostErrors, TypeOutOfRange) {
  Small t;
  cf::Context ctx = context_for(t.l, t.s.config.box, cf::Precision::kDouble);
  std::vector<uint32_t> types = t.s.config.types;
  std::vector<double> f(t.s.n_local * 3);
  const std::size_t ghost = t.s.config.size() - 1;
  types[ghost] = 1;
  EXPECT_EQ(error_of([&] {
              ctx.compute_local(t.s.n_local, t.ghosts(), t.s.config.positions.data(), types.data(), {f.data()});
            }),
            "particle " + std::to_string(ghost) + " has type index 1 but there are 1 types");
}

TEST(LocalGhostErrors, CountsThatOverflow) {
  Small t;
  cf::Context ctx = context_for(t.l, t.s.config.box, cf::Precision::kDouble);
  const std::size_t huge = std::numeric_limits<std::size_t>::max();
  EXPECT_EQ(error_of([&] { ctx.compute_local(huge, 2, t.s.config.positions.data(), nullptr, {}); }),
            "compute_local: " + std::to_string(huge) + " locals and 2 ghosts overflow a particle count");
}

// ---- the C API -----------------------------------------------------------------------------------

// cf_compute_local and cf_compute_local_full give the C++ call's numbers (bitwise: the same engine
// on the same input), and bad input comes back as CF_ERROR_INPUT with the C++ message.
TEST(CApiLocal, MatchesTheCppCallAndNamesBadInput) {
  Small t;
  const Slab& s = t.s;
  const std::size_t nl = s.n_local, ng = t.ghosts();
  cf::Context ctx = context_for(t.l, s.config.box, cf::Precision::kDouble);
  std::vector<double> f(nl * 3), e(nl), w(9), shares(nl * 9);
  double energy = 0;
  ctx.compute_local(nl, ng, s.config.positions.data(), s.config.types.data(),
                    {f.data(), e.data(), &energy, w.data(), shares.data()});

  cf_context* c = nullptr;
  ASSERT_EQ(cf_create(&c, 3), CF_OK);
  const double box[3] = {0, s.config.box.length[1], s.config.box.length[2]};
  const int periodic[3] = {0, 1, 1};
  ASSERT_EQ(cf_set_box(c, box, periodic), CF_OK);
  ASSERT_EQ(cf_set_cutoff(c, t.l.ff.cutoff, "truncate"), CF_OK);
  ASSERT_EQ(cf_add_type(c, "A", 1.0, 1.0, nullptr), CF_OK);
  std::vector<double> cf_f(nl * 3), cf_w(9), cf_e(nl), cf_shares(nl * 9, 1.0);
  double cf_energy = 0;
  ASSERT_EQ(cf_compute_local(c, nl, ng, s.config.positions.data(), s.config.types.data(), cf_f.data(), &cf_energy,
                             cf_w.data()),
            CF_OK)
      << cf_last_error(c);
  EXPECT_EQ(cf_f, f);
  EXPECT_EQ(cf_energy, energy);
  EXPECT_EQ(cf_w, w);
  ASSERT_EQ(cf_compute_local(c, nl, ng, s.config.positions.data(), nullptr, nullptr, &cf_energy, nullptr), CF_OK);
  EXPECT_EQ(cf_energy, energy) << "energy only, types NULL (all type 0)";
  // Accumulate: the shares added to ones.
  ASSERT_EQ(cf_compute_local_full(c, nl, ng, s.config.positions.data(), nullptr, nullptr, cf_e.data(), nullptr,
                                  nullptr, cf_shares.data(), 1),
            CF_OK);
  EXPECT_EQ(cf_e, e);
  for (std::size_t k = 0; k < shares.size(); ++k) ASSERT_EQ(cf_shares[k], 1.0 + shares[k]) << "entry " << k;

  EXPECT_EQ(cf_compute_local(c, nl, ng, nullptr, nullptr, cf_f.data(), nullptr, nullptr), CF_ERROR_INPUT);
  EXPECT_EQ(std::string(cf_last_error(c)), "positions is a null pointer (" + std::to_string(nl + ng) + " particles)");
  const int all_periodic[3] = {1, 1, 1};
  const double cube[3] = {t.l.config.box.length[0], box[1], box[2]};
  ASSERT_EQ(cf_set_box(c, cube, all_periodic), CF_OK);
  EXPECT_EQ(cf_compute_local(c, nl, ng, s.config.positions.data(), nullptr, cf_f.data(), nullptr, nullptr),
            CF_ERROR_INPUT);
  EXPECT_THAT(cf_last_error(c), HasSubstr("ghost particles, but every axis of the box is periodic"));
  EXPECT_EQ(cf_compute_local(nullptr, 0, 0, nullptr, nullptr, nullptr, nullptr, nullptr), CF_ERROR_INPUT);
  cf_destroy(c);
}

}  // namespace
