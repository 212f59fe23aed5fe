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
#include "search/rank_order.h"
#include "search/step_gate.h"
#include "forces/fused_step.h"

namespace cellforce {

struct GpuOptions {
  Precision precision = Precision::kDouble;
  Accumulation accumulation = Accumulation::kJacobi;
  TraversalForm traversal = TraversalForm::kAuto;  // kAuto: resolve_traversal() at each build
  SortMethod sort = SortMethod::kCub;
  GridOptions grid;
  ReuseOptions reuse;  // skin > 0: stages 1-3 reused while no particle moved more than skin / 2
  std::optional<Grid> grid_override;  // tests only: this grid, unchecked
  ListMemory memory = ListMemory::kAuto;  // the pair lists' memory mode (EngineChoice::memory)
  std::optional<int> list_splits;     // tests only: the list build's column splits per row tile
                                      // (cuda/pair_list.cuh build_splits) instead of the rule
  std::optional<int> list_threads;    // tests only: the list force kernel's threads per particle (1, 2,
                                      // 4 or 8) instead of the rule (1 from ~135,000 particles on an H100)
  std::optional<int> list_block;      // tests only: threads a block (128 or 256) of the list force kernel
                                      // that runs the next step's kick-drift, instead of the rule (pair_list.cu
                                      // fused_block)
  std::optional<bool> list_masks;     // tests only (false): the list build's fill tests every pair
                                      // again instead of reading the count pass's masks (BuildMasks)
  std::optional<bool> list_lend_masks;  // tests only (false): fast memory's unsorted keys, IDs and sort
                                        // scratch keep arrays of their own, never the masks' room (change 85)
  std::optional<std::size_t> list_mask_words;  // tests only: the masks' room holds at most this many
                                               // words (as lean memory's room on a full device)
  std::optional<bool> list_count_masked;  // tests only (true): count the units each fill writes from
                                          // masks (list_masked_units; a wait for the fill)
  std::optional<bool> build_graph;  // tests only (false): the build's fixed part is always queued
                                    // operation by operation, never as a CUDA graph (cuda/build_graph.cuh)
  std::optional<bool> build_graph_audit;  // tests only (true): a replayed build's bookkeeping runs under
                                          // a stream capture that must record nothing (BuildGraph)
  std::optional<bool> gate_notice;        // tests only (false): a gated chunk's host waits for the gate's
                                          // copy at its end, not for a shut kernel's notice (gate_readback.cuh)
  std::optional<bool> gate_notice_check;  // tests only (true): it waits for the copy, and the notice must be
                                          // there exactly where the gate closed, with the copy's values
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

  // Device arrays (core/system.h): the work is ordered after what the caller's `stream` (a
  // cudaStream_t; null: the legacy default stream) holds, and the results are written on the
  // engine's stream, which the caller's stream then waits for. Energy and virial are computed when
  // any of out.energies, out.energy, out.virial is given. The host does not wait for the device
  // (nor for the caller's stream): the box, force field and pointers are checked on the host, the
  // arrays on the device, and what the kernels find (a coordinate that is not finite, a type index
  // out of range, a pair whose force is not finite) is raised by synchronize(). The host waits
  // only with an open axis (the particles' bounds, 2 x dim numbers, plan the grid when the
  // structure is built), with a skin and the displacement check (the largest displacement, 8
  // bytes; with the check off, once per build retired by `every`, for the dangerous-build count),
  // with pair lists when the structure is built (the list's size, 24 bytes, and the free memory)
  // and with the reuse audit. Results are bitwise those of evaluate() on the same input.
  // Throws cellforce::Error for bad pointers or physics, before anything is queued.
  void evaluate_device(const DeviceSystemView& system, const ForceField& ff, const DeviceOutputs& out,
                       void* stream);
  // Waits for the engine's work, reads what the kernels flagged since the last synchronize() and
  // the counts of the last evaluation and the stage times of the last timed one (stats(); zeros
  // where none was timed: evaluate_resident's time_stages), and throws cellforce::Error for
  // the first problem found (naming the particle, or both particles of a pair; the outputs of the
  // calls since the last synchronize() are then not to be used).
  void synchronize(const ForceField& ff);

