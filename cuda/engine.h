// The CUDA force engine: the spatial-subdivision pipeline of GPU Gems 3 ch. 32 on the device
// (cell IDs -> count -> sort -> collision cells -> traversal -> accumulate, one file each under
// cuda/), with the traversal evaluating Lennard-Jones directly. Plain C++: host code and tests
// include it without the CUDA headers.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/engine_options.h"
#include "core/force_field.h"
#include "core/grid.h"
#include "core/reuse.h"
#include "core/system.h"

namespace cellforce {

// How the traversal maps collision cells onto threads.
enum class TraversalForm : uint8_t {
  kWarpPerCell,    // cooperative: a warp shares one cell, occupants staged 32 at a time in shared
                   // memory, partial sums added in a fixed order (the chapter's future work)
  kThreadPerCell,  // the chapter's: one thread walks one collision cell
};

// Stage 2's implementation; both are stable and sort only the bits the grid needs.
enum class SortMethod : uint8_t {
  kCub,      // CUB's device radix sort
  kChapter,  // the chapter's three-phase radix sort (tabulate, prefix sums, stable reorder)
};

struct GpuOptions {
  Precision precision = Precision::kDouble;
  Accumulation accumulation = Accumulation::kJacobi;
  TraversalForm traversal = TraversalForm::kWarpPerCell;
  SortMethod sort = SortMethod::kCub;
  GridOptions grid;
  ReuseOptions reuse;  // skin > 0: stages 1-3 reused while no particle moved more than skin / 2
  std::optional<Grid> grid_override;  // tests only: this grid, unchecked
  int device = 0;                     // CUDA device ordinal
};

class GpuEngine {
 public:
  // Throws cellforce::Error when the device cannot be used.
  explicit GpuEngine(GpuOptions options = {});
  ~GpuEngine();
  GpuEngine(const GpuEngine&) = delete;
  GpuEngine& operator=(const GpuEngine&) = delete;

  // Host arrays in, host results out (SystemView and ForceResult as for the CPU engine): forces
  // always; per-particle and total energy and the virial when requested (the kernels compute
  // energy and virial together when either is asked for). Throws cellforce::Error on bad input,
  // naming the particle or parameter, or both particles of a coincident or overflowing pair.
  void evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                ForceResult& result);

  // Every pair the traversal finds with r < rc, once per evaluation (a pair found twice appears
  // twice), as (min index, max index), in no particular order. Also sets the candidate and
  // interacting pair counts and the largest occupancy in stats(). With a skin, the structure is
  // rebuilt or reused as for evaluate() (so the pairs show what reuse finds).
  std::vector<std::pair<uint32_t, uint32_t>> visited_pairs(const SystemView& system,
                                                           const ForceField& ff);

  // The candidate and interacting pair counts and the largest occupancy, in stats(), without
  // storing the pairs (what visited_pairs() sets, for any size of system).
  void count_pairs(const SystemView& system, const ForceField& ff);

  // Reuse across a restart (core/reuse.h): the structure in use, and building it again from the
  // positions it was built from, with the count of evaluations it had served.
  ReuseState reuse_state() const;
  void restore_reuse(const SystemView& built_from, const ForceField& ff, int64_t served);

  // Stage times (evaluate) are measured with CUDA events on the engine's stream: stream time from
  // one stage's start to the next, so they include the host round trips that size the next
  // buffers (the valid count, the number of cells). Pair counts come from count_pairs() or
  // visited_pairs(); each call zeroes what it does not compute.
  const PipelineStats& stats() const { return stats_; }
  const GpuOptions& options() const { return options_; }
  // The device's name as the driver reports it (e.g. "NVIDIA H100 80GB HBM3").
  std::string device_name() const;

  // Empty when a CUDA device can be used here; otherwise why not.
  static std::string unavailable();

  struct Impl;  // device buffers, stream and events, reused across evaluations

 private:
  std::vector<std::pair<uint32_t, uint32_t>> record(const SystemView& system, const ForceField& ff,
                                                    bool keep);
  void prepare(const SystemView& system, const ForceField& ff);
  void build(const SystemView& system, const ForceField& ff);
  void audit(const SystemView& system, const ForceField& ff);
  GpuOptions options_;
  ReusePolicy reuse_;
  PipelineStats stats_;
  std::unique_ptr<Impl> impl_;
};

const char* to_string(TraversalForm form);
const char* to_string(SortMethod sort);

}  // namespace cellforce
