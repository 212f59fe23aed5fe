// The cellforce command line, a client of the public API: every command reaches the engine through
// a cellforce::Context (scene/engine_context.h), its engine flags checked against the option table
// (core/option_table.h) and handed to Context::set_option. `cellforce forces` reads one
// configuration (extended XYZ or H5MD) and writes its forces, energies and virial to HDF5 (see
// cli/forces.h). `cellforce evaluate` builds a lattice scene (by default the LAMMPS in.lj fluid's
// starting state: fcc, density 0.8442, 32,000 particles, rc 2.5), evaluates forces, energy and
// virial once per repeat with the CPU or the CUDA pipeline, and reports the physics, the search
// structure's counts and the stage times, optionally next to the O(n^2) brute force.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <csignal>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <vector>

#include <cellforce/cellforce.hpp>

#include "cli/bench.h"
#include "scene/engine_context.h"
#include "cli/forces.h"
#include "cli/option_rules.h"
#include "cli/options.h"
#include "cli/run.h"
#include "core/error.h"
#include "core/grid.h"
#include "core/memory.h"
#include "core/names.h"
#include "core/numbers.h"
#include "core/option_table.h"
#include "core/text.h"
#include "io/output_paths.h"
#include "io/text_file.h"
#include "scene/lattice.h"