  // Resident evaluation, for an MD loop whose state stays on the device (cuda/md_engine.cu):
  // positions (n x dim, wrapped on periodic axes) and types (n, or null) are the caller's device
  // arrays, validated by the caller before its run. The work is queued on the engine's stream()
  // and the host does not wait, except with an open axis when the structure is built (the
  // particles' bounds, 2 x dim numbers), with a skin and the displacement check (the largest
  // displacement; evaluate_gated() has none; with the check off, once per build retired by `every`)
  // and with pair lists when the structure is built (the list's size). Forces stay on the
  // device (device_forces(), n x dim); with `request`, so do the energy and virial totals
  // (device_totals(): energy, then w_xx, w_yy, w_zz, w_xy, w_xz, w_yz). The kernels' flags are
  // not read: they accumulate until check_flags() (or synchronize()). Stage times are not read either
  // (collect_timing() reads the last timed evaluation's). The reuse audit does not run here.
  // `known_d2`: where the step gate closed at these positions, the largest squared displacement
  // its kick-drift measured (the bits max_displacement2 would reduce to, but that a non-finite
  // displacement reads +inf: a rebuild, where the reduction's NaN would not; the divergence is
  // flagged either way): the reuse check takes it instead of reducing it again on the device and
  // waiting for it (~60-100 us a build, the device idle).
  // `time_stages` false: the evaluation records none of its stage events, so collect_timing() and
  // stats()' stage times are not for it (change 83: each event held the device ~1-6 us, a build's
  // graph then holds none). For an evaluation whose stage times nothing reads: the MD engine's run
  // samples its last evaluation's and leaves them out of every other.
  void evaluate_resident(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                         const ForceField& ff, const Request& request, std::optional<double> known_d2 = {},
                         bool time_stages = true);
  // Reads the flags raised since the last check (synchronises the stream) and clears them; throws
  // cellforce::Error naming both particles of a pair whose force was not finite (the positions
  // come to the host only then, for the message).
  void check_flags(const Box& box, std::size_t n, const double* positions, const ForceField& ff);
  // The step gate (step_gate.h), for a resident MD run: how many of the next evaluations may be
  // queued behind the gate (0: none may). Positive only while the structure in use has its pair
  // list, the displacement check is on, the audit is off, flags accumulate (resident evaluations)
  // and nothing but the displacement could ask for a rebuild before then (same box, count and
  // cutoff; `every` bounds the count).
  int64_t gate_steps(const Box& box, std::size_t n, const ForceField& ff) const;
  // What the run's kick-drift kernels need: the bits of (skin / 2)^2 and the positions the
  // structure in use was built from (n x dim, device).
  unsigned long long gate_limit() const;
  const double* device_build_positions() const;
  // Where the gated steps' last drift kernels place the positions in the list's rank order
  // (rank_order.h: the gather's values), for gated evaluations that then leave their gather out.
  // Valid until the structure is rebuilt (the gate's chunk); `particles` is the array the chunk's
  // first evaluation reads (a fused evaluation swaps it with the second one). With `fused` (a Verlet chunk in fast
  // mode), the list's second rank-ordered array is reserved too, for gated evaluations that run the
  // next step's kick-drift (evaluate_gated's `then`).
  cuda::RankOrder rank_order(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                             const ForceField& ff, bool fused = false);
  // After a chunk whose last gated evaluation ran: its forces, left in rank order (the RankOrder's
  // `forces`, when not null), into device_forces() in the caller's order.
  void unrank_forces(std::size_t n);
  // One gated evaluation (forces only, from the pair list), queued; the host does not wait and
  // nothing is counted until settle_gate(). The step's drift placed the positions (rank_order()),
  // so the evaluation does not gather them, and it leaves the forces where the RankOrder says (in
  // rank order, or in device_forces() when the build is lean).
  // With `then` (fast mode, rank_order()'s `fused`), the evaluation runs the next gated step's
  // Verlet kick-drift on the chunk's rank-order state instead of storing its forces (change 59,
  // cuda/pair_list.cuh list_forces); the gate's test is then the next step's.
  void evaluate_gated(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                      const ForceField& ff, const cuda::GateView& gate, const cuda::NextKickDrift* then = nullptr);
  // After the host read the gate: `served` gated evaluations ran (the structure served them, the
  // largest squared displacement among them `served_d2`). stats() then reads as after a reused
  // evaluation.
  void settle_gate(int64_t served, double served_d2);
  const double* device_forces() const;
  const double* device_totals() const;
  void* stream() const;   // the engine's cudaStream_t
  // stats() gets the counts of the last evaluation and the stage times of the last timed one (zeros
  // where none was timed); synchronises (the timed one's last event, else the stream).
  void collect_timing();

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
  const PipelineStats& stats() const { return stats_; }
  // The device bytes each stage buffer holds now (those that hold any), by name; their sum is what
  // stats().buffer_bytes held after the last timed evaluation.
  std::vector<std::pair<const char*, std::size_t>> buffers() const;
  // Pair lists (ReuseOptions::list): the entries of the lists built from the structure in use (every
  // pair within rc + skin, once from each side); 0 when its evaluations traverse the cells.
  std::size_t listed_pairs() const;
  // Builds whose list fill read the count pass's decisions for every pair (cuda/pair_list.cuh
  // BuildMasks: once the room they ask for is there), and builds whose room held only some units'
  // decisions (lean memory on a device without room for them all, change 71).
  std::size_t list_masked_fills() const;
  std::size_t list_partly_masked_fills() const;
  // With GpuOptions::list_count_masked: the work units whose list the last build's fill wrote from
  // the count pass's masks (0 where it walked them all again).
  std::size_t list_masked_units() const;
  // Lean builds whose count pass read occupants staged in the last list's array (change 70).
  std::size_t list_staged_counts() const;
  // Builds whose fixed part (cell IDs to the list's partition) a CUDA graph replayed, and the
  // graphs captured for it (cuda/build_graph.cuh).
  std::size_t build_replays() const;
  std::size_t build_captures() const;
  const GpuOptions& options() const { return options_; }
  // The traversal form in use: options().traversal, or what kAuto chose at the last build (kAuto
  // before the first).
  TraversalForm traversal() const;
  // The device's name as the driver reports it (e.g. "NVIDIA H100 80GB HBM3").
  std::string device_name() const;

  // Empty when a CUDA device can be used here; otherwise why not.
  static std::string unavailable();
  // The memory of CUDA device `device` in bytes (cudaMemGetInfo's total, what the lists' memory
  // mode weighs: lists_memory); 0 where it cannot be used or does not exist.
  static std::size_t memory_bytes(int device);

  struct Impl;  // device buffers, stream and events, reused across evaluations

 private:
  std::vector<std::pair<uint32_t, uint32_t>> record(const SystemView& system, const ForceField& ff,
                                                    bool keep);
  void prepare(const SystemView& system, const ForceField& ff, const DeviceSystemView* on_device = nullptr);
  void traverse(const SystemView& system, const ForceField& ff, const Request& request, bool read_flags = true);
  void prepare_resident(const SystemView& system, const ForceField& ff, const DeviceSystemView& on_device,
                        std::optional<double> known_d2 = {});
  void plan_corners(const Box& box, std::size_t n, const double* positions);
  void finish_timing();
  void build(const SystemView& system, const ForceField& ff);
  void audit(const SystemView& system, const ForceField& ff);
  GpuOptions options_;
  ReusePolicy reuse_;
  PipelineStats stats_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace cellforce
