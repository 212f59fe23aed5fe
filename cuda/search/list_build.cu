// The pair-list build (search/pair_list.cuh): ranks, the count pass over the collision cells' row
// tiles, the lists' lengths and layout, the fill, and the room for the count pass's masks.
#include <cub/device/device_partition.cuh>
#include <cub/device/device_scan.cuh>
#include <cub/device/device_select.cuh>
#include <thrust/iterator/counting_iterator.h>
#include <thrust/iterator/transform_iterator.h>

#include <algorithm>
#include <cmath>

#include "core/error.h"
#include "search/list_kernels.cuh"
#include "search/pair_list.cuh"
#include "with_dim.cuh"

namespace cellforce::cuda {
namespace {

// The scratch bytes of a CUB call over `items` (query(bytes): the call with no scratch, which only
// sizes it), asked of CUB only when the count differs from the last one (PairList::CubBytes).
template <class Query>
std::size_t cub_bytes(PairList::CubBytes& cached, std::size_t items, Query&& query) {
  if (cached.items != (long long)items) {
    cached.bytes = 0;
    CF_CUDA_CHECK(query(cached.bytes));
    cached.items = (long long)items;
  }
  return cached.bytes;
}

// Waits for the stream and trims the device's current pool (which cudaMallocAsync uses) to nothing,
// so that what was freed in stream order is free again: cudaMemGetInfo counts it, and a buffer
// taken next cannot stand beside the one it replaces.
void trim_pool(cudaStream_t stream) {
  CF_CUDA_CHECK(cudaStreamSynchronize(stream));
  int device = 0;
  cudaMemPool_t pool = nullptr;
  CF_CUDA_CHECK(cudaGetDevice(&device));
  CF_CUDA_CHECK(cudaDeviceGetMemPool(&pool, device));
  CF_CUDA_CHECK(cudaMemPoolTrimTo(pool, 0));
}

// Room for the next builds' masks (BuildMasks), as plan_mask_room (search/list_build.h) sizes it
// from the device's free memory: all of `words` and 1/8 more, or in lean memory (`part`) the prefix
// of the units the free memory holds (the rest walk their columns again). After the fill that read
// the old masks (freed in stream order, the pool trimmed so that the free memory counts them).
// Growing is rare: a system's first build, a system that grew denser, and in lean mode the first
// build of each size and the build after the list grew. A demand refused is not asked again
// (masks_refused), nor is a lean room granted in part (masks_settled), until the room is given up
// (give_up_masks: a growing list, a new system).
void grow_masks(PairList& list, std::size_t words, bool part, cudaStream_t stream) {
  list.masks.release();
  trim_pool(stream);
  std::size_t free_bytes = 0, total_bytes = 0;
  CF_CUDA_CHECK(cudaMemGetInfo(&free_bytes, &total_bytes));
  const MaskRoom room = plan_mask_room(words, part, free_bytes, list.mask_limit, list.later_bytes);
  if (room.settled) list.masks_settled = true;
  if (room.words > 0) list.masks.reserve(room.words);
  if (room.refused) list.masks_refused = words;  // not asked again for as many or more: each ask waits for the device
}


// One pair-list build (build_pair_list), step by step: the ranks, the work units and their masks,
// the count pass, the lists' lengths and layout, the sizes read by the host, the list's room and
// the fill.
template <class Real, class Accum>
class ListBuilder {
 public:
  ListBuilder(const TraversalArgs<Real, Accum>& cells, const uint32_t* sorted_keys, const Control* control,
              std::size_t entries, double list_cutoff, const ListArgs<Real, Accum>& args, PairList& list,
              cudaStream_t stream, const StagedEntry<Real>* count_staged, const ListBuildHead& head)
      : cells_(cells), count_cells_(cells), sorted_keys_(sorted_keys), entries_(entries), list_(list),
        stream_(stream), head_(head), queue_(head.queue), n_(args.n), dim_(args.grid.dim),
        staging_{sorted_keys, args.positions, args.types, args.num_types, control},
        cutoff2_(list_cutoff * list_cutoff), in2_(Real(cutoff2_ * (1 - 1e-5))), out2_(Real(cutoff2_ * (1 + 1e-5))),
        pre2_(Real(prefilter_bound(cells.grid, double(out2_)))), lean_(cells.staged == nullptr) {
    // The count pass reads count_staged where the cells have no staged occupants (lean memory): they
    // lie in the list's array, which the fill then writes, so only the count pass reads them.
    // cells_ keeps staged null: the list's headroom and the masks' room take a null cells.staged
    // for lean mode.
    if (!cells.staged && count_staged) count_cells_.staged = count_staged;
  }

