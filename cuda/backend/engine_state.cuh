// The CUDA engine's state (GpuEngine::Impl, backend/engine.h): the stream and its stage events, the
// device buffers of every stage (a registry, so that the memory each holds can be listed and the
// build's graph keyed by their addresses), the pair table's upload, the kernels' flags and the
// counts the host reads. Its jobs live in files of their own: the build of the neighbour structure
// (backend/structure_build.cu), the evaluations over the cells or the pair lists
// (backend/evaluation.cu), the buffers and host bookkeeping (backend/engine_state.cu). Buffers grow
// in the stream's order (DeviceBuffer::bind) and are reused, so repeated evaluations allocate
// nothing (except pair lists in lean memory: backend/memory_plan.h).
#pragma once

#include <cuda_runtime.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "backend/build_graph.cuh"
#include "backend/call_graph.cuh"
#include "backend/memory_plan.h"
#include "backend/engine.h"
#include "check.cuh"
#include "device_buffer.cuh"
#include "forces/traversal.cuh"
#include "search/pair_list.cuh"
#include "search/stages.cuh"
#include "staging.cuh"
#include "transfer.cuh"

namespace cellforce {

using cuda::DeviceBuffer;

template <class T>
T* as(DeviceBuffer<std::byte>& b) {
  return reinterpret_cast<T*>(b.data());
}

using cuda::download;
using cuda::upload;

struct GpuEngine::Impl {
  // Events recorded between the stages of one evaluation.
  enum Event : int {
    kStart,
    kUploaded,
    kChecked,
    kCellIds,
    kCounted,
    kSorted,
    kCellsFound,
    kTraversed,
    kAccumulated,
    kDownloaded,
    kNumEvents
  };

