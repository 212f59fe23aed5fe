// Benchmark, not a test: CUDA stages 1-3 (cell IDs, count of valid entries, CUB radix sort and
// the chapter's own radix sort on the same arrays, collision cells)
// for the LJ liquid (fcc at density 0.8442, jittered by 0.05 sigma, rc 2.5) at several sizes.
// Median of repeated runs timed with CUDA events after a warm-up. Prints a Markdown table and
// writes JSON. The remaining stages join as issue 3 brings them.
#include <cuda_runtime.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <vector>

#include "check.cuh"
#include "cli/options.h"
#include "scene/lattice.h"
#include "search/stages.cuh"

using namespace cellforce;

int main(int argc, char** argv) {
  CLI::App app{"CUDA stage benchmark: cell IDs, valid count, CUB and chapter sorts, cells"};
  std::vector<int> cells = {20, 40, 64, 102};
  int repeats = 21;
  std::string json_path;
  app.add_option("--cells", cells, "fcc unit cells per axis (N = 4 cells^3)");
  app.add_option("--repeats", repeats, "timed runs per stage");
  app.add_option("--json", json_path, "write the rows here");
  CLI11_PARSE(app, argc, argv);

  cudaDeviceProp prop{};
  CF_CUDA_CHECK(cudaGetDeviceProperties(&prop, 0));
  std::printf("device: %s\n\n", prop.name);
  std::printf("| N | grid | entries | valid | key bits | cell IDs ms | count ms | CUB sort ms | chapter sort ms | collision cells ms | cells | cell IDs GB/s |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  nlohmann::json rows = nlohmann::json::array();
  cudaEvent_t t0, t1;
  CF_CUDA_CHECK(cudaEventCreate(&t0));
  CF_CUDA_CHECK(cudaEventCreate(&t1));
  for (int c : cells) {
    Configuration config = make_lattice(Lattice::kFcc, c, 0.8442);
    jitter(config, 0.05, 2026);
    const SystemView sys = config.view();
    const Grid g = plan_grid(sys.box, 2.5, sys.positions, sys.n);
    const std::size_t n = sys.n, entries = n << g.dim;
    cuda::DeviceBuffer<double> pos(n * g.dim);
    CF_CUDA_CHECK(cudaMemcpy(pos.data(), config.positions.data(), n * g.dim * sizeof(double),
                             cudaMemcpyHostToDevice));
    cuda::DeviceBuffer<uint32_t> keys(entries), ids(entries), keys_out(entries), ids_out(entries);
    cuda::DeviceBuffer<Control> control(n);
    cuda::DeviceBuffer<std::byte> scratch;
    auto time_ms = [&](auto&& work) {
      work();  // warm-up (and scratch sizing)
      CF_CUDA_CHECK(cudaDeviceSynchronize());
      std::vector<double> t;
      for (int r = 0; r < repeats; ++r) {
        CF_CUDA_CHECK(cudaEventRecord(t0));
        work();
        CF_CUDA_CHECK(cudaEventRecord(t1));
        CF_CUDA_CHECK(cudaEventSynchronize(t1));
        float ms = 0;
        CF_CUDA_CHECK(cudaEventElapsedTime(&ms, t0, t1));
        t.push_back(ms);
      }
      return cli::median(t);
    };
    const double t_ids = time_ms([&] {
      cuda::build_cell_ids(g, pos.data(), n, keys.data(), ids.data(), control.data(), 0);
    });
    cuda::DeviceBuffer<cuda::PipelineCounts> counts(1);
    const double t_count = time_ms([&] { cuda::count_valid(keys.data(), entries, counts.data(), scratch, 0); });
    const std::size_t valid = cuda::read_counts(counts.data(), 0).valid;
    const double t_sort = time_ms([&] {
      cuda::radix_sort_cub(keys.data(), ids.data(), keys_out.data(), ids_out.data(), entries,
                           g.key_bits, scratch, 0);
    });
    // The chapter's sort into its own arrays; a row is only printed when they equal CUB's.
    cuda::DeviceBuffer<uint32_t> keys_chapter(entries), ids_chapter(entries);
    cuda::ChapterSortScratch chapter_scratch;
    const double t_chapter = time_ms([&] {
      cuda::radix_sort_chapter(keys.data(), ids.data(), keys_chapter.data(), ids_chapter.data(),
                               entries, g.key_bits, chapter_scratch, 0);
    });
    auto host_copy = [&](const cuda::DeviceBuffer<uint32_t>& d) {
      std::vector<uint32_t> h(entries);
      CF_CUDA_CHECK(
          cudaMemcpy(h.data(), d.data(), entries * sizeof(uint32_t), cudaMemcpyDeviceToHost));
      return h;
    };
    if (host_copy(keys_chapter) != host_copy(keys_out) ||
        host_copy(ids_chapter) != host_copy(ids_out)) {
      std::fprintf(stderr, "N %zu: the chapter's sort differs from CUB's\n", n);
      return 1;
    }
    cuda::DeviceBuffer<CollisionCell> cells_out;
    cuda::CollisionScratch collision_scratch;
    const double t_cells = time_ms([&] {
      cuda::find_collision_cells(keys_out.data(), g.slab_bits, entries, std::min<std::size_t>(entries, g.num_cells),
                                 std::min<std::size_t>(n, g.num_cells), counts.data(), cells_out,
                                 collision_scratch, 0);
    });
    const std::size_t ncells = cuda::read_counts(counts.data(), 0).cell_range[1];
    // Stage 1 moves at least: positions read, keys and object IDs written, control written.
    const double bytes = double(n) * (g.dim * 8.0 + double(std::size_t(1) << g.dim) * 8.0 + 2.0);
    std::printf("| %zu | %u^3 | %zu | %zu | %d | %.4f | %.4f | %.4f | %.4f | %.4f | %zu | %.0f |\n",
                n, g.n[0], entries, valid, g.key_bits, t_ids, t_count, t_sort, t_chapter, t_cells,
                ncells,
                bytes / (t_ids * 1e-3) / 1e9);
    rows.push_back({{"n", n}, {"cells_per_axis", g.n[0]}, {"entries", entries}, {"valid", valid},
                    {"key_bits", g.key_bits}, {"cell_ids_ms", t_ids}, {"count_ms", t_count},
                    {"cub_sort_ms", t_sort}, {"chapter_sort_ms", t_chapter},
                    {"collision_cells_ms", t_cells}, {"collision_cells", ncells}});
  }
  if (!json_path.empty()) {
    std::ofstream f(json_path);
    f << nlohmann::json{{"device", prop.name}, {"rows", rows}}.dump(2) << "\n";
  }
  return 0;
}
