#include "scene/scene_start.h"

#include <cstdio>

#include "scene/engine_context.h"
#include "core/error.h"
#include "core/system.h"
#include "state/stable_start.h"
#include "state/velocities.h"

namespace cellforce {

Configuration scene_configuration(const Scene& scene, std::size_t* wrapped) {
  Configuration config = with_context(scene.source, [&] { return build_configuration(scene, wrapped); });
  with_context(scene.source, [&] { validate_system(config.view(), scene.force_field); });
  return config;
}

std::vector<double> scene_masses(const Scene& scene, const Configuration& config) {
  std::vector<double> masses(config.size());
  for (std::size_t i = 0; i < masses.size(); ++i) masses[i] = scene.masses[config.types[i]];
  return masses;
}

// The engine for the scene, through the public API: the system and engine choices
// (make_context), and the integrator.
Context scene_context(const Scene& scene, const Box& box) {
  Context ctx = make_context(box, scene.force_field, scene.engine);
  IntegratorOptions integrator;
  integrator.kind = scene.integrator.kind == IntegratorKind::kLangevin ? Integrator::kLangevin : Integrator::kVerlet;
  integrator.dt = scene.integrator.dt;
  integrator.temperature = scene.integrator.temperature;
  integrator.friction = scene.integrator.friction;
  integrator.seed = scene.seed;
  ctx.set_integrator(integrator);
  return ctx;
}

void set_state(Context& ctx, const MdState& state, const std::vector<double>& masses) {
  ctx.set_state(state.config.size(), state.config.positions.data(),
                state.velocities.empty() ? nullptr : state.velocities.data(), state.config.types.data(),
                masses.data(), state.step);
}

// The state's positions, velocities and forces from the context (a download with CUDA).
void fetch_state(Context& ctx, MdState& state) {
  const std::size_t nd = state.config.positions.size();
  state.velocities.resize(nd);
  state.forces.resize(nd);
  ctx.get_state(state.config.positions.data(), state.velocities.data(), state.forces.data());
  state.step = ctx.current_step();
}

// [minimize]: FIRE on the starting configuration (a fresh run's, before the velocities are
// drawn); returns the summary line.
std::string minimize_start(Context& ctx, const Scene& scene, MdState& state, const std::vector<double>& masses) {
  set_state(ctx, state, masses);
  MinimizeOptions fire;
  fire.force_tolerance = scene.minimize.force_tolerance;
  fire.max_steps = scene.minimize.max_steps;
  fire.dt = scene.minimize.dt;
  fire.dt_max = scene.minimize.dt_max;
  fire.max_displacement = scene.minimize.max_displacement;
  const MinimizeResult r = with_context(scene.source + ": [minimize]", [&] { return ctx.minimize(fire); });
  fetch_state(ctx, state);
  const std::size_t n = state.config.size();
  char line[320];
  std::snprintf(line, sizeof line,
                "  minimize (FIRE): %lld steps; max force %.4g -> %.4g (particle %zu); energy per particle "
                "%.6g -> %.6g",
                (long long)r.steps, r.initial_max_force, r.final_max_force, r.final_max_force_particle,
                r.initial_energy / double(n), r.final_energy / double(n));
  return line;
}

// Dynamics that the first step would throw apart (overlaps) are refused before any output.
void check_start(const Scene& scene, const MdState& state, const std::vector<double>& masses, bool restart) {
  std::string remedy;  // the default advice (add [minimize]) unless it cannot help
  if (restart)
    remedy = "the checkpoint's state cannot continue at this dt: lower dt ([minimize] applies to fresh runs "
             "only, and would change the scene's fingerprint)";
  else if (scene.minimize.enabled) {
    char text[200];
    std::snprintf(text, sizeof text, "[minimize] stops at a largest force of %g, too large for this dt: lower "
                  "[minimize] force_tolerance, or lower dt", scene.minimize.force_tolerance);
    remedy = text;
  }
  check_stable_start(state, masses, scene.integrator.dt, scene.force_field, remedy);
}

SceneStart start_scene(const Scene& scene) {
  MdState state;
  state.config = scene_configuration(scene);
  std::vector<double> masses = scene_masses(scene, state.config);
  SceneStart start{scene_context(scene, state.config.box), MdState{}, {}};
  if (scene.minimize.enabled) minimize_start(start.ctx, scene, state, masses);
  const bool langevin = scene.integrator.kind == IntegratorKind::kLangevin;
  initialize_velocities(state, masses, scene.initial_temperature, scene.seed, !langevin);
  with_context(scene.source + ": step 0", [&] { set_state(start.ctx, state, masses); });
  fetch_state(start.ctx, state);
  with_context(scene.source + ": step 0", [&] { check_start(scene, state, masses, false); });
  start.state = std::move(state);
  start.masses = std::move(masses);
  return start;
}

}  // namespace cellforce
