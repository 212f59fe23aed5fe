// The CUDA engine: plans the grid on the host, runs the stages on its own stream, times each with
// CUDA events, and reads the kernels' flags when the host synchronises. The stages keep their
// counts in device memory (cuda::PipelineCounts) and the buffers are sized by bounds the host
// knows from n and the grid, so that no stage waits for the host. Device buffers live in Impl,
// grow in the stream's order (DeviceBuffer::bind) and are reused, so repeated evaluations
// allocate nothing (except pair lists in lean memory, whose builds free and take again what is
// dead between builds where the dead list's array cannot hold it).
#include "engine.h"

#include <cuda_runtime.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>
#include <utility>
#include <vector>

#include "build_graph.cuh"
#include "check.cuh"
#include "core/error.h"
#include "device_buffer.cuh"
#include "stages.cuh"
#include "pair_list.cuh"
#include "traversal.cuh"

namespace cellforce {

using cuda::DeviceBuffer;

namespace {

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

template <class T>
T* as(DeviceBuffer<std::byte>& b) {
  return reinterpret_cast<T*>(b.data());
}

template <class T>
void upload(DeviceBuffer<T>& d, const T* h, std::size_t count, cudaStream_t stream) {
  d.reserve(std::max<std::size_t>(count, 1));
  if (count)
    CF_CUDA_CHECK(cudaMemcpyAsync(d.data(), h, count * sizeof(T), cudaMemcpyHostToDevice, stream));
}

template <class T>
void download(std::vector<T>& h, const T* d, std::size_t count, cudaStream_t stream) {
  h.resize(count);
  if (count)
    CF_CUDA_CHECK(cudaMemcpyAsync(h.data(), d, count * sizeof(T), cudaMemcpyDeviceToHost, stream));
}

// r^2 of a pair by minimum image in double, for the close-pair error message.
double distance2(const SystemView& s, uint32_t i, uint32_t j) {
  double r2 = 0;
  for (int a = 0; a < s.box.dim; ++a) {
    const double inv_length = s.box.periodic[a] ? 1.0 / s.box.length[a] : 0.0;
    const double d = separation(s.positions[std::size_t(i) * s.box.dim + a],
                                s.positions[std::size_t(j) * s.box.dim + a], s.box.length[a], inv_length);
    r2 += d * d;
  }
  return r2;
}

// Makes the engine's device current for a scope and restores the caller's afterwards.
class DeviceScope {
 public:
  explicit DeviceScope(int device) {
    CF_CUDA_CHECK(cudaGetDevice(&previous_));
    if (previous_ != device) CF_CUDA_CHECK(cudaSetDevice(device));
  }
  ~DeviceScope() { cudaSetDevice(previous_); }  // cannot throw; a failure shows at the next call
  DeviceScope(const DeviceScope&) = delete;
  DeviceScope& operator=(const DeviceScope&) = delete;

 private:
  int previous_ = 0;
};

}  // namespace

struct GpuEngine::Impl {
  cudaStream_t stream = nullptr;
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
  TraversalForm form = TraversalForm::kWarpPerCell;  // the traversal of the structure in use
  DeviceBuffer<std::byte> staged, table, force_slots, energy_slots, cell_sums;
  DeviceBuffer<double> forces, energies, totals;
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
  cuda::BuildGraph graph;  // the build's fixed part as a CUDA graph (cuda/build_graph.cuh)
  std::size_t builds = 0, list_built_for = ~std::size_t(0);
  bool list_usable = false;
  // Lean memory (pair lists on a system whose buffers would not fit beside each other): the build
  // keeps no staged occupants (it stages them as it loads them), keeps masks only for the units the
  // device's free memory holds and only while the list's array is lent (change 71), puts the
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
    f("build positions", build_positions);
    f("chapter sort: keys", chapter_sort.keys), f("chapter sort: values", chapter_sort.values);
    f("chapter sort: counts", chapter_sort.counts), f("chapter sort: digit totals", chapter_sort.digit_totals);
    f("collision cells: run starts", collision.run_start), f("collision cells: CUB scratch", collision.cub);
    f("type split: keys", split.keys), f("type split: keys out", split.keys_out), f("type split: order", split.order);
    f("type split: order out", split.order_out), f("type split: cells", split.cells);
    f("type split: counts", split.counts), f("type split: CUB scratch", split.cub);
    list.for_each_buffer(f);
  }

  // Device bytes held by the stage buffers.
  std::size_t bytes() {
    std::size_t b = 0;
    for_each_buffer([&](const char*, const auto& buffer) { b += buffer.bytes(); });
    return b;
  }

  // The same by buffer: those that hold any.
  std::vector<std::pair<const char*, std::size_t>> buffers() {
    std::vector<std::pair<const char*, std::size_t>> out;
    for_each_buffer([&](const char* name, const auto& buffer) {
      if (buffer.bytes()) out.emplace_back(name, buffer.bytes());
    });
    return out;
  }

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

  // The key of the build's fixed part (cuda/build_graph.cuh): the address and capacity of every
  // buffer it names, and what else shapes its operations and their arguments: the system's size
  // and grid, the positions and types it reads, whether it resets the flags, whether it records its
  // stage events (`timing`: a timed build must not replay an untimed graph), the options and the device.
  cuda::BuildGraph::Key build_key(const GpuOptions& o, const Grid& g, const ForceField& ff, std::size_t n) {
    using cuda::add_to_key;
    cuda::BuildGraph::Key k;
    k.reserve(192);
    for (const auto v : {n, entries, max_cells, std::size_t(timing), std::size_t(form), std::size_t(multiprocessors), std::size_t(g.dim),
                         std::size_t(g.num_cells), std::size_t(g.key_bits), std::size_t(accumulate_flags),
                         std::size_t(o.precision), std::size_t(ff.num_types()), std::size_t(ff.mode),
                         std::size_t(o.list_splits.value_or(0)), std::size_t(o.list_masks.value_or(true)),
                         o.list_mask_words.value_or(0), std::size_t(o.list_threads.value_or(0))})
      add_to_key(k, v);
    for (const double v : {g.half_width, ff.cutoff, o.reuse.skin}) add_to_key(k, v);
    for (int a = 0; a < kMaxDim; ++a) {
      add_to_key(k, g.n[a]);
      for (const double v : {g.origin[a], g.cell[a], g.inv_cell[a], g.length[a], g.inv_length[a], g.half_width_cells[a]})
        add_to_key(k, v);
    }
    add_to_key(k, pos);
    add_to_key(k, typ);
    for_each_part_buffer([&](const auto& buffer) {
      add_to_key(k, static_cast<const void*>(buffer.data()));
      add_to_key(k, buffer.capacity());
    });
    return k;
  }

  // A stage event of the build's fixed part: a node of its graph while it is captured (recorded at
  // every replay), else recorded; nothing in an untimed evaluation (`timing`, change 83).
  void stage_record(Event e) {
    if (!timing) return;
    if (graph.capturing()) CF_CUDA_CHECK(cudaEventRecordWithFlags(events[e], stream, cudaEventRecordExternal));
    else record(e);
  }

  ~Impl() {
    // Queued work may still use the buffers and the pinned table: stream-ordered memory is freed
    // without waiting for it, so wait here (a destructor cannot throw; errors are ignored).
    if (stream) cudaStreamSynchronize(stream);
    for (cudaEvent_t e : events)
      if (e) cudaEventDestroy(e);
    if (joined) cudaEventDestroy(joined);
    if (finished) cudaEventDestroy(finished);
    if (table_copied) cudaEventDestroy(table_copied);
    if (pinned_table) cudaFreeHost(pinned_table);
    if (stream) cudaStreamDestroy(stream);
  }

