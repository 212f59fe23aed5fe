// Pair lists for a reused structure (ReuseOptions::list, CUDA): the traversal of a build records,
// for every particle, the partners the cell search finds within rc + skin, and the evaluations
// the structure serves walk those lists instead of the cells' candidates.
//
// Why: a collision cell's candidates fill a volume of (c + 2h)^3 ~ 32 rc^3 around each H occupant
// (c >= rc + h, h = rc / sqrt(2)), of which the cutoff sphere is 4.2 rc^3: 85-95% of the tests
// fail. The build's list holds the pairs within rc + skin only, (1 + skin/rc)^3 of the useful ones.
//
// Layout. Particles are numbered by rank: the order of their H entries in the sorted cell-ID array,
// so that ranks run cell by cell and a particle's partners have nearby ranks. The list of rank p
// is the concatenation, in cell-type order, of the partners found from its row in its cell of
// each type (the Jacobi slots' structure: one writer per particle and type, condition 1), each in
// the cell's occupant order. Stored by groups of kGroup consecutive ranks, each as long as its
// longest list (not the longest of all: ~20% less memory in a liquid) in whole chunks of kChunk
// entries (16 bytes), chunk-major within the group (list_entry): a warp's threads read consecutive
// chunks, one 16-byte load each, and the build's fill writes a chunk it fills whole with one store
// (search/list_build.cu ChunkWriter). Every pair is in both partners' lists: each thread sums the
// whole force on its own particle, in its list's fixed order, with no atomics (bitwise
// reproducible).
//
// Exactness: the build keeps exactly the pairs with r < rc + skin in double (positions by minimum
// image; the staged coordinates decide wherever their rounding cannot matter), so a pair
// closer than rc now, with no particle moved more than skin / 2, is in the list; every
// evaluation tests r < rc again.
#pragma once

#include <cuda_runtime.h>

#include <cstddef>
#include <cmath>
#include <cstdint>
#include <functional>
#include <type_traits>

#include "core/error.h"
#include "mapped_post.h"
#include "search/cells.cuh"
#include "search/list_build.h"  // split_columns, build_splits, prefilter_bound, fixed-point coordinates
#include "search/rank_order.cuh"

namespace cellforce::cuda {


constexpr int kListBlock = 128;  // threads per block of every list kernel (4 warps; the fused force
                                 // kernel may take twice as many: forces/list_forces.cu fused_block)
constexpr uint32_t kGroup = 32;  // ranks that share a length in the list's layout
constexpr uint32_t kChunk = 4;   // list entries per 16-byte chunk: a group's length is whole chunks

// Where entry k of rank p's list is: chunk k / kChunk of its group (whose chunks start at
// `group_chunk0`, group_chunks[p / kGroup]) holds that chunk of the group's kGroup ranks side by
// side, kChunk entries each.
CF_HD std::size_t list_entry(unsigned long long group_chunk0, std::size_t p, uint32_t k) {
  return (std::size_t(group_chunk0 + k / kChunk) * kGroup + p % kGroup) * kChunk + k % kChunk;
}

// The count pass's decisions, kept for the fill: per work unit of the build (a row tile and column
// range), a 32-bit word per column tile and row lane whose bit k marks column k of the tile as a
// partner of the lane's row, so that the fill writes the list from the words without testing a
// pair again. In the room the builds before asked for (grow_masks): every unit's words in fast
// memory mode, in lean mode as many as the device's free memory holds, while the list's array is
// lent and where that is at least 1/16 of them. Unit u's words are [base[u],
// base[u + 1]) (an exclusive sum over the units, the same in every run); a unit keeps them when
// they end within the buffer (a prefix of the units), and one that does not walks its columns again
// in the fill, so the list is the same whatever the buffer holds. base[units], the words all units
// would take, sizes the buffer for the next build. A tile of P rows only whose
// words are kept is not tested at all: the H rows that pair with it write its words, since a pair's
// decision is the same from either side (and with one column split per row tile, an H row tile's
// words for the columns of the cell's earlier H row tiles: those tiles write them;
// search/list_build.cu list_rows).
struct BuildMasks {
  uint32_t* words = nullptr;                  // capacity words, or null: no room (every unit walks again)
  unsigned long long capacity = 0;
  const unsigned long long* base = nullptr;   // units + 1, or null: no masks (list_masks off, or no units)
  unsigned long long* filled = nullptr;       // tests only (count_masked_units): units the fill wrote from words
  __device__ bool kept(uint32_t unit) const { return words && base[unit + 1] <= capacity; }
};

// The build's four sizes as the kernel that gathers them posts them into mapped host memory, then
// the build's tag: the host waits for the sizes, not for the stream, so the device can fill
// meanwhile, and the kernel's post spares the device the turnaround a copy engine's copy and an
// event would cost a build.
struct PostedSizes {
  unsigned long long value[4];
  unsigned long long tag;  // the host's build number (never 0); 0 before any build
};

// The host's side of the post (MappedPost: made on the current device when first asked for). A
// build that throws before its wait may leave its post pending: the engine synchronises its stream
// before it (and this memory) goes (GpuEngine::Impl's destructor).
class SizesReadback {
 public:
  // A new build's tag (`tag`), and where its kernel posts the sizes and then the tag.
  PostedSizes* begin(unsigned long long& tag) {
    PostedSizes* device = posted_.device();
    tag = ++builds_;
    return device;
  }
  // The last build's four sizes, once its tag has arrived. An error in the stream's work stops the wait.
  struct Sizes {
    unsigned long long value[4];
  };
  // Where a build the device decided posts (backend/call_graph.cuh): its tag is the device's count
  // of such builds with the top bit set (device_tag), never a host build's.
  PostedSizes* device_post() { return posted_.device(); }
  static constexpr unsigned long long kDeviceTag = 1ull << 63;
  // The last post, whatever its tag, without waiting: false when none is there yet or the device
  // wrote a new one while it was read.
  bool peek(unsigned long long& tag, Sizes& sizes) const {
    tag = posted_.tag();
    if (tag == 0) return false;
    const volatile PostedSizes& v = posted_.values();
    sizes = Sizes{{v.value[0], v.value[1], v.value[2], v.value[3]}};
    return posted_.tag() == tag;
  }
  Sizes wait(cudaStream_t stream) const {
    for (;;) {
      if (posted_.arrived(builds_)) break;
      const cudaError_t done = cudaStreamQuery(stream);
      if (done == cudaSuccess) {
        if (posted_.arrived(builds_)) break;
        throw Error("internal error: the list's sizes were not posted");
      }
      if (done != cudaErrorNotReady) CF_CUDA_CHECK(done);
    }
    const volatile PostedSizes& v = posted_.values();
    return Sizes{{v.value[0], v.value[1], v.value[2], v.value[3]}};
  }

