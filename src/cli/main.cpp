// The cellforce command line. `cellforce evaluate` builds a lattice scene (by default the LAMMPS
// in.lj fluid's starting state: fcc, density 0.8442, 32,000 particles, rc 2.5), evaluates forces,
// energy and virial once per repeat with the CPU or the CUDA pipeline, and reports the physics, the
// pipeline's counts and its stage times, optionally next to the O(n^2) brute force.
#include <omp.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <vector>

#include "cli/options.h"
#include "core/error.h"
#include "cpu/engine.h"
#include "reference/brute_force.h"
#include "scene/lattice.h"

#ifdef CELLFORCE_HAVE_CUDA
#include "engine.h"  // cuda/engine.h
#endif

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
  Precision precision = Precision::kDouble;
  Accumulation accumulation = Accumulation::kJacobi;
  CellRule rule = CellRule::kTight;
  std::string backend = "auto";
  std::string traversal = "warp";
  std::string sort = "cub";
  int repeats = 5;
  bool brute = false;
  std::string json;
};

int evaluate(const EvaluateArgs& args) {
  Configuration config = make_lattice(args.lattice, args.cells, args.density);
  if (args.jitter > 0) jitter(config, args.jitter, args.seed);
  const SystemView sys = config.view();
  const int dim = sys.box.dim;
  ForceField ff;
  ff.cutoff = args.cutoff;
  ff.mode = args.mode;
  CpuOptions options;
  options.precision = args.precision;
  options.accumulation = args.accumulation;
  options.grid.rule = args.rule;
  const Request request{true, true};
  ForceResult result;

  // The backend: "auto" takes the GPU when one can be used.
  std::string backend = args.backend;
#ifdef CELLFORCE_HAVE_CUDA
  if (backend == "auto") backend = GpuEngine::unavailable().empty() ? "cuda" : "cpu";
  std::unique_ptr<GpuEngine> gpu;
  if (backend == "cuda") {
    GpuOptions g;
    g.precision = args.precision;
    g.accumulation = args.accumulation;
    g.grid.rule = args.rule;
    g.traversal = args.traversal == "thread" ? TraversalForm::kThreadPerCell : TraversalForm::kWarpPerCell;
    g.sort = args.sort == "chapter" ? SortMethod::kChapter : SortMethod::kCub;
    gpu = std::make_unique<GpuEngine>(g);
  }
#else
  if (backend == "auto") backend = "cpu";
  if (backend == "cuda") throw Error("--backend cuda: this cellforce was built without CUDA");
#endif
  CpuEngine cpu(options);
  std::string engine_name = "CPU, " + std::to_string(omp_get_max_threads()) + " threads";
  auto evaluate_once = [&](bool counts) {
#ifdef CELLFORCE_HAVE_CUDA
    if (gpu) {
      gpu->evaluate(sys, ff, request, result);
      if (counts) {
        const PipelineStats timing = gpu->stats();
        gpu->count_pairs(sys, ff);  // candidate and interacting counts
        PipelineStats merged = gpu->stats();
        merged.t_cell_ids = timing.t_cell_ids;
        merged.t_count = timing.t_count;
        merged.t_sort = timing.t_sort;
        merged.t_collision_cells = timing.t_collision_cells;
        merged.t_traversal = timing.t_traversal;
        merged.t_accumulate = timing.t_accumulate;
        merged.t_transfer = timing.t_transfer;
        merged.t_total = timing.t_total;
        return merged;
      }
      return gpu->stats();
    }
#endif
    (void)counts;
    cpu.evaluate(sys, ff, request, result);
    return cpu.stats();
  };
#ifdef CELLFORCE_HAVE_CUDA
  if (gpu) engine_name = std::string("CUDA, ") + to_string(gpu->options().traversal) + ", " +
                         to_string(gpu->options().sort) + " sort";
#endif

  std::printf("cellforce evaluate: %zu particles (%s lattice, %d cells per axis, density %g, jitter %g)\n",
              sys.n, dim == 3 ? "3D" : "2D", args.cells, args.density, args.jitter);
  std::printf("  box %.6g per edge, periodic; cutoff %g (%s); precision %s; %s; %s\n",
              sys.box.length[0], ff.cutoff, to_string(ff.mode), to_string(args.precision),
              to_string(args.accumulation), engine_name.c_str());

  std::vector<double> total, t_ids, t_sort, t_cells, t_trav, t_acc;
  PipelineStats s;
  for (int r = 0; r < std::max(1, args.repeats); ++r) {
    s = evaluate_once(r + 1 == std::max(1, args.repeats));
    total.push_back(s.t_total - s.t_transfer);
    t_ids.push_back(s.t_cell_ids + s.t_count);
    t_sort.push_back(s.t_sort);
    t_cells.push_back(s.t_collision_cells);
    t_trav.push_back(s.t_traversal);
    t_acc.push_back(s.t_accumulate);
  }
  const Grid& g = s.grid;
  std::printf("grid: %u x %u x %u cells, edge %.6g, half-width h %.6g (rule %s: edge >= %.6g)\n",
              g.n[0], g.n[1], g.n[2], g.cell[0], g.half_width,
              args.rule == CellRule::kTight ? "rc + h" : "3h",
              min_cell_edge(args.rule, ff.cutoff, g.half_width));
  std::printf("entries: %zu (%zu valid), collision cells %zu, max occupancy %zu\n", s.entries,
              s.valid_entries, s.collision_cells, s.max_occupancy);
  std::printf("pairs: %zu tested, %zu within the cutoff (%.1f%%)\n", s.candidate_pairs,
              s.interacting_pairs, 100.0 * double(s.interacting_pairs) / double(std::max<std::size_t>(1, s.candidate_pairs)));

  double trace = 0, fmax = 0;
  for (int a = 0; a < dim; ++a) trace += result.virial[a][a];
  for (std::size_t i = 0; i < sys.n; ++i) {
    double f2 = 0;
    for (int a = 0; a < dim; ++a) f2 += result.forces[i * dim + a] * result.forces[i * dim + a];
    fmax = std::max(fmax, std::sqrt(f2));
  }
  std::printf("potential energy per particle %.9f\n", result.energy / double(sys.n));
  std::printf("configurational pressure trace(W)/(d V) %.9f\n", trace / (dim * sys.box.volume()));
  std::printf("max |F| %.6g\n", fmax);
  std::printf("time per evaluation, median of %zu: %.3f ms  [cell IDs %.3f | sort %.3f | collision cells %.3f | traversal %.3f | accumulate %.3f]%s\n",
              total.size(), 1e3 * median(total), 1e3 * median(t_ids), 1e3 * median(t_sort),
              1e3 * median(t_cells), 1e3 * median(t_trav), 1e3 * median(t_acc),
              backend == "cuda" ? " (stream time, host copies excluded)" : "");

  nlohmann::json out = {{"n", sys.n},
                        {"cutoff", ff.cutoff},
                        {"cutoff_mode", to_string(ff.mode)},
                        {"precision", to_string(args.precision)},
                        {"accumulation", to_string(args.accumulation)},
                        {"backend", backend},
                        {"engine", engine_name},
                        {"energy_per_particle", result.energy / double(sys.n)},
                        {"time_median_s", median(total)}};
  if (args.brute) {
    ForceResult ref;
    const auto t0 = std::chrono::steady_clock::now();
    brute_force(sys, ff, request, ref);
    const double tb = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    double rms = 0, worst = 0, worst_abs = 0;
    for (double f : ref.forces) rms += f * f;
    rms = std::sqrt(rms / double(sys.n));
    for (std::size_t i = 0; i < sys.n; ++i) {
      double d2 = 0, r2 = 0;
      for (int a = 0; a < dim; ++a) {
        const double d = result.forces[i * dim + a] - ref.forces[i * dim + a];
        d2 += d * d;
        r2 += ref.forces[i * dim + a] * ref.forces[i * dim + a];
      }
      worst = std::max(worst, std::sqrt(d2) / std::max(std::sqrt(r2), rms > 0 ? rms : 1.0));
      worst_abs = std::max(worst_abs, std::sqrt(d2));
    }
    std::printf("brute force (double, all pairs): %.3f ms, %.1fx the pipeline; energy per particle %.9f\n",
                1e3 * tb, tb / median(total), ref.energy / double(sys.n));
    // On a perfect lattice the forces cancel to rounding (F_rms ~ 1e-13): read the absolute
    // difference there, the relative one on a jittered or disordered scene.
    std::printf("  max |dF_i| = %.3g (brute-force F_rms %.3g); max |dF_i| / max(|F_i|, F_rms) = %.3g; "
                "energy relative difference %.3g\n",
                worst_abs, rms, worst,
                std::abs(result.energy - ref.energy) / std::max(1e-300, std::abs(ref.energy)));
    out["brute_force_time_s"] = tb;
    out["max_force_error"] = worst;
    out["max_force_error_abs"] = worst_abs;
    out["brute_force_force_rms"] = rms;
  }
  if (!args.json.empty()) {
    std::ofstream f(args.json);
    if (!f) throw Error("cannot write '" + args.json + "'");
    f << out.dump(2) << "\n";
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"cellforce: spatial-subdivision cutoff search and Lennard-Jones forces"};
  app.set_version_flag("--version", "cellforce 0.1.0");
  app.require_subcommand(1);

  EvaluateArgs ev;
  CLI::App* evaluate_cmd = app.add_subcommand(
      "evaluate", "Evaluate forces, energy and virial of a lattice scene with the CPU or CUDA pipeline "
                  "(default: the LAMMPS in.lj fluid, fcc at density 0.8442, 32,000 particles, rc 2.5)");
  evaluate_cmd->add_option("--lattice", ev.lattice, "Lattice")
      ->transform(CLI::CheckedTransformer(cli::kLattices, CLI::ignore_case));
  evaluate_cmd->add_option("--cells", ev.cells, "Unit cells per axis")->check(CLI::PositiveNumber);
  evaluate_cmd->add_option("--density", ev.density, "Number density")->check(CLI::PositiveNumber);
  evaluate_cmd->add_option("--jitter", ev.jitter, "Uniform random displacement amplitude per axis")
      ->check(CLI::NonNegativeNumber);
  evaluate_cmd->add_option("--seed", ev.seed, "Seed of the jitter");
  evaluate_cmd->add_option("--cutoff", ev.cutoff, "Cutoff radius rc")->check(CLI::PositiveNumber);
  evaluate_cmd->add_option("--cutoff-mode", ev.mode, "truncate, shift or force-shift")
      ->transform(CLI::CheckedTransformer(cli::kCutoffModes, CLI::ignore_case));
  evaluate_cmd->add_option("--precision", ev.precision, "single, mixed or double")
      ->transform(CLI::CheckedTransformer(cli::kPrecisions, CLI::ignore_case));
  evaluate_cmd->add_option("--accumulation", ev.accumulation, "jacobi or gauss-seidel")
      ->transform(CLI::CheckedTransformer(cli::kAccumulations, CLI::ignore_case));
  evaluate_cmd->add_option("--cell-rule", ev.rule, "tight (c >= rc + h) or chapter (c >= 3h)")
      ->transform(CLI::CheckedTransformer(cli::kCellRules, CLI::ignore_case));
  evaluate_cmd->add_option("--backend", ev.backend, "cpu, cuda, or auto (the GPU when one can be used)")
      ->check(CLI::IsMember({"cpu", "cuda", "auto"}));
  evaluate_cmd->add_option("--traversal", ev.traversal, "CUDA traversal: warp (a warp per cell) or thread (a thread per cell)")
      ->check(CLI::IsMember({"warp", "thread"}));
  evaluate_cmd->add_option("--sort", ev.sort, "CUDA sort: cub or chapter (the chapter's radix sort)")
      ->check(CLI::IsMember({"cub", "chapter"}));
  evaluate_cmd->add_option("--repeats", ev.repeats, "Evaluations to time")->check(CLI::PositiveNumber);
  evaluate_cmd->add_flag("--brute-force", ev.brute, "Also run the O(n^2) double brute force and compare");
  evaluate_cmd->add_option("--json", ev.json, "Write a JSON summary here");

  CLI11_PARSE(app, argc, argv);
  try {
    if (evaluate_cmd->parsed()) return evaluate(ev);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
  return 0;
}
