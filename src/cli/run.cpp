#include "cli/run.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <filesystem>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>

#include <cellforce/cellforce.hpp>
#include <nlohmann/json.hpp>

#include "scene/engine_context.h"
#include "scene/scene_start.h"
#include "core/error.h"
#include "core/names.h"
#include "core/numbers.h"
#include "core/option_table.h"
#include "core/text.h"
#include "io/checkpoint.h"
#include "io/h5md_writer.h"
#include "io/output_paths.h"
#include "io/text_file.h"
#include "scene/scene.h"
#include "state/md_state.h"
#include "state/velocities.h"

#ifndef CELLFORCE_VERSION
#define CELLFORCE_VERSION "unknown"
#endif

namespace cellforce {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

std::string duration_text(double s) {
  char buf[64];
  if (!std::isfinite(s) || s < 0) return "?";
  if (s < 60) std::snprintf(buf, sizeof buf, "%.0f s", s);
  else if (s < 3600) std::snprintf(buf, sizeof buf, "%d min %02d s", int(s / 60), int(s) % 60);
  else std::snprintf(buf, sizeof buf, "%d h %02d min", int(s / 3600), int(s / 60) % 60);
  return buf;
}

// A progress bar on a terminal (redrawn in place, at most 5 times a second), plain lines every
// 10% otherwise. Thermo lines go through print() so that they appear above the bar.
class Progress {
 public:
  Progress(int64_t first, int64_t last, bool enabled)
      : first_(first), last_(last), enabled_(enabled), tty_(::isatty(STDOUT_FILENO) != 0), start_(Clock::now()) {}
  void print(const std::string& line) {
    if (tty_ && drawn_) std::printf("\r\033[K");
    std::printf("%s\n", line.c_str());
    drawn_ = false;
    if (enabled_ && tty_) draw(current_);
    std::fflush(stdout);
  }
  void update(int64_t step) {
    current_ = step;
    if (!enabled_ || last_ <= first_) return;
    const double t = seconds_since(start_);
    if (tty_) {
      if (t - last_draw_ >= 0.2 || step == last_) draw(step), last_draw_ = t;
    } else {
      const int64_t decile = (step - first_) * 10 / (last_ - first_);
      if (decile > last_decile_) {
        last_decile_ = decile;
        std::printf("progress: %s\n", status(step).c_str());
        std::fflush(stdout);
      }
    }
  }
  void finish() {
    if (tty_ && drawn_) std::printf("\n");
    std::fflush(stdout);
  }