  cudaStream_t stream = nullptr;
  bool owns_stream = true;  // the engine made `stream` (GpuOptions::stream null), so it destroys it
  cudaEvent_t events[kNumEvents] = {};
  DeviceBuffer<double> positions;
  DeviceBuffer<uint32_t> types;
  DeviceBuffer<uint32_t> keys, object_ids, sorted_keys, sorted_ids;
  DeviceBuffer<Control> control;
  DeviceBuffer<std::byte> cub;  // count and sort temporaries
  cuda::ChapterSortScratch chapter_sort;
  DeviceBuffer<CollisionCell> cells;
  cuda::CollisionScratch collision;
  cuda::SplitScratch split;
  DeviceBuffer<cuda::PipelineCounts> counts;  // stage 1-3 counts, read by the later stages
  DeviceBuffer<uint32_t> tile_start;           // tile form: the cells' first row tiles
  bool tiles_built = false;                    // tile_start holds the tiles of the structure in use
  TraversalForm form = TraversalForm::kWarpPerCell;  // the traversal of the structure in use
  DeviceBuffer<std::byte> staged, table, force_slots, energy_slots, cell_sums;
  DeviceBuffer<double> forces, energies, totals;
  DeviceBuffer<std::byte> virial_slots;  // evaluate_local: the locals' virial slots ...
  DeviceBuffer<double> virials;          // ... and their sums (kVirialComponents a local)
  DeviceBuffer<cuda::DeviceFlags> flags;
  DeviceBuffer<uint2> pairs;
  DeviceBuffer<double> build_positions;  // reuse: positions at the build in use (n x dim)
  std::vector<uint32_t> build_keys;      // audit (host): stage 1's keys of that build, user order
  std::vector<Control> build_control;    // audit (host): its control bits
  // Bounds of the structure in use, from its build (cuda::PipelineCounts): the cell-ID entries
  // n x 2^d (>= the valid ones) and min(n, grid cells) (>= the collision cells).
  std::size_t entries = 0, max_cells = 0;
  // Pair lists (ReuseOptions::list): the list of the build numbered list_built_for, when it could
  // be built (list_usable); builds counts the structures built.
  cuda::PairList list;
  cuda::BuildGraph graph;  // the build's fixed part as a CUDA graph (backend/build_graph.cuh)
  // Force calls whose rebuild the device decides (backend/call_graph.cuh, backend/device_calls.cu):
  // the graph, the device's state, the calls it served since the host last read that state
  // (unsettled), whether the state must first be set to the structure in use (stale: the host's
  // own path served the last call), the device's builds the host has counted, and the last device
  // build whose posted sizes the host settled.
  cuda::CallGraph call_graph;
  DeviceBuffer<cuda::CallState> call_state;
  std::size_t calls_unsettled = 0, calls_settled = 0;
  bool call_state_stale = true;
  unsigned long long device_builds = 0, settled_tag = 0;
  std::size_t list_overflows = 0;  // device builds whose list did not fit its array (settled)
  // While a call graph's build body is captured: Impl::build queues its fixed part plainly (no
  // build graph of its own inside the capture).
  bool plain_build = false;
  // While a call graph is captured: the caller's arrays its evaluations write the forces and the
  // per-particle energies into (null: the engine's own, copied out after).
  double* forces_out = nullptr;
  double* energies_out = nullptr;
  // While a call graph's unconditional list path is captured: the device word that makes its
  // kernels return at once (ListArgs::skip; null elsewhere).
  const unsigned long long* list_skip = nullptr;
  // Whether the graphs write the caller's output arrays (the first two words of their keys): not
  // once a caller has changed them more than twice between two calls a kept graph served (a new
  // array each call, or more by turns than graphs are kept: one would be made every call); the
  // engine's arrays are then copied out.
  bool direct_outputs = true;
  int output_changes = 0;
  // Whether the graphs hold the call's input pass (the caller's input arrays, words 2-5 of their
  // keys): not once a caller has changed them as above (the pass is then queued before the graph);
  // and whether the graph ready_device_call found holds it.
  bool input_in_graph = true;
  int input_changes = 0;
  bool call_input_inside = false;
  // Whether the engine's stream holds work a decided call must follow (flags reset, room taken, a
  // host path's call): the caller's stream then waits for it; the key of the last decided call
  // (another key may have taken room).
  bool engine_dirty = true;
  cuda::CallGraph::Key last_call_key;
  // The stream the last decided call ran on (the caller's; `finished` recorded there after it),
  // null when none is pending: the engine's own stream waits for it before anything it queues.
  cudaStream_t decided_on = nullptr;
  bool decided_pending = false;
  cudaGraphExec_t call_exec = nullptr;  // the graph ready_device_call found or made for this call
  std::size_t builds = 0, list_built_for = ~std::size_t(0);
  bool list_usable = false;
  // Lean memory (pair lists on a system whose buffers would not fit beside each other): the build
  // keeps no staged occupants (it stages them as it loads them), keeps masks only for the units the
  // device's free memory holds and only while the list's array is lent, puts the
  // unsorted keys and IDs and the sort's scratch in the dead list's array where they fit (lend; else
  // it frees the last list first, and them after the sort); the same list, bit for bit.
  bool lean = false, lend = false;
  int multiprocessors = 1;  // of the engine's device, read once
  bool has_types = false;