  bool run() {
    const std::size_t slots = std::size_t(1) << dim_;
    list_.order.reserve(std::max<std::size_t>(n_, 1));
    list_.rank.reserve(std::max<std::size_t>(n_, 1));
    list_.slot_counts.reserve(std::max<std::size_t>(n_ * slots, 1));
    list_.length.reserve(std::max<std::size_t>(n_, 1));
    list_.sizes.reserve(2);
    list_.selected.reserve(1);
    list_.width = list_.pairs = list_.slots = 0;
    if (n_ == 0) return true;
    select_ranks();
    if (queue_) CF_CUDA_CHECK(cudaMemsetAsync(list_.slot_counts.data(), 0, n_ * slots * sizeof(uint32_t), stream_));
    plan_units();
    prepare_masks();
    partition_units();
    if (count_cells_.staged != cells_.staged && row_blocks_) ++list_.staged_counts;
    if (head_.done) head_.done();  // the build's fixed part ends here
    if (row_blocks_) walk<ListPass::kCount>();
    // With one column split the count pass added the mirrored counts itself (list_rows's mirror).
    if (masks_.words && list_.splits > 1) walk<ListPass::kMirrored>();
    size_lists();
    post_sizes();
    // Where the list has an array already, the fill is queued behind the sizes' post before the
    // host reads them, so that the device fills while the host waits, decides and queues what
    // follows, instead of waiting for the host's launch. It writes nothing where the list needs
    // more chunks than the array holds (its guard reads the total); the host then fills again after
    // making room. A list the host then drops (the cells serve) was written in vain, and its array
    // is freed in stream order.
    const unsigned long long chunks_held = list_.neighbors.capacity() / (std::size_t(kGroup) * kChunk);
    const bool early = row_blocks_ && chunks_held > 0;
    if (early) walk<ListPass::kFill>(list_.group_chunks.data() + groups_, chunks_held);
    if (list_.overflow) {  // a build the device decided: no wait, the host settles from the post later
      flag_overflow<<<1, 32, 0, stream_>>>(list_.group_chunks.data() + groups_, early ? chunks_held : 0,
                                           list_.sizes.data(), n_, list_.overflow);
      CF_CUDA_CHECK_LAUNCH();
      return true;
    }
    const SizesReadback::Sizes read = list_.readback.wait(stream_);
    const std::size_t width = std::size_t(read.value[0]), pairs = std::size_t(read.value[1]);
    const std::size_t mask_words = masks_.base ? std::size_t(read.value[2]) : 0;  // every unit's masks
    const std::size_t entries_total = std::size_t(read.value[3]) * kGroup * kChunk;  // padding included
    const bool held = entries_total <= list_.neighbors.capacity();
    if (!make_room(entries_total, pairs, held)) return false;
    if (row_blocks_ && width && !(early && held)) walk<ListPass::kFill>();
    settle(width, pairs, entries_total, mask_words);
    return true;
  }

 private:
  // Ranks: the particles of the H entries in sorted order (each particle has exactly one).
  void select_ranks() {
    const auto home =
        thrust::make_transform_iterator(thrust::counting_iterator<uint32_t>(0), IsHome{sorted_keys_, cells_.grid.slab_bits});
    std::size_t bytes = cub_bytes(list_.select_bytes, entries_, [&](std::size_t& b) {
      return cub::DeviceSelect::Flagged(nullptr, b, cells_.sorted_ids, home, list_.order.data(), list_.selected.data(),
                                        int(entries_), stream_);
    });
    list_.scratch.reserve(std::max<std::size_t>(bytes, 1));
    if (!queue_) return;
    CF_CUDA_CHECK(cub::DeviceSelect::Flagged(list_.scratch.data(), bytes, cells_.sorted_ids, home, list_.order.data(),
                                             list_.selected.data(), int(entries_), stream_));
    invert_order<<<blocks_for(n_), kBlock, 0, stream_>>>(list_.order.data(), n_, list_.rank.data(), list_.sizes.data());
    CF_CUDA_CHECK_LAUNCH();
  }