 private:
  std::string status(int64_t step) const {
    const double t = seconds_since(start_);
    const double done = double(step - first_), total = double(last_ - first_);
    const double rate = t > 0 ? done / t : 0;
    char buf[160];
    std::snprintf(buf, sizeof buf, "%3.0f%%  step %lld of %lld  %.1f steps/s  %s left", 100.0 * done / total,
                  (long long)step, (long long)last_, rate, duration_text(rate > 0 ? (total - done) / rate : NAN).c_str());
    return buf;
  }
  void draw(int64_t step) {
    const int width = 30;
    const int filled = int(double(step - first_) / double(last_ - first_) * width);
    std::string bar(std::size_t(width), ' ');
    for (int k = 0; k < filled; ++k) bar[std::size_t(k)] = '#';
    std::printf("\r\033[K[%s] %s", bar.c_str(), status(step).c_str());
    std::fflush(stdout);
    drawn_ = true;
  }
  int64_t first_, last_;
  bool enabled_, tty_;
  Clock::time_point start_;
  double last_draw_ = -1;
  int64_t last_decile_ = 0;
  int64_t current_ = 0;
  bool drawn_ = false;
};

// The thermo CSV file of an earlier run: its header and its rows with their steps.
struct ThermoRows {
  std::string header;
  std::vector<std::pair<int64_t, std::string>> rows;
};

ThermoRows read_thermo_rows(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot read the thermo file");
  ThermoRows out;
  long line_no = 0;
  for (std::string line; std::getline(in, line);) {
    ++line_no;
    if (line_no == 1) {
      out.header = line;
      continue;
    }
    if (line.empty()) continue;
    long long row_step = 0;
    const auto [ptr, ec] = std::from_chars(line.data(), line.data() + line.size(), row_step);
    if (ec != std::errc() || ptr == line.data() + line.size() || *ptr != ',')
      throw Error(path + ":" + std::to_string(line_no) + ": not a thermo row (step,time,...): " + quote_excerpt(line));
    out.rows.emplace_back(int64_t(row_step), line);
  }
  return out;
}

// A restart continues the rows (frames) of an earlier run's file from the checkpoint's step on;
// where the file holds entries before the checkpoint, they must reach to within one interval of
// it, or the continued file would have a gap (a checkpoint of another, longer run; a file cut
// short). A file with no entry up to the checkpoint (started by an earlier restart, or added to
// the scene since) is continued as it is. `steps` are the file's, in order; `every` the run's
// interval (the file's own, read from its first two entries, when larger).
void check_covers(const std::vector<int64_t>& steps, int64_t checkpoint_step, int64_t every, const std::string& path,
                  const std::string& restart, const char* what) {
  int64_t spacing = every;
  if (steps.size() >= 2 && steps[1] > steps[0]) spacing = std::max(spacing, steps[1] - steps[0]);
  int64_t last = -1;
  for (const int64_t s : steps)
    if (s <= checkpoint_step) last = std::max(last, s);
  if (last >= 0 && checkpoint_step - last >= spacing)  // a difference: no overflow near INT64_MAX
    throw Error(restart + ": checkpoint at step " + std::to_string(checkpoint_step) + ", but " + path + " holds " +
                what + " up to step " + std::to_string(last) +
                " only: continuing would leave a gap (is the checkpoint from another run? --overwrite starts "
                "afresh instead)");
}

// The scene with the command line's overrides applied.
Scene scene_for(const RunArgs& args) {
  Scene scene = args.scene.empty() ? default_scene() : read_scene(args.scene);
  if (args.steps >= 0) scene.steps = args.steps;
  // The command line's engine options replace the scene's (checked here too: RunArgs may come from
  // elsewhere than the command line, whose flags check them already).
  for (const auto& [id, value] : {std::pair<OptionId, const std::string&>{OptionId::kBackend, args.backend},
                                  {OptionId::kPrecision, args.precision},
                                  {OptionId::kTraversal, args.traversal}}) {
    if (value.empty()) continue;
    const char* name = option_name(id, value);
    if (!name)
      throw Error(option_flag(id) + " " + quote_excerpt(value) + ": expected " + name_list(option_spec(id).names));
    scene.engine.set(id, name);
  }
  if (!args.thermo_file.empty()) scene.output.thermo_file = args.thermo_file;
  if (args.skin_auto)
    scene.engine.set(OptionId::kSkin, kAutoSkin);
  else if (!(args.skin < 0))  // NaN too: the context's set_option names it
    scene.engine.set(OptionId::kSkin, format_number(args.skin));
  if (!args.trajectory.empty()) scene.output.trajectory = args.trajectory;
  if (args.trajectory_every > 0) {
    if (scene.output.trajectory.empty()) throw Error("--trajectory-every: the run writes no trajectory (--trajectory)");
    scene.output.trajectory_every = args.trajectory_every;
  }
  return scene;
}

// Every output is checked, and claimed for this run, before anything is computed: a fresh run does
// not replace an earlier one's outputs unless asked to; no output may be another output or an
// input; a run whose outputs another run is writing (two runs started at once into one folder, or
// two restarts of one run) is refused before it touches any file.
OutputClaim claim_outputs(const RunArgs& args, const Scene& scene, bool restart) {
  const SceneOutput& output = scene.output;
  std::vector<InputFile> inputs;
  if (!args.scene.empty()) inputs.push_back({args.scene, "scene file"});
  if (scene.particles.source == ParticleSource::kFile) inputs.push_back({scene.particles.path, "[particles] path"});
  if (restart) inputs.push_back({args.restart, "--restart checkpoint"});
  const bool replace = restart || args.overwrite;
  return claim_output_files(
      {{output.thermo_file, args.thermo_file.empty() ? "[output] thermo_file" : "--thermo-file", replace},
       {output.trajectory, args.trajectory.empty() ? "[output] trajectory" : "--trajectory", replace},
       {output.checkpoint, "[output] checkpoint", replace}},
      inputs,
      "an earlier run's output: continue that run with --restart CHECKPOINT, or replace it with --overwrite",
      {{"--restart checkpoint", "[output] checkpoint"}});
}

// The trajectory's elements and the names of its species (the scene's types).
H5mdOptions trajectory_options(const SceneOutput& output) {
  H5mdOptions o;
  o.velocities = output.velocities;
  o.forces = output.forces;
  o.observables = {"potential_energy", "kinetic_energy", "total_energy", "temperature", "pressure"};
  o.creator_version = CELLFORCE_VERSION;
  return o;
}

std::vector<std::string> type_names(const Scene& scene) {
  std::vector<std::string> names;
  for (const ParticleType& t : scene.force_field.types) names.push_back(t.name);
  return names;
}

// The thermo CSV and the H5MD trajectory of a run. On a restart the thermo rows and trajectory
// frames beyond the checkpoint are dropped (that part of the run is redone); the thermo file is
// rewritten under a temporary name. The earlier files are read (and checked to reach the
// checkpoint) before either is changed.
class RunFiles {
 public:
  RunFiles(const RunArgs& args, const Scene& scene, const MdState& state, bool restart) : output_(scene.output) {
    std::vector<std::string> rows;
    if (restart && !output_.thermo_file.empty() && std::filesystem::exists(output_.thermo_file)) {
      const ThermoRows earlier = read_thermo_rows(output_.thermo_file);
      std::vector<int64_t> steps;
      for (const auto& [step, line] : earlier.rows) steps.push_back(step);
      check_covers(steps, state.step, output_.thermo_every, output_.thermo_file, args.restart, "thermo rows");
      // The row at the checkpoint's step stays only if the uninterrupted run writes one there (a
      // run also writes a row at its last step).
      rows.push_back(earlier.header);
      for (const auto& [step, line] : earlier.rows)
        if (step < state.step || (step == state.step && step % output_.thermo_every == 0)) rows.push_back(line);
    }
    if (restart && !output_.trajectory.empty() && std::filesystem::exists(output_.trajectory))
      check_covers(H5mdWriter::stored_steps(output_.trajectory), state.step, output_.trajectory_every,
                   output_.trajectory, args.restart, "trajectory frames");
    if (!output_.thermo_file.empty()) {
      if (rows.empty()) rows.push_back("step,time,temperature,kinetic_energy,potential_energy,total_energy,pressure");
      write_text_atomically(output_.thermo_file, rows, "the thermo file");
      csv_ = std::make_unique<std::ofstream>(output_.thermo_file, std::ios::app);
      if (!*csv_) throw Error(output_.thermo_file + ": cannot write the thermo file");
    }
    if (!output_.trajectory.empty()) {
      H5mdOptions o = trajectory_options(output_);
      o.append = restart && std::filesystem::exists(output_.trajectory);
      if (restart && !o.append)
        std::printf("note: %s does not exist; it starts at step %lld\n", output_.trajectory.c_str(),
                    (long long)state.step);
      trajectory_ = std::make_unique<H5mdWriter>(output_.trajectory, state.config.box, state.config.types,
                                                 type_names(scene), o);
      if (o.append) trajectory_->truncate_after(state.step);
    }
  }