  void record(Event e) {
    if (!timing) return;
    CF_CUDA_CHECK(cudaEventRecord(events[e], stream));
    if (e == kDownloaded) timed_events = true;
  }
  // Whether this evaluation records its stage events (evaluate_resident's time_stages, change 83).
  // Each held the device between its two operations: at 256,000 particles ~3-6 us around each of
  // the build graph's four event nodes (against ~0.1 us between two kernels of the graph) and ~7-8
  // us in all around an MD chunk's closing evaluation (change 82's CUPTI timeline).
  bool timing = true;
  // Whether a timed evaluation has recorded its events to the last (kDownloaded): stage times are
  // read only then (an engine whose evaluations were all untimed has events never recorded).
  bool timed_events = false;
  double seconds(Event from, Event to) const {
    float ms = 0;
    CF_CUDA_CHECK(cudaEventElapsedTime(&ms, events[from], events[to]));
    return 1e-3 * ms;
  }

  std::vector<std::byte> host_table;  // the table last uploaded (uploaded again only on change)
  // Its staging in pinned memory, so that the upload never waits for the stream; table_copied
  // marks when the copy has left it.
  void* pinned_table = nullptr;
  std::size_t pinned_bytes = 0;
  cudaEvent_t table_copied = nullptr;

  // The pair table of `f` on the device: copied only when it changed since the last upload. Waits
  // only when it changes while the previous table's copy is still queued.
  template <class Real>
  void upload_table(const ForceField& f) {
    const std::vector<LJParams<Real>> params = make_pair_table<Real>(f);
    const std::size_t bytes = params.size() * sizeof(LJParams<Real>);
    if (host_table.size() == bytes && std::memcmp(host_table.data(), params.data(), bytes) == 0) return;
    if (graph.capturing() || !graph.queuing())  // GpuEngine::build uploads it before the build's fixed
      throw Error("internal error: the pair table changed inside the build's graph");  // part: none in its graph
    CF_CUDA_CHECK(cudaEventSynchronize(table_copied));
    if (pinned_bytes < bytes) {
      if (pinned_table) CF_CUDA_CHECK(cudaFreeHost(pinned_table));
      pinned_table = nullptr;
      pinned_bytes = 0;
      CF_CUDA_CHECK(cudaMallocHost(&pinned_table, bytes));
      pinned_bytes = bytes;
    }
    host_table.resize(bytes);
    std::memcpy(host_table.data(), params.data(), bytes);
    std::memcpy(pinned_table, params.data(), bytes);
    table.reserve(bytes);
    CF_CUDA_CHECK(cudaMemcpyAsync(table.data(), pinned_table, bytes, cudaMemcpyHostToDevice, stream));
    CF_CUDA_CHECK(cudaEventRecord(table_copied, stream));
  }

  // Host-array calls read their own flags: any that resident evaluations or compute_device left
  // are dropped (the MD engine reads its own after each call; the API synchronizes before a
  // host-array call).
  void per_call_flags() {
    if (!accumulate_flags) return;
    accumulate_flags = false;
    plan_from_corners = false;
  }

  void reset_flags() {
    flags.reserve(1);
    cuda::DeviceFlags* f = flags.data();
    static_assert(offsetof(cuda::DeviceFlags, bad_coordinate) == sizeof(f->bad_pair) &&
                  offsetof(cuda::DeviceFlags, bad_type) == 2 * sizeof(f->bad_pair));
    CF_CUDA_CHECK(cudaMemsetAsync(f, 0, sizeof(cuda::DeviceFlags), stream));
    CF_CUDA_CHECK(cudaMemsetAsync(f, 0xff, 3 * sizeof(f->bad_pair), stream));  // "none" for the minima
  }

