// cellforce::Context's state (include/cellforce/cellforce.hpp), shared by its source files:
// context.cpp (the physics, the engine choices and the force calls), context_local.cpp (the force
// calls of local and ghost particles) and context_md.cpp (the MD state and the changes of physics
// or engine carried into it).
#pragma once

#include <cellforce/cellforce.hpp>

#include <memory>
#include <vector>

#include "backends/force_engine.h"
#include "backends/md_engine.h"
#include "core/box.h"
#include "core/error.h"
#include "core/force_field.h"
#include "core/reuse.h"

namespace cellforce {

// A caller's array of n particles must not be null (n = 0: anything goes).
inline void check_output(const void* p, const char* what, std::size_t n) {
  if (n > 0 && p == nullptr)
    throw Error(std::string(what) + " is a null pointer (" + std::to_string(n) + " particles)");
}

// The pair counts and search structure of an engine's statistics, as count_pairs() reports them.
inline PairCounts pair_counts(const PipelineStats& stats) {
  PairCounts counts;
  counts.tested = stats.candidate_pairs;
  counts.within_cutoff = stats.interacting_pairs;
  for (int a = 0; a < kMaxDim; ++a) {
    counts.grid_cells[a] = stats.grid.n[a];
    counts.cell_edge[a] = a < stats.grid.dim ? stats.grid.cell[a] : 0.0;
  }
  counts.half_width = stats.grid.half_width;
  counts.entries = stats.entries;
  counts.valid_entries = stats.valid_entries;
  counts.collision_cells = stats.collision_cells;
  counts.max_occupancy = stats.max_occupancy;
  return counts;
}

// Hidden: the library exports the API alone, not the state behind it (its members take std::string).
struct [[gnu::visibility("hidden")]] Context::Impl {
  int dim = 3;
  Box box;
  bool has_box = false, has_cutoff = false;
  ForceField ff;
  EngineChoice choice;  // the engine options (set_option; a new context's: core/option_table.h)
  // The device stream every engine of this context runs on (CUDA; null on the CPU): made here and
  // given to each engine, so that force calls and MD steps are one ordered queue. Declared before
  // the engines, so that it outlives them.
  std::shared_ptr<void> stream;
  int stream_device = -1;
  std::unique_ptr<ForceEngine> engine;
  ForceResult result;  // compute()'s staging (the engine's layout), reused across calls
  Statistics statistics;
  bool device_pending = false;  // compute_device calls since the last synchronize()
  // Molecular dynamics: the engine holding the state, and what it holds it under. While a state
  // exists, md_box and md_ff are box and ff (every change is carried into the state: carry()).
  std::unique_ptr<MdEngine> md;
  IntegratorOptions integrator;
  Box md_box;
  ForceField md_ff;
  std::vector<double> masses;
  std::vector<uint32_t> types;
  ReuseOptions md_reuse;                     // what `md` was made with
  ListMemory md_memory = ListMemory::kAuto;  // and the lists' memory mode its skin was resolved for
  // The external force every evaluation of the MD state's forces adds (set_external_forces and the
  // others), given to each MD engine made, and the particle count its array holds (0: a callback,
  // or none).
  ExternalForce external;
  std::size_t external_n = 0;
  int external_device = -1;  // the CUDA device of a device array (external.device)
  // Before the state moves to an engine of `c`: a device array is refused (naming `what`) unless
  // that engine is CUDA on the array's device.
  void check_external_engine(const EngineChoice& c, const std::string& what) const;
  // Makes `e` (an array of n particles; n 0: a callback or none) the context's external force and
  // the state's, whose forces are then evaluated again.
  void set_external(ExternalForce e, std::size_t n);
  // Before a state of n particles is set: an external array of another count is refused, naming
  // `what` (the call).
  void check_external(std::size_t n, const char* what) const;
  // An external array of n particles for the state (or, without one, the next set_state), named
  // by `what` when it cannot be.
  void check_external_count(std::size_t n, const char* what) const;
  // What Context::text and held_neighbor_state returned last (the caller copies it at once).
  std::string held_text;
  ReuseState held_neighbor;

  explicit Impl(int d) : dim(d) {
    if (d != 2 && d != 3) throw Error("dimension " + std::to_string(d) + ": expected 2 or 3");
    box.dim = d;
    ff.types.clear();
  }

