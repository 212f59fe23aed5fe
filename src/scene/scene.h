// A scene: everything `cellforce run` needs, read from a TOML file (systems/*.toml) or built in
// (the LAMMPS in.lj fluid). Unknown keys and impossible values are errors that name the file,
// the line and the key.
//
//   [system]       dimension = 3, periodic = [true, true, true]
//   [particles]    source = "lattice" | "random" | "file"
//                    lattice: lattice = "fcc"|"bcc"|"sc"|"square"|"hexagonal", cells = [nx, ny, nz],
//                             density = rho or lattice_constant = a, box = [Lx, Ly, Lz] (default:
//                             the lattice's extent), offset = [x, y, z], sphere_radius = r (keep
//                             only sites within r of the lattice centre)
//                    random:  count = n, box = [Lx, Ly, Lz], min_distance = d
//                    file:    path = "x.xyz" (extended XYZ or H5MD, relative to the scene file),
//                             frame = -1
//                  composition = { A = 0.8, B = 0.2 } (lattice, random; default: all the first type)
//   [[types]]      name, mass = 1, sigma = 1, epsilon = 1 (one table per type)
//   [interactions] cutoff = 2.5, mode = "truncate"|"shift"|"force-shift",
//                  mixing = "lorentz-berthelot"|"geometric",
//                  [[interactions.pairs]] types = ["A", "B"], sigma, epsilon
//   [initial]      temperature = T, seed = 1
//   [integrator]   kind = "nve"|"langevin", dt = 0.005, temperature = T, friction = 1 (langevin)
//   [run]          steps = n, backend = "auto"|"cpu"|"cuda", precision = "single"|"mixed"|"double"
//   [minimize]     force_tolerance = 100, max_steps = 10000, dt = 0.001, dt_max = 10 x dt,
//                  max_displacement = 0.1 (the section's presence turns it on; every key optional)
// [minimize] relaxes a fresh run's starting configuration with FIRE (src/md/minimize.h) before the
// velocities are drawn, until the largest per-particle force is below force_tolerance
// (energy/length units), moving no particle more than max_displacement (length units) per step;
// not converging within max_steps stops the run. Without it, a start whose first time step would
// move a particle by more than 0.1 x the smallest sigma (an overlap) is refused; so is such a
// restart.
//   [neighbor]     skin = "auto", check = true, every = 0, audit = false, list = false (list only
//                  with a skin given as a length)
// skin = "auto" (the default, also without [neighbor]) lets the engine choose (core/reuse.h
// resolve_reuse: pair lists with a skin of 0.24 rc on CUDA with Jacobi accumulation where they fit
// the box, 0.18 rc where the lists run in lean memory, else no skin; the run header prints the choice). A length: skin > 0 builds the cell structure (stages 1-3) for rc + skin and reuses it while no
// particle has moved more than skin/2 since the build (check), and at most `every` steps when
// every > 0; audit = true counts on every reused step the pairs within rc the structure misses or
// repeats (a diagnostic: slow); list = true (CUDA, Jacobi) has each build record every particle's
// partners within rc + skin, and the steps it serves walk those lists instead of the cells'
// candidates. Reuse is exact, so it is not part of the fingerprint.
// Input paths ([particles] path) are relative to the scene file's folder; output paths are
// relative to the working folder. The quoted choices ("fcc", "cuda", "auto", ...) are read in any
// letter case ("CUDA"), as on the command line and in the API; keys and type names are not.
// Composition fractions need not add up to 1 (they are shares of their sum, however large).
//
//   [output]       thermo_every = 100, thermo_file = "thermo.csv", trajectory = "traj.h5",
//                  trajectory_every = 1000, velocities = false, forces = false,
//                  checkpoint = "checkpoint.h5", checkpoint_every = 0 (0: at the end only)
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "core/force_field.h"
#include "core/option_table.h"
#include "scene/lattice.h"