  // The positions (and types) of this evaluation, on every evaluation.
  // From the host arrays of `sys` (copied), or, when `on_device` is given, its device arrays (the
  // same particles, borrowed).
  void upload_system(const SystemView& sys, const DeviceSystemView* on_device = nullptr) {
    record(kStart);
    const std::size_t nd = sys.n * std::size_t(sys.box.dim);
    if (on_device) {  // borrowed: the caller keeps them unchanged until the work is done
      borrow(on_device->positions, on_device->types);
    } else {
      upload(positions, sys.positions, nd, stream);
      if (sys.types) upload(types, sys.types, sys.n, stream);
      borrow(positions.data(), sys.types ? types.data() : nullptr);
    }
    record(kUploaded);
  }

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
                   Precision precision) const {
    static constexpr const char* kAxis[kMaxDim] = {"x", "y", "z"};
    if (f.impossible)
      throw Error("CUDA engine: a traversal kernel met a particle index out of range (an internal "
                  "error, not bad input)");
    if (f.bad_coordinate != ~0ull)
      throw Error("particle " + std::to_string(f.bad_coordinate >> 32) + " has a non-finite " +
                  kAxis[std::min<unsigned>(unsigned(f.bad_coordinate & 0xffffffffu), kMaxDim - 1)] + " coordinate");
    if (f.bad_type != ~0ull)
      throw Error("particle " + std::to_string(f.bad_type >> 32) + " has type index " +
                  std::to_string(f.bad_type & 0xffffffffu) + " but there are " + std::to_string(ff.num_types()) +
                  " types");
    if (f.bad_pair != ~0ull) {
      const auto i = uint32_t(f.bad_pair >> 32), j = uint32_t(f.bad_pair & 0xffffffffu);
      if (system.positions) throw_close_pair(system, i, j, distance2(system, i, j), &ff, precision);
      throw Error("particles " + std::to_string(i) + " and " + std::to_string(j) +
                  " are too close: the Lennard-Jones force is not finite in this precision");
    }
  }

  // The counts of the structure in use, into the statistics (after a synchronisation).
  void read_counts(PipelineStats& st) {
    cuda::PipelineCounts c{};
    if (entries > 0) {
      CF_CUDA_CHECK(cudaMemcpyAsync(&c, counts.data(), sizeof(c), cudaMemcpyDeviceToHost, stream));
      CF_CUDA_CHECK(cudaStreamSynchronize(stream));
    }
    st.valid_entries = std::size_t(c.valid);
    st.collision_cells = c.cell_range[1];
  }

  cudaEvent_t joined = nullptr, finished = nullptr;  // the caller's stream <-> the engine's
  std::size_t device_bytes = 0;  // the device's memory (cudaMemGetInfo's total), once asked
  // CUB's scratch bytes for the sort of `sort_entries` keys of `sort_bits` bits (a host query of
  // CUB's dispatch: asked again only when either changes, as pair_list.cu's CubBytes).
  std::size_t sort_entries = 0, sort_scratch = 0;
  int sort_bits = -1;
  std::size_t sort_scratch_bytes(std::size_t n_entries, int bits) {
    if (n_entries != sort_entries || bits != sort_bits) {
      sort_scratch = cuda::radix_sort_cub_bytes(n_entries, bits);
      sort_entries = n_entries;
      sort_bits = bits;
    }
    return sort_scratch;
  }

  // Stages 1-3 on the uploaded positions: cell IDs, count, sort, collision cells (split by type
  // for Gauss-Seidel). With a skin, keeps the build's positions (and, for the audit, its keys).
  void build(const GpuOptions& o, PipelineStats& st, const SystemView& sys, const ForceField& ff) {
    const double skin = o.reuse.skin;
    if (o.grid_override) {
      st.grid = *o.grid_override;
    } else {
      GridOptions go = o.grid;
      go.slabs = lists(o, sys.box, ff.cutoff);  // the list's ranks by layer in a cell (change 86)
      st.grid = plan_from_corners ? plan_grid(sys.box, ff.cutoff, corners, corner_count, go, skin)
                                  : plan_grid(sys.box, ff.cutoff, sys.positions, sys.n, go, skin);
      check_grid(st.grid, sys.box, ff.cutoff, o.grid.rule, skin);
      check_staging(st.grid, ff.cutoff, o.precision, skin, o.grid.rule);
    }
    check_precision_range(ff, o.precision);
    const Grid& g = st.grid;
    const std::size_t n = sys.n;
    const bool was_lean = lean;
    const std::size_t last_entries = entries;
    entries = n << g.dim;
    max_cells = std::min<std::size_t>(n, g.num_cells);
    const std::size_t run_bound = std::min<std::size_t>(entries, g.num_cells);
    const std::size_t cap = std::max<std::size_t>(entries, 1);
    counts.reserve(1);
    form = resolve_traversal(o.traversal, max_cells, multiprocessors);
    ++builds;
    lean = lend = false;
    const bool listed = lists(o, sys.box, ff.cutoff);
    const bool tiled = form == TraversalForm::kWarpPerTile || listed;  // the cells' tiles, in final order
    if (listed) {
      // Lean where asked, or where the fast layout would not fit in 90% of the device (lists_memory:
      // the rule the automatic skin follows too).
      if (device_bytes == 0) {  // asked once: cudaMemGetInfo at every build held the device idle ~8 us
        std::size_t free_bytes = 0;
        CF_CUDA_CHECK(cudaMemGetInfo(&free_bytes, &device_bytes));
      }
      lean = lists_memory(o.memory, n, device_bytes) == ListMemory::kLean;
      if (lean) {
        // The new build makes a new list: the old one is dead. Its array holds the unsorted keys and
        // IDs and the sort's scratch where all three fit in it (lent below), then the occupants
        // staged for the count pass where they fit (build_list, change 70), and then the new list
        // where that fits (build_pair_list): no device allocation of the list's size at every build
        // (at 100M particles ~45 GB, ~129 ms with the device idle: performance.md, change 69). Else
        // freed here, so that the sort's arrays have its room. Kept, the array does not shrink: a
        // lean engine holds its longest list, as a fast one does.
        lend = o.sort == SortMethod::kCub &&
               list.neighbors.capacity() >=
                   2 * lent_words(cap) + (sort_scratch_bytes(entries, g.key_bits) + 3) / 4;
        if (!lend) list.neighbors.release();
        list.ranked_forces.release();  // lean gated evaluations store in the caller's order
        list.fixed_next.release();     // and run no kick-drift (change 59)
        list.ranked_next.release();
        staged.release();
      }
    }
    // A lean build's masks' room was sized to the memory it left (grow_masks, change 71): kept for
    // lean builds of the same system whose keys are lent (they take no room anew); given up before
    // anything else is taken where that room may be wanted (a new system, the other mode, keys in
    // arrays of their own, or lean after fast mode's room, sized without regard to lean's), and asked
    // for again at the build's end where masks are used (build_list).
    const bool keep_room = lean && was_lean && entries == last_entries && lend;
    if ((lean || was_lean) && !keep_room) cuda::give_up_masks(list);
    // Fast memory (change 85): the unsorted keys and IDs and the sort's scratch are dead from the
    // sort to the next build, the count pass's masks from the fill to the next count pass, so the
    // masks' room holds the former where it is large enough (every build of a system after its first,
    // in a liquid: ~236 bytes a particle of masks against 64 of keys and IDs and ~70 of scratch), as
    // the dead list's array does in lean memory. A build with no room yet (a system's first) frees
    // them after its sort instead, so that they and the masks the build then asks for are never held
    // together. Where the room is too small (tests' capped rooms) they keep arrays of their own.
    const bool masks_to_come = listed && !lean && o.sort == SortMethod::kCub && o.list_lend_masks.value_or(true) &&
                               o.list_masks.value_or(true);
    const bool lend_masks =
        masks_to_come && list.masks.capacity() >= 2 * lent_words(cap) + (sort_scratch_bytes(entries, g.key_bits) + 3) / 4;
    const bool free_after_sort = masks_to_come && !lend_masks && list.masks.capacity() == 0;
    // The unsorted keys and IDs: their own arrays, or (lean, a list array kept above) the dead list's
    // first words, the sort's scratch after them.
    uint32_t *unsorted_keys = nullptr, *unsorted_ids = nullptr;
    cuda::ScratchLoan loan;
    if (lend || lend_masks) {
      uint32_t* room = lend ? list.neighbors.data() : list.masks.data();
      const std::size_t room_words = lend ? list.neighbors.capacity() : list.masks.capacity();
      if (lend_masks && keys.capacity() > 0) cub.release();  // it held the sort's scratch: the room holds it now
      keys.release();
      object_ids.release();
      unsorted_keys = room;
      unsorted_ids = unsorted_keys + lent_words(cap);
      loan.data = reinterpret_cast<std::byte*>(unsorted_ids + lent_words(cap));
      loan.bytes = (room_words - 2 * lent_words(cap)) * sizeof(uint32_t);
    } else {
      keys.reserve(cap);
      object_ids.reserve(cap);
      unsorted_keys = keys.data();
      unsorted_ids = object_ids.data();
    }
    sorted_keys.reserve(cap);
    sorted_ids.reserve(cap);
    control.reserve(std::max<std::size_t>(n, 1));
    if (skin > 0) build_positions.reserve(std::max<std::size_t>(n * std::size_t(g.dim), 1));
    if (tiled) tile_start.reserve(max_cells + 1);
    // The fixed part of a list build, from here to the list's partition (build_pair_list), queued,
    // captured or replayed as a CUDA graph (cuda/build_graph.cuh): in fast memory with CUB's sort,
    // Jacobi slots and no audit. Its operations are queued only while graph.queuing().
    const bool graphed = o.build_graph.value_or(true) && listed && !lean &&
                         o.sort == SortMethod::kCub && o.accumulation == Accumulation::kJacobi && !o.reuse.audit &&
                         !o.list_count_masked.value_or(false) && n > 0;
    graph.begin(graphed ? build_key(o, g, ff, n) : cuda::BuildGraph::Key{}, graphed, stream,
                o.build_graph_audit.value_or(false));
    const bool queue = graph.queuing();
    if (queue) {
      // The cell-ID kernel also counts the valid entries (the counts zeroed before it) and, with a
      // skin, keeps the build's positions (change 80: no CUB reduction over the keys, no copy).
      cuda::build_cell_ids(g, pos, n, unsorted_keys, unsorted_ids, control.data(), stream, counts.data(),
                           skin > 0 ? build_positions.data() : nullptr);
      if (skin > 0 && o.reuse.audit) {  // before the sort (the chapter's may reuse the input); read after a sync
        download(build_keys, unsorted_keys, entries, stream);
        download(build_control, control.data(), n, stream);
      }
      stage_record(kCellIds);
      stage_record(kCounted);  // counted with the cell IDs
      switch (o.sort) {
        case SortMethod::kCub:
          cuda::radix_sort_cub(unsorted_keys, unsorted_ids, sorted_keys.data(), sorted_ids.data(), entries,
                               g.key_bits, cub, stream, loan);
          break;
        case SortMethod::kChapter:
          cuda::radix_sort_chapter(unsorted_keys, unsorted_ids, sorted_keys.data(), sorted_ids.data(), entries,
                                   g.key_bits, chapter_sort, stream);
          break;
      }
      stage_record(kSorted);
    }
    if ((lean || free_after_sort) && o.sort == SortMethod::kCub) {  // dead until the next build (the chapter's
      keys.release();                                               // sort may reuse them)
      object_ids.release();
      cub.release();
    }
    if (queue) {
      cuda::find_collision_cells(sorted_keys.data(), g.slab_bits, entries, run_bound, max_cells, counts.data(), cells,
                                 collision, stream, true);
      if (o.accumulation == Accumulation::kGaussSeidel)
        cuda::split_by_type(g, cells, max_cells, counts.data(), split, stream);
      if (tiled) cuda::tile_starts(cells.data(), counts.data()->cell_range, max_cells, tile_start.data(), cub, stream);
      stage_record(kCellsFound);
    }
    st.entries = entries;
    st.valid_entries = st.collision_cells = 0;  // on the device until read_counts()
  }

  // Words of a dead list's array (or the masks' room) lent to an unsorted array of `cap` entries:
  // whole 256-byte blocks (the keys' kernel stores 16 bytes at a time; CUB's scratch wants 256-byte
  // alignment).
  static std::size_t lent_words(std::size_t cap) { return (cap + 63) / 64 * 64; }

  // Whether evaluations walk pair lists (core/reuse.h states the condition).
  static bool lists(const GpuOptions& o, const Box& box, double cutoff) {
    return pair_lists_serve(o.reuse, o.accumulation, box, cutoff);
  }

  // What the list kernels read: the positions of this evaluation, the physics, the outputs.
  template <class Real, class Accum>
  cuda::ListArgs<Real, Accum> list_args(const Grid& g, const SystemView& sys, const ForceField& ff,
                                        const Request& req) {
    const std::size_t n = sys.n, dim = std::size_t(g.dim);
    upload_table<Real>(ff);
    if (!accumulate_flags && graph.queuing()) reset_flags();
    forces.reserve(std::max<std::size_t>(n * dim, 1));
    if (req.energy) energies.reserve(std::max<std::size_t>(n, 1));
    cuda::ListArgs<Real, Accum> la;
    la.grid = g;
    la.n = n;
    la.positions = pos;
    la.types = typ;
    la.num_types = uint32_t(ff.num_types());
    la.table = as<LJParams<Real>>(table);
    la.first = make_lj_params<Real>(ff.pair_sigma(0, 0), ff.pair_epsilon(0, 0), ff.cutoff, ff.mode);
    la.rc2 = Real(ff.cutoff) * Real(ff.cutoff);
    la.forces = forces.data();
    la.energies = req.energy ? energies.data() : nullptr;
    la.flags = flags.data();
    return la;
  }

  // The list of the structure just built, from the positions it was built from (the ones the
  // displacement check measures against): part of every build, whoever asked for it (an
  // evaluation, the pair recorder, a restored structure).
  template <class Real, class Accum>
  void build_list(const GpuOptions& o, const Grid& g, const SystemView& sys, const ForceField& ff) {
    const cuda::ListArgs<Real, Accum> la = list_args<Real, Accum>(g, sys, ff, Request{false, false});
    // Lean: the cells without a staged array of their own (n x 2^d x 32 bytes less: the fill stages
    // each occupant as it loads it, the count pass too unless the last list's array holds them,
    // below); otherwise staged once, which the build's two passes read faster.
    const cuda::TraversalArgs<Real, Accum> cell_args =
        lean ? traversal_args<Real, Accum>(g, sys, ff, ff.mode) : prepare<Real, Accum>(g, sys, ff, ff.mode);
    // Lean, with the last list's array kept (build): its room holds the occupants staged for the
    // count pass, which the fill then writes over (change 70; the fill stages as it loads).
    const cuda::StagedEntry<Real>* count_staged = nullptr;
    if (lean && list.neighbors.capacity() * sizeof(uint32_t) >= entries * sizeof(cuda::StagedEntry<Real>)) {
      auto* into = reinterpret_cast<cuda::StagedEntry<Real>*>(list.neighbors.data());
      cuda::stage_occupants<Real>(g, sorted_keys.data(), sorted_ids.data(), entries, &counts.data()->valid, pos, typ,
                                  uint32_t(ff.num_types()), control.data(), into, stream);
      count_staged = into;
    }
    list.forced_splits = o.list_splits.value_or(0);
    // Lean builds keep masks only while the list's array is kept (lend): otherwise it is freed and
    // taken again at every build, and the masks would give way to it every time.
    list.use_masks = o.list_masks.value_or(true) && !(lean && !lend);
    list.mask_limit = o.list_mask_words.value_or(0);
    list.count_masked_units = o.list_count_masked.value_or(false);
    // What this engine may still take after a lean build, which the masks' room leaves free: the
    // positions the evaluations gather (up to 32 bytes a particle) and the energies, until it has them.
    const std::size_t n = sys.n;
    const bool gathered = list.fixed.capacity() >= n || list.ranked.capacity() >= n;
    list.later_bytes =
        lean ? (gathered ? 0 : n * sizeof(cuda::RankedParticle)) + (energies.capacity() >= n ? 0 : n * sizeof(double))
             : 0;
    list.forced_threads = o.list_threads.value_or(0);
    list.forced_block = o.list_block.value_or(0);
    // The build's fixed part ends before the count pass (cuda/build_graph.cuh).
    const cuda::ListBuildHead head{graph.queuing(), [&] {
                                     if (graph.open()) graph.end(build_key(o, g, ff, n), stream);
                                   }};
    list_usable = cuda::build_pair_list<Real, Accum>(cell_args, sorted_keys.data(), control.data(), entries,
                                                     ff.cutoff + o.reuse.skin, la, list, stream, count_staged, head);
    if (!list_usable) list.ranked_forces.release();  // no gated evaluations: the cells serve
    list_built_for = builds;
  }

  // The list path of one evaluation: the listed pairs at this evaluation's positions. Returns false
  // when the structure has no list (it could not be built: the cells then serve it).
  template <class Real, class Accum>
  bool evaluate_lists(const Grid& g, const SystemView& sys, const ForceField& ff, const Request& req) {
    if (list_built_for != builds)  // every build makes its list (GpuEngine::build): a bug otherwise
      throw Error("internal error: the pair list does not belong to the structure in use");
    if (!list_usable || sys.n == 0) return false;  // the cells serve it (and an empty system)
    const bool observables = list_forces<Real, Accum>(g, sys, ff, req, cuda::GateView{});
    record(kTraversed);
    if (observables) {
      totals.reserve(cuda::kCellSums);
      cuda::sum_cells<Accum>(as<Accum>(list.block_sums), list.blocks.data(), totals.data(), stream);
    }
    record(kAccumulated);
    return true;
  }

  // The listed pairs' kernels at this evaluation's positions (behind `gate` when it has one: the
  // step gate's evaluations, GpuEngine::evaluate_gated). Returns whether energy and virial were asked.
  template <class Real, class Accum>
  bool list_forces(const Grid& g, const SystemView& sys, const ForceField& ff, const Request& req,
                   const cuda::GateView& gate, const cuda::NextKickDrift* then = nullptr) {
    const cuda::ListArgs<Real, Accum> la = list_args<Real, Accum>(g, sys, ff, req);
    cuda::Switches sw;
    sw.dim = g.dim;
    sw.multi_type = ff.num_types() > 1;
    sw.mode = ff.mode;
    sw.observables = req.energy || req.virial;
    cuda::list_forces<Real, Accum>(sw, la, list, stream, gate, gate.gate && !lean, then);  // rank_order()'s rule
    return sw.observables;
  }

  // Where the gated drifts place the positions for the list in use, and where its gated
  // evaluations leave the forces: in rank order unless the build is lean (24 bytes a particle
  // more) (GpuEngine::rank_order).
  template <class Real, class Accum>
  cuda::RankOrder rank_order(const Grid& g, const SystemView& sys, const ForceField& ff, bool fused) {
    list.fused_block = 0;  // a gated chunk begins: its fused force kernels, if any, set it
    return cuda::rank_order<Real, Accum>(list_args<Real, Accum>(g, sys, ff, Request{false, false}), list, !lean,
                                         fused && !lean);
  }

  // Every particle's list partners (user indices, list order), downloaded: the list audit's input.
  std::vector<std::vector<uint32_t>> list_partners(std::size_t n) {
    std::vector<uint32_t> rank_order, lengths, entries_of;
    std::vector<unsigned long long> rows;
    download(rank_order, list.order.data(), n, stream);
    download(lengths, list.length.data(), n, stream);
    download(rows, list.group_chunks.data(), (n + cuda::kGroup - 1) / cuda::kGroup + 1, stream);
    download(entries_of, list.neighbors.data(), list.slots, stream);
    CF_CUDA_CHECK(cudaStreamSynchronize(stream));
    std::vector<std::vector<uint32_t>> partners(n);
    for (std::size_t p = 0; p < n; ++p) {
      std::vector<uint32_t>& mine = partners[rank_order[p]];
      for (uint32_t k = 0; k < lengths[p]; ++k)
        mine.push_back(rank_order[entries_of[cuda::list_entry(rows[p / cuda::kGroup], p, k)]]);
    }
    return partners;
  }

  // A reused structure: the stage events recorded back to back (zero stage times).
  void skip_build() {
    record(kCellIds);
    record(kCounted);
    record(kSorted);
    record(kCellsFound);
  }

  // The arguments shared by the force and pair-recording kernels; stages the occupants.
  template <class Real, class Accum>
  cuda::TraversalArgs<Real, Accum> prepare(const Grid& g, const SystemView& sys,
                                           const ForceField& ff, CutoffMode mode) {
    staged.reserve(std::max<std::size_t>(entries, 1) * sizeof(cuda::StagedEntry<Real>));
    if (graph.queuing())
      cuda::stage_occupants<Real>(g, sorted_keys.data(), sorted_ids.data(), entries, &counts.data()->valid, pos,
                                  typ, uint32_t(ff.num_types()), control.data(), as<cuda::StagedEntry<Real>>(staged),
                                  stream);
    cuda::TraversalArgs<Real, Accum> args = traversal_args<Real, Accum>(g, sys, ff, mode);
    args.staged = as<cuda::StagedEntry<Real>>(staged);
    return args;
  }

  // The same arguments without staging (args.staged null).
  template <class Real, class Accum>
  cuda::TraversalArgs<Real, Accum> traversal_args(const Grid& g, const SystemView& sys, const ForceField& ff,
                                                  CutoffMode mode) {
    ForceField f = ff;
    f.mode = mode;
    upload_table<Real>(f);
    cuda::TraversalArgs<Real, Accum> args;
    args.grid = g;
    args.cells = cells.data();
    args.cell_range = counts.data()->cell_range;
    args.max_cells = uint32_t(max_cells);
    args.tile_start = tile_start.data();
    args.max_tiles = uint32_t(cuda::max_tiles(entries, max_cells));
    args.sorted_ids = sorted_ids.data();
    args.n = sys.n;
    args.multiprocessors = multiprocessors;
    args.table = as<LJParams<Real>>(table);
    args.num_types = uint32_t(ff.num_types());
    args.rc2 = Real(ff.cutoff) * Real(ff.cutoff);
    wrap_lengths(g, args.length, args.inv_length);  // core/cell_totals.h
    if (!accumulate_flags && graph.queuing()) reset_flags();
    args.flags = flags.data();
    return args;
  }

  // Returns whether the pair lists served (else the cells did).
  template <class Real, class Accum>
  bool traverse_and_sum(const GpuOptions& o, const Grid& g, const SystemView& sys,
                        const ForceField& ff, const Request& req) {
    if (lists(o, sys.box, ff.cutoff) && evaluate_lists<Real, Accum>(g, sys, ff, req)) return true;
    const bool gs = o.accumulation == Accumulation::kGaussSeidel;
    const bool observables = req.energy || req.virial;
    const std::size_t n = sys.n, dim = std::size_t(g.dim);
    const int copies = gs ? 1 : g.num_types();
    // Energy and virial sums per collision cell, or per row tile for the tile form.
    const bool tiles = form == TraversalForm::kWarpPerTile;
    const std::size_t sums = tiles ? cuda::max_tiles(entries, max_cells) : max_cells;
    cuda::TraversalArgs<Real, Accum> args = prepare<Real, Accum>(g, sys, ff, ff.mode);

    force_slots.reserve(std::max<std::size_t>(copies * n * dim, 1) * sizeof(Accum));
    CF_CUDA_CHECK(cudaMemsetAsync(force_slots.data(), 0, copies * n * dim * sizeof(Accum), stream));
    args.force = as<Accum>(force_slots);
    args.force_slot_stride = gs ? 0 : n * dim;
    if (observables) {
      energy_slots.reserve(std::max<std::size_t>(copies * n, 1) * sizeof(Accum));
      CF_CUDA_CHECK(cudaMemsetAsync(energy_slots.data(), 0, copies * n * sizeof(Accum), stream));
      cell_sums.reserve(std::max<std::size_t>(sums, 1) * cuda::kCellSums * sizeof(Accum));
      args.energy = as<Accum>(energy_slots);
      args.energy_slot_stride = gs ? 0 : n;
      args.cell_sums = as<Accum>(cell_sums);
    }
    cuda::Switches sw;
    sw.dim = g.dim;
    sw.wrap = g.any_wrap_inside_cell();
    sw.multi_type = ff.num_types() > 1;
    sw.mode = ff.mode;
    sw.observables = observables;
    if (!gs) {
      cuda::traverse(form, sw, args, stream);
    } else {
      for (int t = 0; t < g.num_types(); ++t) {  // one pass per cell type, in type order
        args.cell_range = counts.data()->type_start + t;
        cuda::traverse(form, sw, args, stream);
      }
    }
    record(kTraversed);

    forces.reserve(std::max<std::size_t>(n * dim, 1));
    if (req.energy) energies.reserve(std::max<std::size_t>(n, 1));
    cuda::sum_slots<Accum>(as<Accum>(force_slots), req.energy ? as<Accum>(energy_slots) : nullptr,
                           g.dim, n, copies, forces.data(), req.energy ? energies.data() : nullptr,
                           stream);
    if (observables) {
      totals.reserve(cuda::kCellSums);
      cuda::sum_cells<Accum>(as<Accum>(cell_sums), tiles ? tile_start.data() + max_cells : &counts.data()->cell_range[1],
                             totals.data(), stream);
    }
    record(kAccumulated);
    return false;
  }
};