  // Calls f(name, buffer) on every device buffer of the stages.
  template <class F>
  void for_each_buffer(F&& f) {
    f("positions", positions), f("types", types), f("cell IDs: keys", keys), f("cell IDs: object IDs", object_ids);
    f("sort: keys", sorted_keys), f("sort: object IDs", sorted_ids), f("cell IDs: control bits", control);
    f("CUB scratch", cub), f("collision cells", cells), f("stage counts", counts), f("tiles: first tile", tile_start);
    f("staged occupants", staged), f("LJ table", table), f("Jacobi slots: forces", force_slots);
    f("Jacobi slots: energies", energy_slots), f("cell sums", cell_sums), f("forces", forces);
    f("energies", energies), f("totals", totals), f("flags", flags), f("pairs (tests)", pairs);
    f("Jacobi slots: virials (ghosts)", virial_slots), f("virials (ghosts)", virials);
    f("build positions", build_positions), f("decided calls: state", call_state);
    f("chapter sort: keys", chapter_sort.keys), f("chapter sort: values", chapter_sort.values);
    f("chapter sort: counts", chapter_sort.counts), f("chapter sort: digit totals", chapter_sort.digit_totals);
    f("collision cells: run starts", collision.run_start), f("collision cells: CUB scratch", collision.cub);
    f("type split: keys", split.keys), f("type split: keys out", split.keys_out), f("type split: order", split.order);
    f("type split: order out", split.order_out), f("type split: cells", split.cells);
    f("type split: counts", split.counts), f("type split: CUB scratch", split.cub);
    list.for_each_buffer(f);
  }

  // Device bytes held by the stage buffers.
  std::size_t bytes();

  // The same by buffer: those that hold any.
  std::vector<std::pair<const char*, std::size_t>> buffers();

  // Calls f on every buffer the build's fixed part names (its graph holds their addresses): an
  // operation added to the part adds its buffers here. The others (the evaluations' and the list's
  // own, some swapped at every gated step) do not key its graph.
  template <class F>
  void for_each_part_buffer(F&& f) {
    f(keys), f(object_ids), f(sorted_keys), f(sorted_ids), f(control), f(cub), f(counts), f(cells);
    f(collision.run_start), f(collision.cub), f(tile_start), f(build_positions), f(staged);
    f(flags), f(table), f(forces);  // forces: reserved by the part's list_args, written after it
    list.for_each_head_buffer(f);
  }

  // The key of the build's fixed part (backend/build_graph.cuh): the address and capacity of every
  // buffer it names, and what else shapes its operations and their arguments: the system's size
  // and grid, the positions and types it reads, whether it resets the flags, whether it records its
  // stage events (`timing`: a timed build must not replay an untimed graph), the options and the device.
  cuda::BuildGraph::Key build_key(const GpuOptions& o, const Grid& g, const ForceField& ff, std::size_t n);

  // A stage event of the build's fixed part: a node of its graph while it is captured (recorded at
  // every replay), else recorded; nothing in an untimed evaluation (`timing`).
  void stage_record(Event e);

  ~Impl();

  void record(Event e);
  // Whether this evaluation records its stage events (evaluate_resident's time_stages): each event
  // holds the device for a few microseconds between its two operations, so only the evaluations
  // whose stage times something reads record them.
  bool timing = true;
  // Whether a timed evaluation has recorded its events to the last (kDownloaded): stage times are
  // read only then (an engine whose evaluations were all untimed has events never recorded).
  bool timed_events = false;
  double seconds(Event from, Event to) const;

  std::vector<std::byte> host_table;  // the table last uploaded (uploaded again only on change)
  // Its staging in pinned memory, so that the upload never waits for the stream; table_copied
  // marks when the copy has left it.
  void* pinned_table = nullptr;
  std::size_t pinned_bytes = 0;
  cudaEvent_t table_copied = nullptr;

  // The pair table of `f` on the device: copied only when it changed since the last upload. Waits
  // only when it changes while the previous table's copy is still queued.
  template <class Real>
  void upload_table(const ForceField& f);

  // Host-array calls read their own flags: any that resident evaluations or compute_device left
  // are dropped (the MD engine reads its own after each call; the API synchronizes before a
  // host-array call).
  void per_call_flags();

  void reset_flags();

  // The positions (and types) of this evaluation, on every evaluation.
  // From the host arrays of `sys` (copied through `staging`), or, when `on_device` is given, its
  // device arrays (the same particles, borrowed). With `check`, the host arrays are checked as they
  // are copied (finite coordinates, types of the force field): one pass over them, and on a bad
  // value validate_system's error, which names the particle.
  void upload_system(const SystemView& sys, const DeviceSystemView* on_device = nullptr,
                     const ForceField* check = nullptr);
  // Host arrays' copies to and from the device (cuda/staging.cuh).
  cuda::PinnedStaging staging;
  std::vector<double> local_virials;  // evaluate_local's per-particle virials (6 each) on the host