namespace cellforce {

enum class ParticleSource : uint8_t { kLattice, kRandom, kFile };
enum class IntegratorKind : uint8_t { kNve, kLangevin };

struct SceneParticles {
  ParticleSource source = ParticleSource::kLattice;
  // lattice
  Lattice lattice = Lattice::kFcc;
  std::array<int, 3> cells = {20, 20, 20};
  double density = 0.8442;        // number density (used when lattice_constant is 0)
  double lattice_constant = 0.0;  // 0: from the density
  std::array<double, 3> box = {0, 0, 0};     // 0: the lattice's extent (lattice), required (random)
  std::array<double, 3> offset = {0, 0, 0};  // lattice origin
  double sphere_radius = 0.0;                // > 0: keep lattice sites within this of the centre
  // random
  std::size_t count = 0;
  double min_distance = 0.0;
  // file
  std::string path;  // as resolved against the scene file's folder
  long frame = -1;
  // lattice and random: type name -> fraction (normalised); empty: all of the first type
  std::vector<std::pair<std::string, double>> composition;
};

struct SceneIntegrator {
  IntegratorKind kind = IntegratorKind::kNve;
  double dt = 0.005;
  double temperature = 1.0;  // Langevin target kT
  double friction = 1.0;     // Langevin gamma (1 / time)
};

// [minimize]: FIRE before the dynamics (see FireSettings in src/md/minimize.h).
struct SceneMinimize {
  bool enabled = false;            // the scene has a [minimize] section
  double force_tolerance = 100.0;  // converged when max_i |F_i| < this
  int64_t max_steps = 10000;
  double dt = 0.001;               // FIRE's initial time step
  double dt_max = 0.01;            // its largest (default 10 x dt)
  double max_displacement = 0.1;   // per particle and step
};

struct SceneOutput {
  int64_t thermo_every = 100;
  std::string thermo_file;   // CSV; empty: screen only
  std::string trajectory;    // H5MD; empty: none
  int64_t trajectory_every = 1000;
  bool velocities = false;
  bool forces = false;
  std::string checkpoint;    // empty: none
  int64_t checkpoint_every = 0;  // 0: at the end of the run only
};

struct Scene {
  std::string source = "built-in";  // the file it came from
  std::string text;                 // the file's text (empty for the built-in scene)
  int dim = 3;
  std::array<bool, 3> periodic = {true, true, true};
  SceneParticles particles;
  std::vector<double> masses;  // per type, same order as force_field.types
  ForceField force_field;
  double initial_temperature = 1.44;
  uint64_t seed = 1;
  SceneIntegrator integrator;
  SceneMinimize minimize;
  int64_t steps = 1000;
  // The engine options of [run] (backend, precision) and [neighbor] (skin, neighbor-check,
  // neighbor-every, neighbor-audit, and neighbor-list with a length skin) as Context::set_option
  // takes them, checked against the option table as the file is read.
  OptionList engine;
  SceneOutput output;
};

// The LAMMPS in.lj benchmark fluid: fcc at density 0.8442, 20^3 unit cells (32,000 particles),
// rc 2.5 (truncated), T = 1.44, dt 0.005, NVE; on the GPU when one can be used.
Scene default_scene();

// Reads a scene; throws cellforce::Error naming the file, line and key of the first problem.
Scene read_scene(const std::string& path);
// The same from text; `name` stands for the file in messages, and relative paths in the scene
// are resolved against `folder`.
Scene parse_scene(const std::string& text, const std::string& name, const std::string& folder = ".");

// A fingerprint of what determines a run's trajectory (system, particles, types, interactions,
// initial state, integrator, minimisation), not of its length, outputs, backend or the file's comments: a
// checkpoint can only continue a run with the same fingerprint.
uint64_t scene_fingerprint(const Scene& scene);

// The scene's starting configuration (box, positions, types) and the names of its types.
// Lattice and random placements are deterministic for the scene's seed.
// Positions on periodic axes are wrapped into [0, L) (a file may hold unwrapped coordinates, as
// LAMMPS and OpenMM write them); `wrapped`, when given, receives how many particles were moved.
Configuration build_configuration(const Scene& scene, std::size_t* wrapped = nullptr);

}  // namespace cellforce
