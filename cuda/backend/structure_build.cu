// The neighbour structure's build (GpuEngine::Impl::build): stages 1-3 of the chapter's pipeline
// on the device (cell IDs with the valid count, the radix sort, the collision cells, and for the
// tile form and pair lists the cells' tile starts), with the memory each array takes decided by
// backend/memory_plan.h and the fixed part of a list build queued, captured or replayed as a CUDA
// graph (backend/build_graph.cuh). The list itself is built after it (backend/evaluation.cu).
#include "backend/engine_state.cuh"
#include "backend/memory_plan.h"
#include "core/error.h"

namespace cellforce {

void GpuEngine::Impl::build(const GpuOptions& o, PipelineStats& st, const SystemView& sys, const ForceField& ff,
                            bool listed) {
  plan_build_grid(o, st, sys, ff);
  const Grid& g = st.grid;
  const std::size_t n = sys.n;
  const std::size_t last_entries = entries;
  entries = n << g.dim;
  max_cells = std::min<std::size_t>(n, g.num_cells);
  counts.reserve(1);
  form = cuda::resolve_traversal(o.traversal, max_cells, multiprocessors);
  ++builds;
  const cuda::BuildMemoryPlan plan = plan_build_memory(o, listed, n, last_entries, g);
  // The unsorted keys and IDs: their own arrays, or a dead room's first words (the lean build's
  // last list, or the masks' room), the sort's scratch after them.
  const std::size_t cap = std::max<std::size_t>(entries, 1);
  uint32_t *unsorted_keys = nullptr, *unsorted_ids = nullptr;
  cuda::ScratchLoan loan;
  if (lend || plan.lend_masks) {
    uint32_t* room = lend ? list.neighbors.data() : list.masks.data();
    const std::size_t room_words = lend ? list.neighbors.capacity() : list.masks.capacity();
    if (plan.lend_masks && keys.capacity() > 0) cub.release();  // it held the sort's scratch: the room holds it now
    keys.release();
    object_ids.release();
    unsorted_keys = room;
    unsorted_ids = unsorted_keys + cuda::lent_words(cap);
    loan.data = reinterpret_cast<std::byte*>(unsorted_ids + cuda::lent_words(cap));
    loan.bytes = (room_words - 2 * cuda::lent_words(cap)) * sizeof(uint32_t);
  } else {
    keys.reserve(cap);
    object_ids.reserve(cap);
    unsorted_keys = keys.data();
    unsorted_ids = object_ids.data();
  }
  const bool tiled = form == TraversalForm::kWarpPerTile || listed;  // the cells' tiles, in final order
  sorted_keys.reserve(cap);
  sorted_ids.reserve(cap);
  control.reserve(std::max<std::size_t>(n, 1));
  if (o.reuse.skin > 0) build_positions.reserve(std::max<std::size_t>(n * std::size_t(g.dim), 1));
  if (tiled) tile_start.reserve(max_cells + 1);
  tiles_built = tiled;
  // The fixed part of a list build, from here to the list's partition (build_pair_list), queued,
  // captured or replayed as a CUDA graph (backend/build_graph.cuh). Its operations are queued only
  // while graph.queuing().
  if (!plain_build)
    graph.begin(plan.graphed ? build_key(o, g, ff, n) : cuda::BuildGraph::Key{}, plan.graphed, stream,
                o.test.build_graph_audit.value_or(false));
  if (graph.queuing()) queue_ids_and_sort(o, g, n, unsorted_keys, unsorted_ids, loan);
  if ((lean || plan.free_after_sort) && o.sort == SortMethod::kCub) {  // dead until the next build (the
    keys.release();                                                    // chapter's sort may reuse them)
    object_ids.release();
    cub.release();
  }
  if (graph.queuing()) {
    const std::size_t run_bound = std::min<std::size_t>(entries, g.num_cells);
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

void GpuEngine::Impl::plan_build_grid(const GpuOptions& o, PipelineStats& st, const SystemView& sys,
                                      const ForceField& ff) {
  const double skin = o.reuse.skin;
  if (o.test.grid_override) {
    st.grid = *o.test.grid_override;
  } else {
    GridOptions go = o.grid;
    go.slabs = lists(o, sys.box, ff.cutoff);  // the list's ranks by layer in a cell
    st.grid = plan_from_corners ? plan_grid(sys.box, ff.cutoff, corners, corner_count, go, skin)
                                : plan_grid(sys.box, ff.cutoff, sys.positions, sys.n, go, skin);
    check_grid(st.grid, sys.box, ff.cutoff, o.grid.rule, skin);
    check_staging(st.grid, ff.cutoff, o.precision, skin, o.grid.rule);
  }
  check_precision_range(ff, o.precision);
}

cuda::BuildMemoryPlan GpuEngine::Impl::plan_build_memory(const GpuOptions& o, bool listed, std::size_t n,
                                                         std::size_t last_entries, const Grid& g) {
  const bool cub_sort = o.sort == SortMethod::kCub;
  if (listed && device_bytes == 0) {  // asked once: cudaMemGetInfo holds the device idle
    std::size_t free_bytes = 0;
    CF_CUDA_CHECK(cudaMemGetInfo(&free_bytes, &device_bytes));
  }
  cuda::BuildMemoryInputs in;
  in.listed = listed;
  in.memory = o.memory;
  in.n = n;
  in.device_bytes = device_bytes;
  in.cub_sort = cub_sort;
  in.was_lean = lean;
  in.entries = entries;
  in.last_entries = last_entries;
  in.list_words = list.neighbors.capacity();
  in.mask_words = list.masks.capacity();
  in.lent_need_words =
      listed && cub_sort ? cuda::lent_room_words(std::max<std::size_t>(entries, 1), sort_scratch_bytes(entries, g.key_bits))
                         : 0;
  in.masks_allowed = o.test.list_lend_masks.value_or(true) && o.test.list_masks.value_or(true);
  in.graph_allowed = o.test.build_graph.value_or(true) && o.accumulation == Accumulation::kJacobi && !o.reuse.audit &&
                     !o.test.list_count_masked.value_or(false);
  const cuda::BuildMemoryPlan plan = cuda::plan_build_memory(in);
  lean = plan.lean;
  lend = plan.lend;
  if (lean) {
    // The new build makes a new list: the old one is dead. Its array holds the unsorted keys and
    // IDs and the sort's scratch where they fit in it (lend), then the occupants staged for the
    // count pass where they fit (build_list), and then the new list where that fits
    // (build_pair_list): no device allocation of the list's size at every build. Else freed here,
    // so that the sort's arrays have its room. Kept, the array does not shrink: a lean engine holds
    // its longest list, as a fast one does.
    if (!lend) list.neighbors.release();
    list.ranked_forces.release();  // lean gated evaluations store in the caller's order
    list.fixed_next.release();     // and run no kick-drift
    list.ranked_next.release();
    staged.release();
  }
  if (plan.give_up_masks) cuda::give_up_masks(list);
  return plan;
}

void GpuEngine::Impl::queue_ids_and_sort(const GpuOptions& o, const Grid& g, std::size_t n, uint32_t* unsorted_keys,
                                         uint32_t* unsorted_ids, const cuda::ScratchLoan& loan) {
  const bool skin = o.reuse.skin > 0;
  // The cell-ID kernel also counts the valid entries (the counts zeroed before it) and, with a
  // skin, keeps the build's positions.
  cuda::build_cell_ids(g, pos, n, unsorted_keys, unsorted_ids, control.data(), stream, counts.data(),
                       skin ? build_positions.data() : nullptr);
  if (skin && o.reuse.audit) {  // before the sort (the chapter's may reuse the input); read after a sync
    download(build_keys, unsorted_keys, entries, stream);
    download(build_control, control.data(), n, stream);
  }
  stage_record(kCellIds);
  stage_record(kCounted);  // counted with the cell IDs
  switch (o.sort) {
    case SortMethod::kCub:
      cuda::radix_sort_cub(unsorted_keys, unsorted_ids, sorted_keys.data(), sorted_ids.data(), entries, g.key_bits,
                           cub, stream, loan);
      break;
    case SortMethod::kChapter:
      cuda::radix_sort_chapter(unsorted_keys, unsorted_ids, sorted_keys.data(), sorted_ids.data(), entries,
                               g.key_bits, chapter_sort, stream);
      break;
  }
  stage_record(kSorted);
}

}  // namespace cellforce