 private:
  MappedPost<PostedSizes> posted_;
  unsigned long long builds_ = 0;
};

struct PairList {
  DeviceBuffer<uint32_t> order;        // n: the particle of rank p
  DeviceBuffer<uint32_t> rank;         // n: the rank of particle i
  DeviceBuffer<uint32_t> slot_counts;  // n x 2^d: partners of rank p found in its cell of type t
  DeviceBuffer<uint32_t> length;       // n: partners of rank p
  DeviceBuffer<unsigned long long> group_chunks;  // groups + 1: the first chunk of each group of
                                                 // kGroup ranks (an exclusive sum of their lengths)
  DeviceBuffer<uint32_t> neighbors;    // slots: the rank of p's k-th partner at list_entry (a list's
                                       // padding up to its group's length is never written)
  DeviceBuffer<RankedParticle> ranked; // n: gathered at every evaluation, placed by a gated step's
                                       // drift (double pairs, an open axis)
  DeviceBuffer<FixedParticle> fixed;   // n: the same (float pairs, all periodic)
  DeviceBuffer<RankedParticle> ranked_next;  // n: where a force kernel that runs the next step's
  DeviceBuffer<FixedParticle> fixed_next;    // kick-drift places it; swapped with the
                                             // array it read after its launch
  DeviceBuffer<double> ranked_forces;  // n x dim: the gated evaluations' forces in rank order (RankOrder)
  DeviceBuffer<unsigned long long> sizes;  // 2: the longest list and the sum of the lengths (posted
                                           // with the masks' words and the list's chunks into
                                           // `readback`)
  SizesReadback readback;
  DeviceBuffer<uint32_t> selected;     // 1: CUB's count of H entries (n)
  DeviceBuffer<uint32_t> split_counts; // splits > 1: the count pass's partners per work unit (row
                                       // tile x column split) and lane, for the fill's offsets
  DeviceBuffer<uint32_t> masks;        // BuildMasks::words, sized by the build before (grow_masks)
  DeviceBuffer<unsigned long long> mask_base;  // BuildMasks::base, units + 1
  DeviceBuffer<uint32_t> walk_order;   // launched units: the count pass's (in order) first, then
                                       // the rest (not read); held only while
                                       // the build keeps masks
  DeviceBuffer<uint32_t> walked;       // 1: how many units the count pass walks
  DeviceBuffer<unsigned long long> filled;  // 1: count_masked_units' counter
  DeviceBuffer<uint32_t> blocks;       // 1: the force kernel's blocks (their sums' count)
  DeviceBuffer<std::byte> block_sums;  // kCellSums per block of the force kernel
  DeviceBuffer<std::byte> scratch;     // CUB
  // CUB's scratch size for each of the build's CUB calls, asked again only when the call's item
  // count changes (each query runs CUB's dispatch on the host, where at small sizes the device
  // waits through the build).
  struct CubBytes {
    long long items = -1;
    std::size_t bytes = 0;
  };
  CubBytes select_bytes, base_bytes, part_bytes, scan_bytes;
  std::size_t width = 0, pairs = 0;    // of the last build (width: the longest list; pairs: the sum
  std::size_t slots = 0;               // of the lengths; slots: the entries the layout holds)
  int threads_per_particle = 1;        // the force kernel's: 1, 2, 4 or 8 (from n and the device)
  int splits = 1;                      // the build's column splits per row tile (build_splits)
  int forced_splits = 0;               // tests only: this many splits (at most 8) instead of the rule
  int forced_threads = 0;              // tests only: this many threads per particle (1, 2, 4 or 8)
  int forced_block = 0;                // tests only: this many threads a block (kBlock or 2 kBlock) for
                                       // the force kernels that run the next step's kick-drift
  int fused_block = 0;                 // the last such launch's threads a block (forces/list_forces.cu fused_block;
                                       // reset to 0 as a gated chunk begins: GpuEngine's list_block)
  struct BlockShape {                  // its kernel's resident blocks a multiprocessor, kBlock and
    const void* kernel = nullptr;      // 2 kBlock threads a block (asked once per kernel)
    int resident[2] = {0, 0};
  };
  BlockShape shape;
  int multiprocessors = 0;             // the device's, as the build had them (threads_per_particle's rule)
  bool dependent_launch = false;       // the device schedules a kernel before the last one ends
                                       // (programmatic dependent launch: compute capability 9.0 on)
  bool use_masks = true;               // false: every fill walks the columns again (tests; lean builds
                                       // whose list array is not kept, backend/evaluation.cu)
  std::size_t mask_limit = 0;          // tests only (nonzero): the masks' room holds at most this many words
  std::size_t later_bytes = 0;         // lean: what the engine may still take after the build (the
                                       // gathered positions, the energies), left free by grow_masks
  bool count_masked_units = false;     // tests only: count the units each fill writes from masks
  std::size_t masked_units = 0;        // with count_masked_units: the last fill's
  std::size_t masked_fills = 0;        // builds whose fill read every unit's masks
  std::size_t mask_words = 0;          // the last fill's: the words every unit's masks take, and
  std::size_t mask_words_held = 0;     // those its room held (0: no masks read; the units whose
                                       // words end within it read them, the rest walked again)
  std::size_t partly_masked_fills = 0; // builds whose masks' room held less than every unit's words
                                       // (lean memory: the room the device has left)
  std::size_t staged_counts = 0;       // builds whose count pass alone read staged occupants (count_staged)
  std::size_t masks_refused = 0;       // the smallest mask demand the device had no (full) room for (0: none)
  bool masks_settled = false;          // lean: the room was sized to the memory left (in part): not
                                       // asked for again until it is given up (give_up_masks)
  // A build the device decided (backend/call_graph.cuh), while it is captured: the post's tag is
  // read from device_tag (kDeviceTag added), and the build ends after the early fill, setting
  // *overflow to whether the list needed more chunks than its array holds (the fill then wrote
  // nothing: the cells serve until the next build) and adding it to overflow[1]. Null otherwise.
  const unsigned long long* device_tag = nullptr;
  unsigned long long* overflow = nullptr;