  // The work units: each row tile's columns in `splits` ranges (build_splits), a warp each.
  void plan_units() {
    list_.splits = list_.forced_splits > 0 ? std::min(list_.forced_splits, 8)
                                           : build_splits(cells_.max_tiles, cells_.multiprocessors);
    const std::size_t units = std::size_t(cells_.max_tiles) * std::size_t(list_.splits);
    row_blocks_ = unsigned((units + kBlock / 32 - 1) / (kBlock / 32));
    launched_units_ = row_blocks_ * (kBlock / 32);
    if (list_.splits > 1) list_.split_counts.reserve(std::size_t(row_blocks_) * kBlock);  // a word per warp lane
  }

  // The count pass's masks for the fill, in the room the previous builds asked for (none at the
  // first: it walks twice); in lean memory mode (cells without staged occupants) that room may hold
  // a prefix of the units only (grow_masks).
  void prepare_masks() {
    if (!list_.use_masks || !row_blocks_) {
      give_up_masks(list_);
      list_.mask_base.release();
      return;
    }
    list_.mask_base.reserve(std::size_t(launched_units_) + 1);
    if (queue_) {
      unit_mask_words<<<blocks_for(std::size_t(launched_units_) + 1), kBlock, 0, stream_>>>(
          cells_, uint32_t(list_.splits), launched_units_, list_.mask_base.data());
      CF_CUDA_CHECK_LAUNCH();
    }
    std::size_t base_bytes = cub_bytes(list_.base_bytes, launched_units_ + 1, [&](std::size_t& b) {
      return cub::DeviceScan::ExclusiveSum(nullptr, b, list_.mask_base.data(), list_.mask_base.data(),
                                           int(launched_units_ + 1), stream_);
    });
    list_.scratch.reserve(std::max<std::size_t>(base_bytes, 1));
    if (queue_)
      CF_CUDA_CHECK(cub::DeviceScan::ExclusiveSum(list_.scratch.data(), base_bytes, list_.mask_base.data(),
                                                  list_.mask_base.data(), int(launched_units_ + 1), stream_));
    masks_ = BuildMasks{list_.masks.data(), list_.masks.capacity(), list_.mask_base.data()};
    if (list_.count_masked_units) {  // never in a graph (backend/memory_plan.cpp)
      list_.filled.reserve(1);
      CF_CUDA_CHECK(cudaMemsetAsync(list_.filled.data(), 0, sizeof(unsigned long long), stream_));
      masks_.filled = list_.filled.data();
    }
  }

  // The count pass's units first (CountWalks), the rest after them, where a row tile's columns are
  // one unit (splits = 1: the larger systems, build_splits): with splits (small systems) the
  // partition costs more than it saves. Only with masks in use: without (a build before the room
  // for them, or with none) the count pass walks every unit of the range, and those come first in
  // launch order already, so walk_order is not kept.
  void partition_units() {
    partitioned_ = row_blocks_ && list_.splits == 1 && masks_.words;
    if (!partitioned_) {
      list_.walk_order.release();
      list_.walked.release();
      return;
    }
    list_.walk_order.reserve(launched_units_);
    list_.walked.reserve(1);
    const CountWalks<Real, Accum> walks{cells_, uint32_t(list_.splits), masks_};
    const thrust::counting_iterator<uint32_t> all(0);
    std::size_t part_bytes = cub_bytes(list_.part_bytes, launched_units_, [&](std::size_t& b) {
      return cub::DevicePartition::If(nullptr, b, all, list_.walk_order.data(), list_.walked.data(),
                                      int(launched_units_), walks, stream_);
    });
    list_.scratch.reserve(std::max<std::size_t>(part_bytes, 1));
    if (queue_)
      CF_CUDA_CHECK(cub::DevicePartition::If(list_.scratch.data(), part_bytes, all, list_.walk_order.data(),
                                             list_.walked.data(), int(launched_units_), walks, stream_));
  }

