// The CUDA force engine: the spatial-subdivision pipeline of GPU Gems 3 ch. 32 on the device (cell
// IDs -> sort -> collision cells in cuda/search/, traversal -> accumulation in cuda/forces/), with
// the traversal evaluating Lennard-Jones directly, and pair lists built from the structure for the
// evaluations it serves. Three ways in: host arrays (evaluate), the caller's device arrays on the
// caller's stream (evaluate_device), and the MD engine's state on the engine's stream
// (cuda::ResidentForces). Plain C++: host code and tests include it without the CUDA headers.
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
#include "search/rank_order.h"
#include "search/step_gate.h"
#include "backends/test_hooks.h"
#include "backend/resident_forces.h"
#include "forces/fused_step.h"

namespace cellforce {

// The CUDA settings in the engine's descriptions and the benchmarks' tables.
inline const char* to_string(TraversalForm form) {
  switch (form) {
    case TraversalForm::kWarpPerCell: return "warp-per-cell";
    case TraversalForm::kThreadPerCell: return "thread-per-cell";
    case TraversalForm::kWarpPerTile: return "block-per-tile";  // option value "tile"
    case TraversalForm::kAuto: return "auto";
  }
  return "?";
}
inline const char* to_string(SortMethod sort) { return sort == SortMethod::kCub ? "cub" : "chapter"; }

struct GpuOptions {
  Precision precision = Precision::kDouble;
  Accumulation accumulation = Accumulation::kJacobi;
  TraversalForm traversal = TraversalForm::kAuto;  // kAuto: resolve_traversal (memory_plan.h) at each build
  SortMethod sort = SortMethod::kCub;
  GridOptions grid;
  ReuseOptions reuse;  // skin > 0: stages 1-3 reused while no particle moved more than skin / 2
  ListMemory memory = ListMemory::kAuto;  // the pair lists' memory mode (EngineChoice::memory)
  void* stream = nullptr;             // the caller's cudaStream_t to run on; null: the engine's own
  EngineTestHooks test;               // tests only (backends/test_hooks.h)
  int device = 0;                     // CUDA device ordinal
};

class GpuEngine final : public cuda::ResidentForces {
 public:
  // Throws cellforce::Error when the device cannot be used.
  explicit GpuEngine(GpuOptions options = {});
  ~GpuEngine() override;
  GpuEngine(const GpuEngine&) = delete;
  GpuEngine& operator=(const GpuEngine&) = delete;

  // Host arrays in, host results out (SystemView and ForceResult as for the CPU engine): forces
  // always; per-particle and total energy and the virial when requested (the kernels compute
  // energy and virial together when either is asked for). Throws cellforce::Error on bad input,
  // naming the particle or parameter, or both particles of a coincident or overflowing pair.
  void evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                ForceResult& result);

  // Local and ghost particles (ForceEngine::evaluate_local's contract, backends/force_engine.h):
  // particles n_local .. n - 1 are ghosts; results for the locals only, each local's share of its
  // pairs (result.virials n_local x dim x dim when request.virial), the totals the locals' sums in
  // index order. The cells' traversal in the tile form with ghosts (forces/traversal.cuh
  // traverse_local), whatever the traversal option: no pair of two ghosts is tested, and
  // stats()' candidate and interacting counts are this call's. A build for it makes no pair list
  // (a later call reusing that structure walks the cells). Throws as evaluate() does.
  void evaluate_local(const SystemView& system, std::size_t n_local, const ForceField& ff,
                      const Request& request, ForceResult& result);

  // Device arrays (core/system.h): the work is ordered after what the caller's `stream` (a
  // cudaStream_t; null: the legacy default stream) holds, and the results are written on the
  // engine's stream, which the caller's stream then waits for. Energy and virial are computed when
  // any of out.energies, out.energy, out.virial is given. The host does not wait for the device
  // (nor for the caller's stream): the box, force field and pointers are checked on the host, the
  // arrays on the device, and what the kernels find (a coordinate that is not finite, a type index
  // out of range, a pair whose force is not finite) is raised by synchronize().
  // With a skin, pair lists, the displacement check and every axis periodic, once the first calls
  // have built the structure the device decides each call's rebuild (a CUDA graph a call, run on
  // the caller's stream: backend/call_graph.cuh) and the host waits for nothing; the results are
  // bitwise those of the host-decided path (EngineTestHooks::device_decides false) until a list
  // outgrows its array (list_overflows(); the cells serve, exact, and the next call rebuilds into
  // a larger array once the host has read the build's sizes: from there on exact, not bitwise that
  // path's). Otherwise the host
  // waits with an open axis (the particles' bounds, 2 x dim numbers, plan the grid when the
  // structure is built), with a skin and the displacement check (the largest displacement, 8
  // bytes; with the check off, once per build retired by `every`, for the dangerous-build count),
  // with pair lists when the structure is built (the list's size, 24 bytes, and the free memory)
  // and with the reuse audit. Results are bitwise those of evaluate() on the same input.
  // Throws cellforce::Error for bad pointers or physics, before anything is queued.
  void evaluate_device(const DeviceInput& input, const ForceField& ff, const DeviceOutputs& out,
                       void* stream);
  // Waits for the engine's work, reads what the kernels flagged since the last synchronize() and
  // the counts of the last evaluation and the stage times of the last timed one (stats(); zeros
  // where none was timed: evaluate_resident's time_stages), and throws cellforce::Error for
  // the first problem found (naming the particle, or both particles of a pair; the outputs of the
  // calls since the last synchronize() are then not to be used).
  void synchronize(const ForceField& ff);