  // The device arrays this evaluation reads (types null: all type 0).
  void borrow(const double* p, const uint32_t* t) {
    pos = p;
    typ = t;
    has_types = t != nullptr;
  }

  // The evaluation's device positions and types (the engine's copies of host arrays, or the
  // caller's device arrays); typ is null for all type 0.
  const double* pos = nullptr;
  const uint32_t* typ = nullptr;
  // Resident evaluations (evaluate_resident): the open axes' bounds of the particles as two corner
  // points for plan_grid, and flags that accumulate until check_flags() or synchronize() resets
  // them.
  double corners[2 * kMaxDim] = {};
  std::size_t corner_count = 0;
  bool plan_from_corners = false, accumulate_flags = false;

  // Throws for a flag the kernels raised (read after the stream has been synchronised). Without
  // the positions (system.positions null: device arrays the caller may have changed since), a
  // close pair is named without its distance.
  void throw_flags(const cuda::DeviceFlags& f, const SystemView& system, const ForceField& ff,
                   Precision precision) const;

  // The counts of the structure in use, into the statistics (after a synchronisation).
  void read_counts(PipelineStats& st);

  cudaEvent_t joined = nullptr, finished = nullptr;  // the caller's stream <-> the engine's
  std::size_t device_bytes = 0;  // the device's memory (cudaMemGetInfo's total), once asked
  // CUB's scratch bytes for the sort of `sort_entries` keys of `sort_bits` bits (a host query of
  // CUB's dispatch: asked again only when either changes, as search/pair_list.cuh's CubBytes).
  std::size_t sort_entries = 0, sort_scratch = 0;
  int sort_bits = -1;
  std::size_t sort_scratch_bytes(std::size_t n_entries, int bits);

  // Stages 1-3 on the uploaded positions: cell IDs, count, sort, collision cells (split by type
  // for Gauss-Seidel). With a skin, keeps the build's positions (and, for the audit, its keys).
  // `listed`: a pair list is built after it (build_list), which the memory plan and the tiles serve.
  void build(const GpuOptions& o, PipelineStats& st, const SystemView& sys, const ForceField& ff, bool listed);
  // The build's steps: the grid (planned and checked, or the test's), where the build's arrays go
  // (backend/memory_plan.h; it applies the lean mode's releases), and stage 1 and 2's queueing.
  void plan_build_grid(const GpuOptions& o, PipelineStats& st, const SystemView& sys, const ForceField& ff);
  cuda::BuildMemoryPlan plan_build_memory(const GpuOptions& o, bool listed, std::size_t n, std::size_t last_entries,
                                          const Grid& g);
  void queue_ids_and_sort(const GpuOptions& o, const Grid& g, std::size_t n, uint32_t* unsorted_keys,
                          uint32_t* unsorted_ids, const cuda::ScratchLoan& loan);

  // Whether evaluations walk pair lists (core/reuse.h states the condition).
  static bool lists(const GpuOptions& o, const Box& box, double cutoff) {
    return pair_lists_serve(o.reuse, o.accumulation, box, cutoff);
  }

  // What the list kernels read: the positions of this evaluation, the physics, the outputs.
  template <class Real, class Accum>
  cuda::ListArgs<Real, Accum> list_args(const Grid& g, const SystemView& sys, const ForceField& ff,
                                        const Request& req);

  // The list of the structure just built, from the positions it was built from (the ones the
  // displacement check measures against): part of every build, whoever asked for it (an
  // evaluation, the pair recorder, a restored structure).
  template <class Real, class Accum>
  void build_list(const GpuOptions& o, const Grid& g, const SystemView& sys, const ForceField& ff);