namespace {

using namespace cellforce;
using cli::median;

struct EvaluateArgs {
  Lattice lattice = Lattice::kFcc;
  int cells = 20;
  double density = 0.8442;
  double jitter = 0.0;
  uint64_t seed = 1;
  double cutoff = 2.5;
  CutoffMode mode = CutoffMode::kTruncate;
  OptionList engine = command_engine_defaults();  // backend, precision, accumulation, cell rule, traversal, sort
  int repeats = 5;
  bool brute = false;
  std::string json;
};

int evaluate(const EvaluateArgs& args) {
  const OutputClaim claim = claim_output_files({{args.json, "--json", true}}, {}, "");  // before the work
  const int ldim = lattice_dimension(args.lattice);
  check_particle_count(lattice_site_count(args.lattice, {args.cells, args.cells, ldim == 3 ? args.cells : 1}), ldim,
                       "--cells " + std::to_string(args.cells));
  Configuration config = make_lattice(args.lattice, args.cells, args.density);
  if (args.jitter > 0) jitter(config, args.jitter, args.seed);
  const Box& box = config.box;
  const std::size_t n = config.size();
  const int dim = box.dim;
  ForceField ff;
  ff.cutoff = args.cutoff;
  ff.mode = args.mode;
  Context ctx = make_context(box, ff, args.engine);
  const std::string precision = args.engine.value(OptionId::kPrecision);
  const std::string accumulation = args.engine.value(OptionId::kAccumulation);
  const CellRule rule = parse_name(args.engine.value(OptionId::kCellRule), kCellRuleNames).value_or(CellRule::kTight);
  const std::string backend = ctx.backend_name();
  const std::string engine_name = ctx.description();
  std::vector<double> forces(n * std::size_t(dim));
  double energy = 0, virial[9] = {};
  const Outputs outputs{forces.data(), nullptr, &energy, virial};

  std::printf("cellforce evaluate: %zu particles (%s lattice, %d cells per axis, density %g, jitter %g)\n",
              n, dim == 3 ? "3D" : "2D", args.cells, args.density, args.jitter);
  std::printf("  box %.6g per edge, periodic; cutoff %g (%s); precision %s; %s; %s\n",
              box.length[0], ff.cutoff, to_string(ff.mode), precision.c_str(), accumulation.c_str(),
              engine_name.c_str());

  std::vector<double> total, t_ids, t_sort, t_cells, t_trav, t_acc;
  for (int r = 0; r < std::max(1, args.repeats); ++r) {
    ctx.compute(n, config.positions.data(), config.types.data(), outputs);
    const Statistics s = ctx.statistics();
    total.push_back(s.pipeline_seconds);
    t_ids.push_back(s.cell_ids_seconds);
    t_sort.push_back(s.sort_seconds);
    t_cells.push_back(s.collision_cells_seconds);
    t_trav.push_back(s.traversal_seconds);
    t_acc.push_back(s.accumulate_seconds);
  }
  const PairCounts s = ctx.count_pairs(n, config.positions.data(), config.types.data());
  std::printf("grid: %u x %u x %u cells, edge %.6g, half-width h %.6g (rule %s: edge >= %.6g)\n",
              s.grid_cells[0], s.grid_cells[1], s.grid_cells[2], s.cell_edge[0], s.half_width,
              rule == CellRule::kTight ? "rc + h" : "3h", min_cell_edge(rule, ff.cutoff, s.half_width));
  std::printf("entries: %zu (%zu valid), collision cells %zu, max occupancy %zu\n", s.entries,
              s.valid_entries, s.collision_cells, s.max_occupancy);
  std::printf("pairs: %zu tested, %zu within the cutoff (%.1f%%)\n", s.tested,
              s.within_cutoff, 100.0 * double(s.within_cutoff) / double(std::max<std::size_t>(1, s.tested)));

  double trace = 0, fmax = 0;
  for (int a = 0; a < dim; ++a) trace += virial[a * dim + a];
  for (std::size_t i = 0; i < n; ++i) {
    double f2 = 0;
    for (int a = 0; a < dim; ++a) f2 += forces[i * dim + a] * forces[i * dim + a];
    fmax = std::max(fmax, std::sqrt(f2));
  }
  std::printf("potential energy per particle %.9f\n", energy / double(n));
  std::printf("configurational pressure trace(W)/(d V) %.9f\n", trace / (dim * box.volume()));
  std::printf("max |F| %.6g\n", fmax);
  std::printf("time per evaluation, median of %zu: %.3f ms  [cell IDs %.3f | sort %.3f | collision cells %.3f | traversal %.3f | accumulate %.3f]%s\n",
              total.size(), 1e3 * median(total), 1e3 * median(t_ids), 1e3 * median(t_sort),
              1e3 * median(t_cells), 1e3 * median(t_trav), 1e3 * median(t_acc),
              backend == "cuda" ? " (stream time, host copies excluded)" : "");

  nlohmann::json out = {{"n", n},
                        {"cutoff", ff.cutoff},
                        {"cutoff_mode", to_string(ff.mode)},
                        {"precision", precision},
                        {"accumulation", accumulation},
                        {"backend", backend},
                        {"engine", engine_name},
                        {"energy_per_particle", energy / double(n)},
                        {"time_median_s", median(total)}};
  if (args.brute) {
    // The oracle through the API: every pair in double on the host, whatever the context's engine.
    std::vector<double> ref_forces(n * std::size_t(dim));
    double ref_energy = 0, ref_virial[9] = {};
    const auto t0 = std::chrono::steady_clock::now();
    ctx.compute_brute_force(n, config.positions.data(), config.types.data(),
                            Outputs{ref_forces.data(), nullptr, &ref_energy, ref_virial});
    const double tb = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    double rms = 0, worst = 0, worst_abs = 0;
    for (double f : ref_forces) rms += f * f;
    rms = std::sqrt(rms / double(n));
    for (std::size_t i = 0; i < n; ++i) {
      double d2 = 0, r2 = 0;
      for (int a = 0; a < dim; ++a) {
        const double d = forces[i * dim + a] - ref_forces[i * dim + a];
        d2 += d * d;
        r2 += ref_forces[i * dim + a] * ref_forces[i * dim + a];
      }
      worst = std::max(worst, std::sqrt(d2) / std::max(std::sqrt(r2), rms > 0 ? rms : 1.0));
      worst_abs = std::max(worst_abs, std::sqrt(d2));
    }
    std::printf("brute force (double, all pairs): %.3f ms, %.1fx the pipeline; energy per particle %.9f\n",
                1e3 * tb, tb / median(total), ref_energy / double(n));
    // On a perfect lattice the forces cancel to rounding (F_rms ~ 1e-13): read the absolute
    // difference there, the relative one on a jittered or disordered scene.
    std::printf("  max |dF_i| = %.3g (brute-force F_rms %.3g); max |dF_i| / max(|F_i|, F_rms) = %.3g; "
                "energy relative difference %.3g\n",
                worst_abs, rms, worst,
                std::abs(energy - ref_energy) / std::max(1e-300, std::abs(ref_energy)));
    out["brute_force_time_s"] = tb;
    out["max_force_error"] = worst;
    out["max_force_error_abs"] = worst_abs;
    out["brute_force_force_rms"] = rms;
  }
  if (!args.json.empty()) write_text_atomically(args.json, {out.dump(2)}, "the JSON summary");
  return 0;
}

// A name from `names` as cli::name_in reads it (any letter case, shown in --help as {a,b,c}); the
// option receives the named enum value (CLI11 reads an enum from its integer).
template <class T>
CLI::Validator one_of(const std::map<std::string, T>& names) {
  const CLI::Validator name = cli::name_in(names);
  return CLI::Validator(
      [names, name](std::string& value) -> std::string {
        std::string error = name(value);  // value in lower case when it names one
        if (error.empty()) value = std::to_string(static_cast<int>(names.at(value)));
        return error;
      },
      name.get_description());
}

// A choice among an engine option's names as a flag (option_flag), its value checked against the
// table's names where it enters (any letter case) and kept as the table spells it, for
// Context::set_option.
CLI::Option* add_engine_option(CLI::App* cmd, OptionList& engine, OptionId id, const std::string& description) {
  return cmd
      ->add_option_function<std::string>(
          option_flag(id), [&engine, id](const std::string& value) { engine.set(id, option_name(id, value)); },
          description)
      ->transform(cli::name_in(option_spec(id).names))
      ->type_name("ENUM");
}

// The options that choose and configure the engine, shared by every command that evaluates.
void add_backend_options(CLI::App* cmd, OptionList& engine) {
  add_engine_option(cmd, engine, OptionId::kBackend, "cpu, cuda, or auto (the GPU when one can be used; the default)");
  add_engine_option(cmd, engine, OptionId::kPrecision, "single, mixed or double (default double)");
  add_engine_option(cmd, engine, OptionId::kAccumulation, "jacobi or gauss-seidel");
  add_engine_option(cmd, engine, OptionId::kCellRule, "tight (c >= rc + h) or chapter (c >= 3h)");
  add_engine_option(cmd, engine, OptionId::kTraversal,
                    "CUDA traversal: auto (the default: tile for few cells per multiprocessor, else warp), warp (a "
                    "warp per cell), thread (a thread per cell) or tile (a block per 32 occupants of a cell)");
  add_engine_option(cmd, engine, OptionId::kSort, "CUDA sort: cub or chapter (the chapter's radix sort)");
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"cellforce: spatial-subdivision cutoff search and Lennard-Jones forces"};
  app.set_version_flag("--version", "cellforce " CELLFORCE_VERSION);
  app.require_subcommand(1);

