// One front for the CPU and CUDA engines, chosen by name at run time: what the CLI commands
// (evaluate, forces) and the benchmark scripts share.
#pragma once

#include <memory>
#include <string>

#include "core/engine_options.h"
#include "core/force_field.h"
#include "core/grid.h"
#include "core/reuse.h"
#include "core/system.h"

namespace cellforce {

struct BackendChoice {
  std::string backend = "auto";  // cpu, cuda, or auto (the GPU when one can be used)
  Precision precision = Precision::kDouble;
  Accumulation accumulation = Accumulation::kJacobi;
  CellRule rule = CellRule::kTight;
  std::string traversal = "warp";  // CUDA: warp (a warp per cell) or thread (a thread per cell)
  std::string sort = "cub";        // CUDA: cub or chapter
  ReuseOptions reuse;              // skin, check, every, audit (core/reuse.h)
};

class ForceBackend {
 public:
  // Throws cellforce::Error when the backend cannot be used (no CUDA device, a CPU-only build).
  explicit ForceBackend(const BackendChoice& choice);
  ~ForceBackend();
  ForceBackend(const ForceBackend&) = delete;
  ForceBackend& operator=(const ForceBackend&) = delete;

  void evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                ForceResult& result);
  // The last evaluation's stage times; with `counts`, also the candidate and interacting pair
  // counts (the CUDA engine counts them in an extra pass over the same system, which with a skin
  // counts as one more evaluation of the structure: it may rebuild, and it uses up one of
  // `every`; the build counts it reports are the extra pass's).
  PipelineStats stats(const SystemView& system, const ForceField& ff, bool counts);

  // Reuse across a restart (the engines' reuse_state / restore_reuse).
  ReuseState reuse_state() const;
  void restore_reuse(const SystemView& built_from, const ForceField& ff, int64_t served);

  const std::string& name() const { return name_; }                // "cpu" or "cuda"
  const std::string& description() const { return description_; }  // device, threads, algorithm
  // Per algorithm choice: traversal and sort (CUDA) or "-" (CPU).
  std::string traversal() const;
  std::string sort() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::string name_, description_;
};

}  // namespace cellforce