namespace {

// What the CUDA pipeline can hold, checked before anything runs (host and resident paths).
void check_capacity(const SystemView& system, const ForceField& ff) {
  if (ff.num_types() > cuda::kMaxStagedTypes)
    throw Error("the CUDA engine supports at most " + std::to_string(cuda::kMaxStagedTypes) +
                " particle types; the force field has " + std::to_string(ff.num_types()));
  const std::size_t entries = system.n << system.box.dim;
  if (entries > std::size_t(INT32_MAX))
    throw Error("the CUDA engine takes at most 2^31 - 1 cell-ID entries (N x 2^d): " +
                std::to_string(system.n) + " particles in " + std::to_string(system.box.dim) +
                "D make " + std::to_string(entries));
}

}  // namespace

GpuEngine::GpuEngine(GpuOptions options)
    : options_(std::move(options)), reuse_(options_.reuse), impl_(std::make_unique<Impl>()) {
  validate_reuse(options_.reuse);
  if (const std::optional<int> t = options_.list_threads; t && *t != 1 && *t != 2 && *t != 4 && *t != 8)
    throw Error("CUDA engine: list_threads must be 1, 2, 4 or 8 threads per particle, not " + std::to_string(*t));
  if (const std::optional<int> b = options_.list_block; b && *b != 128 && *b != 256)
    throw Error("CUDA engine: list_block must be 128 or 256 threads a block, not " + std::to_string(*b));
  const std::string why = unavailable();
  if (!why.empty()) throw DeviceError("CUDA engine: " + why);
  int count = 0;
  CF_CUDA_CHECK(cudaGetDeviceCount(&count));
  if (options_.device < 0 || options_.device >= count)
    throw DeviceError("CUDA engine: device " + std::to_string(options_.device) + " does not exist (" +
                std::to_string(count) + " device(s))");
  const DeviceScope scope(options_.device);
  CF_CUDA_CHECK(cudaStreamCreateWithFlags(&impl_->stream, cudaStreamNonBlocking));
  CF_CUDA_CHECK(cudaDeviceGetAttribute(&impl_->multiprocessors, cudaDevAttrMultiProcessorCount,
                                       options_.device));
  int major = 0;
  CF_CUDA_CHECK(cudaDeviceGetAttribute(&major, cudaDevAttrComputeCapabilityMajor, options_.device));
  impl_->list.dependent_launch = major >= 9;
  for (cudaEvent_t& e : impl_->events) CF_CUDA_CHECK(cudaEventCreate(&e));
  CF_CUDA_CHECK(cudaEventCreateWithFlags(&impl_->joined, cudaEventDisableTiming));
  CF_CUDA_CHECK(cudaEventCreateWithFlags(&impl_->finished, cudaEventDisableTiming));
  CF_CUDA_CHECK(cudaEventCreateWithFlags(&impl_->table_copied, cudaEventDisableTiming));
  impl_->for_each_buffer([&](const char*, auto& buffer) { buffer.bind(impl_->stream); });
}

