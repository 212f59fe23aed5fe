// Reuse of the neighbour structure between evaluations: a Verlet skin for the cell search.
//
// Stages 1-3 (cell IDs, sort, collision cells) depend on positions only through which cells each
// particle's box touches. Built for the cutoff rc + skin, the structure holds every pair closer
// than rc + skin exactly once (the design note's conditions, read with rc + skin). While no
// particle has moved more than skin / 2 since that build, a pair now closer than rc was closer
// than rc + skin then, so the traversal of the old structure with the current positions (staged
// afresh every evaluation, relative to the same cell centres) and the strict r < rc test finds
// every interacting pair exactly once. The engines then skip stages 1-3 until a particle has
// moved more than skin / 2 (the check), the box, particle count or cutoff change, or `every`
// evaluations have passed. With the check off, the audit counts what reuse got wrong: pairs
// now closer than rc that the old structure does not find (never visits, or visits with a particle
// staged as another image after a long move: missed) or finds more than once (repeated).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "core/box.h"
#include "core/engine_options.h"
#include "core/grid.h"
#include "core/system.h"

namespace cellforce {

struct ReuseOptions {
  double skin = 0.0;    // length units; 0: stages 1-3 run on every evaluation
  bool automatic = false;  // skin and list chosen by resolve_reuse() from the backend and the
                           // system (the API's and the scenes' default; the engines see the result)
  bool check = true;    // rebuild when a particle has moved more than skin / 2 since the build
  int64_t every = 0;    // a structure serves at most this many evaluations, its build's included
                        // (1: rebuild on every one; 0: no limit)
  bool audit = false;   // on every reused evaluation, count missed and repeated pairs against a
                        // fresh host search (slow: diagnostics and tests only)
  bool list = false;    // CUDA, with a skin and Jacobi accumulation: each build records every
                        // particle's partners within rc + skin (cuda/search/pair_list.cuh) and the
                        // evaluations it serves walk those lists instead of the cells' candidates
};

// Throws cellforce::Error naming the parameter (skin, every) when it is not usable.
void validate_reuse(const ReuseOptions& options);

// Whether the CUDA engine's evaluations walk pair lists with these (resolved) options: lists asked
// for, a skin, Jacobi accumulation, and rc + skin within half of every periodic edge (the minimum
// image then names each pair once). The one statement of the condition: the engine, the automatic
// choice and the description use it.
bool pair_lists_serve(const ReuseOptions& resolved, Accumulation accumulation, const Box& box, double cutoff);

// The automatic choice (ReuseOptions::automatic): a rule of the backend, the system and (through
// `memory`, the CUDA engine's lists_memory) the device's memory, not a timing, so that every run
// of a scene on the same device makes the same choice and the same bits (a system near a device's
// capacity may get another skin on a device with less memory).
// - An MD engine (md: its steps, minimisation) on CUDA with Jacobi accumulation, where rc + skin
//   fits in half of every periodic edge: pair lists with a skin of kAutoSkinPerCutoff x rc (0.6 at
//   in.lj's rc 2.5: of the skins validation/reports/performance.md compares, the one that serves
//   in.lj fastest from 32,000 to 1,048,576 particles, and far faster than the cells every step).
//   Where the lists run in lean memory (`memory`, from lists_memory: the device too small for the
//   fast layout), kAutoLeanSkinPerCutoff x rc: a lean build keeps its count pass's masks only in
//   the memory left, and a shorter list leaves more (performance.md: at ~100M particles of in.lj
//   every mask is held from a skin of 0.45 down, and 0.45 serves fastest).
// - Force calls (md false: compute, compute_device) take the same rule: on CUDA the device decides
//   compute_device's rebuilds (cuda/backend/call_graph.cuh), so the check makes it wait for nothing
//   once its graph is made.
// - Otherwise no skin: without lists the skin's larger cells cost the traversal about what the
//   skipped builds save (performance.md), and on the CPU the build is a few percent of an
//   evaluation (validation/reports/stability.md, table 11; performance.md, the CPU backend).
// `backend` is the one the engine runs on (cpu or cuda, not auto). check, every and audit are the
// caller's; with automatic false the options come back as they are.
inline constexpr double kAutoSkinPerCutoff = 0.24;
inline constexpr double kAutoLeanSkinPerCutoff = 0.18;
ReuseOptions resolve_reuse(const ReuseOptions& options, Backend backend, Accumulation accumulation, bool md,
                           const Box& box, double cutoff, ListMemory memory);

// The resolved choice in words, for run headers: "skin 0.6 (auto: 0.24 rc), pair lists",
// "skin 0.45 (auto: 0.18 rc, lean memory), pair lists", "none, stages 1-3 every evaluation (auto:
// no skin on the cpu)", "skin 0.3, cells reused" (what the engine does: lists asked for on the
// CPU, or where they do not fit, are cells reused). `memory` as resolve_reuse's.
std::string describe_reuse(const ReuseOptions& requested, const ReuseOptions& resolved, Backend backend,
                           Accumulation accumulation, bool md, const Box& box, double cutoff, ListMemory memory);

// When to rebuild, apart from the displacement: the first evaluation, a change of box, particle
// count or cutoff, skin 0, or a structure that has served `every` evaluations. Shared by both
// engines.
class ReusePolicy {
 public:
  explicit ReusePolicy(ReuseOptions options = {}) : options_(options) {}
  const ReuseOptions& options() const { return options_; }
  bool enabled() const { return options_.skin > 0.0; }
  // Whether the structure must be rebuilt whatever the displacement.
  bool must_rebuild(const SystemView& system, double cutoff) const;
  // Whether it must be rebuilt only because it has served `every` evaluations (same system).
  bool retired(const SystemView& system, double cutoff) const;
  // The decision of one evaluation, shared by the engines: must_rebuild(), else (when measured)
  // the largest squared displacement since the build, from displacement2() (the engine's own
  // reduction), against skin / 2. Sets stats.rebuilt and stats.max_displacement and zeroes the
  // audit's counts. With the check off, a rebuild that retires a structure after `every`
  // evaluations measures the displacement once, for stats.dangerous_build.
  template <class Displacement2>
  bool decide(const SystemView& system, double cutoff, Displacement2&& displacement2,
              PipelineStats& stats) const {
    bool rebuild = must_rebuild(system, cutoff);
    stats.max_displacement = 0;
    stats.missed_pairs = stats.repeated_pairs = 0;
    stats.dangerous_build = false;
    if (!rebuild && measures_displacement()) {
      const double d2 = displacement2();
      stats.max_displacement = std::sqrt(d2);
      rebuild = too_far(d2);
    } else if (rebuild && !options_.check && retired(system, cutoff)) {
      // Unchecked reuse: did the structure `every` retires outlive its exactness? (One reduction
      // per build; with the check on every structure is retired before that.)
      stats.dangerous_build = displacement2() > limit2();
    }
    stats.rebuilt = rebuild;
    return rebuild;
  }
  // Whether the displacement since the build (squared, largest over particles) asks for one.
  bool too_far(double max_displacement2) const { return options_.check && max_displacement2 > limit2(); }
  // (skin / 2)^2: the squared displacement a structure serves up to (the step gate compares its
  // bits on the device).
  double limit2() const {
    const double half = 0.5 * options_.skin;
    return half * half;
  }
  // Evaluations the structure in use may still serve before `every` asks for a rebuild (INT64_MAX
  // without a limit; 0 when none is valid).
  int64_t remaining() const {
    if (!valid_) return 0;
    return options_.every > 0 ? std::max<int64_t>(options_.every - served_, 0) : INT64_MAX;
  }
  // Whether the displacement needs computing on a reused evaluation (for the check or the audit;
  // a retiring build measures it once more for the dangerous-build count).
  bool measures_displacement() const { return enabled() && (options_.check || options_.audit); }
  void built(const SystemView& system, double cutoff);
  void reused(int64_t evaluations = 1) { served_ += evaluations; }
  // Builds the device decided since the host last looked (CUDA force calls: backend/call_graph.cuh),
  // and the evaluations the structure in use has served now, its build's included.
  void adopt(std::size_t device_builds, int64_t served) {
    builds_ += device_builds;
    served_ = served;
  }
  // The structure no longer matches the last build (a fresh search overwrote it).
  void invalidate() { valid_ = false; }
  std::size_t builds() const { return builds_; }
  std::size_t particles() const { return n_; }  // of the last build
  // Evaluations of the structure in use, its build's included (0 when none is valid); a restart
  // sets it back to what the uninterrupted run had (set_served, after rebuilding the structure).
  int64_t served() const { return valid_ ? served_ : 0; }
  void set_served(int64_t served) { served_ = served; }