  // The rows' walk, counting or filling, in the geometry's instantiation (2D/3D, wrap in a cell).
  // fill_chunks, fill_room: a fill's guard (list_rows), or none.
  template <ListPass Pass>
  void walk(const unsigned long long* fill_chunks = nullptr, unsigned long long fill_room = 0) {
    constexpr bool kFill = Pass == ListPass::kFill;
    Switches sw;
    sw.dim = dim_;
    sw.wrap = cells_.grid.any_wrap_inside_cell();
    detail::dispatch(sw, [&](auto traits) {
      using T = decltype(traits);
      if constexpr (!T::kMultiType && T::kMode == CutoffMode::kTruncate && !T::kObservables) {
        const TraversalArgs<Real, Accum>& walked_cells = Pass == ListPass::kCount ? count_cells_ : cells_;
        list_rows<T, Pass><<<row_blocks_, kBlock, 0, stream_>>>(
            walked_cells, staging_, list_.rank.data(), in2_, out2_, pre2_, cutoff2_, uint32_t(list_.splits),
            list_.slot_counts.data(), list_.splits > 1 ? list_.split_counts.data() : nullptr,
            list_.group_chunks.data(), kFill ? list_.neighbors.data() : nullptr, masks_,
            partitioned_ ? list_.walk_order.data() : nullptr, list_.walked.data(), fill_chunks, fill_room);
      }
    });
    CF_CUDA_CHECK_LAUNCH();
  }

  // Each group of kGroup ranks is as long as its longest list, in whole chunks: the lengths (sizes[0]
  // and [1] were zeroed by invert_order), the groups' lengths, then (a scan) their first chunks; and
  // the force kernel's threads per particle and block count (for sum_cells).
  void size_lists() {
    groups_ = (n_ + kGroup - 1) / kGroup;
    list_.group_chunks.reserve(groups_ + 1);
    list_.multiprocessors = cells_.multiprocessors;
    list_.threads_per_particle =
        list_.forced_threads > 0 ? list_.forced_threads : list_threads_per_particle(n_, cells_.multiprocessors);
    const uint32_t blocks = blocks_for(n_ * std::size_t(list_.threads_per_particle));
    list_.blocks.reserve(1);
    with_dim(dim_, [&](auto d) {
      sum_slot_counts<decltype(d)::value><<<blocks_for(n_ + kGroup), kBlock, 0, stream_>>>(
          list_.slot_counts.data(), n_, groups_, list_.length.data(), list_.group_chunks.data(), list_.sizes.data(),
          blocks, list_.blocks.data());
      CF_CUDA_CHECK_LAUNCH();
    });
    std::size_t scan_bytes = cub_bytes(list_.scan_bytes, groups_ + 1, [&](std::size_t& b) {
      return cub::DeviceScan::ExclusiveSum(nullptr, b, list_.group_chunks.data(), list_.group_chunks.data(),
                                           int(groups_ + 1), stream_);
    });
    list_.scratch.reserve(std::max<std::size_t>(scan_bytes, 1));
    CF_CUDA_CHECK(cub::DeviceScan::ExclusiveSum(list_.scratch.data(), scan_bytes, list_.group_chunks.data(),
                                                list_.group_chunks.data(), int(groups_ + 1), stream_));
  }

  // The host reads the four sizes with one wait, not three in a row: the longest list, the pairs,
  // the words every unit's masks would take and the list's chunks, posted into its mapped memory.
  void post_sizes() {
    unsigned long long tag = 0;
    PostedSizes* post = list_.device_tag ? list_.readback.device_post() : list_.readback.begin(tag);
    gather_sizes<<<1, 32, 0, stream_>>>(list_.sizes.data(), masks_.base ? masks_.base + launched_units_ : nullptr,
                                        list_.group_chunks.data() + groups_, post, tag, list_.device_tag);
    CF_CUDA_CHECK_LAUNCH();
  }

