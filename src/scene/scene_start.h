// A scene's molecular dynamics as `cellforce run` starts it, shared by the run command and the
// Python module's Simulation.from_scene: the configuration and masses, the context (physics, engine
// options, integrator), [minimize], the initial velocities, the state set and its first step
// checked. Errors name the scene file and what it holds.
#pragma once

#include <cellforce/cellforce.hpp>

#include <cstddef>
#include <string>
#include <vector>

#include "core/box.h"
#include "scene/scene.h"
#include "state/md_state.h"

namespace cellforce {

// The scene's starting configuration (scene.h's build_configuration), validated against its force
// field; `wrapped`, when given, receives how many positions were wrapped into the box.
Configuration scene_configuration(const Scene& scene, std::size_t* wrapped = nullptr);
// Each particle's mass, from its type's.
std::vector<double> scene_masses(const Scene& scene, const Configuration& config);

// The engine for the scene, through the public API: the system and engine choices (make_context),
// and the integrator.
Context scene_context(const Scene& scene, const Box& box);

// The state into the context (set_state), and back from it (get_state: a download with CUDA).
void set_state(Context& ctx, const MdState& state, const std::vector<double>& masses);
void fetch_state(Context& ctx, MdState& state);

// [minimize]: FIRE on the starting configuration (a fresh run's, before the velocities are
// drawn), the state set in the context and fetched back; returns the summary line.
std::string minimize_start(Context& ctx, const Scene& scene, MdState& state, const std::vector<double>& masses);

// Dynamics that the first step would throw apart (overlaps) are refused (state/stable_start.h),
// with the remedy that fits a fresh run or a restart.
void check_start(const Scene& scene, const MdState& state, const std::vector<double>& masses, bool restart);

// A fresh run's start: configuration, masses, context, [minimize], the initial velocities of
// [initial], the state set in the context (step 0) and checked. `state` holds it as set.
struct SceneStart {
  Context ctx;
  MdState state;
  std::vector<double> masses;
};
SceneStart start_scene(const Scene& scene);

}  // namespace cellforce