GpuEngine::~GpuEngine() {
  try {
    const DeviceScope scope(options_.device);  // the buffers are freed on their own device
    impl_.reset();
  } catch (...) {
    impl_.reset();  // a destructor cannot throw
  }
}

// Traversal and accumulation in the engine's precision, then the kernels' flags (read after a
// synchronisation): on an error the caller's result is left as it was (as the CPU engine does).
void GpuEngine::traverse(const SystemView& system, const ForceField& ff, const Request& request, bool read_flags) {
  Impl& s = *impl_;
  const Grid& g = stats_.grid;
  switch (options_.precision) {
    case Precision::kSingle: stats_.listed = s.traverse_and_sum<float, float>(options_, g, system, ff, request); break;
    case Precision::kMixed: stats_.listed = s.traverse_and_sum<float, double>(options_, g, system, ff, request); break;
    case Precision::kDouble:
      stats_.listed = s.traverse_and_sum<double, double>(options_, g, system, ff, request);
      break;
  }
  if (!read_flags) return;
  cuda::DeviceFlags flags{};
  CF_CUDA_CHECK(cudaMemcpyAsync(&flags, s.flags.data(), sizeof(flags), cudaMemcpyDeviceToHost, s.stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  s.throw_flags(flags, system, ff, options_.precision);
}

void GpuEngine::evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                         ForceResult& result) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  s.per_call_flags();
  prepare(system, ff);
  traverse(system, ff, request);
  const Grid& g = stats_.grid;

  const std::size_t n = system.n, dim = std::size_t(g.dim);
  result.dim = g.dim;
  download(result.forces, s.forces.data(), n * dim, s.stream);
  download(result.energies, s.energies.data(), request.energy ? n : 0, s.stream);
  double totals[cuda::kCellSums] = {};
  if (request.energy || request.virial)
    CF_CUDA_CHECK(cudaMemcpyAsync(totals, s.totals.data(), sizeof(totals), cudaMemcpyDeviceToHost, s.stream));
  s.record(kDownloaded);
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));

  result.energy = request.energy ? totals[0] : 0.0;
  const double no_virial[6] = {};
  set_virial(result, g.dim, request.virial ? totals + 1 : no_virial);

  finish_timing();
  s.read_counts(stats_);
  audit(system, ff);  // after the total: its host search is no part of the engine's time
}