  bool has_trajectory() const { return trajectory_ != nullptr; }

  void write_frame(const MdState& s, const Thermo& th) {
    trajectory_->write_frame(s.step, s.time, s.config.positions.data(),
                             output_.velocities ? s.velocities.data() : nullptr,
                             output_.forces ? s.forces.data() : nullptr,
                             {th.potential, th.kinetic, th.total, th.temperature, th.pressure});
  }

  void write_row(int64_t step, double time, const Thermo& th) {
    if (!csv_) return;
    char line[320];
    std::snprintf(line, sizeof line, "%lld,%.10g,%.12g,%.17g,%.17g,%.17g,%.12g\n", (long long)step, time,
                  th.temperature, th.kinetic, th.potential, th.total, th.pressure);
    *csv_ << line << std::flush;
    if (!*csv_) throw Error(output_.thermo_file + ": cannot write the thermo file (disk full?)");
  }

  void close() {
    if (trajectory_) trajectory_->close();
  }

 private:
  const SceneOutput& output_;
  std::unique_ptr<std::ofstream> csv_;
  std::unique_ptr<H5mdWriter> trajectory_;
};

void print_header(const Scene& scene, const MdState& state, Context& ctx, const std::string& minimize_line,
                  const RunArgs& args, std::size_t wrapped) {
  const ForceField& ff = scene.force_field;
  const int dim = scene.dim;
  std::printf("cellforce run: %s\n", scene.source.c_str());
  std::printf("  %zu particles, %dD, box", state.config.size(), dim);
  for (int a = 0; a < dim; ++a)
    std::printf(" %.6g%s", state.config.box.length[a], state.config.box.periodic[a] ? "" : " (open)");
  std::printf(", %zu type(s); cutoff %g (%s)\n", ff.types.size(), ff.cutoff, to_string(ff.mode));
  // The neighbour structure as the engine resolved it (skin auto: a rule of backend and box).
  int64_t every = 0;  // checked as the scene was read
  read_decimal(scene.engine.value(OptionId::kNeighborEvery), every);
  const double skin = ctx.skin();
  std::printf("  neighbour search: %s\n", ctx.neighbor().c_str());
  if (skin > 0)
    std::printf("  cell structure built for rc + skin %g, reused while no particle moved more than %g%s\n", skin,
                0.5 * skin, every > 0 ? (", and for at most " + std::to_string(every) + " steps").c_str() : "");
  std::printf("  %s, dt %g, %lld steps; %s, precision %s\n",
              scene.integrator.kind == IntegratorKind::kLangevin ? "Langevin (BAOAB)" : "NVE (velocity Verlet)",
              scene.integrator.dt, (long long)scene.steps, ctx.description().c_str(),
              scene.engine.value(OptionId::kPrecision).c_str());
  if (!minimize_line.empty()) std::printf("%s\n", minimize_line.c_str());
  if (!args.restart.empty()) std::printf("  restarting from %s at step %lld\n", args.restart.c_str(), (long long)state.step);
  else if (wrapped > 0)
    std::printf("  %zu particle(s) of %s lay outside the periodic box: wrapped into it\n", wrapped,
                scene.particles.path.c_str());
}

// The performance summary of the loop: rates, where a step's time went (forces, integration,
// output, the host's own), the bytes that crossed between host and device per step, and the
// force engine's stages (`engine`: statistics_json()'s "run" object, which holds the engine's own).
void print_summary(const Scene& scene, double skin, bool lists, const RunStatistics& st, const nlohmann::json& engine,
                   std::size_t n, int64_t steps_done, double loop_seconds, double setup_seconds, double output_seconds,
                   std::size_t output_bytes) {
  std::printf("\nperformance: %lld steps of %zu particles in %.3f s (setup %.3f s)\n", (long long)steps_done, n,
              loop_seconds, setup_seconds);
  if (steps_done <= 0) return;
  const double steps = double(steps_done);
  std::printf("  %.2f steps/s, %.4g particle-steps/s, %.4f ms per step\n", steps / loop_seconds,
              steps * double(n) / loop_seconds, 1e3 * loop_seconds / steps);
  const double other = loop_seconds - st.force_seconds - st.integration_seconds - output_seconds;
  std::printf("  per step (ms): forces %.4f (%.0f%%) | integration %.4f (%.0f%%) | output %.4f (%.0f%%) | "
              "host and waits %.4f (%.0f%%)\n",
              1e3 * st.force_seconds / steps, 100 * st.force_seconds / loop_seconds,
              1e3 * st.integration_seconds / steps, 100 * st.integration_seconds / loop_seconds,
              1e3 * output_seconds / steps, 100 * output_seconds / loop_seconds, 1e3 * other / steps,
              100 * other / loop_seconds);
  std::printf("  host <-> device per step: %.4g bytes of state and results (%zu B over the run for output%s)\n",
              double(st.bytes_to_host + st.bytes_to_device - output_bytes) / steps, output_bytes,
              st.bytes_to_host + st.bytes_to_device == 0 ? "; the state lives on the host" : "");
  const nlohmann::json& stage = engine.at("stage_seconds");
  auto ms = [&](const char* name) { return 1e3 * stage.at(name).get<double>(); };
  if (const int64_t samples = engine.at("stage_samples"); samples > 0)
    std::printf("  per force evaluation (ms, %lld sampled): cell IDs %.4f | sort %.4f | collision cells %.4f | "
                "traversal %.4f | accumulate %.4f | engine total %.4f\n",
                (long long)samples, ms("cell_ids"), ms("sort"), ms("collision_cells"), ms("traversal"),
                ms("accumulate"), ms("total"));
  const OptionList& options = scene.engine;
  if (skin > 0)
    std::printf("  neighbour structure: skin %g, %lld builds in %lld evaluations (one per %.1f steps), "
                "%lld dangerous; largest displacement served %.4g (limit skin/2 = %g%s); check %.4f ms per "
                "evaluation\n",
                skin, (long long)st.builds, (long long)st.evaluations,
                steps / double(std::max<int64_t>(st.builds, 1)), (long long)st.dangerous_builds,
                st.largest_served_displacement, 0.5 * skin,
                options.flag(OptionId::kNeighborCheck) ? "" : ", not checked", ms("check"));
  // A list the engine declined (too crowded for the device's memory) leaves its evaluations to the cells.
  if (lists)
    std::printf("  pair lists served %lld of %lld evaluations (%lld steps behind the step gate)\n",
                engine.at("list_evaluations").get<long long>(), (long long)st.evaluations,
                engine.at("gated_steps").get<long long>());
  if (skin > 0 && options.flag(OptionId::kNeighborAudit))
    std::printf("  audit: missed pairs %zu, repeated pairs %zu (%s)\n", st.missed_pairs, st.repeated_pairs,
                lists ? "of the pair lists" : "of the cell structure");
}

}  // namespace

