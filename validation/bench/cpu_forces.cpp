// Benchmark, not a test: time of one CPU force evaluation for the LJ liquid (fcc at density 0.8442
// with a small random displacement, so that forces are not zero; rc 2.5) with every precision and
// accumulation of the pipeline, next to the O(n^2) brute force. Prints a Markdown table and writes
// the rows as JSON.
#include <omp.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cli/option_rules.h"
#include "cli/options.h"
#include "cpu/engine.h"
#include "reference/brute_force.h"
#include "scene/lattice.h"

namespace {

using namespace cellforce;
using cli::median;
using Clock = std::chrono::steady_clock;

// Median relative force error and max of |dF_i| / max(|F_i|, F_rms).
void force_error(const ForceResult& r, const ForceResult& ref, int dim, double& med, double& worst) {
  const std::size_t n = ref.forces.size() / dim;
  double rms = 0;
  for (double f : ref.forces) rms += f * f;
  rms = std::sqrt(rms / double(n));
  std::vector<double> rel(n);
  worst = 0;
  for (std::size_t i = 0; i < n; ++i) {
    double d2 = 0, f2 = 0;
    for (int a = 0; a < dim; ++a) {
      const double d = r.forces[i * dim + a] - ref.forces[i * dim + a];
      d2 += d * d;
      f2 += ref.forces[i * dim + a] * ref.forces[i * dim + a];
    }
    rel[i] = std::sqrt(d2) / std::max(std::sqrt(f2), 1e-300);
    worst = std::max(worst, std::sqrt(d2) / std::max(std::sqrt(f2), rms));
  }
  med = median(rel);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"CPU force-evaluation benchmark: pipeline variants vs brute force"};
  std::vector<int> cells = {20};
  int repeats = 9, brute_repeats = 3;
  double jitter_amplitude = 0.05;
  std::string json_path;
  cli::add_number(&app, "--cells", cells, "fcc unit cells per axis (N = 4 cells^3); several allowed", cli::kPositive);
  cli::add_number(&app, "--repeats", repeats, "timed evaluations per pipeline variant (after one warm-up)",
                  cli::kPositive);
  cli::add_number(&app, "--brute-repeats", brute_repeats, "timed brute-force evaluations", cli::kNonNegative);
  cli::add_number(&app, "--jitter", jitter_amplitude, "uniform displacement amplitude (sigma)", cli::kNonNegative);
  app.add_option("--json", json_path, "write the rows here");
  CLI11_PARSE(app, argc, argv);

  struct Variant {
    Precision precision;
    Accumulation accumulation;
    bool observables;
  };
  const Variant variants[] = {
      {Precision::kDouble, Accumulation::kJacobi, true},
      {Precision::kDouble, Accumulation::kJacobi, false},
      {Precision::kDouble, Accumulation::kGaussSeidel, true},
      {Precision::kMixed, Accumulation::kJacobi, true},
      {Precision::kSingle, Accumulation::kJacobi, true},
  };
  nlohmann::json rows = nlohmann::json::array();
  std::printf("threads: %d\n\n", omp_get_max_threads());
  std::printf("| N | method | precision | accumulation | outputs | median ms | ms range | pairs tested | pairs < rc | ns per pair < rc | median rel. force error | max error |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (int c : cells) {
    Configuration config = make_lattice(Lattice::kFcc, c, 0.8442);
    jitter(config, jitter_amplitude, 2026);
    const SystemView sys = config.view();
    ForceField ff;  // rc 2.5, truncate, one type
    ForceResult ref;
    std::vector<double> tb;
    for (int r = 0; r < std::max(1, brute_repeats); ++r) {
      const auto t0 = Clock::now();
      brute_force(sys, ff, Request{true, true}, ref);
      tb.push_back(std::chrono::duration<double>(Clock::now() - t0).count());
    }
    const double nb = double(sys.n) * double(sys.n - 1) / 2;
    std::size_t pairs_in_cutoff = 0;
    for (const Variant& v : variants) {
      CpuOptions options;
      options.precision = v.precision;
      options.accumulation = v.accumulation;
      CpuEngine engine(options);
      const Request request{v.observables, v.observables};
      ForceResult result;
      engine.evaluate(sys, ff, request, result);  // warm-up: buffers sized
      std::vector<double> t;
      for (int r = 0; r < std::max(1, repeats); ++r) {
        engine.evaluate(sys, ff, request, result);
        t.push_back(engine.stats().t_total);
      }
      double med_err, max_err;
      force_error(result, ref, 3, med_err, max_err);
      const PipelineStats& s = engine.stats();
      pairs_in_cutoff = s.interacting_pairs;
      const double tm = median(t);
      std::printf("| %zu | pipeline | %s | %s | %s | %.2f | %.2f-%.2f | %zu | %zu | %.1f | %.2e | %.2e |\n",
                  sys.n, to_string(v.precision), to_string(v.accumulation),
                  v.observables ? "F, E, W" : "F", 1e3 * tm, 1e3 * *std::min_element(t.begin(), t.end()),
                  1e3 * *std::max_element(t.begin(), t.end()), s.candidate_pairs, s.interacting_pairs,
                  1e9 * tm / double(s.interacting_pairs), med_err, max_err);
      rows.push_back({{"n", sys.n},
                      {"method", "pipeline"},
                      {"precision", to_string(v.precision)},
                      {"accumulation", to_string(v.accumulation)},
                      {"observables", v.observables},
                      {"median_s", tm},
                      {"times_s", t},
                      {"candidate_pairs", s.candidate_pairs},
                      {"interacting_pairs", s.interacting_pairs},
                      {"stage_s",
                       {{"cell_ids", s.t_cell_ids},
                        {"sort", s.t_sort},
                        {"collision_cells", s.t_collision_cells},
                        {"traversal", s.t_traversal},
                        {"accumulate", s.t_accumulate}}},
                      {"median_rel_force_error", med_err},
                      {"max_force_error", max_err}});
    }
    // The brute force's pairs inside rc are the pipeline's (the coverage tests prove the sets equal).
    const double tbm = median(tb);
    std::printf("| %zu | brute force | double | - | F, E, W | %.2f | %.2f-%.2f | %.0f | %zu | %.1f | (reference) | - |\n",
                sys.n, 1e3 * tbm, 1e3 * *std::min_element(tb.begin(), tb.end()),
                1e3 * *std::max_element(tb.begin(), tb.end()), nb, pairs_in_cutoff,
                1e9 * tbm / double(pairs_in_cutoff));
    rows.push_back({{"n", sys.n}, {"method", "brute_force"}, {"precision", "double"},
                    {"median_s", tbm}, {"times_s", tb}});
  }
  if (!json_path.empty()) {
    std::ofstream f(json_path);
    f << nlohmann::json{{"threads", omp_get_max_threads()}, {"rows", rows}}.dump(2) << "\n";
  }
  return 0;
}