void GpuEngine::evaluate_device(const DeviceSystemView& dsys, const ForceField& ff,
                                const DeviceOutputs& out, void* stream) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  if (dsys.n > 0 && (!dsys.positions || !out.forces))
    throw Error(std::string(dsys.positions ? "forces" : "positions") + " is a null pointer (" +
                std::to_string(dsys.n) + " particles)");
  // Every pointer must be one the device can use: a host pointer here would fault the context.
  const std::pair<const void*, const char*> pointers[] = {{dsys.positions, "positions"}, {dsys.types, "types"},
                                                          {out.forces, "forces"}, {out.energies, "energies"},
                                                          {out.energy, "energy"}, {out.virial, "virial"}};
  for (const auto& [p, what] : pointers) {
    if (!p || (dsys.n == 0 && (p == dsys.positions || p == dsys.types || p == out.forces || p == out.energies)))
      continue;
    cudaPointerAttributes attributes{};
    const cudaError_t err = cudaPointerGetAttributes(&attributes, p);
    if (err != cudaSuccess) (void)cudaGetLastError();
    if (err != cudaSuccess || attributes.type == cudaMemoryTypeUnregistered ||
        (attributes.type == cudaMemoryTypeHost && attributes.devicePointer == nullptr))
      throw Error(std::string(what) + " is not a device pointer (compute_device takes device arrays; use "
                  "compute for host arrays)");
  }
  // What can be checked without the arrays: the box, the force field, the capacity.
  const std::size_t n = dsys.n, dim = std::size_t(dsys.box.dim);
  const SystemView system{dsys.box, n, nullptr, nullptr};  // no host arrays: nothing reads them
  validate_physics(dsys.box, ff, n);
  check_capacity(system, ff);

  const auto caller = static_cast<cudaStream_t>(stream);
  CF_CUDA_CHECK(cudaEventRecord(s.joined, caller));  // the engine starts after the caller's work
  CF_CUDA_CHECK(cudaStreamWaitEvent(s.stream, s.joined, 0));
  if (!s.accumulate_flags) {  // flags accumulate until synchronize()
    s.reset_flags();
    s.accumulate_flags = true;
  }
  // The arrays are checked on the device; what it finds is raised by synchronize().
  cuda::check_input(dsys.positions, dsys.types, n, int(dim), uint32_t(ff.num_types()), s.flags.data(), s.stream);
  s.plan_from_corners = true;
  s.corner_count = 0;
  prepare_resident(system, ff, dsys);
  const Request request{out.energies || out.energy, out.virial != nullptr};
  traverse(system, ff, request, false);
  if (n) {
    CF_CUDA_CHECK(cudaMemcpyAsync(out.forces, s.forces.data(), n * dim * sizeof(double),
                                  cudaMemcpyDeviceToDevice, s.stream));
    if (out.energies)
      CF_CUDA_CHECK(cudaMemcpyAsync(out.energies, s.energies.data(), n * sizeof(double),
                                    cudaMemcpyDeviceToDevice, s.stream));
  }
  if (request.energy || request.virial)  // sum_cells wrote the totals (zeros for no cells)
    cuda::write_totals(s.totals.data(), int(dim), out.energy, out.virial, s.stream);
  s.record(kDownloaded);
  CF_CUDA_CHECK(cudaEventRecord(s.finished, s.stream));
  CF_CUDA_CHECK(cudaStreamWaitEvent(caller, s.finished, 0));
  if (options_.reuse.audit && !stats_.rebuilt) {  // diagnostics: the positions come to the host
    std::vector<double> host_positions;
    std::vector<uint32_t> host_types;
    download(host_positions, dsys.positions, n * dim, s.stream);
    if (dsys.types) download(host_types, dsys.types, n, s.stream);
    CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
    audit(SystemView{dsys.box, n, host_positions.data(), dsys.types ? host_types.data() : nullptr}, ff);
  }
}

void GpuEngine::synchronize(const ForceField& ff) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  if (!s.accumulate_flags) return;
  cuda::DeviceFlags flags{};
  CF_CUDA_CHECK(cudaMemcpyAsync(&flags, s.flags.data(), sizeof(flags), cudaMemcpyDeviceToHost, s.stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  s.accumulate_flags = false;
  s.plan_from_corners = false;
  finish_timing();
  s.read_counts(stats_);
  s.throw_flags(flags, SystemView{}, ff, options_.precision);
}

void GpuEngine::evaluate_resident(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                                  const ForceField& ff, const Request& request, std::optional<double> known_d2,
                                  bool time_stages) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  s.timing = time_stages;
  struct TimedAgain {  // every other evaluation records its stage events, whatever this one throws
    Impl& s;
    ~TimedAgain() { s.timing = true; }
  } timed_again{s};
  if (!s.accumulate_flags) {  // the first resident evaluation: flags from here on accumulate
    s.reset_flags();
    s.accumulate_flags = true;
  }
  const SystemView system{box, n, nullptr, nullptr};  // no host arrays: nothing reads them
  const DeviceSystemView on_device{box, n, positions, types};
  s.plan_from_corners = true;
  s.corner_count = 0;
  prepare_resident(system, ff, on_device, known_d2);
  traverse(system, ff, request, false);
  s.record(kDownloaded);
  if (options_.reuse.audit && !stats_.rebuilt) {  // diagnostics: the positions come to the host
    std::vector<double> host_positions;
    std::vector<uint32_t> host_types;
    download(host_positions, positions, n * std::size_t(box.dim), s.stream);
    if (types) download(host_types, types, n, s.stream);
    CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
    audit(SystemView{box, n, host_positions.data(), types ? host_types.data() : nullptr}, ff);
  }
}

