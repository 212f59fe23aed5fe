// The CPU force engine: the spatial-subdivision pipeline of GPU Gems 3 ch. 32 run stage by stage
// (cell_ids -> sort -> collision_cells -> traversal -> accumulate, one file each under src/cpu),
// with the traversal evaluating Lennard-Jones directly.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

#include "core/engine_options.h"
#include "core/grid.h"
#include "core/reuse.h"
#include "core/system.h"

namespace cellforce {

struct CpuOptions {
  Precision precision = Precision::kDouble;
  Accumulation accumulation = Accumulation::kJacobi;
  GridOptions grid;
  ReuseOptions reuse;  // skin > 0: stages 1-3 reused while no particle moved more than skin / 2
  // OpenMP threads of the engine's parallel regions (each call runs its regions with this many);
  // 0: OpenMP's default for the calling thread (omp_get_max_threads()).
  int threads = 0;
  // Tests only: use this grid as given, unchecked, instead of planning one.
  std::optional<Grid> grid_override;
};

class CpuEngine {
 public:
  explicit CpuEngine(CpuOptions options = {});
  ~CpuEngine();
  CpuEngine(const CpuEngine&) = delete;
  CpuEngine& operator=(const CpuEngine&) = delete;

  // Forces (always), per-particle and total energy and virial (when requested). Throws
  // cellforce::Error on bad input, or naming both particles of a coincident or overflowing pair.
  void evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                ForceResult& result);
  // As evaluate() for particles 0 .. n_local - 1 of the system with n_local .. n - 1 as their ghosts
  // (ForceEngine::evaluate_local): results for the locals only, their per-particle virials with
  // the virial, no pair of two ghosts evaluated or counted. The audit (neighbor-audit) is not run.
  void evaluate_local(const SystemView& system, std::size_t n_local, const ForceField& ff,
                      const Request& request, ForceResult& result);

  // Every pair the traversal evaluates with r < rc, once per evaluation (a pair evaluated twice
  // appears twice), as (min index, max index), in no particular order. With a skin, the structure
  // is rebuilt or reused as for evaluate() (so the pairs show what reuse finds).
  // With n_local, particles n_local .. n - 1 are ghosts (as evaluate_local): no pair of two.
  std::vector<std::pair<uint32_t, uint32_t>> visited_pairs(const SystemView& system,
                                                           const ForceField& ff,
                                                           std::optional<std::size_t> n_local = {});

  // Reuse across a restart (core/reuse.h): the structure in use, and building it again from the
  // positions it was built from, with the count of evaluations it had served.
  ReuseState reuse_state() const;
  void restore_reuse(const SystemView& built_from, const ForceField& ff, int64_t served);

  const PipelineStats& stats() const { return stats_; }
  // The bytes each stage buffer holds now (those that hold any), by name; their sum is what
  // stats().buffer_bytes held after the last evaluation.
  std::vector<std::pair<const char*, std::size_t>> buffers() const;
  const CpuOptions& options() const { return options_; }
  // The threads the engine's parallel regions run with when called from this thread.
  int threads() const;

  struct Scratch;  // opaque: stage buffers reused across evaluations

 private:
  void prepare(const SystemView& system, const ForceField& ff);
  // evaluate() and evaluate_local() (n_local given: ghosts from there on).
  void run(const SystemView& system, const ForceField& ff, const Request& request, ForceResult& result,
           std::optional<std::size_t> n_local);
  void build(const SystemView& system, const ForceField& ff);
  void audit(const SystemView& system, const ForceField& ff);
  CpuOptions options_;
  ReusePolicy reuse_;
  PipelineStats stats_;
  std::unique_ptr<Scratch> scratch_;
};

}  // namespace cellforce