int run_md(const RunArgs& args) {
  const auto t_setup = Clock::now();
  const Scene scene = scene_for(args);
  const bool restart = !args.restart.empty();
  const SceneOutput& output = scene.output;
  const OutputClaim claim = claim_outputs(args, scene, restart);
  for (const std::string& leftover : claim.removed_leftovers())
    std::printf("note: removed %s, left behind by a write that was killed\n", leftover.c_str());

  MdState state;
  std::size_t wrapped = 0;
  state.config = scene_configuration(scene, &wrapped);
  const std::size_t n = state.config.size();
  const std::vector<double> masses = scene_masses(scene, state.config);
  // What the trajectory would refuse (type names too long for its attribute) is refused before
  // any output is written.
  if (!output.trajectory.empty())
    H5mdWriter::check(output.trajectory, state.config.box, state.config.types, type_names(scene),
                      trajectory_options(output));
  Context ctx = scene_context(scene, state.config.box);

  std::string minimize_line;
  if (scene.minimize.enabled && !restart) minimize_line = minimize_start(ctx, scene, state, masses);
  const bool langevin = scene.integrator.kind == IntegratorKind::kLangevin;
  initialize_velocities(state, masses, scene.initial_temperature, scene.seed, !langevin);

  CheckpointInfo checkpoint_info;
  checkpoint_info.seed = scene.seed;
  checkpoint_info.scene_fingerprint = scene_fingerprint(scene);
  checkpoint_info.scene = scene.source;
  checkpoint_info.backend = ctx.backend_name();
  checkpoint_info.precision = scene.engine.value(OptionId::kPrecision);
  CheckpointInfo saved;
  if (restart) {
    saved = read_checkpoint(args.restart, state, checkpoint_info);
    state.time = double(state.step) * scene.integrator.dt;
    if (state.step > scene.steps)
      throw Error(args.restart + ": checkpoint at step " + std::to_string(state.step) + ", beyond the run's " +
                  std::to_string(scene.steps) + " steps");
    if (saved.backend != checkpoint_info.backend || saved.precision != checkpoint_info.precision)
      std::printf("note: %s was written by backend %s, precision %s; this run uses %s, %s: it continues the run, "
                  "but not bit for bit\n", args.restart.c_str(), saved.backend.c_str(), saved.precision.c_str(),
                  checkpoint_info.backend.c_str(), checkpoint_info.precision.c_str());
  }
  with_context(scene.source + ": step " + std::to_string(state.step), [&] { set_state(ctx, state, masses); });
  if (restart) {
    // With a skin, the structure the uninterrupted run was reusing is built again from the
    // positions it was built from, so that the force sums keep their order (bit for bit).
    const double skin = ctx.skin();
    const bool same_lists = !saved.neighbor_list || *saved.neighbor_list == ctx.neighbor_lists();
    if (skin > 0 && saved.skin == skin && same_lists && !saved.neighbor.build_positions.empty()) {
      with_context(args.restart, [&] { ctx.restore_neighbor_state(saved.neighbor); });
    } else if (skin > 0) {
      std::printf("note: %s holds no cell structure for skin %g%s: the restarted run builds its own at step %lld, "
                  "so it continues the run to round-off, not bit for bit\n",
                  args.restart.c_str(), skin, ctx.neighbor_lists() ? " with pair lists" : " without pair lists",
                  (long long)state.step);
    }
  }
  fetch_state(ctx, state);
  if (state.step < scene.steps)
    with_context(scene.source + ": step " + std::to_string(state.step), [&] { check_start(scene, state, masses, restart); });

  // Outputs are touched only now that everything that can refuse the run has run.
  RunFiles files(args, scene, state, restart);
  print_header(scene, state, ctx, minimize_line, args, wrapped);
  const bool screen = !args.quiet;
  double t_output = 0;
  std::size_t output_bytes = 0;
  // Thermo on the screen and in the CSV file, and a trajectory frame: what an output step reads
  // (8 numbers, and the state for a frame).
  auto report = [&](bool thermo_line, bool frame, Progress& progress) {
    const auto t0 = Clock::now();
    const RunStatistics before = ctx.run_statistics();
    const Thermo th = ctx.thermo();
    state.step = ctx.current_step();
    state.time = double(state.step) * scene.integrator.dt;
    if (frame && files.has_trajectory()) {
      fetch_state(ctx, state);
      files.write_frame(state, th);
    }
    if (thermo_line) {
      const double inv_n = n ? 1.0 / double(n) : 0.0;
      if (screen) {
        char line[256];
        std::snprintf(line, sizeof line, "%10lld %10.4f %10.5f %12.6f %12.6f %12.6f %11.5f", (long long)state.step,
                      state.time, th.temperature, th.kinetic * inv_n, th.potential * inv_n, th.total * inv_n,
                      th.pressure);
        progress.print(line);
      }
      files.write_row(state.step, state.time, th);
    }
    const RunStatistics after = ctx.run_statistics();
    output_bytes += (after.bytes_to_host - before.bytes_to_host) + (after.bytes_to_device - before.bytes_to_device);
    t_output += seconds_since(t0);
  };
  auto save_checkpoint = [&] {
    const auto t0 = Clock::now();
    const RunStatistics before = ctx.run_statistics();
    fetch_state(ctx, state);
    state.time = double(state.step) * scene.integrator.dt;
    // The structure in use; the restart evaluates this step's forces once more, which serves it
    // once more: it is saved one evaluation short.
    checkpoint_info.skin = ctx.skin();
    checkpoint_info.neighbor_list = ctx.neighbor_lists();
    checkpoint_info.neighbor = ctx.neighbor_state();
    if (checkpoint_info.neighbor.served > 0) checkpoint_info.neighbor.served -= 1;
    write_checkpoint(output.checkpoint, state, checkpoint_info);
    const RunStatistics after = ctx.run_statistics();
    output_bytes += after.bytes_to_host - before.bytes_to_host;
    t_output += seconds_since(t0);
  };

  Progress setup_lines(state.step, scene.steps, false);
  if (screen) setup_lines.print("      step       time       temp      ke/atom      pe/atom    etot/atom       press");
  if (!restart) report(true, true, setup_lines);
  else if (screen) setup_lines.print("(continuing from " + args.restart + ")");
  const double setup_seconds = seconds_since(t_setup);
  // The summary covers the loop only: the setup evaluation (allocations, GPU warm-up) is left out.
  ctx.reset_run_statistics();
  t_output = 0;
  output_bytes = 0;

  // The loop advances from one output step to the next in one call: the engine queues the steps
  // between and reads its flags once.
  const auto t_loop = Clock::now();
  Progress progress(state.step, scene.steps, screen);
  const int64_t first = state.step, last = scene.steps;
  auto next_multiple = [](int64_t step, int64_t every) { return every > 0 ? (step / every + 1) * every : INT64_MAX; };
  int64_t step = state.step;
  while (step < last) {
    const int64_t checkpoint_every = !output.checkpoint.empty() ? output.checkpoint_every : 0;
    const int64_t to = std::min({last, next_multiple(step, output.thermo_every),
                                 files.has_trajectory() ? next_multiple(step, output.trajectory_every) : INT64_MAX,
                                 next_multiple(step, checkpoint_every)});
    const bool thermo_step = to % output.thermo_every == 0 || to == last;
    const bool frame_step = files.has_trajectory() && to % output.trajectory_every == 0;
    try {
      ctx.step(to - step, thermo_step || frame_step);
    } catch (const Error& e) {  // name the scene (the engine names the step)
      rethrow_with(scene.source + ": ", e);
    }
    step = to;
    if (thermo_step || frame_step) report(thermo_step, frame_step, progress);
    if (checkpoint_every > 0 && step % checkpoint_every == 0 && step != last) save_checkpoint();
    progress.update(step);
  }
  if (!output.checkpoint.empty()) save_checkpoint();
  files.close();
  progress.finish();
  const double loop_seconds = seconds_since(t_loop);
  print_summary(scene, ctx.skin(), ctx.neighbor_lists(), ctx.run_statistics(),
                nlohmann::json::parse(ctx.statistics_json()).at("run"), n, last - first, loop_seconds, setup_seconds,
                t_output, output_bytes);
  return 0;
}

}  // namespace cellforce