  EvaluateArgs ev;
  CLI::App* evaluate_cmd = app.add_subcommand(
      "evaluate", "Evaluate forces, energy and virial of a lattice scene with the CPU or CUDA pipeline "
                  "(default: the LAMMPS in.lj fluid, fcc at density 0.8442, 32,000 particles, rc 2.5)");
  evaluate_cmd->add_option("--lattice", ev.lattice, "Lattice")
      ->transform(one_of(cli::kLattices));
  cli::add_number(evaluate_cmd, "--cells", ev.cells, "Unit cells per axis", cli::kPositive);
  cli::add_number(evaluate_cmd, "--density", ev.density, "Number density", cli::kPositive);
  cli::add_number(evaluate_cmd, "--jitter", ev.jitter, "Uniform random displacement amplitude per axis",
                  cli::kNonNegative);
  cli::add_number(evaluate_cmd, "--seed", ev.seed, "Seed of the jitter");
  cli::add_number(evaluate_cmd, "--cutoff", ev.cutoff, "Cutoff radius rc", cli::kPositive);
  evaluate_cmd->add_option(option_flag(OptionId::kCutoffMode), ev.mode, "truncate, shift or force-shift")
      ->transform(one_of(cli::kCutoffModes));
  add_backend_options(evaluate_cmd, ev.engine);
  cli::add_number(evaluate_cmd, "--repeats", ev.repeats, "Evaluations to time", cli::kPositive);
  evaluate_cmd->add_flag("--brute-force", ev.brute, "Also run the O(n^2) double brute force and compare");
  evaluate_cmd->add_option("--json", ev.json, "Write a JSON summary here");

