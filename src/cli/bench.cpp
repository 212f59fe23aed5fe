#include "cli/bench.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <new>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>

#include <cellforce/cellforce.hpp>

#include "scene/engine_context.h"
#include "cli/options.h"
#include "core/error.h"
#include "core/grid.h"
#include "core/memory.h"
#include "core/names.h"
#include "core/numbers.h"
#include "core/option_table.h"
#include "core/text.h"
#include "io/output_paths.h"
#include "io/text_file.h"
#include "scene/scene.h"
#include "state/velocities.h"

#ifdef CELLFORCE_BENCH_EMBED
#include "cli/embed_loop.h"
#endif

#ifndef CELLFORCE_VERSION
#define CELLFORCE_VERSION "unknown"
#endif

namespace cellforce {
namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// fcc unit cells per axis whose 4 c^3 particles are nearest to n.
int fcc_cells_for(double n) {
  const int c = std::max(1, int(std::lround(std::cbrt(n / 4.0))));
  return c;
}

// The same particles (positions, velocities, types) numbered anew: particle i becomes the one that
// was from[i]. One array at a time through one scratch vector (the state's size over again would
// be ~5 GB at 100M particles). The forces are not set yet (they would need the same).
void renumber(MdState& state, const std::vector<std::size_t>& from) {
  if (!state.forces.empty()) throw Error("internal error: renumber() before the forces are set");
  const std::size_t n = state.config.size(), dim = std::size_t(state.config.box.dim);
  std::vector<double> scratch(n * dim);
  for (std::vector<double>* a : {&state.config.positions, &state.velocities}) {
    for (std::size_t i = 0; i < n; ++i)
      for (std::size_t c = 0; c < dim; ++c) scratch[i * dim + c] = (*a)[from[i] * dim + c];
    a->swap(scratch);
  }
  std::vector<uint32_t> types(n);
  for (std::size_t i = 0; i < n; ++i) types[i] = state.config.types[from[i]];
  state.config.types.swap(types);
}

// --order shuffled: a Fisher-Yates shuffle driven by std::mt19937_64 (fully specified: the same
// order everywhere). --order cells: by the sort key of the particle's H entry on the grid planned
// for rc + skin with the engine's cell rule and slabs, as a list build ranks them (home cell, then
// slab), the lattice's order kept inside a slab.
void apply_numbering(MdState& state, Numbering order, uint64_t seed, double cutoff, double skin, CellRule rule) {
  if (order == Numbering::kLattice) return;
  const std::size_t n = state.config.size();
  std::vector<std::size_t> from(n);
  for (std::size_t i = 0; i < n; ++i) from[i] = i;
  if (order == Numbering::kShuffled) {
    std::mt19937_64 rng(seed ^ 0x73687566666c65ull);
    for (std::size_t i = n; i > 1; --i) std::swap(from[i - 1], from[std::size_t(rng() % i)]);
  } else {
    GridOptions options;
    options.rule = rule;
    options.slabs = true;  // as the engine plans a grid its lists are built from
    const Grid g = plan_grid(state.config.box, cutoff, state.config.positions.data(), n, options, skin);
    std::vector<uint32_t> home(n);
    for (std::size_t i = 0; i < n; ++i) {
      double x[kMaxDim] = {0, 0, 0};
      uint32_t ids[kMaxCellTypes];
      uint32_t slab = 0;
      for (int a = 0; a < g.dim; ++a) x[a] = state.config.positions[i * std::size_t(g.dim) + std::size_t(a)];
      bin_particle(g, x, ids, &slab);
      home[i] = sort_key(g, ids[0], false, slab);
    }
    std::stable_sort(from.begin(), from.end(), [&](std::size_t a, std::size_t b) { return home[a] < home[b]; });
  }
  renumber(state, from);
}

// The skin asked for: auto (the engine's rule) or a length.
bool automatic_skin(const OptionList& engine) { return same_name(engine.value(OptionId::kSkin), kAutoSkin); }
double skin_length(const OptionList& engine) {
  double skin = 0;
  read_real(engine.value(OptionId::kSkin), skin);  // a length (format_number's text) unless auto
  return skin;
}

// The integrator of a size: in.lj's NVE, or Langevin at its temperature.
IntegratorOptions bench_integrator(const BenchArgs& args, const Scene& scene) {
  IntegratorOptions integrator;
  integrator.kind = args.langevin ? Integrator::kLangevin : Integrator::kVerlet;
  integrator.dt = scene.integrator.dt;
  integrator.temperature = scene.initial_temperature;  // kT 1.44
  integrator.friction = 1.0;
  integrator.seed = scene.seed;
  return integrator;
}

// The skin the context gives this state (auto resolved for its backend, box and size): what a
// numbering by cells plans its grid for. A context of its own, given back before the timed one is
// made, so that the timed context starts as every other size's does.
double skin_in_effect(const BenchArgs& args, const OptionList& engine, const Scene& scene, const MdState& state,
                      const std::vector<double>& masses) {
  Context probe = make_context(state.config.box, scene.force_field, engine);
  probe.set_integrator(bench_integrator(args, scene));
  probe.set_state(state.config.size(), state.config.positions.data(), state.velocities.data(),
                  state.config.types.data(), masses.data());
  return probe.skin();
}

// Least-squares slope of y against x.
double slope(const std::vector<double>& x, const std::vector<double>& y) {
  const double n = double(x.size());
  double sx = 0, sy = 0;
  for (std::size_t i = 0; i < x.size(); ++i) sx += x[i], sy += y[i];
  const double mx = sx / n, my = sy / n;
  double sxy = 0, sxx = 0;
  for (std::size_t i = 0; i < x.size(); ++i) sxy += (x[i] - mx) * (y[i] - my), sxx += (x[i] - mx) * (x[i] - mx);
  return sxx > 0 ? sxy / sxx : NAN;
}

// Per particle |F_i - R_i| / |R_i| (particles whose reference force is exactly zero are left out):
// the median and the largest.
std::pair<double, double> force_errors(const std::vector<double>& f, const std::vector<double>& ref, int dim) {
  std::vector<double> rel;
  rel.reserve(ref.size() / std::size_t(dim));
  for (std::size_t i = 0; i * std::size_t(dim) < ref.size(); ++i) {
    double d2 = 0, r2 = 0;
    for (int a = 0; a < dim; ++a) {
      const double d = f[i * dim + a] - ref[i * dim + a];
      d2 += d * d;
      r2 += ref[i * dim + a] * ref[i * dim + a];
    }
    if (r2 > 0) rel.push_back(std::sqrt(d2 / r2));
  }
  if (rel.empty()) return {NAN, NAN};
  return {cli::median(rel), *std::max_element(rel.begin(), rel.end())};
}

// n doubles in the machine's byte order (little-endian on x86 and ARM), written whole or not at all.
void save_doubles(const std::string& path, const std::vector<double>& v) {
  write_bytes_atomically(path, v.data(), v.size() * sizeof(double), "the final configuration");
}

// The prefix of the --save-final files of a size of n particles.
std::string save_final_prefix(const BenchArgs& args, std::size_t n) { return args.save_final + "-" + std::to_string(n); }

struct SizeResult {
  nlohmann::json row;
  bool ok = false;
};

// One size's timed run: what it is given and where it writes (the row, the last configuration).
struct TimedRun {
  const BenchArgs& args;
  const Scene& scene;
  const MdState& state;
  const std::vector<double>& masses;
  double planned_skin;  // the numbering by cells was planned for it (0 otherwise)
  nlohmann::json& row;
  std::vector<double>& final_positions;
  std::vector<double>& final_forces;
};

// What the timed chunks measured: the steps, their wall time, and the total energy per particle at
// the start and after each chunk, against time.
struct Chunks {
  int64_t steps = 0, warmup_steps = 0;
  double seconds = 0, setup_seconds = 0;
  std::vector<double> t, e;
};

// Warm-up (allocations, first builds), then a calibration of the rate, both excluded; then the
// timed steps in `samples` chunks, each ending with an energy sample (its wait in the chunk's
// time). advance(count, observe) queues steps; energy() waits for them and gives the total energy;
// start() runs once before the timed chunks.
template <class Advance, class Energy, class Start>
Chunks time_chunks(const TimedRun& run, Clock::time_point t_setup, Advance advance, Energy energy, Start start) {
  const BenchArgs& args = run.args;
  const double n = double(run.state.config.size());
  Chunks c;
  advance(std::max<int64_t>(args.warmup, 1), true);
  energy();
  const auto t_cal = Clock::now();
  const int64_t cal_steps = std::max<int64_t>(args.warmup / 2, 5);
  advance(cal_steps, true);
  energy();
  const double cal_rate = double(cal_steps) / std::max(seconds_since(t_cal), 1e-9);
  c.setup_seconds = seconds_since(t_setup);
  c.warmup_steps = std::max<int64_t>(args.warmup, 1) + cal_steps;
  const int samples = std::max(args.samples, 2);
  int64_t steps = args.steps > 0 ? args.steps : int64_t(std::ceil(args.seconds * cal_rate));
  steps = std::max<int64_t>(steps, samples);
  const int64_t chunk = (steps + samples - 1) / samples;
  c.steps = chunk * samples;
  start();
  c.t.push_back(0.0);
  c.e.push_back(energy() / n);
  for (int s = 0; s < samples; ++s) {
    const auto t0 = Clock::now();
    advance(chunk, true);
    const double total = energy();
    c.seconds += seconds_since(t0);
    c.t.push_back(double((s + 1) * chunk) * run.scene.integrator.dt);
    c.e.push_back(total / n);
  }
  return c;
}

// The row's timing and energy fields from the chunks.
void record_chunks(const TimedRun& run, const Chunks& c) {
  nlohmann::json& row = run.row;
  const double n = double(run.state.config.size());
  row["setup_seconds"] = c.setup_seconds;
  row["steps"] = c.steps;
  row["warmup_steps"] = c.warmup_steps;
  row["seconds"] = c.seconds;
  row["steps_per_second"] = double(c.steps) / c.seconds;
  row["particle_steps_per_second"] = double(c.steps) * n / c.seconds;
  row["ms_per_step"] = 1e3 * c.seconds / double(c.steps);
  row["energy_per_particle_start"] = c.e.front();
  row["energy_per_particle_end"] = c.e.back();
  row["nve_drift"] = run.args.langevin ? NAN : slope(c.t, c.e);  // per particle per unit time (NVE only)
  row["nve_time_span"] = c.t.back();
}

// The row's fields from the run statistics of the timed steps: RunStatistics, and the engine's own
// from statistics_json()'s "run" object (`engine`).
void record_run_statistics(nlohmann::json& row, const RunStatistics& st, const nlohmann::json& engine, int64_t steps,
                           std::size_t n) {
  const double per_step = 1e3 / double(steps);
  row["forces_ms_per_step"] = per_step * st.force_seconds;
  row["integration_ms_per_step"] = per_step * st.integration_seconds;
  nlohmann::json stages = nlohmann::json::object();
  for (const auto& [stage, seconds] : engine.at("stage_seconds").items()) stages[stage] = 1e3 * seconds.get<double>();
  stages["samples"] = engine.at("stage_samples");
  row["stage_ms_per_evaluation"] = stages;
  row["builds"] = st.builds;
  row["evaluations"] = st.evaluations;
  const int64_t list_evaluations = engine.at("list_evaluations");
  row["gated_steps"] = engine.at("gated_steps");
  row["list_evaluations"] = list_evaluations;
  row["neighbor_list"] = st.evaluations > 0 && list_evaluations == st.evaluations;  // lists served every step
  row["dangerous_builds"] = st.dangerous_builds;
  row["bytes_per_step_host_device"] = double(st.bytes_to_host + st.bytes_to_device) / double(steps);
  row["buffer_bytes"] = st.buffer_bytes;
  for (const char* key : {"list_pairs", "list_slots", "list_mask_words", "list_mask_words_held", "graph_builds",
                          "list_block", "gate_closings", "gate_closings_early"})
    row[key] = engine.at(key);
  row["state_bytes"] = st.state_bytes;
  row["bytes_per_particle"] = double(st.buffer_bytes + st.state_bytes) / double(n);
  row["memory_by_buffer"] = nlohmann::json::array();  // [name, bytes], largest first
  for (const nlohmann::json& buffer : engine.at("memory"))
    row["memory_by_buffer"].push_back({buffer.at("name"), buffer.at("bytes")});
}

// The context's own MD loop (Context::step).
void time_steps(const TimedRun& run, Context& ctx) {
  const BenchArgs& args = run.args;
  nlohmann::json& row = run.row;
  const MdState& state = run.state;
  const std::size_t n = state.config.size();
  row["loop"] = "step";
  row["integrator"] = args.langevin ? "langevin" : "nve";
  ctx.set_integrator(bench_integrator(args, run.scene));
  const auto t_setup = Clock::now();
  ctx.set_state(n, state.config.positions.data(), state.velocities.data(), state.config.types.data(),
                run.masses.data());
  row["external_force"] = args.external_force;
  if (args.external_force > 0) {
    const std::size_t dim = std::size_t(state.config.box.dim);
    std::vector<double> field(n * dim, 0.0);
    for (std::size_t i = 0; i < n; ++i) field[i * dim] = i % 2 == 0 ? args.external_force : -args.external_force;
    ctx.set_external_forces(n, field.data());
  }
  row["backend"] = ctx.backend_name();
  row["description"] = ctx.description();
  row["traversal"] = ctx.traversal();
  row["sort"] = ctx.sort();
  row["skin"] = ctx.skin();  // in effect (auto resolved)
  if (args.order == Numbering::kCells && ctx.skin() != run.planned_skin)  // the numbering's grid
    throw Error("internal error: the numbering was planned for the skin " + std::to_string(run.planned_skin) +
                ", the context has " + std::to_string(ctx.skin()));
  row["neighbor"] = ctx.neighbor();
  Thermo th;
  const Chunks c = time_chunks(
      run, t_setup, [&](int64_t count, bool observe) { ctx.step(count, observe); },
      [&] {
        th = ctx.thermo();
        return th.total;
      },
      [&] { ctx.reset_run_statistics(); });  // the run statistics of the timed chunks
  record_chunks(run, c);
  record_run_statistics(row, ctx.run_statistics(), nlohmann::json::parse(ctx.statistics_json()).at("run"), c.steps,
                        n);
  row["temperature_end"] = th.temperature;
  ctx.get_state(run.final_positions.data(), nullptr, run.final_forces.data());
}

// An embedding code's loop (cli/embed_loop.h): its own velocity Verlet around compute_device.
void time_embedded(const TimedRun& run, Context& ctx) {
#ifdef CELLFORCE_BENCH_EMBED
  const BenchArgs& args = run.args;
  nlohmann::json& row = run.row;
  const MdState& state = run.state;
  const std::size_t n = state.config.size();
  if (args.langevin) throw Error("--embed: the embedding loop is velocity Verlet (NVE); leave out --langevin");
  if (args.external_force > 0) throw Error("--embed: the embedding loop has no external force; leave out --external-force");
  if (args.order == Numbering::kCells)  // planned for step()'s skin, which the force calls do not use
    throw Error("--embed: --order cells numbers the particles for step()'s neighbour grid; use lattice or shuffled");
  if (ctx.backend_name() != "cuda") throw Error("--embed: needs the cuda backend (compute_device)");
  row["loop"] = "embed";
  row["integrator"] = "nve";
  const auto t_setup = Clock::now();
  EmbeddedVerlet loop(ctx, n, state.config.positions.data(), state.velocities.data(), state.config.types.data(),
                      run.masses.data(), run.scene.integrator.dt);
  row["backend"] = ctx.backend_name();
  row["description"] = ctx.description();
  row["traversal"] = ctx.traversal();
  row["sort"] = ctx.sort();
  row["skin"] = ctx.skin();  // force calls: as the context resolves it for them
  row["neighbor"] = ctx.neighbor();
  std::size_t builds_before = 0;
  const Chunks c = time_chunks(
      run, t_setup, [&](int64_t count, bool observe) { loop.step(count, observe); },
      [&] { return loop.total_energy(); }, [&] { builds_before = ctx.statistics().builds; });
  record_chunks(run, c);
  const Statistics st = ctx.statistics();  // of the last force call
  row["stage_ms_per_evaluation"] = {{"cell_ids", 1e3 * st.cell_ids_seconds},
                                    {"sort", 1e3 * st.sort_seconds},
                                    {"collision_cells", 1e3 * st.collision_cells_seconds},
                                    {"traversal", 1e3 * st.traversal_seconds},
                                    {"accumulate", 1e3 * st.accumulate_seconds},
                                    {"total", 1e3 * st.pipeline_seconds},
                                    {"samples", 1}};
  row["builds"] = int64_t(st.builds - builds_before);
  row["evaluations"] = c.steps;
  row["compute_device_host_us"] = 1e6 * loop.call_host_seconds();
  row["buffer_bytes"] = st.buffer_bytes;
  row["bytes_per_particle"] = double(st.buffer_bytes) / double(n);  // the engine's; the loop's own arrays not
  loop.download(run.final_positions.data(), run.final_forces.data());
#else
  (void)run;
  (void)ctx;
  throw Error("--embed: this cellforce was built without CUDA");
#endif
}

// One size: warm-up, calibration, timed chunks with energy samples, then the reference.
SizeResult bench_size(const BenchArgs& args, const OptionList& engine, int cells, const std::string& label) {
  SizeResult out;
  nlohmann::json& row = out.row;
  Scene scene = default_scene();
  scene.particles.cells = {cells, cells, cells};
  scene.force_field.mode = args.mode;
  const double n_sites = 4.0 * double(cells) * double(cells) * double(cells);
  row = {{"engine", "cellforce"},
         {"configuration", label},
         {"precision", engine.value(OptionId::kPrecision)},
         {"n", std::size_t(n_sites)},
         {"fcc_cells", cells},
         {"cutoff", scene.force_field.cutoff},
         {"cutoff_mode", to_string(args.mode)},
         {"skin_requested", automatic_skin(engine) ? nlohmann::json(kAutoSkin) : nlohmann::json(skin_length(engine))}};
  try {
    check_particle_count(n_sites, 3, "fcc " + std::to_string(cells) + "^3 unit cells");
    MdState state;
    state.config = build_configuration(scene);
    const std::size_t n = state.config.size();
    const int dim = 3;
    const std::vector<double> masses(n, scene.masses[0]);
    initialize_velocities(state, masses, scene.initial_temperature, scene.seed, !args.langevin);
    row["order"] = name_of(args.order, kNumberingNames);
    row["memory"] = engine.value(OptionId::kMemory);  // as asked (--memory)
    // The numbering by cells plans its grid for the skin in effect (checked against the timed
    // context's below).
    const double planned_skin =
        args.order == Numbering::kCells ? skin_in_effect(args, engine, scene, state, masses) : 0.0;
    const CellRule rule = parse_name(engine.value(OptionId::kCellRule), kCellRuleNames).value_or(CellRule::kTight);
    apply_numbering(state, args.order, scene.seed, scene.force_field.cutoff, planned_skin, rule);
    std::vector<double> final_positions(n * dim), final_forces(n * dim);
    {
      Context ctx = make_context(state.config.box, scene.force_field, engine);
      const TimedRun run{args, scene, state, masses, planned_skin, row, final_positions, final_forces};
      if (args.embed) time_embedded(run, ctx);
      else time_steps(run, ctx);
    }  // the timed context's memory is given back before the reference needs its own
    if (!args.save_final.empty()) {
      const std::string prefix = save_final_prefix(args, n);
      save_doubles(prefix + ".positions.f64", final_positions);
      save_doubles(prefix + ".forces.f64", final_forces);
      row["saved"] = prefix;
    }
    out.ok = true;  // the timing stands whatever becomes of the reference
    if (args.reference) {
      try {
        OptionList ref_engine = engine;
        ref_engine.set(OptionId::kPrecision, name_of(Precision::kDouble, kPrecisionNames));
        ref_engine.set(OptionId::kSkin, format_number(0.0));  // no skin: the cells, built once
        ref_engine.set(OptionId::kNeighborList, name_of(false, kBooleanNames));
        Context ref = make_context(state.config.box, scene.force_field, ref_engine);
        std::vector<double> ref_forces(n * dim);
        Outputs o;
        o.forces = ref_forces.data();
        ref.compute(n, final_positions.data(), state.config.types.data(), o);
        const auto [med, worst] = force_errors(final_forces, ref_forces, dim);
        row["force_error_median"] = med;
        row["force_error_max"] = worst;
        row["force_error_reference"] = ref.backend_name() + " double, same configuration (the run's last)";
      } catch (const std::bad_alloc&) {
        row["force_error_failure"] = "out of memory (host) for the double-precision reference";
      } catch (const std::exception& e) {
        row["force_error_failure"] = std::string("the double-precision reference failed: ") + e.what();
      }
    }
  } catch (const std::bad_alloc&) {
    row["error"] = "out of memory (host) at " + std::to_string(std::size_t(n_sites)) + " particles";
  } catch (const std::exception& e) {
    row["error"] = e.what();
  }
  return out;
}

std::string fixed(double v, const char* fmt) {
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, v);
  return buf;
}