void GpuEngine::check_flags(const Box& box, std::size_t n, const double* positions, const ForceField& ff) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  if (!s.accumulate_flags) return;
  cuda::DeviceFlags flags{};
  CF_CUDA_CHECK(cudaMemcpyAsync(&flags, s.flags.data(), sizeof(flags), cudaMemcpyDeviceToHost, s.stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  s.reset_flags();
  if (!flags.impossible && flags.bad_pair == ~0ull) return;
  // The error path only: the positions come to the host for the message.
  std::vector<double> host;
  download(host, positions, n * std::size_t(box.dim), s.stream);
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  s.throw_flags(flags, SystemView{box, n, host.data(), nullptr}, ff, options_.precision);
}

int64_t GpuEngine::gate_steps(const Box& box, std::size_t n, const ForceField& ff) const {
  const Impl& s = *impl_;
  const ReuseOptions& r = options_.reuse;
  if (n == 0 || !r.check || r.audit || !Impl::lists(options_, box, ff.cutoff)) return 0;
  if (!s.list_usable || s.list_built_for != s.builds || !s.accumulate_flags) return 0;
  if (reuse_.must_rebuild(SystemView{box, n, nullptr, nullptr}, ff.cutoff)) return 0;
  return reuse_.remaining();
}

unsigned long long GpuEngine::gate_limit() const {
  const double limit = reuse_.limit2();
  unsigned long long bits = 0;
  std::memcpy(&bits, &limit, sizeof bits);
  return bits;
}

const double* GpuEngine::device_build_positions() const { return impl_->build_positions.data(); }

cuda::RankOrder GpuEngine::rank_order(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                                      const ForceField& ff, bool fused) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  if (!s.list_usable || s.list_built_for != s.builds)
    throw Error("internal error: rank_order() without the pair list of the structure in use");
  s.borrow(positions, types);
  const SystemView system{box, n, nullptr, nullptr};
  const Grid& g = stats_.grid;
  switch (options_.precision) {
    case Precision::kSingle: return s.rank_order<float, float>(g, system, ff, fused);
    case Precision::kMixed: return s.rank_order<float, double>(g, system, ff, fused);
    case Precision::kDouble: break;
  }
  return s.rank_order<double, double>(g, system, ff, fused);
}

void GpuEngine::unrank_forces(std::size_t n) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  if (s.lean) return;  // lean gated evaluations stored in the caller's order (rank_order)
  cuda::unrank_forces(s.list, n, stats_.grid.dim, s.forces.data(), s.stream);
}

void GpuEngine::evaluate_gated(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                               const ForceField& ff, const cuda::GateView& gate, const cuda::NextKickDrift* then) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  const SystemView system{box, n, nullptr, nullptr};
  s.borrow(positions, types);  // no timing events: the gated evaluations are not timed by stage
  const Grid& g = stats_.grid;
  const Request forces_only{false, false};
  switch (options_.precision) {
    case Precision::kSingle: s.list_forces<float, float>(g, system, ff, forces_only, gate, then); break;
    case Precision::kMixed: s.list_forces<float, double>(g, system, ff, forces_only, gate, then); break;
    case Precision::kDouble: s.list_forces<double, double>(g, system, ff, forces_only, gate, then); break;
  }
}

void GpuEngine::settle_gate(int64_t served, double served_d2) {
  if (served <= 0) return;
  reuse_.reused(served);
  stats_.rebuilt = false;
  stats_.listed = true;  // the gated evaluations walk the lists
  stats_.dangerous_build = false;
  stats_.max_displacement = std::sqrt(served_d2);
  stats_.missed_pairs = stats_.repeated_pairs = 0;
  stats_.builds = reuse_.builds();
  stats_.list_block = impl_->list.fused_block;  // 0: the chunk ran no such kernel
}

const double* GpuEngine::device_forces() const { return impl_->forces.data(); }
std::size_t GpuEngine::listed_pairs() const {
  const Impl& s = *impl_;
  return s.list_usable && s.list_built_for == s.builds ? s.list.pairs : 0;
}
std::vector<std::pair<const char*, std::size_t>> GpuEngine::buffers() const { return impl_->buffers(); }
std::size_t GpuEngine::list_masked_fills() const { return impl_->list.masked_fills; }
std::size_t GpuEngine::list_partly_masked_fills() const { return impl_->list.partly_masked_fills; }
std::size_t GpuEngine::list_masked_units() const { return impl_->list.masked_units; }
std::size_t GpuEngine::list_staged_counts() const { return impl_->list.staged_counts; }
std::size_t GpuEngine::build_replays() const { return impl_->graph.replays(); }
std::size_t GpuEngine::build_captures() const { return impl_->graph.captures(); }
const double* GpuEngine::device_totals() const { return impl_->totals.data(); }
void* GpuEngine::stream() const { return impl_->stream; }
void GpuEngine::collect_timing() {
  const DeviceScope scope(options_.device);
  if (impl_->timed_events) CF_CUDA_CHECK(cudaEventSynchronize(impl_->events[kDownloaded]));
  else CF_CUDA_CHECK(cudaStreamSynchronize(impl_->stream));
  finish_timing();
  impl_->read_counts(stats_);
}

// The stage times of the evaluation whose events were recorded last (synchronised).
void GpuEngine::finish_timing() {
  Impl& s = *impl_;
  // Pair counts come from count_pairs()/visited_pairs(), not from the force kernels.
  stats_.candidate_pairs = stats_.interacting_pairs = stats_.max_occupancy = 0;
  // The last timed evaluation's (none: zeros, its events never recorded).
  auto seconds = [&](Event from, Event to) { return s.timed_events ? s.seconds(from, to) : 0.0; };
  stats_.t_transfer = seconds(kStart, kUploaded) + seconds(kAccumulated, kDownloaded);
  stats_.t_check = seconds(kUploaded, kChecked);
  stats_.t_cell_ids = seconds(kChecked, kCellIds);
  stats_.t_count = seconds(kCellIds, kCounted);
  stats_.t_sort = seconds(kCounted, kSorted);
  stats_.t_collision_cells = seconds(kSorted, kCellsFound);
  stats_.t_traversal = seconds(kCellsFound, kTraversed);
  stats_.t_accumulate = seconds(kTraversed, kAccumulated);
  stats_.t_total = seconds(kStart, kDownloaded);
  stats_.buffer_bytes = s.bytes();
  stats_.list_pairs = listed_pairs();
  stats_.list_slots = stats_.list_pairs ? s.list.slots : 0;
  stats_.list_mask_words = stats_.list_pairs ? s.list.mask_words : 0;
  stats_.list_mask_words_held = stats_.list_pairs ? s.list.mask_words_held : 0;
}


// Validates the input, uploads it, then rebuilds the structure (stages 1-3) or keeps the last
// one: shared by evaluate() and the pair recorder.
void GpuEngine::prepare(const SystemView& system, const ForceField& ff, const DeviceSystemView* on_device) {
  Impl& s = *impl_;
  validate_system(system, ff);
  check_capacity(system, ff);
  s.upload_system(system, on_device);
  const bool rebuild = reuse_.decide(system, ff.cutoff, [&] {
    return cuda::max_displacement2(system.box, s.pos, s.build_positions.data(), system.n, s.cub,
                                   s.stream);
  }, stats_);
  s.record(kChecked);
  if (rebuild) {
    build(system, ff);
  } else {
    s.skip_build();
    reuse_.reused();
  }
  stats_.builds = reuse_.builds();
}

// prepare() for resident evaluations: the caller validated the arrays (at the start of its run;
// drifts are checked on the device), so nothing here reads them on the host.
void GpuEngine::prepare_resident(const SystemView& system, const ForceField& ff, const DeviceSystemView& on_device,
                                 std::optional<double> known_d2) {
  Impl& s = *impl_;
  check_capacity(system, ff);
  s.upload_system(system, &on_device);
  const bool rebuild = reuse_.decide(system, ff.cutoff, [&] {
    return known_d2 ? *known_d2
                    : cuda::max_displacement2(system.box, s.pos, s.build_positions.data(), system.n, s.cub, s.stream);
  }, stats_);
  s.record(kChecked);
  if (rebuild) {
    plan_corners(system.box, system.n, on_device.positions);
    build(system, ff);
  } else {
    s.skip_build();
    reuse_.reused();
  }
  stats_.builds = reuse_.builds();
}