  ForcesArgs fa;
  CLI::App* forces_cmd = app.add_subcommand(
      "forces", "Forces, per-particle energies, energy and virial of one configuration (extended XYZ "
                "or H5MD) with the CPU or CUDA pipeline, written to HDF5 (/forces, /energies, "
                "/energy, /virial, and attributes saying how)");
  forces_cmd->add_option("input", fa.input, "Configuration: extended XYZ (ASE convention) or H5MD")
      ->required()->check(cli::existing_file());
  forces_cmd->add_option("--out,-o", fa.out, "HDF5 file to write")->required();
  cli::add_number(forces_cmd, "--cutoff", fa.cutoff, "Cutoff radius rc", cli::kPositive)->capture_default_str();
  forces_cmd->add_option(option_flag(OptionId::kCutoffMode), fa.mode, "truncate, shift or force-shift")
      ->transform(one_of(cli::kCutoffModes));
  forces_cmd->add_option("--type", fa.types,
                         "NAME:SIGMA:EPSILON for each species (repeat); without it a file of one "
                         "species gets sigma = epsilon = 1");
  forces_cmd->add_option("--pair", fa.pairs, "A:B:SIGMA:EPSILON, an explicit pair value (repeat)");
  forces_cmd->add_option(option_flag(OptionId::kMixing), fa.mixing, "lorentz-berthelot or geometric")
      ->transform(one_of(cli::kMixings));
  add_backend_options(forces_cmd, fa.engine);
  cli::add_number(forces_cmd, "--dim", fa.read.dim, "2 or 3 (XYZ: default 3, a 2D file has z = 0; H5MD: from the file)",
                  cli::between(2, 3));
  cli::add_number(forces_cmd, "--frame", fa.read.frame, "Frame to read, 0-based; negative counts from the end (-1: the last)")
      ->capture_default_str();
  forces_cmd->add_option("--group", fa.read.group, "H5MD particles group (default: the only one)");
  cli::add_number(forces_cmd, "--repeats", fa.repeats, "Evaluations to time (the file records their median)",
                  cli::kPositive)->capture_default_str();
  forces_cmd->add_flag("--quiet,-q", fa.quiet, "No summary on stdout");
  forces_cmd->add_flag("--overwrite", fa.overwrite, "Replace an existing --out file (refused otherwise)");