double number_or_nan(const nlohmann::json& row, const char* key) {
  return row.contains(key) && row[key].is_number() ? row[key].get<double>() : NAN;
}

}  // namespace

int run_bench(const BenchArgs& args) {
  std::vector<int> cells = args.cells;
  for (const double n : args.sizes) {
    if (!(n >= 1) || !std::isfinite(n)) throw Error("--sizes: expected particle counts >= 1, got " + fixed(n, "%g"));
    cells.push_back(fcc_cells_for(n));
  }
  if (cells.empty()) cells = {20, 40, 64, 102};  // 32,000, 256,000, 1,048,576 and 4,244,832 particles
  if (args.samples < 2) throw Error("--samples: at least 2 energy samples, got " + std::to_string(args.samples));
  if (args.warmup < 1) throw Error("--warmup: at least 1 step, got " + std::to_string(args.warmup));
  if (!(args.seconds > 0)) throw Error("--seconds: expected a time > 0");

  OptionList engine = args.engine;
  std::string label = args.label;
  if (args.chapter) {  // a thread per cell, the chapter's sort and cell rule, a rebuild every step
    engine.set(OptionId::kTraversal, name_of(TraversalForm::kThreadPerCell, kTraversalNames));
    engine.set(OptionId::kSort, name_of(SortMethod::kChapter, kSortNames));
    engine.set(OptionId::kCellRule, name_of(CellRule::kChapter, kCellRuleNames));
    engine.set(OptionId::kSkin, format_number(0.0));
    engine.set(OptionId::kNeighborList, name_of(false, kBooleanNames));
    if (label.empty()) label = "chapter";
  }
  if (label.empty()) label = "default";
  if (automatic_skin(engine) && engine.flag(OptionId::kNeighborList))
    throw Error("--neighbor-list: give a skin (--skin); without one the skin is auto, which chooses pair lists itself");
  // Every file the bench will write is checked (and claimed) before the first size is timed; each
  // is replaced when it exists, as a rerun of the bench expects.
  std::vector<OutputFile> outputs = {{args.json, "--json", true}};
  if (!args.save_final.empty())
    for (const int c : cells) {
      const std::string prefix = save_final_prefix(args, std::size_t(4) * std::size_t(c) * std::size_t(c) * std::size_t(c));
      // Two sizes that round to one fcc lattice write the same files, each in its turn.
      if (std::none_of(outputs.begin(), outputs.end(), [&](const OutputFile& o) { return o.path == prefix + ".forces.f64"; })) {
        outputs.push_back({prefix + ".positions.f64", "--save-final", true});
        outputs.push_back({prefix + ".forces.f64", "--save-final", true});
      }
    }
  const OutputClaim claim = claim_output_files(outputs, {}, "");

  const bool lists = engine.flag(OptionId::kNeighborList);
  const std::string reuse = automatic_skin(engine)    ? ", skin auto"
                            : skin_length(engine) > 0 ? ", skin " + fixed(skin_length(engine), "%g") +
                                                            (lists ? " with pair lists" : "")
                                                      : ", no skin";
  std::printf("cellforce bench: LAMMPS in.lj (fcc, density 0.8442, rc 2.5 %s, T 1.44, %s, dt 0.005), %s, "
              "precision %s%s\n",
              to_string(args.mode), args.langevin ? "Langevin kT 1.44 friction 1" : "NVE", label.c_str(),
              engine.value(OptionId::kPrecision).c_str(), reuse.c_str());
  std::printf("%12s %14s %10s %12s %10s %9s %9s %9s %9s %9s %8s %8s %11s %11s\n", "N", "form", "steps/s",
              "particle-st/s", "ms/step", "ids", "sort", "cells", "trav", "accum", "st/build", "B/part",
              "F err med", "NVE drift");
  nlohmann::json rows = nlohmann::json::array();
  bool failed = false;
  for (const int c : cells) {
    SizeResult r = bench_size(args, engine, c, label);
    const nlohmann::json& row = r.row;
    if (!r.ok) {
      failed = true;
      std::printf("%12zu  error: %s\n", row["n"].get<std::size_t>(), row["error"].get<std::string>().c_str());
    } else {
      const nlohmann::json& st = row["stage_ms_per_evaluation"];
      std::printf("%12zu %14s %10.1f %12.4g %10.4f %9.4f %9.4f %9.4f %9.4f %9.4f %8.1f %8.0f %11.3g %11.3g\n",
                  row["n"].get<std::size_t>(), row["traversal"].get<std::string>().c_str(),
                  row["steps_per_second"].get<double>(), row["particle_steps_per_second"].get<double>(),
                  row["ms_per_step"].get<double>(), st["cell_ids"].get<double>(), st["sort"].get<double>(),
                  st["collision_cells"].get<double>(), st["traversal"].get<double>(), st["accumulate"].get<double>(),
                  double(row["steps"].get<int64_t>()) / double(std::max<int64_t>(row["builds"].get<int64_t>(), 1)),
                  row["bytes_per_particle"].get<double>(), number_or_nan(row, "force_error_median"),
                  row["nve_drift"].get<double>());
    }
    std::fflush(stdout);
    rows.push_back(row);
    if (!args.json.empty()) {  // after every size: a later size that crashes the process loses nothing
      nlohmann::json doc = {{"version", CELLFORCE_VERSION}, {"rows", rows}};
      write_text_atomically(args.json, {doc.dump(1)}, "the bench JSON");
    }
  }
  std::printf("stage times are per sampled force evaluation (ms, device time with cuda); B/part: device (or host) "
              "bytes of the engine's buffers and the MD state per particle; F err med: median over particles of "
              "|F - F_double| / |F_double| at the last step; NVE drift: slope of E_total / N against time\n");
  return failed ? 1 : 0;
}

}  // namespace cellforce