// The grid of an open axis spans the particles: their bounds, read back (2 x dim numbers) only for
// a build; periodic axes need none.
void GpuEngine::plan_corners(const Box& box, std::size_t n, const double* positions) {
  Impl& s = *impl_;
  s.corner_count = 0;
  bool open = false;
  for (int a = 0; a < box.dim; ++a) open = open || !box.periodic[a];
  if (!open) return;
  double lo[kMaxDim], hi[kMaxDim];
  cuda::bounding_box(positions, n, box.dim, lo, hi, s.cub, s.stream);
  bool finite = true;
  for (int a = 0; a < box.dim; ++a) {
    s.corners[a] = lo[a];
    s.corners[box.dim + a] = hi[a];
    finite = finite && std::isfinite(lo[a]) && std::isfinite(hi[a]);
  }
  // A drift that diverged this step: plan one cell (the kernels clamp what they bin) and let the
  // caller's flag check name the particle.
  s.corner_count = n && finite ? 2 : 0;
}

// Stages 1-3 on the uploaded positions, the policy invalid until they complete.
void GpuEngine::build(const SystemView& system, const ForceField& ff) {
  reuse_.invalidate();
  Impl& s = *impl_;
  const bool lists = Impl::lists(options_, system.box, ff.cutoff);
  const std::size_t replays = s.graph.replays();
  stats_.graph_build = false;
  // Stages 1-3, then the list in the engine's precision; the pair table first, before the build's
  // fixed part, whose graph holds no copy of it.
  auto stages = [&](auto real, auto accum) {
    using Real = decltype(real);
    using Accum = decltype(accum);
    if (lists) s.upload_table<Real>(ff);
    s.build(options_, stats_, system, ff);
    if (lists) s.build_list<Real, Accum>(options_, stats_.grid, system, ff);
  };
  try {
    switch (options_.precision) {
      case Precision::kSingle: stages(float{}, float{}); break;
      case Precision::kMixed: stages(float{}, double{}); break;
      case Precision::kDouble: stages(double{}, double{}); break;
    }
    if (s.graph.open()) throw Error("internal error: the build's fixed part did not end");
    stats_.graph_build = s.graph.replays() > replays;
  } catch (...) {
    s.graph.abandon(s.stream);
    throw;
  }
  reuse_.built(system, ff.cutoff);
}

ReuseState GpuEngine::reuse_state() const {
  if (reuse_.served() == 0) return {};
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  ReuseState state;
  state.served = reuse_.served();
  download(state.build_positions, s.build_positions.data(), reuse_.particles() * std::size_t(stats_.grid.dim),
           s.stream);
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  return state;
}

void GpuEngine::restore_reuse(const SystemView& built_from, const ForceField& ff, int64_t served) {
  if (!reuse_.enabled()) return;
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  s.plan_from_corners = false;  // the grid from these host positions
  validate_system(built_from, ff);
  s.upload_system(built_from);
  s.record(kChecked);
  build(built_from, ff);
  reuse_.set_served(served);
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
}

// The audit of a reused structure: pairs closer than rc now that it misses or repeats: the pair
// lists when they served this evaluation, else the cells.
void GpuEngine::audit(const SystemView& system, const ForceField& ff) {
  if (!options_.reuse.audit || stats_.rebuilt) return;
  const auto pairs = pairs_within(system, ff.cutoff);
  const ReuseAudit a = stats_.listed ? audit_lists(impl_->list_partners(system.n), pairs)
                                     : audit_reuse(stats_.grid, impl_->build_keys.data(),
                                                   impl_->build_control.data(), system, ff.cutoff, pairs);
  stats_.missed_pairs = a.missed;
  stats_.repeated_pairs = a.repeated;
}

// Runs the pair recorder; with `keep` the pairs are stored (the buffer grows to the count the
// kernel reports and the kernel reruns), without it only counted.
std::vector<std::pair<uint32_t, uint32_t>> GpuEngine::record(const SystemView& system,
                                                             const ForceField& ff, bool keep) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  s.per_call_flags();
  prepare(system, ff);
  const Grid& g = stats_.grid;
  cuda::TraversalArgs<double, double> args =
      s.prepare<double, double>(g, system, ff, CutoffMode::kTruncate);
  s.read_counts(stats_);
  cuda::DeviceFlags flags{};
  for (;;) {
    if (keep) {
      s.pairs.reserve(std::max<std::size_t>(stats_.valid_entries * 8, 1024));
      args.pairs = s.pairs.data();
      args.pair_capacity = s.pairs.capacity();
    }
    cuda::record_pairs(s.form, g.dim, g.any_wrap_inside_cell(), args, s.stream);
    CF_CUDA_CHECK(cudaMemcpyAsync(&flags, s.flags.data(), sizeof(flags), cudaMemcpyDeviceToHost, s.stream));
    CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
    if (flags.impossible)
      throw Error("CUDA engine: the pair recorder met a particle index out of range (an internal error)");
    if (!keep || flags.recorded <= s.pairs.capacity()) break;
    s.pairs.reserve(std::size_t(flags.recorded));
    s.reset_flags();
  }
  std::vector<uint2> raw;
  if (keep) download(raw, s.pairs.data(), std::size_t(flags.recorded), s.stream);
  std::vector<CollisionCell> cells;
  download(cells, s.cells.data(), stats_.collision_cells, s.stream);
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  stats_.candidate_pairs = std::size_t(flags.candidates);
  stats_.interacting_pairs = std::size_t(flags.interacting);
  stats_.max_occupancy = 0;
  for (const CollisionCell& c : cells)
    stats_.max_occupancy = std::max<std::size_t>(stats_.max_occupancy, std::size_t(c.h) + c.p);
  // Stage times belong to evaluate().
  stats_.t_cell_ids = stats_.t_count = stats_.t_sort = stats_.t_collision_cells = 0;
  stats_.t_traversal = stats_.t_accumulate = stats_.t_transfer = stats_.t_total = stats_.t_check = 0;
  audit(system, ff);
  std::vector<std::pair<uint32_t, uint32_t>> pairs(raw.size());
  for (std::size_t k = 0; k < raw.size(); ++k) pairs[k] = {raw[k].x, raw[k].y};
  return pairs;
}

std::vector<std::pair<uint32_t, uint32_t>> GpuEngine::visited_pairs(const SystemView& system,
                                                                    const ForceField& ff) {
  return record(system, ff, true);
}

void GpuEngine::count_pairs(const SystemView& system, const ForceField& ff) {
  (void)record(system, ff, false);
}

TraversalForm GpuEngine::traversal() const {
  if (options_.traversal != TraversalForm::kAuto) return options_.traversal;
  return impl_->entries > 0 || stats_.builds > 0 ? impl_->form : TraversalForm::kAuto;  // auto: chosen at a build
}

std::string GpuEngine::device_name() const {
  cudaDeviceProp prop{};
  CF_CUDA_CHECK(cudaGetDeviceProperties(&prop, options_.device));
  return prop.name;
}

std::size_t GpuEngine::memory_bytes(int device) {
  // Never throws: a device that cannot be used is the engine's to report, when it is made. An
  // error one of these calls returns is cleared (a sticky one stays, for the engine to meet).
  auto ok = [](cudaError_t e) {
    if (e != cudaSuccess) (void)cudaGetLastError();
    return e == cudaSuccess;
  };
  int count = 0, previous = 0;
  if (!ok(cudaGetDeviceCount(&count)) || device < 0 || device >= count || !ok(cudaGetDevice(&previous))) return 0;
  std::size_t free_bytes = 0, total_bytes = 0;
  if (!ok(cudaSetDevice(device)) || !ok(cudaMemGetInfo(&free_bytes, &total_bytes))) total_bytes = 0;
  (void)ok(cudaSetDevice(previous));
  return total_bytes;
}

std::string GpuEngine::unavailable() {
  int count = 0;
  const cudaError_t err = cudaGetDeviceCount(&count);
  if (err != cudaSuccess) {
    (void)cudaGetLastError();  // clear the error this call left
    return std::string("no CUDA device: cudaGetDeviceCount failed with ") + cudaGetErrorName(err) +
           " (" + cudaGetErrorString(err) + ")";
  }
  if (count == 0) return "no CUDA device: cudaGetDeviceCount returned 0";
  return {};
}

}  // namespace cellforce
