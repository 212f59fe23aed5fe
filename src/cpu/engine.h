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

#include "core/grid.h"
#include "core/system.h"

namespace cellforce {

// Arithmetic of the narrow phase / accumulation of its results.
enum class Precision : uint8_t {
  kSingle,  // float pairs, float sums
  kMixed,   // float pairs, double sums
  kDouble,  // double pairs, double sums
};

// How per-particle results are gathered (spatial-subdivision.md, stage 5).
enum class Accumulation : uint8_t {
  kJacobi,       // one pass; 2^d output slots per particle (one per cell type), summed at the end
  kGaussSeidel,  // 2^d passes, one per cell type, adding straight into the output
};

struct CpuOptions {
  Precision precision = Precision::kDouble;
  Accumulation accumulation = Accumulation::kJacobi;
  GridOptions grid;
  // Tests only: use this grid as given, unchecked, instead of planning one.
  std::optional<Grid> grid_override;
};

// Counts and stage times (seconds) of the last evaluation.
struct PipelineStats {
  Grid grid;
  std::size_t entries = 0;            // n x 2^d cell-ID entries
  std::size_t valid_entries = 0;      // H plus valid P entries
  std::size_t collision_cells = 0;
  std::size_t max_occupancy = 0;      // most entries in one collision cell
  std::size_t candidate_pairs = 0;    // pairs tested (after the control-bit rule)
  std::size_t interacting_pairs = 0;  // pairs with r < rc
  double t_cell_ids = 0, t_sort = 0, t_collision_cells = 0, t_traversal = 0, t_accumulate = 0;
  double t_total = 0;
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

  // Every pair the traversal evaluates with r < rc, once per evaluation (a pair evaluated twice
  // appears twice), as (min index, max index), in no particular order.
  std::vector<std::pair<uint32_t, uint32_t>> visited_pairs(const SystemView& system,
                                                           const ForceField& ff);

  const PipelineStats& stats() const { return stats_; }
  const CpuOptions& options() const { return options_; }

  struct Scratch;  // opaque: stage buffers reused across evaluations

 private:
  void build(const SystemView& system, const ForceField& ff, bool split_by_type);
  CpuOptions options_;
  PipelineStats stats_;
  std::unique_ptr<Scratch> scratch_;
};

const char* to_string(Precision precision);
const char* to_string(Accumulation accumulation);

}  // namespace cellforce