  // What the engines are made from: `c` with the backend kAuto stands for, and an automatic skin
  // resolved for the force calls' or the MD engine's use (for_md), box `b`, cutoff `rc` and the
  // lists' memory mode (resolve_reuse: a rule of the backend, the system and the device;
  // md_list_memory).
  static EngineChoice resolved(const EngineChoice& c, const Box& b, double rc, bool for_md,
                               ListMemory memory = ListMemory::kFast) {
    EngineChoice r = c;
    r.backend = resolve_backend(c.backend);
    r.reuse = resolve_reuse(c.reuse, r.backend, c.accumulation, for_md, b, rc, memory);
    return r;
  }
  EngineChoice resolved(const Box& b, bool for_md, ListMemory memory = ListMemory::kFast) const {
    return resolved(choice, b, ff.cutoff, for_md, memory);
  }

  // `c` with the context's stream for its device (made at the first engine on it). Replacing the
  // stream while an engine runs on it is for carry() alone, which keeps the old one alive until
  // the old engines are gone.
  EngineChoice with_stream(EngineChoice c, bool replacing = false) {
    if (c.backend != Backend::kCuda) return c;
    if (!stream || stream_device != c.device) {
      if (stream && (engine || md) && !replacing)
        throw Error("internal error: the context's stream was replaced while an engine still ran on it");
      stream = make_engine_stream(c);
      stream_device = c.device;
    }
    c.stream = stream.get();
    return c;
  }

  static bool same_reuse(const ReuseOptions& a, const ReuseOptions& b) {
    return a.skin == b.skin && a.list == b.list && a.check == b.check && a.every == b.every && a.audit == b.audit;
  }

  // The neighbour structure in use: the MD state's as set_state resolved it, else force calls' on
  // the current box.
  struct Neighbor {
    EngineChoice choice;  // backend resolved, reuse as the engine runs it
    Box box;
    double cutoff;
    bool md;
    ListMemory memory;  // what an automatic skin was resolved for
  };
  Neighbor neighbor() const {
    const bool has_md = md != nullptr;
    const ListMemory memory = has_md ? md_memory : ListMemory::kFast;
    Neighbor nb{resolved(has_md ? md_box : box, has_md, memory), has_md ? md_box : box,
                has_md ? md_ff.cutoff : ff.cutoff, has_md, memory};
    if (has_md) nb.choice.reuse = md_reuse;
    return nb;
  }

  // The force engine (force calls: an automatic skin resolved as for steps, for the box and cutoff
  // set when it is made; set_physics makes it again where they resolve to another).
  ForceEngine& get_engine() {
    if (!engine) engine = make_force_engine(with_stream(resolved(box, false)));
    return *engine;
  }
  ForceEngine& named_engine() { return md ? md->forces() : get_engine(); }

  MdEngine& get_md() {
    if (!md) throw Error("no MD state: call set_state first");
    return *md;
  }

  IntegratorSettings settings() const;

  // A new physics, named `setting` in messages: carried into the MD state when there is one
  // (context_md.cpp), then taken.
  void set_physics(const Box& b, const ForceField& f, const std::string& setting);
  // New engine choices, named `setting` in messages: carried with the MD state into a new engine
  // when there is one, else taken, the force engine to be made again at the next call.
  void set_engine(const EngineChoice& c, const std::string& setting);
  // The MD state now under box `b`, force field `f` and engine choices `c`: on the engine it has
  // when `new_engine` is false and the skin resolves as before, else on a new one. Throws naming
  // `setting` when the state cannot take them, and then leaves the context as it was; on success
  // the context holds b, f and c.
  // `scale` (dim factors, or null): each coordinate of the state multiplied by its axis' factor
  // before it is wrapped into `b` (set_box with scaled positions).
  void carry(const Box& b, const ForceField& f, const EngineChoice& c, bool new_engine, const std::string& setting,
             const double* scale = nullptr);

  // What compute needs before any array is read; the arrays themselves are checked by the engine
  // (validate_system: non-finite coordinates, type indices, rc against the box).
  void check_ready() const {
    check_physics();
    check_precision_range(ff, choice.precision);
  }
  void check_physics() const {
    if (!has_box) throw Error("no box: call set_box (cf_set_box) before computing");
    if (!has_cutoff) throw Error("no cutoff: call set_cutoff (cf_set_cutoff) before computing");
    if (ff.types.empty()) throw Error("no particle types: add one with add_type (cf_add_type) before computing");
    ff.validate();
  }

  // The device's verdict on the compute_device calls since the last one (throws what it found).
  void synchronize() {
    if (!engine || !device_pending) return;
    device_pending = false;
    engine->synchronize(ff);
    record_statistics();
  }

  void record_statistics();
};

// Context::statistics_json()'s text (statistics_json.cpp): `ctx`'s statistics and those of its MD
// engine, `s`.
std::string statistics_text(const Context& ctx, const Context::Impl& s);

}  // namespace cellforce
