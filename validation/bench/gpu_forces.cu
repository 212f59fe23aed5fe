// Benchmark, not a test: the whole CUDA pipeline through GpuEngine for the LJ liquid (fcc at
// density 0.8442, jittered by 0.05 sigma, rc 2.5) at several sizes, for each precision, traversal
// form and sort implementation. Stage times come from the engine's CUDA events; each is the median
// over repeated evaluations after a warm-up. Pair evaluations per second = pairs with r < rc (from
// the engine's pair recorder) over the traversal time. Prints a Markdown table and writes JSON.
#include <cuda_runtime.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "check.cuh"
#include "cli/options.h"
#include "backend/engine.h"
#include "scene/lattice.h"

using namespace cellforce;

namespace {

struct Variant {
  Precision precision;
  TraversalForm form;
  SortMethod sort;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"CUDA pipeline benchmark: stage times per precision, traversal form and sort"};
  std::vector<int> cells = {20, 40, 64, 102};
  int repeats = 11;
  bool observables = false;
  bool thread_form = true;
  bool chapter_sort = true;
  std::string json_path;
  app.add_option("--cells", cells, "fcc unit cells per axis (N = 4 cells^3)");
  app.add_option("--repeats", repeats, "timed evaluations per variant");
  app.add_flag("--observables", observables, "also compute energy and virial");
  app.add_option("--thread-form", thread_form, "include the thread-per-cell traversal");
  app.add_option("--chapter-sort", chapter_sort, "include the chapter's radix sort");
  app.add_option("--json", json_path, "write the rows here");
  CLI11_PARSE(app, argc, argv);

  cudaDeviceProp prop{};
  CF_CUDA_CHECK(cudaGetDeviceProperties(&prop, 0));
  std::printf("device: %s; request: forces%s; times in ms, median of %d; the valid count is the cell-ID "
              "kernel's since change 80 (count ~0)\n\n",
              prop.name, observables ? " + energy + virial" : " only", repeats);
  std::printf("| N | precision | traversal | sort | cell IDs | count | sort | collision cells | "
              "traversal | slot sum | pipeline | transfers | pairs/s (1e9) | candidates/s (1e9) |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");

  std::vector<Variant> variants;
  for (Precision p : {Precision::kSingle, Precision::kMixed, Precision::kDouble})
    variants.push_back({p, TraversalForm::kWarpPerCell, SortMethod::kCub});
  for (Precision p : {Precision::kSingle, Precision::kMixed})
    variants.push_back({p, TraversalForm::kWarpPerTile, SortMethod::kCub});
  if (chapter_sort) variants.push_back({Precision::kMixed, TraversalForm::kWarpPerCell, SortMethod::kChapter});
  if (thread_form)
    for (Precision p : {Precision::kSingle, Precision::kDouble})
      variants.push_back({p, TraversalForm::kThreadPerCell, SortMethod::kCub});

  nlohmann::json rows = nlohmann::json::array();
  for (int c : cells) {
    Configuration config = make_lattice(Lattice::kFcc, c, 0.8442);
    jitter(config, 0.05, 2026);
    const SystemView sys = config.view();
    ForceField ff;
    ff.cutoff = 2.5;
    ff.types = {{"LJ", 1.0, 1.0}};
    ff.mode = CutoffMode::kTruncate;
    Request request;
    request.energy = observables;
    request.virial = observables;

    std::size_t pairs = 0, candidates = 0;
    {
      GpuEngine counter;
      counter.count_pairs(sys, ff);
      pairs = counter.stats().interacting_pairs;
      candidates = counter.stats().candidate_pairs;
    }
    for (const Variant& v : variants) {
      GpuOptions o;
      o.precision = v.precision;
      o.traversal = v.form;
      o.sort = v.sort;
      GpuEngine engine(o);
      ForceResult result;
      engine.evaluate(sys, ff, request, result);  // warm-up: buffers sized
      std::vector<double> t_ids, t_count, t_sort, t_cells, t_trav, t_acc, t_total, t_xfer;
      for (int r = 0; r < repeats; ++r) {
        engine.evaluate(sys, ff, request, result);
        const PipelineStats& s = engine.stats();
        t_ids.push_back(1e3 * s.t_cell_ids);
        t_count.push_back(1e3 * s.t_count);
        t_sort.push_back(1e3 * s.t_sort);
        t_cells.push_back(1e3 * s.t_collision_cells);
        t_trav.push_back(1e3 * s.t_traversal);
        t_acc.push_back(1e3 * s.t_accumulate);
        t_total.push_back(1e3 * (s.t_total - s.t_transfer));
        t_xfer.push_back(1e3 * s.t_transfer);
      }
      const double trav = cli::median(t_trav);
      const double pipeline = cli::median(t_total);
      std::printf("| %zu | %s | %s | %s | %.4f | %.4f | %.4f | %.4f | %.4f | %.4f | %.4f | %.2f | "
                  "%.2f | %.1f |\n",
                  sys.n, to_string(v.precision), to_string(v.form), to_string(v.sort),
                  cli::median(t_ids), cli::median(t_count), cli::median(t_sort), cli::median(t_cells),
                  trav, cli::median(t_acc), pipeline, cli::median(t_xfer),
                  double(pairs) / (trav * 1e-3) / 1e9, double(candidates) / (trav * 1e-3) / 1e9);
      std::fflush(stdout);
      rows.push_back({{"n", sys.n},
                      {"precision", to_string(v.precision)},
                      {"traversal", to_string(v.form)},
                      {"sort", to_string(v.sort)},
                      {"grid", engine.stats().grid.n[0]},
                      {"valid_entries", engine.stats().valid_entries},
                      {"collision_cells", engine.stats().collision_cells},
                      {"pairs", pairs},
                      {"candidates", candidates},
                      {"cell_ids_ms", cli::median(t_ids)},
                      {"count_ms", cli::median(t_count)},
                      {"sort_ms", cli::median(t_sort)},
                      {"collision_cells_ms", cli::median(t_cells)},
                      {"traversal_ms", trav},
                      {"slot_sum_ms", cli::median(t_acc)},
                      {"pipeline_ms", pipeline},
                      {"transfer_ms", cli::median(t_xfer)}});
    }
  }
  if (!json_path.empty()) {
    std::ofstream f(json_path);
    f << nlohmann::json{{"device", prop.name}, {"observables", observables}, {"rows", rows}}.dump(2)
      << "\n";
  }
  return 0;
}
