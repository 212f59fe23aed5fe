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

#include "backends/force_engine.h"
#include "core/names.h"
#include "core/error.h"
#include "core/text.h"
#include "io/h5md_writer.h"
#include "io/output_paths.h"
#include "md/checkpoint.h"
#include "md/md.h"
#include "md/minimize.h"
#include "scene/scene.h"

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

struct StageTotals {
  double cell_ids = 0, sort = 0, collision_cells = 0, traversal = 0, accumulate = 0, transfer = 0, total = 0;
  double check = 0;
  // Reuse of the cell structure ([neighbor] skin): builds, the largest displacement a reused
  // structure served, and the audit's counts.
  int64_t builds = 0;
  double served = 0;
  std::size_t missed = 0, repeated = 0;
  void add(const PipelineStats& s) {
    check += s.t_check;
    builds += s.rebuilt ? 1 : 0;
    if (!s.rebuilt) served = std::max(served, s.max_displacement);
    missed += s.missed_pairs;
    repeated += s.repeated_pairs;
    cell_ids += s.t_cell_ids + s.t_count;
    sort += s.t_sort;
    collision_cells += s.t_collision_cells;
    traversal += s.t_traversal;
    accumulate += s.t_accumulate;
    transfer += s.t_transfer;
    total += s.t_total;
  }
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

void write_text_atomically(const std::string& path, const std::vector<std::string>& lines) {
  const std::string tmp = path + ".partial-" + std::to_string(::getpid());
  {
    errno = 0;
    std::ofstream out(tmp, std::ios::trunc);
    for (const std::string& line : lines) out << line << '\n';
    out.flush();
    if (!out) {
      const int code = errno;
      std::remove(tmp.c_str());
      throw Error(path + ": cannot write the thermo file" + (code ? std::string(": ") + std::strerror(code) : ""));
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw Error(path + ": cannot move the thermo file into place");
  }
}

}  // namespace

int run_md(const RunArgs& args) {
  const auto t_setup = Clock::now();
  Scene scene = args.scene.empty() ? default_scene() : read_scene(args.scene);
  if (args.steps >= 0) scene.steps = args.steps;
  if (!args.backend.empty()) {
    const auto backend = parse_name(args.backend, kBackendNames);
    if (!backend) throw Error("--backend " + quote_excerpt(args.backend) + ": expected " + name_list(kBackendNames));
    scene.backend.backend = *backend;
  }
  if (!args.precision.empty()) {
    const auto precision = parse_name(args.precision, kPrecisionNames);
    if (!precision)
      throw Error("--precision " + quote_excerpt(args.precision) + ": expected " + name_list(kPrecisionNames));
    scene.backend.precision = *precision;
  }
  if (!args.thermo_file.empty()) scene.output.thermo_file = args.thermo_file;
  if (!(args.skin < 0)) scene.backend.reuse.skin = args.skin;  // NaN too: validate_reuse names it
  if (!args.trajectory.empty()) scene.output.trajectory = args.trajectory;
  if (args.trajectory_every > 0) {
    if (scene.output.trajectory.empty()) throw Error("--trajectory-every: the run writes no trajectory (--trajectory)");
    scene.output.trajectory_every = args.trajectory_every;
  }
  const bool restart = !args.restart.empty();
  const SceneOutput& output = scene.output;

  // Every output is checked before anything is computed: a fresh run does not replace an earlier
  // one's outputs unless asked to; no output may be another output or an input.
  {
    std::vector<InputFile> inputs;
    if (!args.scene.empty()) inputs.push_back({args.scene, "scene file"});
    if (scene.particles.source == ParticleSource::kFile) inputs.push_back({scene.particles.path, "[particles] path"});
    if (restart) inputs.push_back({args.restart, "--restart checkpoint"});
    const bool replace = restart || args.overwrite;
    check_output_files({{output.thermo_file, args.thermo_file.empty() ? "[output] thermo_file" : "--thermo-file", replace},
                        {output.trajectory, args.trajectory.empty() ? "[output] trajectory" : "--trajectory", replace},
                        {output.checkpoint, "[output] checkpoint", replace}},
                       inputs,
                       "an earlier run's output: continue that run with --restart CHECKPOINT, or replace it with "
                       "--overwrite",
                       {{"--restart checkpoint", "[output] checkpoint"}});
  }

  MdState state;
  std::size_t wrapped = 0;
  state.config = with_context(scene.source, [&] { return build_configuration(scene, &wrapped); });
  const std::size_t n = state.config.size();
  const int dim = scene.dim;
  std::vector<double> masses(n);
  for (std::size_t i = 0; i < n; ++i) masses[i] = scene.masses[state.config.types[i]];
  const ForceField& ff = scene.force_field;
  with_context(scene.source, [&] { validate_system(state.config.view(), ff); });

  const std::unique_ptr<ForceEngine> engine_owner = make_force_engine(scene.backend);
  ForceEngine& engine = *engine_owner;
  IntegratorSettings integrator;
  integrator.langevin = scene.integrator.kind == IntegratorKind::kLangevin;
  integrator.dt = scene.integrator.dt;
  integrator.kT = scene.integrator.temperature;
  integrator.friction = scene.integrator.friction;
  integrator.seed = scene.seed;

  ForceResult result;
  StageTotals stages;
  int64_t evaluations = 0;
  double t_output = 0;
  auto compute = [&](MdState& s, bool observe) {
    const SystemView view = s.config.view();
    engine.evaluate(view, ff, Request{observe, observe}, result);
    stages.add(engine.stats(view, ff, false));
    ++evaluations;
    s.forces.swap(result.forces);  // no copy: the engine overwrites the old buffer next time
  };

  // [minimize]: a fresh run relaxes its starting configuration before the velocities are drawn
  // (a restart continues from the checkpoint's positions, which the fresh run minimised).
  std::string minimize_line;
  if (scene.minimize.enabled && !restart) {
    FireSettings fire;
    fire.force_tolerance = scene.minimize.force_tolerance;
    fire.max_steps = scene.minimize.max_steps;
    fire.dt = scene.minimize.dt;
    fire.dt_max = scene.minimize.dt_max;
    fire.max_displacement = scene.minimize.max_displacement;
    const FireResult r = with_context(scene.source + ": [minimize]", [&] {
      return minimize_fire(state, masses, fire, [&](MdState& s) {
        compute(s, true);
        return result.energy;
      });
    });
    char line[320];
    std::snprintf(line, sizeof line,
                  "  minimize (FIRE): %lld steps; max force %.4g -> %.4g (particle %zu); energy per particle "
                  "%.6g -> %.6g",
                  (long long)r.steps, r.initial_max_force, r.final_max_force, r.final_max_force_particle,
                  r.initial_energy / double(n), r.final_energy / double(n));
    minimize_line = line;
  }
  initialize_velocities(state, masses, scene.initial_temperature, scene.seed, !integrator.langevin);

  CheckpointInfo checkpoint_info;
  checkpoint_info.seed = scene.seed;
  checkpoint_info.scene_fingerprint = scene_fingerprint(scene);
  checkpoint_info.scene = scene.source;
  checkpoint_info.backend = to_string(engine.backend());
  checkpoint_info.precision = to_string(scene.backend.precision);
  if (restart) {
    const CheckpointInfo saved = read_checkpoint(args.restart, state, checkpoint_info);
    state.time = double(state.step) * integrator.dt;
    if (state.step > scene.steps)
      throw Error(args.restart + ": checkpoint at step " + std::to_string(state.step) + ", beyond the run's " +
                  std::to_string(scene.steps) + " steps");
    if (saved.backend != checkpoint_info.backend || saved.precision != checkpoint_info.precision)
      std::printf("note: %s was written by backend %s, precision %s; this run uses %s, %s: it continues the run, "
                  "but not bit for bit\n", args.restart.c_str(), saved.backend.c_str(), saved.precision.c_str(),
                  checkpoint_info.backend.c_str(), checkpoint_info.precision.c_str());
    // With a skin, the structure the uninterrupted run was reusing is built again from the
    // positions it was built from, so that the force sums keep their order (bit for bit).
    const double skin = scene.backend.reuse.skin;
    if (skin > 0 && saved.skin == skin && !saved.reuse.build_positions.empty()) {
      SystemView built = state.config.view();
      built.positions = saved.reuse.build_positions.data();
      with_context(args.restart, [&] { engine.restore_reuse(built, ff, saved.reuse.served); });
    } else if (skin > 0) {
      std::printf("note: %s holds no cell structure for skin %g: the restarted run builds its own at step %lld, "
                  "so it continues the run to round-off, not bit for bit\n",
                  args.restart.c_str(), skin, (long long)state.step);
    }
  }

  with_context(scene.source + ": step " + std::to_string(state.step), [&] {
    compute(state, true);
    // Dynamics that the first step would throw apart (overlaps) are refused before any output.
    if (state.step < scene.steps) {
      std::string remedy;  // the default advice (add [minimize]) unless it cannot help
      if (restart)
        remedy = "the checkpoint's state cannot continue at this dt: lower dt ([minimize] applies to fresh runs "
                 "only, and would change the scene's fingerprint)";
      else if (scene.minimize.enabled) {
        char text[200];
        std::snprintf(text, sizeof text, "[minimize] stops at a largest force of %g, too large for this dt: lower "
                      "[minimize] force_tolerance, or lower dt", scene.minimize.force_tolerance);
        remedy = text;
      }
      check_stable_start(state, masses, integrator.dt, ff, remedy);
    }
  });

  // Outputs are touched only now that everything that can refuse the run has run. On a restart
  // the thermo rows and trajectory frames beyond the checkpoint are dropped (that part of the run
  // is redone); the thermo file is rewritten under a temporary name.
  // The earlier files are read (and checked to reach the checkpoint) before either is changed.
  std::vector<std::string> rows;
  if (restart && !output.thermo_file.empty() && std::filesystem::exists(output.thermo_file)) {
    const ThermoRows earlier = read_thermo_rows(output.thermo_file);
    std::vector<int64_t> steps;
    for (const auto& [step, line] : earlier.rows) steps.push_back(step);
    check_covers(steps, state.step, output.thermo_every, output.thermo_file, args.restart, "thermo rows");
    // The row at the checkpoint's step stays only if the uninterrupted run writes one there (a
    // run also writes a row at its last step).
    rows.push_back(earlier.header);
    for (const auto& [step, line] : earlier.rows)
      if (step < state.step || (step == state.step && step % output.thermo_every == 0)) rows.push_back(line);
  }
  if (restart && !output.trajectory.empty() && std::filesystem::exists(output.trajectory))
    check_covers(H5mdWriter::stored_steps(output.trajectory), state.step, output.trajectory_every, output.trajectory,
                 args.restart, "trajectory frames");

  std::unique_ptr<std::ofstream> csv;
  if (!output.thermo_file.empty()) {
    if (rows.empty()) rows.push_back("step,time,temperature,kinetic_energy,potential_energy,total_energy,pressure");
    write_text_atomically(output.thermo_file, rows);
    csv = std::make_unique<std::ofstream>(output.thermo_file, std::ios::app);
    if (!*csv) throw Error(output.thermo_file + ": cannot write the thermo file");
  }
  const std::vector<std::string> observables = {"potential_energy", "kinetic_energy", "total_energy",
                                                "temperature", "pressure"};
  std::unique_ptr<H5mdWriter> trajectory;
  if (!output.trajectory.empty()) {
    H5mdOptions o;
    o.velocities = output.velocities;
    o.forces = output.forces;
    o.observables = observables;
    o.creator_version = CELLFORCE_VERSION;
    o.append = restart && std::filesystem::exists(output.trajectory);
    if (restart && !o.append)
      std::printf("note: %s does not exist; it starts at step %lld\n", output.trajectory.c_str(),
                  (long long)state.step);
    std::vector<std::string> names;
    for (const ParticleType& t : scene.force_field.types) names.push_back(t.name);
    trajectory = std::make_unique<H5mdWriter>(output.trajectory, state.config.box, state.config.types, names, o);
    if (o.append) trajectory->truncate_after(state.step);
  }

  const bool screen = !args.quiet;
  std::printf("cellforce run: %s\n", scene.source.c_str());
  std::printf("  %zu particles, %dD, box", n, dim);
  for (int a = 0; a < dim; ++a)
    std::printf(" %.6g%s", state.config.box.length[a], state.config.box.periodic[a] ? "" : " (open)");
  std::printf(", %zu type(s); cutoff %g (%s)\n", ff.types.size(), ff.cutoff, to_string(ff.mode));
  if (scene.backend.reuse.skin > 0)
    std::printf("  cell structure built for rc + skin %g, reused while no particle moved more than %g%s\n",
                scene.backend.reuse.skin, 0.5 * scene.backend.reuse.skin,
                scene.backend.reuse.every > 0 ? (", and for at most " + std::to_string(scene.backend.reuse.every) +
                                                 " steps").c_str() : "");
  std::printf("  %s, dt %g, %lld steps; %s, precision %s\n",
              integrator.langevin ? "Langevin (BAOAB)" : "NVE (velocity Verlet)", integrator.dt,
              (long long)scene.steps, engine.description().c_str(), to_string(scene.backend.precision));
  if (!minimize_line.empty()) std::printf("%s\n", minimize_line.c_str());
  if (restart) std::printf("  restarting from %s at step %lld\n", args.restart.c_str(), (long long)state.step);
  else if (wrapped > 0)
    std::printf("  %zu particle(s) of %s lay outside the periodic box: wrapped into it\n", wrapped,
                scene.particles.path.c_str());

  auto report = [&](const MdState& s, bool thermo_line, bool frame, auto& progress) {
    const auto t0 = Clock::now();
    const Thermo th = thermo(s, masses, result, !integrator.langevin);
    if (frame && trajectory)
      trajectory->write_frame(s.step, s.time, s.config.positions.data(), output.velocities ? s.velocities.data() : nullptr,
                              output.forces ? s.forces.data() : nullptr,
                              {th.potential, th.kinetic, th.total, th.temperature, th.pressure});
    if (thermo_line) {
      const double inv_n = n ? 1.0 / double(n) : 0.0;
      if (screen) {
        char line[256];
        std::snprintf(line, sizeof line, "%10lld %10.4f %10.5f %12.6f %12.6f %12.6f %11.5f", (long long)s.step,
                      s.time, th.temperature, th.kinetic * inv_n, th.potential * inv_n, th.total * inv_n, th.pressure);
        progress.print(line);
      }
      if (csv) {
        char line[320];
        std::snprintf(line, sizeof line, "%lld,%.10g,%.12g,%.17g,%.17g,%.17g,%.12g\n", (long long)s.step, s.time,
                      th.temperature, th.kinetic, th.potential, th.total, th.pressure);
        *csv << line << std::flush;
        if (!*csv) throw Error(output.thermo_file + ": cannot write the thermo file (disk full?)");
      }
    }
    t_output += seconds_since(t0);
  };
  auto save_checkpoint = [&] {
    const auto t0 = Clock::now();
    // The structure in use; the restart evaluates this step's forces once more, which serves it
    // once more: it is saved one evaluation short.
    checkpoint_info.skin = scene.backend.reuse.skin;
    checkpoint_info.reuse = engine.reuse_state();
    if (checkpoint_info.reuse.served > 0) checkpoint_info.reuse.served -= 1;
    write_checkpoint(output.checkpoint, state, checkpoint_info);
    t_output += seconds_since(t0);
  };

  Progress setup_lines(state.step, scene.steps, false);
  if (screen) setup_lines.print("      step       time       temp      ke/atom      pe/atom    etot/atom       press");
  if (!restart) report(state, true, true, setup_lines);
  else if (screen) setup_lines.print("(continuing from " + args.restart + ")");
  const double setup_seconds = seconds_since(t_setup);
  // The summary covers the loop only: the setup evaluation (allocations, GPU warm-up) is left out.
  stages = StageTotals{};
  evaluations = 0;
  t_output = 0;

  const auto t_loop = Clock::now();
  Progress progress(state.step, scene.steps, screen);
  double t_forces_wall = 0;
  const int64_t first = state.step, last = scene.steps;
  while (state.step < last) {
    const int64_t next = state.step + 1;
    const bool thermo_step = next % output.thermo_every == 0 || next == last;
    const bool frame_step = trajectory && next % output.trajectory_every == 0;
    const bool observe = thermo_step || frame_step;
    try {
      advance(state, masses, integrator, [&](MdState& s) {
        const auto t0 = Clock::now();
        compute(s, observe);
        t_forces_wall += seconds_since(t0);
      });
    } catch (const Error& e) {  // name the scene and the step (built only when a step fails)
      throw Error(scene.source + ": step " + std::to_string(next) + ": " + e.message());
    }
    if (observe) report(state, thermo_step, frame_step, progress);
    if (!output.checkpoint.empty() && output.checkpoint_every > 0 && state.step % output.checkpoint_every == 0 &&
        state.step != last)
      save_checkpoint();
    progress.update(state.step);
  }
  if (!output.checkpoint.empty()) save_checkpoint();
  if (trajectory) trajectory->close();
  progress.finish();
  const double loop_seconds = seconds_since(t_loop);

  const double steps = double(last - first);
  std::printf("\nperformance: %lld steps of %zu particles in %.3f s (setup %.3f s)\n", (long long)(last - first), n,
              loop_seconds, setup_seconds);
  if (steps > 0) {
    std::printf("  %.2f steps/s, %.4g particle-steps/s, %.4f ms per step\n", steps / loop_seconds,
                steps * double(n) / loop_seconds, 1e3 * loop_seconds / steps);
    const double per = 1e3 / double(evaluations);
    std::printf("  per force evaluation (ms): cell IDs %.4f | sort %.4f | collision cells %.4f | traversal %.4f |"
                " accumulate %.4f | host copies %.4f | engine total %.4f\n",
                per * stages.cell_ids, per * stages.sort, per * stages.collision_cells, per * stages.traversal,
                per * stages.accumulate, per * stages.transfer, per * stages.total);
    const ReuseOptions& reuse = scene.backend.reuse;
    if (reuse.skin > 0) {
      std::printf("  neighbour structure: skin %g, %lld builds in %lld evaluations (one per %.1f steps); "
                  "largest displacement served %.4g (limit skin/2 = %g%s); check %.4f ms per evaluation",
                  reuse.skin, (long long)stages.builds, (long long)evaluations,
                  steps / double(std::max<int64_t>(stages.builds, 1)), stages.served, 0.5 * reuse.skin,
                  reuse.check ? "" : ", not checked", per * stages.check);
      if (reuse.audit) std::printf("; audit: missed pairs %zu, repeated pairs %zu", stages.missed, stages.repeated);
      std::printf("\n");
    }
    std::printf("  per step (ms): forces %.4f | integration and the rest %.4f | output %.4f\n",
                1e3 * t_forces_wall / steps, 1e3 * (loop_seconds - t_forces_wall - t_output) / steps,
                1e3 * t_output / steps);
  }
  return 0;
}

}  // namespace cellforce