  RunArgs ra;
  CLI::App* run_cmd = app.add_subcommand(
      "run", "Molecular dynamics of a scene file (systems/*.toml); without one, the built-in LAMMPS in.lj "
             "fluid (fcc at density 0.8442, 32,000 particles, rc 2.5, T 1.44, dt 0.005, NVE), on the GPU "
             "when one can be used");
  run_cmd->add_option("scene", ra.scene, "Scene file (TOML)")->check(cli::existing_file());
  cli::add_number(run_cmd, "--steps", ra.steps, "Override the scene's number of steps", cli::kNonNegative);
  run_cmd->add_option(option_flag(OptionId::kBackend), ra.backend, "Override the scene's backend: cpu, cuda or auto")
      ->transform(cli::name_in(option_spec(OptionId::kBackend).names));
  run_cmd
      ->add_option(option_flag(OptionId::kPrecision), ra.precision,
                   "Override the scene's precision: single, mixed or double")
      ->transform(cli::name_in(option_spec(OptionId::kPrecision).names));
  run_cmd
      ->add_option(option_flag(OptionId::kTraversal), ra.traversal,
                   "CUDA traversal: auto (default), warp, thread or tile")
      ->transform(cli::name_in(option_spec(OptionId::kTraversal).names));
  run_cmd->add_option("--thermo-file", ra.thermo_file, "Write the thermodynamics to this CSV file");
  run_cmd->add_option("--trajectory", ra.trajectory, "Write an H5MD trajectory to this file");
  cli::add_number(run_cmd, "--trajectory-every", ra.trajectory_every, "Steps between trajectory frames",
                  cli::kPositive);
  run_cmd->add_option("--restart", ra.restart, "Continue from this checkpoint (written by the same scene)")
      ->check(cli::existing_file());
  run_cmd
      ->add_option_function<std::string>(
          option_flag(OptionId::kSkin),
          [&ra](const std::string& value) {
            if (same_name(value, kAutoSkin)) {
              ra.skin_auto = true;
              return;
            }
            double skin = 0;
            if (const NumberText r = read_real(value, skin); r != NumberText::kOk)
              throw CLI::ValidationError(option_flag(OptionId::kSkin),
                                         "expected auto or a length >= 0: " + real_problem(value, r));
            if (!(skin >= 0) || !std::isfinite(skin))
              throw CLI::ValidationError(option_flag(OptionId::kSkin),
                                         "must be auto or a finite length >= 0, got " + format_number(skin));
            ra.skin = skin;
          },
          "Override the scene's [neighbor] skin: auto (the engine's rule, the default without [neighbor]) or "
          "a length: build the cell structure for rc + skin and reuse it while no particle has moved more "
          "than skin/2 (0: rebuild every step)");
  run_cmd->add_flag("--quiet,-q", ra.quiet, "Only the setup and the performance summary on the screen");
  run_cmd->add_flag("--overwrite", ra.overwrite,
                    "Replace the thermo, trajectory and checkpoint files of an earlier run (refused otherwise)");

