// `cellforce bench`: the LAMMPS in.lj fluid (fcc at density 0.8442, rc 2.5, T 1.44, NVE, dt 0.005)
// at the sizes asked for, timed through the public API as a user's code would run it. Per size: a
// warm-up (excluded), a calibration of the step count, the timed steps in chunks that end with an
// energy sample (for the NVE drift), then the force error of the final configuration against a
// double-precision evaluation of it. A table on the screen and, with --json, the rows in the
// schema of validation/reports/performance.json. A size that cannot run (memory) is a row with an
// "error" and the next size still runs.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "scene/engine_context.h"
#include "core/force_field.h"   // CutoffMode
#include "core/names.h"         // Named
#include "core/option_table.h"

namespace cellforce {

// How the particles are numbered (--order): the fcc's order (in.lj's); cell by cell on the grid of
// rc + skin, the lattice's order inside a cell (the order a list build's ranks give); or a seeded
// random order (what diffusion leaves after a long run, where an engine that keeps the caller's
// order finds no locality in it).
enum class Numbering { kLattice, kCells, kShuffled };
inline constexpr Named<Numbering> kNumberingNames[] = {
    {"lattice", Numbering::kLattice}, {"cells", Numbering::kCells}, {"shuffled", Numbering::kShuffled}};

struct BenchArgs {
  std::vector<double> sizes;      // particle counts; each runs the nearest fcc lattice (4 c^3)
  std::vector<int> cells;         // or fcc unit cells per axis
  OptionList engine = command_engine_defaults();  // backend, precision, traversal, sort, cell rule, skin
                                                  // (auto, as a scene without [neighbor]), lists, memory
  bool chapter = false;           // the chapter's configuration: thread per cell, its radix sort,
                                  // cells >= 1.5 x 2h, rebuild every step
  CutoffMode mode = CutoffMode::kTruncate;
  bool langevin = false;          // Langevin (BAOAB, kT 1.44, friction 1) instead of in.lj's NVE: the
                                  // rows then have no NVE drift
  bool embed = false;             // time an embedding code's own Verlet loop around compute_device
                                  // (cli/embed_loop.h; CUDA, NVE) instead of Context::step
  double external_force = 0;      // > 0: an external force of +-this along x (+ on even particles, - on
                                  // odd: no net force) set on the state (Context::set_external_forces)
  double seconds = 2.0;           // timed seconds per size (sets the steps after the warm-up)
  int64_t steps = 0;              // > 0: exactly these timed steps instead
  int64_t warmup = 50;            // steps before the timing
  int samples = 10;               // energy samples over the timed steps (>= 2)
  bool reference = true;          // the force error against double precision
  std::string json;               // write the rows here
  std::string save_final;         // non-empty: PREFIX.positions.f64 and PREFIX.forces.f64, the last
                                  // step's positions and forces (n x 3 little-endian doubles) per
                                  // size, PREFIX gaining "-<n>"
  std::string label;              // the rows' "configuration" (default: "default" or "chapter")
  Numbering order = Numbering::kLattice;  // how the particles are numbered (the rows' "order")
};

// Returns the exit code: 0 when every size ran, 1 when one failed (its row says why).
int run_bench(const BenchArgs& args);

}  // namespace cellforce
