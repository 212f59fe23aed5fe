// An embedding code's own velocity Verlet around Context::compute_device (the loop `cellforce bench
// --embed` times: src/cli/embed_loop.h, its two kernels on its own stream, the device deciding the
// rebuilds) against the context's own MD loop (Context::step) from the same state, in double
// precision. The arithmetic differs (the embedding loop kicks with 1/m and never wraps; step() kicks
// with F/m, defers its closing half kick and wraps), so the trajectories agree to round-off, not
// bitwise: 1e-9 in the positions after 100 steps (seen ~1e-13), where one pair missed or counted
// twice in one step moves a particle by ~1e-6. Skips where no CUDA device can be used.
#include <gtest/gtest.h>

#include <cellforce/cellforce.hpp>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#ifdef CELLFORCE_HAVE_CUDA
#include "backend/engine.h"  // cuda/backend/engine.h: GpuEngine::unavailable
#include "cli/embed_loop.h"
#endif
#include "scene/lattice.h"
#include "state/velocities.h"

namespace {

namespace cf = cellforce;

TEST(EmbeddedLoop, FollowsStepToRoundOff) {
#ifdef CELLFORCE_HAVE_CUDA
  if (const std::string why = cf::GpuEngine::unavailable(); !why.empty()) GTEST_SKIP() << why;
  cf::MdState state;
  state.config = cf::make_lattice(cf::Lattice::kFcc, 8, 0.8442);  // 2,048 particles, in.lj's density
  const std::size_t n = state.config.size();
  const std::vector<double> masses(n, 1.0);
  cf::initialize_velocities(state, masses, 1.44, 2047, true);
  auto context = [&] {
    cf::Context ctx(3);
    const bool periodic[3] = {true, true, true};
    ctx.set_box(state.config.box.length, periodic);
    ctx.set_cutoff(2.5, cf::CutoffMode::kTruncate);
    ctx.add_type("A", 1.0, 1.0);
    ctx.set_backend(cf::Backend::kCuda);
    ctx.set_precision(cf::Precision::kDouble);
    return ctx;
  };
  constexpr int kSteps = 100;
  constexpr double kDt = 0.005;
  cf::Context stepped = context();
  cf::IntegratorOptions verlet;
  verlet.dt = kDt;
  stepped.set_integrator(verlet);
  stepped.set_state(n, state.config.positions.data(), state.velocities.data(), nullptr, masses.data());
  stepped.step(kSteps);
  std::vector<double> x_step(3 * n), f_step(3 * n);
  stepped.get_state(x_step.data(), nullptr, f_step.data());

  cf::Context embedding = context();
  cf::EmbeddedVerlet loop(embedding, n, state.config.positions.data(), state.velocities.data(), nullptr,
                          masses.data(), kDt);
  loop.step(kSteps, false);
  std::vector<double> x_embed(3 * n), f_embed(3 * n);
  loop.download(x_embed.data(), f_embed.data());

  double dx = 0, df = 0, moved = 0;
  for (std::size_t k = 0; k < x_step.size(); ++k) {
    const double L = state.config.box.length[k % 3];
    double d = x_embed[k] - x_step[k];
    d -= L * std::rint(d / L);  // the embedding loop does not wrap its positions
    dx = std::max(dx, std::abs(d));
    df = std::max(df, std::abs(f_embed[k] - f_step[k]));
    double m = x_step[k] - state.config.positions[k];
    m -= L * std::rint(m / L);
    moved = std::max(moved, std::abs(m));
  }
  EXPECT_LE(dx, 1e-9) << "positions";
  EXPECT_LE(df, 1e-6) << "forces";
  EXPECT_GT(moved, 0.1) << "the particles moved: the steps ran";
#else
  GTEST_SKIP() << "this build has no CUDA";
#endif
}

}  // namespace