  // ---- the MD engine's evaluations (cuda::ResidentForces, backend/resident_forces.h) ----
  int device() const override { return options_.device; }
  void* stream() const override;  // the engine's cudaStream_t (GpuOptions::stream, or its own)
  void evaluate_resident(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                         const ForceField& ff, const Request& request, std::optional<double> known_d2 = {},
                         bool time_stages = true) override;
  void check_flags(const Box& box, std::size_t n, const double* positions, const ForceField& ff) override;
  const double* device_forces() const override;
  double* device_forces_to_add() override;
  const double* device_totals() const override;
  void collect_timing() override;
  int64_t gate_steps(const Box& box, std::size_t n, const ForceField& ff) const override;
  unsigned long long gate_limit() const override;
  const double* device_build_positions() const override;
  cuda::RankOrder rank_order(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                             const ForceField& ff, bool fused = false) override;
  void unrank_forces(std::size_t n) override;
  void evaluate_gated(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                      const ForceField& ff, const cuda::GateView& gate,
                      const cuda::NextKickDrift* then = nullptr) override;
  void settle_gate(int64_t served, double served_d2) override;

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
  // one stage's start to the next. Pair counts come from count_pairs() or visited_pairs(); each
  // call zeroes what it does not compute. The valid entries and collision cells are read from the
  // device after evaluate(), synchronize(), collect_timing() and the pair recorder.
  const PipelineStats& stats() const override { return stats_; }
  // The device bytes each stage buffer holds now (those that hold any), by name; their sum is what
  // stats().buffer_bytes held after the last timed evaluation.
  std::vector<std::pair<const char*, std::size_t>> buffers() const;
  // Pair lists (ReuseOptions::list): the entries of the lists built from the structure in use (every
  // pair within rc + skin, once from each side); 0 when its evaluations traverse the cells.
  std::size_t listed_pairs() const;
  // Builds whose list fill read the count pass's decisions for every pair (search/pair_list.cuh
  // BuildMasks: once the room they ask for is there), and builds whose room held only some units'
  // decisions (lean memory on a device without room for them all).
  std::size_t list_masked_fills() const;
  std::size_t list_partly_masked_fills() const;
  // With the test hook list_count_masked: the work units whose list the last build's fill wrote from
  // the count pass's masks (0 where it walked them all again).
  std::size_t list_masked_units() const;
  // Lean builds whose count pass read occupants staged in the last list's array.
  std::size_t list_staged_counts() const;
  // Builds whose fixed part (cell IDs to the list's partition) a CUDA graph replayed, and the
  // graphs captured for it (backend/build_graph.cuh).
  std::size_t build_replays() const;
  std::size_t build_captures() const;
  // compute_device calls the device's call graph served (it decided their rebuilds: backend/
  // call_graph.cuh), the graphs captured for them, the builds it decided and of those the builds
  // whose list did not fit its array (the cells served until the next build). Counted when the
  // host has read the device's state (synchronize()).
  std::size_t device_calls() const;
  std::size_t call_captures() const;
  std::size_t device_builds() const;
  std::size_t list_overflows() const;
  const GpuOptions& options() const { return options_; }
  // The traversal form in use: options().traversal, or what kAuto chose at the last build (kAuto
  // before the first).
  TraversalForm traversal() const;
  // The device's name as the driver reports it (e.g. "NVIDIA H100 80GB HBM3").
  std::string device_name() const;

  // Empty when a CUDA device can be used here; otherwise why not.
  static std::string unavailable();
  // Whether the device can use `p` (device, managed or mapped host memory; not pageable host memory).
  static bool device_pointer(const void* p);
  // A stream on `device` for an owner to give to its engines (GpuOptions::stream), destroyed with
  // the last copy of the handle. Throws cellforce::DeviceError as the constructor does.
  static std::shared_ptr<void> make_stream(int device);
  // The memory of CUDA device `device` in bytes (cudaMemGetInfo's total, what the lists' memory
  // mode weighs: lists_memory); 0 where it cannot be used or does not exist.
  static std::size_t memory_bytes(int device);

  struct Impl;  // device buffers, stream and events, reused across evaluations (backend/engine_state.cuh)

 private:
  std::vector<std::pair<uint32_t, uint32_t>> record(const SystemView& system, const ForceField& ff,
                                                    bool keep);
  // `lists`: a build makes the pair list where the options ask for one (evaluate_local: none).
  void prepare(const SystemView& system, const ForceField& ff, const DeviceSystemView* on_device = nullptr,
               bool lists = true);
  void traverse(const SystemView& system, const ForceField& ff, const Request& request, bool read_flags = true);
  void prepare_resident(const SystemView& system, const ForceField& ff, const DeviceSystemView& on_device,
                        std::optional<double> known_d2 = {});
  void plan_corners(const Box& box, std::size_t n, const double* positions);
  void finish_timing();
  void build(const SystemView& system, const ForceField& ff, bool lists = true);
  // The decided calls (backend/device_calls.cu): whether this call may be one, queueing it on the
  // call graph (false: the host's own path serves it), and reading what the device did: the
  // posted sizes of its builds without waiting, and with `wait` its state too.
  bool device_decides(const SystemView& system, const ForceField& ff) const;
  bool ready_device_call(const DeviceInput& input, const SystemView& system, const ForceField& ff, const Request& request,
                         const DeviceOutputs& out, bool typed);
  void queue_device_call(const DeviceInput& input, const ForceField& ff, const DeviceOutputs& out, void* stream);
  void wait_decided_calls();
  void settle_device_calls(bool wait);
  void audit(const SystemView& system, const ForceField& ff);
  GpuOptions options_;
  ReusePolicy reuse_;
  PipelineStats stats_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace cellforce
