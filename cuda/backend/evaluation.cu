// One evaluation of the structure in use (GpuEngine::Impl): over the pair lists where the
// structure has them (the list's build after the structure's, the list force kernel of
// forces/list_forces.cuh, and where a gated chunk's drifts place the positions), else over the
// collision cells (staging, the traversal of forces/traversal.cuh in the form the build chose, the
// Jacobi slots' sum or the Gauss-Seidel passes, and the cells' energy and virial).
#include "backend/engine_state.cuh"
#include "core/error.h"
#include "forces/list_forces.cuh"

namespace cellforce {
namespace {

// The cells' traversal's compile-time switches for this grid and force field.
cuda::Switches cell_switches(const Grid& g, const ForceField& ff, bool observables) {
  cuda::Switches sw;
  sw.dim = g.dim;
  sw.wrap = g.any_wrap_inside_cell();
  sw.multi_type = ff.num_types() > 1;
  sw.mode = ff.mode;
  sw.observables = observables;
  return sw;
}

}  // namespace

template <class Real, class Accum>
cuda::ListArgs<Real, Accum> GpuEngine::Impl::list_args(const Grid& g, const SystemView& sys, const ForceField& ff,
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
  la.forces = forces_out ? forces_out : forces.data();
  la.energies = req.energy ? (energies_out ? energies_out : energies.data()) : nullptr;
  la.flags = flags.data();
  la.skip = list_skip;
  return la;
}

template <class Real, class Accum>
void GpuEngine::Impl::build_list(const GpuOptions& o, const Grid& g, const SystemView& sys, const ForceField& ff) {
  const cuda::ListArgs<Real, Accum> la = list_args<Real, Accum>(g, sys, ff, Request{false, false});
  // Lean: the cells without a staged array of their own (n x 2^d x 32 bytes less: the fill stages
  // each occupant as it loads it, the count pass too unless the last list's array holds them,
  // below); otherwise staged once, which the build's two passes read faster.
  const cuda::TraversalArgs<Real, Accum> cell_args =
      lean ? traversal_args<Real, Accum>(g, sys, ff, ff.mode) : prepare<Real, Accum>(g, sys, ff, ff.mode);
  // Lean, with the last list's array kept (build): its room holds the occupants staged for the
  // count pass, which the fill then writes over (the fill stages as it loads).
  const cuda::StagedEntry<Real>* count_staged = nullptr;
  if (lean && list.neighbors.capacity() * sizeof(uint32_t) >= entries * sizeof(cuda::StagedEntry<Real>)) {
    auto* into = reinterpret_cast<cuda::StagedEntry<Real>*>(list.neighbors.data());
    cuda::stage_occupants<Real>(g, sorted_keys.data(), sorted_ids.data(), entries, &counts.data()->valid, pos, typ,
                                uint32_t(ff.num_types()), control.data(), into, stream);
    count_staged = into;
  }
  list.forced_splits = o.test.list_splits.value_or(0);
  // Lean builds keep masks only while the list's array is kept (lend): otherwise it is freed and
  // taken again at every build, and the masks would give way to it every time.
  list.use_masks = o.test.list_masks.value_or(true) && !(lean && !lend);
  list.mask_limit = o.test.list_mask_words.value_or(0);
  list.count_masked_units = o.test.list_count_masked.value_or(false);
  // What this engine may still take after a lean build, which the masks' room leaves free: the
  // positions the evaluations gather (up to 32 bytes a particle) and the energies, until it has them.
  const std::size_t n = sys.n;
  const bool gathered = list.fixed.capacity() >= n || list.ranked.capacity() >= n;
  list.later_bytes =
      lean ? (gathered ? 0 : n * sizeof(cuda::RankedParticle)) + (energies.capacity() >= n ? 0 : n * sizeof(double))
           : 0;
  list.forced_threads = o.test.list_threads.value_or(0);
  list.forced_block = o.test.list_block.value_or(0);
  // The build's fixed part ends before the count pass (backend/build_graph.cuh).
  const cuda::ListBuildHead head{graph.queuing(), [&] {
                                   if (graph.open()) graph.end(build_key(o, g, ff, n), stream);
                                 }};
  list_usable = cuda::build_pair_list<Real, Accum>(cell_args, sorted_keys.data(), control.data(), entries,
                                                   ff.cutoff + o.reuse.skin, la, list, stream, count_staged, head);
  if (!list_usable) list.ranked_forces.release();  // no gated evaluations: the cells serve
  list_built_for = builds;
}

template <class Real, class Accum>
bool GpuEngine::Impl::evaluate_lists(const Grid& g, const SystemView& sys, const ForceField& ff, const Request& req) {
  if (list_built_for != builds)  // every build makes its list (GpuEngine::build): a bug otherwise
    throw Error("internal error: the pair list does not belong to the structure in use");
  if (!list_usable || sys.n == 0) return false;  // the cells serve it (and an empty system)
  const bool observables = list_forces<Real, Accum>(g, sys, ff, req, cuda::GateView{});
  record(kTraversed);
  if (observables) {
    totals.reserve(cuda::kCellSums);
    cuda::sum_cells<Accum>(as<Accum>(list.block_sums), list.blocks.data(), totals.data(), stream, list_skip);
  }
  record(kAccumulated);
  return true;
}

template <class Real, class Accum>
bool GpuEngine::Impl::list_forces(const Grid& g, const SystemView& sys, const ForceField& ff, const Request& req,
                 const cuda::GateView& gate, const cuda::NextKickDrift* then) {
  const cuda::ListArgs<Real, Accum> la = list_args<Real, Accum>(g, sys, ff, req);
  cuda::Switches sw;
  sw.dim = g.dim;
  sw.multi_type = ff.num_types() > 1;
  sw.mode = ff.mode;
  sw.observables = req.energy || req.virial;
  cuda::list_forces<Real, Accum>(sw, la, list, stream, gate, gate.gate && !lean, then);  // rank_order()'s rule
  return sw.observables;
}

template <class Real, class Accum>
cuda::RankOrder GpuEngine::Impl::rank_order(const Grid& g, const SystemView& sys, const ForceField& ff, bool fused) {
  list.fused_block = 0;  // a gated chunk begins: its fused force kernels, if any, set it
  return cuda::rank_order<Real, Accum>(list_args<Real, Accum>(g, sys, ff, Request{false, false}), list, !lean,
                                       fused && !lean);
}

template <class Real, class Accum>
cuda::TraversalArgs<Real, Accum> GpuEngine::Impl::prepare(const Grid& g, const SystemView& sys,
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

template <class Real, class Accum>
cuda::TraversalArgs<Real, Accum> GpuEngine::Impl::traversal_args(const Grid& g, const SystemView& sys, const ForceField& ff,
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

template <class Real, class Accum>
bool GpuEngine::Impl::traverse_and_sum(const GpuOptions& o, const Grid& g, const SystemView& sys,
                      const ForceField& ff, const Request& req) {
  if (lists(o, sys.box, ff.cutoff) && evaluate_lists<Real, Accum>(g, sys, ff, req)) return true;
  evaluate_cells<Real, Accum>(o, g, sys, ff, req);
  return false;
}

template <class Real, class Accum>
void GpuEngine::Impl::reserve_cells(const GpuOptions& o, const Grid& g, std::size_t n, const Request& req) {
  const bool gs = o.accumulation == Accumulation::kGaussSeidel;
  const std::size_t dim = std::size_t(g.dim), copies = gs ? 1 : std::size_t(g.num_types());
  const bool tiles = form == TraversalForm::kWarpPerTile;
  const std::size_t sums = tiles ? cuda::max_tiles(entries, max_cells) : max_cells;
  staged.reserve(std::max<std::size_t>(entries, 1) * sizeof(cuda::StagedEntry<Real>));
  force_slots.reserve(std::max<std::size_t>(copies * n * dim, 1) * sizeof(Accum));
  if (req.energy || req.virial) {
    energy_slots.reserve(std::max<std::size_t>(copies * n, 1) * sizeof(Accum));
    cell_sums.reserve(std::max<std::size_t>(sums, 1) * cuda::kCellSums * sizeof(Accum));
    totals.reserve(cuda::kCellSums);
  }
  forces.reserve(std::max<std::size_t>(n * dim, 1));
  if (req.energy) energies.reserve(std::max<std::size_t>(n, 1));
}

template <class Real, class Accum>
void GpuEngine::Impl::evaluate_cells(const GpuOptions& o, const Grid& g, const SystemView& sys, const ForceField& ff,
                                     const Request& req) {
  const bool gs = o.accumulation == Accumulation::kGaussSeidel;
  const bool observables = req.energy || req.virial;
  const std::size_t n = sys.n, dim = std::size_t(g.dim);
  const int copies = gs ? 1 : g.num_types();
  // Energy and virial sums per collision cell, or per row tile for the tile form.
  const bool tiles = form == TraversalForm::kWarpPerTile;
  reserve_cells<Real, Accum>(o, g, n, req);
  cuda::TraversalArgs<Real, Accum> args = prepare<Real, Accum>(g, sys, ff, ff.mode);

  CF_CUDA_CHECK(cudaMemsetAsync(force_slots.data(), 0, copies * n * dim * sizeof(Accum), stream));
  args.force = as<Accum>(force_slots);
  args.force_slot_stride = gs ? 0 : n * dim;
  if (observables) {
    CF_CUDA_CHECK(cudaMemsetAsync(energy_slots.data(), 0, copies * n * sizeof(Accum), stream));
    args.energy = as<Accum>(energy_slots);
    args.energy_slot_stride = gs ? 0 : n;
    args.cell_sums = as<Accum>(cell_sums);
  }
  const cuda::Switches sw = cell_switches(g, ff, observables);
  if (!gs) {
    cuda::traverse(form, sw, args, stream);
  } else {
    for (int t = 0; t < g.num_types(); ++t) {  // one pass per cell type, in type order
      args.cell_range = counts.data()->type_start + t;
      cuda::traverse(form, sw, args, stream);
    }
  }
  record(kTraversed);

  cuda::sum_slots<Accum>(as<Accum>(force_slots), req.energy ? as<Accum>(energy_slots) : nullptr,
                         g.dim, n, copies, forces_out ? forces_out : forces.data(),
                         req.energy ? (energies_out ? energies_out : energies.data()) : nullptr,
                         stream);
  if (observables)
    cuda::sum_cells<Accum>(as<Accum>(cell_sums), tiles ? tile_start.data() + max_cells : &counts.data()->cell_range[1],
                           totals.data(), stream);
  record(kAccumulated);
}

template <class Real, class Accum>
void GpuEngine::Impl::evaluate_local(const GpuOptions& o, const Grid& g, const SystemView& sys, std::size_t n_local,
                                     const ForceField& ff, const Request& req) {
  const bool gs = o.accumulation == Accumulation::kGaussSeidel;
  const bool observables = req.energy || req.virial;
  const std::size_t dim = std::size_t(g.dim), copies = gs ? 1 : std::size_t(g.num_types());
  constexpr std::size_t kc = kVirialComponents;
  if (!tiles_built) {
    tile_start.reserve(max_cells + 1);
    cuda::tile_starts(cells.data(), counts.data()->cell_range, max_cells, tile_start.data(), cub, stream);
    tiles_built = true;
  }
  force_slots.reserve(std::max<std::size_t>(copies * n_local * dim, 1) * sizeof(Accum));
  forces.reserve(std::max<std::size_t>(n_local * dim, 1));
  if (observables) {
    energy_slots.reserve(std::max<std::size_t>(copies * n_local, 1) * sizeof(Accum));
    virial_slots.reserve(std::max<std::size_t>(copies * n_local * kc, 1) * sizeof(Accum));
    energies.reserve(std::max<std::size_t>(n_local, 1));
    virials.reserve(std::max<std::size_t>(n_local * kc, 1));
  }
  cuda::TraversalArgs<Real, Accum> args = prepare<Real, Accum>(g, sys, ff, ff.mode);
  args.n_local = n_local;
  CF_CUDA_CHECK(cudaMemsetAsync(force_slots.data(), 0, copies * n_local * dim * sizeof(Accum), stream));
  args.force = as<Accum>(force_slots);
  args.force_slot_stride = gs ? 0 : n_local * dim;
  if (observables) {
    CF_CUDA_CHECK(cudaMemsetAsync(energy_slots.data(), 0, copies * n_local * sizeof(Accum), stream));
    CF_CUDA_CHECK(cudaMemsetAsync(virial_slots.data(), 0, copies * n_local * kc * sizeof(Accum), stream));
    args.energy = as<Accum>(energy_slots);
    args.energy_slot_stride = gs ? 0 : n_local;
    args.virial = as<Accum>(virial_slots);
    args.virial_slot_stride = gs ? 0 : n_local * kc;
  }
  const cuda::Switches sw = cell_switches(g, ff, observables);
  if (!gs) {
    cuda::traverse_local(sw, args, stream);
  } else {
    for (int t = 0; t < g.num_types(); ++t) {  // one pass per cell type, in type order
      args.cell_range = counts.data()->type_start + t;
      cuda::traverse_local(sw, args, stream);
    }
  }
  record(kTraversed);
  cuda::sum_slots<Accum>(as<Accum>(force_slots), observables ? as<Accum>(energy_slots) : nullptr, g.dim, n_local,
                         int(copies), forces.data(), observables ? energies.data() : nullptr, stream);
  if (observables) cuda::sum_virial_slots<Accum>(as<Accum>(virial_slots), n_local, int(copies), virials.data(), stream);
  record(kAccumulated);
}

#define CF_EVALUATION(Real, Accum)                                                                              \
  template cuda::ListArgs<Real, Accum> GpuEngine::Impl::list_args<Real, Accum>(const Grid&, const SystemView&,  \
                                                                               const ForceField&, const Request&); \
  template void GpuEngine::Impl::build_list<Real, Accum>(const GpuOptions&, const Grid&, const SystemView&,     \
                                                         const ForceField&);                                  \
  template bool GpuEngine::Impl::evaluate_lists<Real, Accum>(const Grid&, const SystemView&, const ForceField&, \
                                                             const Request&);                                 \
  template bool GpuEngine::Impl::list_forces<Real, Accum>(const Grid&, const SystemView&, const ForceField&,    \
                                                          const Request&, const cuda::GateView&,              \
                                                          const cuda::NextKickDrift*);                         \
  template cuda::RankOrder GpuEngine::Impl::rank_order<Real, Accum>(const Grid&, const SystemView&,             \
                                                                    const ForceField&, bool);                  \
  template cuda::TraversalArgs<Real, Accum> GpuEngine::Impl::prepare<Real, Accum>(                              \
      const Grid&, const SystemView&, const ForceField&, CutoffMode);                                          \
  template cuda::TraversalArgs<Real, Accum> GpuEngine::Impl::traversal_args<Real, Accum>(                       \
      const Grid&, const SystemView&, const ForceField&, CutoffMode);                                          \
  template bool GpuEngine::Impl::traverse_and_sum<Real, Accum>(const GpuOptions&, const Grid&, const SystemView&, \
                                                               const ForceField&, const Request&);            \
  template void GpuEngine::Impl::evaluate_cells<Real, Accum>(const GpuOptions&, const Grid&, const SystemView&,  \
                                                             const ForceField&, const Request&);              \
  template void GpuEngine::Impl::reserve_cells<Real, Accum>(const GpuOptions&, const Grid&, std::size_t,         \
                                                            const Request&);                                  \
  template void GpuEngine::Impl::evaluate_local<Real, Accum>(const GpuOptions&, const Grid&, const SystemView&,  \
                                                             std::size_t, const ForceField&, const Request&);
CF_EVALUATION(float, float)
CF_EVALUATION(float, double)
CF_EVALUATION(double, double)
#undef CF_EVALUATION

}  // namespace cellforce