  // The list's array for `entries_total` slots. False (the array freed): a few crowded particles
  // (the cells are cheaper), or a list that would not fit in the device's free memory (a dense
  // cluster: n^2 partners): the cells serve this structure (plan_list_room). The list in use counts
  // as free: it is replaced. A list that fits the array it has (`held`) takes no memory, and the
  // free memory is not asked for (cudaMemGetInfo holds the device idle).
  bool make_room(std::size_t entries_total, std::size_t pairs, bool held) {
    std::size_t free_bytes = 0, total_bytes = 0;
    if (!held) {
      CF_CUDA_CHECK(cudaMemGetInfo(&free_bytes, &total_bytes));
      free_bytes += list_.neighbors.bytes() + list_.masks.bytes();  // the masks give way to a growing list
    }
    const ListRoom room = plan_list_room(entries_total, pairs, n_, list_.neighbors.capacity(), free_bytes, lean_);
    if (room.declined) {
      list_.neighbors.release();  // dead: the cells serve, and need the room
      give_up_masks(list_);
      list_.mask_base.release();
      return false;
    }
    if (room.reserve) {
      // The largest buffer: the old one is freed and the pool it came from (the device's current
      // one, which cudaMallocAsync uses) trimmed before the new one is taken (in stream order alone
      // the pool could hold both).
      list_.neighbors.release();
      give_up_masks(list_);  // counted as free above: this fill walks every unit again (the same list);
      masks_.words = nullptr;  // the masks are asked for again below, in the room the new list leaves
      trim_pool(stream_);
      list_.neighbors.reserve(room.reserve);
    }
    return true;
  }

  // The build's figures, and the masks' room for the next builds.
  void settle(std::size_t width, std::size_t pairs, std::size_t entries_total, std::size_t mask_words) {
    list_.mask_words = row_blocks_ && width ? mask_words : 0;
    list_.mask_words_held =
        row_blocks_ && width && masks_.words ? std::min<std::size_t>(mask_words, masks_.capacity) : 0;
    if (list_.mask_words_held) {
      if (mask_words <= masks_.capacity) ++list_.masked_fills;
      else ++list_.partly_masked_fills;
    }
    list_.masked_units = 0;
    if (masks_.filled && row_blocks_ && width) {  // tests only: a wait for the fill
      unsigned long long filled = 0;
      CF_CUDA_CHECK(cudaMemcpyAsync(&filled, masks_.filled, sizeof(filled), cudaMemcpyDeviceToHost, stream_));
      CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
      list_.masked_units = std::size_t(filled);
    }
    list_.width = width;
    list_.pairs = pairs;
    list_.slots = entries_total;
    if (masks_.base && mask_words > list_.masks.capacity() && !list_.masks_settled &&
        (!list_.masks_refused || mask_words < list_.masks_refused))
      grow_masks(list_, mask_words, lean_, stream_);
  }

  const TraversalArgs<Real, Accum>& cells_;
  TraversalArgs<Real, Accum> count_cells_;
  const uint32_t* sorted_keys_;
  std::size_t entries_;
  PairList& list_;
  cudaStream_t stream_;
  const ListBuildHead& head_;
  const bool queue_;  // false: the build's graph queued the head (backend/build_graph.cuh)
  const std::size_t n_;
  const int dim_;
  const ListStaging staging_;
  const double cutoff2_;
  const Real in2_, out2_, pre2_;  // pre2: used with float coordinates
  const bool lean_;
  unsigned row_blocks_ = 0;
  uint32_t launched_units_ = 0;
  BuildMasks masks_;
  bool partitioned_ = false;
  std::size_t groups_ = 0;
};

}  // namespace

template <class Real, class Accum>
bool build_pair_list(const TraversalArgs<Real, Accum>& cells, const uint32_t* sorted_keys, const Control* control,
                     std::size_t entries, double list_cutoff, const ListArgs<Real, Accum>& args, PairList& list,
                     cudaStream_t stream, const StagedEntry<Real>* count_staged, const ListBuildHead& head) {
  return ListBuilder<Real, Accum>(cells, sorted_keys, control, entries, list_cutoff, args, list, stream, count_staged,
                                  head)
      .run();
}

#define CF_LIST_BUILD(Real, Accum)                                                                             \
  template bool build_pair_list<Real, Accum>(const TraversalArgs<Real, Accum>&, const uint32_t*, const Control*, \
                                             std::size_t, double, const ListArgs<Real, Accum>&, PairList&,       \
                                             cudaStream_t, const StagedEntry<Real>*, const ListBuildHead&);
CF_LIST_BUILD(float, float)
CF_LIST_BUILD(float, double)
CF_LIST_BUILD(double, double)
#undef CF_LIST_BUILD

}  // namespace cellforce::cuda