  // The list path of one evaluation: the listed pairs at this evaluation's positions. Returns false
  // when the structure has no list (it could not be built: the cells then serve it).
  template <class Real, class Accum>
  bool evaluate_lists(const Grid& g, const SystemView& sys, const ForceField& ff, const Request& req);

  // The listed pairs' kernels at this evaluation's positions (behind `gate` when it has one: the
  // step gate's evaluations, GpuEngine::evaluate_gated). Returns whether energy and virial were asked.
  template <class Real, class Accum>
  bool list_forces(const Grid& g, const SystemView& sys, const ForceField& ff, const Request& req,
                   const cuda::GateView& gate, const cuda::NextKickDrift* then = nullptr);

  // Where the gated drifts place the positions for the list in use, and where its gated
  // evaluations leave the forces: in rank order unless the build is lean (24 bytes a particle
  // more) (GpuEngine::rank_order).
  template <class Real, class Accum>
  cuda::RankOrder rank_order(const Grid& g, const SystemView& sys, const ForceField& ff, bool fused);

  // Every particle's list partners (user indices, list order), downloaded: the list audit's input.
  std::vector<std::vector<uint32_t>> list_partners(std::size_t n);

  // A reused structure: the stage events recorded back to back (zero stage times).
  void skip_build();

  // The arguments shared by the force and pair-recording kernels; stages the occupants.
  template <class Real, class Accum>
  cuda::TraversalArgs<Real, Accum> prepare(const Grid& g, const SystemView& sys,
                                           const ForceField& ff, CutoffMode mode);

  // The same arguments without staging (args.staged null).
  template <class Real, class Accum>
  cuda::TraversalArgs<Real, Accum> traversal_args(const Grid& g, const SystemView& sys, const ForceField& ff,
                                                  CutoffMode mode);

  // The cells' traversal and the sums of its slots and cells (the evaluation of a structure
  // without a list).
  template <class Real, class Accum>
  void evaluate_cells(const GpuOptions& o, const Grid& g, const SystemView& sys, const ForceField& ff,
                      const Request& req);
  // Local and ghost particles (GpuEngine::evaluate_local): the tile form's traversal with ghosts
  // over the cells of the structure in use (its tiles counted here where its build made none: it
  // makes them for the tile form or a list), the locals' slots summed into forces, energies and virials
  // (kVirialComponents a local; with req.energy or req.virial both are computed).
  template <class Real, class Accum>
  void evaluate_local(const GpuOptions& o, const Grid& g, const SystemView& sys, std::size_t n_local,
                      const ForceField& ff, const Request& req);
  // The room evaluate_cells takes, taken now (before a call graph's capture).
  template <class Real, class Accum>
  void reserve_cells(const GpuOptions& o, const Grid& g, std::size_t n, const Request& req);

  // The call graph of the structure in use (backend/device_calls.cu) and its key: every buffer's
  // address and capacity and what else shapes its operations.
  // `input`: the call's input pass is the graph's first node (null: queued before it).
  template <class Real, class Accum>
  cudaGraphExec_t make_call_graph(const GpuOptions& o, const PipelineStats& st, const SystemView& sys, const ForceField& ff,
                       const Request& req, double limit2, const DeviceOutputs& out, const DeviceInput* input,
                       cuda::CallGraph::Key key);
  static constexpr std::size_t kCallKeyInput = 2, kCallKeyInputEnd = 6;  // the input's words
  cuda::CallGraph::Key call_key(const GpuOptions& o, const Grid& g, const ForceField& ff, std::size_t n,
                                const Request& req, const DeviceOutputs& out, const DeviceInput* input);

  // Returns whether the pair lists served (else the cells did).
  template <class Real, class Accum>
  bool traverse_and_sum(const GpuOptions& o, const Grid& g, const SystemView& sys,
                        const ForceField& ff, const Request& req);
};

}  // namespace cellforce
