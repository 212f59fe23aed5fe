// What every force engine (CPU in src/cpu, CUDA in cuda/) is told and what it reports: the
// precision, accumulation and algorithm choices and the per-evaluation pipeline statistics.
#pragma once

#include <cstddef>
#include <cstdint>

#include <cellforce/options.hpp>  // Precision, Backend, the CUDA settings

#include "core/grid.h"

namespace cellforce {

// How per-particle results are gathered (spatial-subdivision.md, stage 5).
enum class Accumulation : uint8_t {
  kJacobi,       // one pass; 2^d output slots per particle (one per cell type), summed at the end
  kGaussSeidel,  // 2^d passes, one per cell type, adding straight into the output
};

// Counts and stage times (seconds) of the last evaluation. Both backends fold the valid count into
// t_cell_ids (the GPU's cell-ID kernel counts them: its t_count is ~0) and the GPU
// includes staging the occupants (the relative-coordinate gather) in t_traversal. t_transfer:
// host <-> device copies (GPU only).
struct PipelineStats {
  Grid grid;
  std::size_t entries = 0;            // n x 2^d cell-ID entries
  std::size_t valid_entries = 0;      // H plus valid P entries
  std::size_t collision_cells = 0;
  std::size_t max_occupancy = 0;      // most entries in one collision cell
  std::size_t candidate_pairs = 0;    // pairs tested (after the control-bit rule)
  std::size_t interacting_pairs = 0;  // pairs with r < rc
  // Bytes the engine holds in its stage buffers after the evaluation (host memory for the CPU,
  // device memory for CUDA). Buffers are sized from particle, entry and collision-cell counts,
  // never from the number of grid cells, so a dilute scene in a huge box costs no more than a
  // dense one of the same size.
  std::size_t buffer_bytes = 0;
  // Pair lists (CUDA, ReuseOptions::list) of the structure in use, after the evaluation: the listed
  // pairs (within rc + skin, once from each side) and the entries their layout holds, padding
  // included (each group of 32 lists as long as its longest, in whole chunks); 0 without lists.
  std::size_t list_pairs = 0, list_slots = 0;
  // The build's masks (CUDA lists, cuda/search/pair_list.cuh BuildMasks): the words every work unit's
  // count-pass decisions take, and those the room held (the units within it read theirs, the rest
  // tested their pairs again); 0 without lists or masks.
  std::size_t list_mask_words = 0, list_mask_words_held = 0;
  // Reuse of the structure (core/reuse.h; skin > 0): whether this evaluation ran stages 1-3, how
  // many builds the engine has made, the largest displacement since the build in use (0 when not
  // measured), and, with the audit, pairs closer than rc that the reused structure never
  // evaluated (missed) or evaluated more than once (repeated). The stage counts above (entries,
  // collision cells) are those of the build in use; t_check is the displacement check.
  bool rebuilt = true;
  // This build replaced a structure that `every` retired after a particle had moved more than
  // skin / 2 since its build (possible only with check = false, measured only then): the
  // evaluations it served may have missed pairs. LAMMPS calls such a build dangerous.
  bool dangerous_build = false;
  // This evaluation walked the pair lists of its structure (CUDA, ReuseOptions::list), not the
  // collision cells (a declined list, or none asked for).
  bool listed = false;
  std::size_t builds = 0;
  double max_displacement = 0;
  std::size_t missed_pairs = 0, repeated_pairs = 0;
  double t_check = 0;
  double t_cell_ids = 0, t_count = 0, t_sort = 0, t_collision_cells = 0, t_traversal = 0,
         t_accumulate = 0, t_transfer = 0;
  double t_total = 0;
  // CUDA pair lists: this evaluation's build ran its fixed part (cell IDs to the list's count pass)
  // as a replayed CUDA graph (cuda/backend/build_graph.cuh).
  bool graph_build = false;
  // CUDA pair lists: threads a block of the force kernels that ran the next step's kick-drift in the
  // last chunk of steps served behind the step gate (128, or 256 where those fill its last wave
  // better: cuda/search/list_build.h fused_block_size); 0 where it ran none (lean memory, Langevin).
  int list_block = 0;
};

inline const char* to_string(Precision precision) {
  switch (precision) {
    case Precision::kSingle: return "single";
    case Precision::kMixed: return "mixed";
    case Precision::kDouble: return "double";
  }
  return "?";
}

inline const char* to_string(Accumulation accumulation) {
  return accumulation == Accumulation::kJacobi ? "jacobi" : "gauss-seidel";
}

inline const char* to_string(Backend backend) {
  switch (backend) {
    case Backend::kAuto: return "auto";
    case Backend::kCpu: return "cpu";
    case Backend::kCuda: return "cuda";
  }
  return "?";
}

}  // namespace cellforce