  BenchArgs ba;
  ba.engine.set(OptionId::kPrecision, name_of(Precision::kMixed, kPrecisionNames));
  CLI::App* bench_cmd = app.add_subcommand(
      "bench", "Time MD steps of the LAMMPS in.lj fluid (fcc at density 0.8442, rc 2.5, T 1.44, NVE, dt 0.005) "
               "at several sizes: steps/s, particle-steps/s, stage times, memory per particle, median force "
               "error against double precision, NVE drift; a table, and JSON rows with --json");
  cli::add_number(bench_cmd, "--sizes", ba.sizes, "Particle counts (each runs the nearest fcc size, 4 c^3; default "
                                                  "32000 256000 1048576 4194304)", cli::Limits{1.0});
  cli::add_number(bench_cmd, "--cells", ba.cells, "fcc unit cells per axis instead (4 c^3 particles)", cli::kPositive);
  add_backend_options(bench_cmd, ba.engine);
  bench_cmd
      ->add_option_function<double>(
          option_flag(OptionId::kSkin),
          [&ba](const double& skin) { ba.engine.set(OptionId::kSkin, format_number(skin)); },  // exact text
          "Build the cell structure for rc + skin and reuse it while no particle moved more than skin/2 (0: "
          "rebuild every step; default: auto, the engine's rule, as a scene without [neighbor])")
      ->transform(cli::number<double>(cli::kNonNegative))
      ->type_name("NUMBER");
  bench_cmd->add_flag_callback(
      option_flag(OptionId::kNeighborList),
      [&ba] { ba.engine.set(OptionId::kNeighborList, name_of(true, kBooleanNames)); },
      "With a skin (CUDA, Jacobi): each build records every particle's partners within rc + skin and the steps it "
      "serves walk those lists");
  add_engine_option(bench_cmd, ba.engine, OptionId::kNeighborCheck,
                    "With a skin: rebuild when a particle has moved more than skin/2 (true, the default) or only "
                    "every --neighbor-every evaluations (false: no displacement check)");
  bench_cmd
      ->add_option_function<int64_t>(
          option_flag(OptionId::kNeighborEvery),
          [&ba](const int64_t& every) { ba.engine.set(OptionId::kNeighborEvery, std::to_string(every)); },
          "With a skin: a structure serves at most this many evaluations (0: no limit, the default)")
      ->transform(cli::number<int64_t>(cli::kNonNegative))
      ->type_name("N");
  bench_cmd->add_flag("--chapter", ba.chapter,
                      "The chapter's configuration: a thread per cell, its radix sort, cells >= 1.5 x 2h, a "
                      "rebuild every step");
  bench_cmd
      ->add_option(option_flag(OptionId::kCutoffMode), ba.mode, "truncate (in.lj, the default), shift or force-shift")
      ->transform(one_of(cli::kCutoffModes));
  cli::add_number(bench_cmd, "--seconds", ba.seconds, "Timed seconds per size (sets the steps)", cli::kPositive)
      ->capture_default_str();
  cli::add_number(bench_cmd, "--steps", ba.steps, "Timed steps per size instead of --seconds", cli::kPositive);
  cli::add_number(bench_cmd, "--warmup", ba.warmup, "Steps before the timing (excluded)", cli::kPositive)
      ->capture_default_str();
  cli::add_number(bench_cmd, "--samples", ba.samples, "Energy samples over the timed steps, for the NVE drift",
                  cli::between(2, 100000))
      ->capture_default_str();
  bench_cmd->add_flag("!--no-reference", ba.reference, "Skip the force error against double precision");
  bench_cmd->add_flag("--embed", ba.embed,
                      "Time the loop of a code that embeds cellforce (CUDA): its own velocity Verlet, two kernels "
                      "of its own on its own stream around compute_device on device arrays, instead of step()");
  cli::add_number(bench_cmd, "--external-force", ba.external_force,
                  "An external force of this size along x, + on even particles and - on odd (no net force), set "
                  "on the MD state (set_external_forces): what an external force costs a step",
                  cli::kPositive);
  bench_cmd->add_flag("--langevin", ba.langevin,
                      "Langevin dynamics (BAOAB, kT 1.44, friction 1) instead of NVE: the same fluid at its "
                      "temperature (no NVE drift)");
  bench_cmd
      ->add_option("--order", ba.order,
                   "How the particles are numbered: lattice (the fcc's order), shuffled (seeded random: the order a "
                   "long run's diffusion leaves) or cells (cell by cell on the grid of rc + skin: the order of a "
                   "list build's ranks)")
      ->transform(one_of(name_map(kNumberingNames)))
      ->default_str("lattice");
  add_engine_option(bench_cmd, ba.engine, OptionId::kMemory,
                    "CUDA pair lists' memory: auto (lean where the fast layout's ~1,320 bytes a particle would not "
                    "fit in 90% of the device; the default), fast, or lean (no staged array, occupants staged as the "
                    "build loads them, the sort's arrays in the dead list's room, the count pass's masks only in the "
                    "memory left: ~700 bytes a particle and up to ~930 with every mask; builds up to ~2x slower where "
                    "the masks find no room; an automatic skin is then 0.18 rc instead of 0.24 rc)");
  bench_cmd->add_option("--label", ba.label, "The rows' configuration name (default: default, or chapter)");
  bench_cmd->add_option("--save-final", ba.save_final,
                        "Write PREFIX-<n>.positions.f64 and PREFIX-<n>.forces.f64: the last step's positions and "
                        "forces, n x 3 little-endian doubles, for an outside check of the force error");
  bench_cmd->add_option("--json", ba.json, "Write the rows here (rewritten whole after every size)");

  CLI11_PARSE(app, argc, argv);
  // A file that outgrows `ulimit -f` gets an error from the write (EFBIG), not a kill by SIGXFSZ.
  std::signal(SIGXFSZ, SIG_IGN);
  try {
    if (run_cmd->parsed()) return run_md(ra);
    if (forces_cmd->parsed()) return run_forces(fa);
    if (evaluate_cmd->parsed()) return evaluate(ev);
    if (bench_cmd->parsed()) return run_bench(ba);
  } catch (const std::bad_alloc&) {
    // The sizes are checked before allocating (core/memory.h); what still runs out names itself
    // where it can (reporting_bad_alloc), and this is the rest.
    std::fprintf(stderr, "out of memory (std::bad_alloc) in cellforce %s: the machine has %.3g GB\n",
                 run_cmd->parsed() ? "run" : forces_cmd->parsed() ? "forces" : bench_cmd->parsed() ? "bench" : "evaluate", double(physical_memory()) / 1e9);
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
  return 0;
}