  // Calls f(name, buffer) on every buffer.
  template <class F>
  void for_each_buffer(F&& f) {
    f("list: order", order), f("list: rank", rank), f("list: slot counts", slot_counts), f("list: lengths", length);
    f("list: group chunks", group_chunks), f("list: entries", neighbors), f("list: positions (double)", ranked);
    f("list: positions (fixed point)", fixed), f("list: next positions (double)", ranked_next);
    f("list: next positions (fixed point)", fixed_next), f("list: forces in rank order", ranked_forces);
    f("list: sizes", sizes), f("list: selected", selected), f("list: split counts", split_counts);
    f("list: masks", masks), f("list: mask bases", mask_base), f("list: walk order", walk_order);
    f("list: walked", walked), f("list: filled", filled), f("list: blocks", blocks);
    f("list: block sums", block_sums), f("list: CUB scratch", scratch);
  }
  // Calls f on every buffer the head of a build (build_pair_list up to its count pass) names: what
  // a graph of the build's fixed part holds (backend/build_graph.cuh, backend/engine_state.cuh's key).
  template <class F>
  void for_each_head_buffer(F&& f) {
    f(order), f(rank), f(slot_counts), f(length), f(sizes), f(selected), f(scratch);
    f(split_counts), f(masks), f(mask_base), f(walk_order), f(walked);
  }
};

// The masks' room given up (freed in stream order), to be asked for again after the next build:
// where the memory it holds may be wanted (a growing list, a new system, backend/memory_plan.cpp's
// lean rules).
inline void give_up_masks(PairList& list) {
  list.masks.release();
  list.masks_refused = 0;
  list.masks_settled = false;
}

// What the list kernels read besides the list.
template <class Real, class Accum>
struct ListArgs {
  Grid grid;                       // its length / inv_length: minimum image on periodic axes
  std::size_t n = 0;
  const double* positions = nullptr;   // n x dim, user order
  const uint32_t* types = nullptr;     // n or null (all type 0)
  uint32_t num_types = 1;
  const LJParams<Real>* table = nullptr;
  LJParams<Real> first;                // table[0], as the host made it (the kernels' single type)
  Real rc2 = 0;
  double* forces = nullptr;            // n x dim, user order (written, not added to)
  double* energies = nullptr;          // n or null: half of each pair's energy
  DeviceFlags* flags = nullptr;
  // Device memory or null: where nonzero when they run, the gather and the list force kernel
  // return at once (a decided call that takes another route: backend/call_graph.cuh).
  const unsigned long long* skip = nullptr;
};

// What the build stages its occupants from (as stage_kernel would: no staged array is needed).
struct ListStaging {
  const uint32_t* sorted_keys = nullptr;  // the sorted cell-ID array (sort_key())
  const double* positions = nullptr;      // n x dim, user order
  const uint32_t* types = nullptr;        // n or null
  uint32_t num_types = 1;
  const Control* control = nullptr;       // n: stage 1's control bits
};


// The head of a list build, up to its count pass, ends the build's fixed part (backend/build_graph.cuh):
// whether its operations are queued (false: a graph replays them), and what to call where the
// part ends (before the count pass; null: nothing).
struct ListBuildHead {
  bool queue = true;
  std::function<void()> done;
};

// Builds the list from the structure just built (cells: its cells, tile starts, sorted IDs and
// staged occupants, or none: then they are staged as the build loads them;
// sorted_keys and control: stage 1-2's; the positions of `list_args`) for partners closer than
// list_cutoff. Synchronises the stream once, to read the list's size (once more when the array
// grows: the old one is freed first; and after the fill when the masks' room grows, BuildMasks).
// Returns false, leaving no list (its array freed), when the grouped array would hold more than
// twice the pairs plus 64 per particle (a few very crowded particles), or would not fit in the
// device's free memory with 1/16 of it (at least 512 MiB) to spare: the caller then traverses the
// cells. count_staged (lean memory, cells without staged occupants): the occupants staged for the
// count pass alone, in the list's own array (the fill writes over them), or null.
template <class Real, class Accum>
bool build_pair_list(const TraversalArgs<Real, Accum>& cells, const uint32_t* sorted_keys, const Control* control,
                     std::size_t entries, double list_cutoff,
                     const ListArgs<Real, Accum>& list_args, PairList& list, cudaStream_t stream,
                     const StagedEntry<Real>* count_staged = nullptr, const ListBuildHead& head = {});


// Whether the evaluations of these args read FixedParticles (float pairs, fixed_point_serves) or
// RankedParticles.
template <class Real, class Accum>
bool gathers_fixed(const ListArgs<Real, Accum>& args) {
  return std::is_same_v<Real, float> && fixed_point_serves(args.grid, std::sqrt(double(args.rc2)));
}

// The positions of `args` gathered into rank order, into `ranked` (list.fixed or list.ranked, as
// gathers_fixed says), reserved here: what an evaluation that no gated drift placed reads.
template <class Particle, class Real, class Accum>
void gather(const ListArgs<Real, Accum>& args, PairList& list, DeviceBuffer<Particle>& ranked, cudaStream_t stream);

// Where the evaluations of the list in use read the positions in rank order (the array list_forces
// gathers into for these args, reserved; the other one released), for a gated step's drift to
// place them (RankOrder), and with `forces_by_rank` where they leave the forces in rank order
// (list.ranked_forces, reserved; else released). With `fused`, the second array of that form is
// reserved too, for evaluations that run the next step's kick-drift (list_forces' `then`); else it
// is released.
template <class Real, class Accum>
RankOrder rank_order(const ListArgs<Real, Accum>& args, PairList& list, bool forces_by_rank, bool fused);

// `ranked` (n x dim, rank p's row at p) into `out` in the caller's order (particle i's row from
// rank[i]'s).
void unrank(const uint32_t* rank, const double* ranked, std::size_t n, int dim, double* out, cudaStream_t stream);

// list.ranked_forces (n x dim, rank order) into `forces` (user order).
void unrank_forces(const PairList& list, std::size_t n, int dim, double* forces, cudaStream_t stream);

}  // namespace cellforce::cuda