 private:
  ReuseOptions options_;
  bool valid_ = false;
  Box box_;
  std::size_t n_ = 0;
  double cutoff_ = 0.0;
  int64_t served_ = 0;  // evaluations of the structure in use, its build's included
  std::size_t builds_ = 0;
};

// What a checkpoint keeps so that a restarted run reuses the structure the uninterrupted run was
// reusing (same cells, same order of the force sums: a bitwise restart): the positions it was
// built from (n x dim; empty when there is none) and the evaluations it had served.
struct ReuseState {
  std::vector<double> build_positions;
  int64_t served = 0;
};

// Largest squared displacement between two position arrays (n x box.dim, minimum image on
// periodic axes, so a particle wrapped back into the box counts what it moved, not L).
double max_displacement2(const Box& box, std::size_t n, const double* now, const double* then);

// Every pair (i < j) closer than `cutoff` (strict, minimum image), from a plain host cell list of
// edge >= cutoff: the audit's own search, independent of the engines' pipelines. In no order.
std::vector<std::pair<uint32_t, uint32_t>> pairs_within(const SystemView& system, double cutoff);

struct ReuseAudit {
  std::size_t missed = 0;    // pairs closer than rc that the structure never evaluates
  std::size_t repeated = 0;  // pairs closer than rc that it evaluates more than once
};

// How often the structure built on `grid` evaluates each of `pairs` as the interacting pair it
// is: the cells both particles' boxes touched at the build, that are one particle's H cell (so a
// collision cell that visits the pair), where the control-bit rule does not skip it, and where the
// separation of the coordinates staged relative to that cell's centre (as the traversal stages
// them, in double) is below the cutoff; a particle that moved too far is staged as another image
// and the pair is then out of range there. build_keys: n x 2^d, user order, as stage 1 wrote them
// (sort_key(), or kInvalidCell); control: n, from the same build; system: now.
ReuseAudit audit_reuse(const Grid& grid, const uint32_t* build_keys, const Control* control,
                       const SystemView& system, double cutoff,
                       const std::vector<std::pair<uint32_t, uint32_t>>& pairs);

// The audit of pair lists (CUDA's, cuda/search/pair_list.cuh): partners[i] holds the particles in i's
// list (user indices, any order). A pair of `pairs` (closer than rc now) is missed when either
// particle's list lacks the other (its force is not summed on that side), repeated when either
// list holds the other more than once.
ReuseAudit audit_lists(const std::vector<std::vector<uint32_t>>& partners,
                       const std::vector<std::pair<uint32_t, uint32_t>>& pairs);

}  // namespace cellforce
