// `cellforce run` end to end: a restart from a checkpoint reproduces the uninterrupted run bit
// for bit (NVE and Langevin, every backend here), the thermo file holds the steps asked for, and
// a checkpoint from another scene or seed is refused.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "cli/run.h"
#include "core/error.h"
#include "io/hdf5.h"
#include "io/output_paths.h"

#include "temp_folder.h"

namespace {

using namespace cellforce;
using ::testing::HasSubstr;
using ::testing::Not;
namespace fs = std::filesystem;
using cftest::backends_here;
// Runs in a fresh working folder (output paths in scenes are relative to it).
using RunFolder = cftest::WorkingFolder;

// A small 2D liquid: 80 particles on a hexagonal lattice at area density 0.7.
// Thermo every 7 steps, frames every 9, checkpoints every 30: none divides another, so the rows
// and frames around a checkpoint are the ones a restart can get wrong.
std::string scene_text(const std::string& kind, const std::string& backend, int64_t steps, uint64_t seed = 5) {
  std::ostringstream s;
  s << "[system]\ndimension = 2\n[particles]\nlattice = \"hexagonal\"\ncells = [8, 5]\ndensity = 0.7\n"
    << "[[types]]\nname = \"A\"\n[interactions]\ncutoff = 2.5\nmode = \"force-shift\"\n"
    << "[initial]\ntemperature = 1.0\nseed = " << seed << "\n[integrator]\nkind = \"" << kind << "\"\ndt = 0.005\n"
    << (kind == "langevin" ? "temperature = 0.8\nfriction = 1.0\n" : "") << "[run]\nsteps = " << steps
    << "\nbackend = \"" << backend << "\"\nprecision = \"double\"\n"
    << "[output]\nthermo_every = 7\nthermo_file = \"thermo.csv\"\ncheckpoint = \"ckpt.h5\"\ncheckpoint_every = 30\n"
    << "trajectory = \"traj.h5\"\ntrajectory_every = 9\nvelocities = true\n";
  return s.str();
}

struct Saved {
  std::vector<double> positions, velocities;
  int64_t step = 0;
};

// Every frame of the trajectory: steps, positions and velocities.
struct Frames {
  std::vector<double> steps, positions, velocities;
  bool operator==(const Frames&) const = default;
};

Frames load_trajectory(const std::string& path) {
  h5::File f = h5::File::open_read(path);
  return {h5::read_doubles(f.id(), "particles/all/position/step", path).values,
          h5::read_doubles(f.id(), "particles/all/position/value", path).values,
          h5::read_doubles(f.id(), "particles/all/velocity/value", path).values};
}

Saved load(const std::string& path) {
  h5::File f = h5::File::open_read(path);
  return {h5::read_doubles(f.id(), "positions", path).values, h5::read_doubles(f.id(), "velocities", path).values,
          h5::read_int_attribute(f.id(), "step", path)};
}

// With a skin too: the checkpoint keeps the cell structure in use (the positions it was built
// from), and the restart builds it again, so the force sums keep their order. Skin -1: none given,
// the scene's auto (on CUDA pair lists with skin 0.6 in this box, the step gate included).
TEST_F(RunFolder, RestartReproducesTheUninterruptedRunBitwise) {
  for (const std::string& backend : backends_here())
    for (const std::string kind : {"nve", "langevin"})
    for (const double skin : {-1.0, 0.0, 0.3}) {
      SCOPED_TRACE(backend + " " + kind + " skin " + std::to_string(skin));
      std::ofstream("scene.toml") << scene_text(kind, backend, 60);
      RunArgs args;
      args.scene = "scene.toml";
      args.quiet = true;
      args.overwrite = true;
      args.skin = skin;
      ASSERT_EQ(run_md(args), 0);
      const Saved full = load("ckpt.h5");
      const std::string full_thermo = read("thermo.csv");
      const Frames full_frames = load_trajectory("traj.h5");
      EXPECT_EQ(full.step, 60);

      // A run that checkpointed at step 30, went on to step 45 (rows to 45, frames to 36) and died
      // there; continued from the checkpoint, the rows and frames beyond 30 are redone.
      args.steps = 30;
      ASSERT_EQ(run_md(args), 0);
      fs::copy_file("ckpt.h5", "ckpt30.h5", fs::copy_options::overwrite_existing);
      EXPECT_EQ(load("ckpt30.h5").step, 30);
      args.steps = 45;
      ASSERT_EQ(run_md(args), 0);
      args.steps = -1;
      args.restart = "ckpt30.h5";
      ASSERT_EQ(run_md(args), 0);
      args.restart.clear();
      const Saved resumed = load("ckpt.h5");
      EXPECT_EQ(resumed.step, 60);
      EXPECT_EQ(resumed.positions, full.positions);
      EXPECT_EQ(resumed.velocities, full.velocities);
      EXPECT_EQ(read("thermo.csv"), full_thermo);
      EXPECT_EQ(load_trajectory("traj.h5"), full_frames);

      // A run of 25 steps continued from its final checkpoint: its row at step 25 (written
      // because it was the last step) is not one of the uninterrupted run's and goes.
      args.steps = 25;
      ASSERT_EQ(run_md(args), 0);
      fs::copy_file("ckpt.h5", "ckpt25.h5", fs::copy_options::overwrite_existing);
      args.steps = -1;
      args.restart = "ckpt25.h5";
      ASSERT_EQ(run_md(args), 0);
      args.restart.clear();
      EXPECT_EQ(load("ckpt.h5").positions, full.positions);
      EXPECT_EQ(read("thermo.csv"), full_thermo);
      EXPECT_EQ(load_trajectory("traj.h5"), full_frames);
      fs::remove("traj.h5");
    }
}

// With the displacement check on, the audit of the reused structure finds no missed or repeated
// pair on any backend (the CUDA run audits its resident evaluations too).
TEST_F(RunFolder, AuditFindsNothingMissedWithTheCheck) {
  for (const std::string& backend : backends_here()) {
    SCOPED_TRACE(backend);
    std::ofstream("scene.toml") << scene_text("nve", backend, 60) << "[neighbor]\nskin = 0.3\naudit = true\n";
    RunArgs args;
    args.scene = "scene.toml";
    args.quiet = true;
    args.overwrite = true;
    testing::internal::CaptureStdout();
    EXPECT_EQ(run_md(args), 0);
    const std::string out = testing::internal::GetCapturedStdout();
    EXPECT_THAT(out, HasSubstr("audit: missed pairs 0, repeated pairs 0"));
    const std::size_t at = out.find("neighbour structure: skin 0.3, ");
    ASSERT_NE(at, std::string::npos) << out;
    long builds = 0, evaluations = 0;
    ASSERT_EQ(std::sscanf(out.c_str() + at, "neighbour structure: skin 0.3, %ld builds in %ld evaluations", &builds,
                          &evaluations), 2);
    EXPECT_LT(builds, evaluations) << "the structure was never reused, so the audit checked nothing";
  }
}

// The run header names the neighbour search the engine chose: a scene without [neighbor] has skin
// auto (no skin on the CPU; on CUDA pair lists with a skin of 0.24 rc where rc + skin fits in half
// the box, as 2 x 3.1 does in this 2D box of edges 10.27 and 11.12); --skin 0.3 is given as it is,
// and --skin auto (skin -1 below) overrides a scene's length.
TEST_F(RunFolder, HeaderNamesTheNeighbourSearch) {
  for (const std::string& backend : backends_here()) {
    SCOPED_TRACE(backend);
    std::ofstream("scene.toml") << scene_text("nve", backend, 5) << "[neighbor]\nskin = 0.3\n";
    std::ofstream("auto.toml") << scene_text("nve", backend, 5);
    for (const double skin : {-2.0, -1.0, 0.3}) {
      RunArgs args;
      args.scene = skin == -2.0 ? "auto.toml" : "scene.toml";  // -2: no [neighbor]
      args.quiet = true;
      args.overwrite = true;
      args.skin_auto = skin == -1.0;
      if (skin > 0) args.skin = skin;
      testing::internal::CaptureStdout();
      EXPECT_EQ(run_md(args), 0);
      const std::string out = testing::internal::GetCapturedStdout();
      if (skin > 0) {
        EXPECT_THAT(out, HasSubstr("  neighbour search: skin 0.3, cells reused\n"));
      } else if (backend == "cpu") {
        EXPECT_THAT(out, HasSubstr("  neighbour search: none, stages 1-3 every evaluation (auto: no skin on the cpu)\n"));
      } else {
        EXPECT_THAT(out, HasSubstr("  neighbour search: skin 0.6 (auto: 0.24 rc), pair lists\n"));
        EXPECT_THAT(out, HasSubstr("  pair lists served 5 of 5 evaluations"));  // the loop's 5 steps
      }
      if (backend == "cpu" || skin > 0) {
        EXPECT_THAT(out, Not(HasSubstr("pair lists served")));
      }
    }
  }
}

// A checkpoint of a structure served by the cells (--skin 0.6: lists not asked for) restarted with
// skin auto (on CUDA: the same skin with pair lists, another summation order) is not restored as
// if it were the same: the run says it continues to round-off. The CPU has no lists: nothing to
// test there.
TEST_F(RunFolder, RestartWithAnotherNeighbourChoiceSaysSo) {
  for (const std::string& backend : backends_here()) {
    if (backend != "cuda") continue;
    std::ofstream("scene.toml") << scene_text("nve", backend, 30);
    RunArgs args;
    args.scene = "scene.toml";
    args.quiet = true;
    args.overwrite = true;
    args.skin = 0.6;
    ASSERT_EQ(run_md(args), 0);
    fs::copy_file("ckpt.h5", "cells.h5", fs::copy_options::overwrite_existing);
    args.skin = -1;
    args.skin_auto = true;
    args.steps = 40;
    args.restart = "cells.h5";
    testing::internal::CaptureStdout();
    EXPECT_EQ(run_md(args), 0);
    const std::string out = testing::internal::GetCapturedStdout();
    EXPECT_THAT(out, HasSubstr("neighbour search: skin 0.6 (auto: 0.24 rc), pair lists"));
    EXPECT_THAT(out, HasSubstr("holds no cell structure for skin 0.6 with pair lists"));
  }
}

TEST_F(RunFolder, ThermoFileHoldsTheStepsAskedFor) {
  std::ofstream("scene.toml") << scene_text("nve", "cpu", 23);
  RunArgs args;
  args.scene = "scene.toml";
  args.quiet = true;
  ASSERT_EQ(run_md(args), 0);
  std::istringstream lines(read("thermo.csv"));
  std::string line;
  std::getline(lines, line);
  EXPECT_EQ(line, "step,time,temperature,kinetic_energy,potential_energy,total_energy,pressure");
  std::vector<long> steps;
  while (std::getline(lines, line)) steps.push_back(std::stol(line.substr(0, line.find(','))));
  EXPECT_EQ(steps, (std::vector<long>{0, 7, 14, 21, 23}));  // every 7, and the last step
  const Frames frames = load_trajectory("traj.h5");
  EXPECT_EQ(frames.steps, (std::vector<double>{0, 9, 18}));  // every 9
  EXPECT_EQ(frames.positions.size(), 3u * 80u * 2u);
}

// --skin: the run reuses the cell structure (the summary says how often it built it) and gives the
// thermo rows of the run without a skin to round-off (the force sums only change order).
TEST_F(RunFolder, SkinReuseGivesTheSameThermo) {
  auto thermo_rows = [&](double skin, const std::string& file) {
    std::ofstream("scene.toml") << scene_text("nve", "cpu", 60);
    RunArgs args;
    args.scene = "scene.toml";
    args.quiet = true;
    args.overwrite = true;
    args.skin = skin;
    args.thermo_file = file;
    testing::internal::CaptureStdout();
    EXPECT_EQ(run_md(args), 0);
    const std::string out = testing::internal::GetCapturedStdout();
    if (skin > 0) {  // the skin reached the engine: fewer builds than evaluations
      const std::size_t at = out.find("neighbour structure: skin 0.3, ");
      EXPECT_NE(at, std::string::npos) << out;
      if (at != std::string::npos) {
        long builds = 0, evaluations = 0;
        EXPECT_EQ(std::sscanf(out.c_str() + at, "neighbour structure: skin 0.3, %ld builds in %ld evaluations",
                              &builds, &evaluations), 2) << out;
        EXPECT_EQ(evaluations, 60);
        EXPECT_GE(builds, 2);
        EXPECT_LT(builds, 20) << "skin 0.3 at T = 1 should serve several steps per build";
      }
    }
    std::vector<std::vector<double>> rows;
    std::istringstream lines(read(file));
    std::string line;
    std::getline(lines, line);
    while (std::getline(lines, line)) {
      std::vector<double> row;
      std::istringstream cells(line);
      for (std::string cell; std::getline(cells, cell, ',');) row.push_back(std::stod(cell));
      rows.push_back(row);
    }
    return rows;
  };
  const auto plain = thermo_rows(0.0, "plain.csv");
  const auto reused = thermo_rows(0.3, "reused.csv");
  ASSERT_EQ(plain.size(), reused.size());
  ASSERT_FALSE(plain.empty());
  for (std::size_t r = 0; r < plain.size(); ++r)
    for (std::size_t c = 0; c < plain[r].size(); ++c)
      EXPECT_NEAR(reused[r][c], plain[r][c], 1e-9 * std::max(1.0, std::fabs(plain[r][c]))) << "row " << r << ", column " << c;
}

// A fresh run refuses to replace an earlier run's outputs unless told to; a refused restart
// leaves the outputs as they were.
TEST_F(RunFolder, OutputsOfAnEarlierRunAreKept) {
  std::ofstream("scene.toml") << scene_text("nve", "cpu", 20);
  RunArgs args;
  args.scene = "scene.toml";
  args.quiet = true;
  ASSERT_EQ(run_md(args), 0);
  const std::string thermo = read("thermo.csv");
  try {
    run_md(args);
    ADD_FAILURE() << "the earlier run's outputs were replaced";
  } catch (const Error& e) {
    EXPECT_THAT(std::string(e.what()), HasSubstr("thermo.csv: exists"));
  }
  EXPECT_EQ(read("thermo.csv"), thermo);
  // A restart refused late (a checkpoint beyond the run) touches nothing.
  args.restart = "ckpt.h5";
  args.steps = 10;
  EXPECT_THROW(run_md(args), Error);
  EXPECT_EQ(read("thermo.csv"), thermo);
  args.restart.clear();
  args.steps = -1;
  args.overwrite = true;
  EXPECT_EQ(run_md(args), 0);
}

// A run that blows up (dt far too large) stops with the scene, the step and a diagnosis.
TEST_F(RunFolder, DivergenceIsReportedWithItsStep) {
  std::string text = scene_text("nve", "cpu", 200);
  text.replace(text.find("dt = 0.005"), 10, "dt = 0.2");
  std::ofstream("scene.toml") << text;
  RunArgs args;
  args.scene = "scene.toml";
  args.quiet = true;
  try {
    run_md(args);
    ADD_FAILURE() << "dt = 0.2 did not diverge";
  } catch (const Error& e) {
    EXPECT_THAT(std::string(e.what()), HasSubstr("scene.toml: step "));
    EXPECT_THAT(std::string(e.what()), HasSubstr("the integration diverged"));
  }
}

TEST_F(RunFolder, CheckpointOfAnotherSceneOrSeedIsRefused) {
  std::ofstream("scene.toml") << scene_text("langevin", "cpu", 30);
  RunArgs args;
  args.scene = "scene.toml";
  args.quiet = true;
  ASSERT_EQ(run_md(args), 0);
  fs::copy_file("ckpt.h5", "old.h5");
  std::ofstream("scene.toml") << scene_text("langevin", "cpu", 30, /*seed=*/6);
  args.restart = "old.h5";
  try {
    run_md(args);
    ADD_FAILURE() << "a checkpoint of another scene was accepted";
  } catch (const Error& e) {
    EXPECT_THAT(std::string(e.what()), HasSubstr("old.h5: written for another system"));
  }
  std::ofstream("scene.toml") << scene_text("langevin", "cpu", 30);
  args.steps = 20;
  try {
    run_md(args);
    ADD_FAILURE() << "a checkpoint beyond the run's end was accepted";
  } catch (const Error& e) {
    EXPECT_THAT(std::string(e.what()), HasSubstr("old.h5: checkpoint at step 30, beyond the run's 20 steps"));
  }
}

}  // namespace

// ---- concurrent runs ------------------------------------------------------------------------------

// The thermo rows (after the header) and the trajectory's frame steps of a run's outputs.
std::size_t thermo_rows(const std::string& path) {
  std::ifstream in(path);
  std::size_t rows = 0;
  std::string line;
  std::getline(in, line);  // the header
  while (std::getline(in, line))
    if (!line.empty()) ++rows;
  return rows;
}

// Two `cellforce run` processes started at once into one folder (fresh, with --overwrite, and two
// restarts from one checkpoint): exactly one runs; the other is refused before it writes anything,
// naming the file another run holds; the survivor's thermo file and trajectory are whole (not
// the loser's header-only thermo file, nor a trajectory truncated under the survivor).
TEST_F(RunFolder, TwoRunsStartedAtOnceIntoOneFolderOneRunsAndTheOtherTouchesNothing) {
  const std::string program = cftest::cellforce_binary();
  if (program.empty()) GTEST_SKIP() << "no cellforce program beside the tests (set CELLFORCE_EXE)";
  // 10,000 steps of a small system: the second run starts long before the first ends.
  const int64_t steps = 10000;
  std::ofstream("scene.toml") << scene_text("nve", "cpu", steps);
  const std::size_t rows = steps / 7 + 2;    // steps 0, 7, ..., 9996 and the last, 10000
  const std::size_t frames = steps / 9 + 1;  // steps 0, 9, ..., 9999
  struct Case {
    std::string name;
    std::vector<std::string> options;
  };
  for (const Case& c : {Case{"fresh", {}}, Case{"--overwrite", {"--overwrite"}},
                        Case{"restart", {"--restart", "start.h5"}}}) {
    SCOPED_TRACE(c.name);
    if (c.name == "restart") {  // a checkpoint at step 300 of this scene, and outputs that reach it
      RunArgs args;
      args.scene = "scene.toml";
      args.quiet = true;
      args.overwrite = true;
      args.steps = 300;
      ASSERT_EQ(run_md(args), 0);
      fs::copy_file("ckpt.h5", "start.h5", fs::copy_options::overwrite_existing);
    }
    std::vector<std::string> args = {"run", "scene.toml", "--quiet"};
    args.insert(args.end(), c.options.begin(), c.options.end());
    const pid_t a = cftest::start_program(program, args, "a.log");
    const pid_t b = cftest::start_program(program, args, "b.log");
    const int code_a = cftest::exit_code(a), code_b = cftest::exit_code(b);
    ASSERT_TRUE((code_a == 0) != (code_b == 0)) << "exit codes " << code_a << " and " << code_b << "\n"
                                                << read("a.log") << "\n" << read("b.log");
    const std::string loser = read(code_a == 0 ? "b.log" : "a.log");
    EXPECT_EQ(code_a == 0 ? code_b : code_a, 1);
    EXPECT_THAT(loser, HasSubstr("thermo.csv: in use by another cellforce run (process " +
                                 std::to_string(code_a == 0 ? a : b)));
    EXPECT_EQ(thermo_rows("thermo.csv"), rows);
    const Frames f = load_trajectory("traj.h5");
    ASSERT_EQ(f.steps.size(), frames);
    EXPECT_EQ(f.steps.back(), double(9 * (frames - 1)));
    EXPECT_EQ(f.velocities.size(), f.positions.size());
    EXPECT_EQ(load("ckpt.h5").step, steps);
    for (const auto& e : fs::directory_iterator(dir_))  // no temporary or lock file is left
      EXPECT_THAT(e.path().filename().string(), Not(testing::AnyOf(HasSubstr(".partial"), HasSubstr(".cellforce-lock"))));
  }
}

// An output that another run holds (here: claimed by this process, as a running run holds it) is
// refused before the run computes or writes anything, with --overwrite and on a restart too.
TEST_F(RunFolder, AnOutputAnotherRunHoldsIsRefusedBeforeAnythingIsWritten) {
  std::ofstream("scene.toml") << scene_text("nve", "cpu", 30);
  RunArgs args;
  args.scene = "scene.toml";
  args.quiet = true;
  ASSERT_EQ(run_md(args), 0);
  const std::string thermo = read("thermo.csv"), traj = read("traj.h5"), ckpt = read("ckpt.h5");
  for (const std::string held : {"thermo.csv", "traj.h5", "ckpt.h5"}) {
    SCOPED_TRACE(held);
    OutputClaim other = claim_output_files({{held, "another run's output", true}}, {}, "");
    for (const bool restart : {false, true}) {
      args.overwrite = !restart;
      args.restart = restart ? "ckpt.h5" : "";
      args.steps = restart ? 60 : -1;
      const std::string msg = cftest::error_of([&] { run_md(args); });
      EXPECT_THAT(msg, HasSubstr(held + ": in use by another cellforce run (process " + std::to_string(::getpid())));
      EXPECT_THAT(msg, HasSubstr(held + ".cellforce-lock"));
      EXPECT_EQ(read("thermo.csv"), thermo);
      EXPECT_EQ(read("traj.h5"), traj);
      EXPECT_EQ(read("ckpt.h5"), ckpt);
    }
  }
  // Released (the other run ended): the restart runs, and removes its lock files when done.
  args.overwrite = false;
  args.restart = "ckpt.h5";
  args.steps = 60;
  EXPECT_EQ(run_md(args), 0);
  EXPECT_EQ(load("ckpt.h5").step, 60);
  for (const auto& e : fs::directory_iterator(dir_)) EXPECT_THAT(e.path().filename().string(), Not(HasSubstr(".cellforce-lock")));
}

// Temporary files that killed writers left beside the outputs are removed by the next run that
// claims those outputs; one whose writer is alive is kept, and so are other files' temporaries.
TEST_F(RunFolder, LeftoversOfKilledWritesAreRemovedAndALiveWritersAreKept) {
  std::ofstream("scene.toml") << scene_text("nve", "cpu", 30);
  const pid_t dead = ::fork();  // a process ID that is no longer alive
  if (dead == 0) ::_exit(0);
  ASSERT_EQ(cftest::exit_code(dead), 0);
  const pid_t live = ::getppid();
  const std::string d = std::to_string(dead), l = std::to_string(live);
  const std::vector<std::string> removed = {"thermo.csv.partial-" + d + "-12345", "traj.h5.partial-" + d + "-7",
                                            "ckpt.h5.partial-probe-" + d + "-99", "thermo.csv.partial-" + d};
  const std::vector<std::string> kept = {"ckpt.h5.partial-" + l + "-5", "other.h5.partial-" + d + "-1",
                                         "traj.h5.partial-notes.txt"};
  for (const std::string& name : removed) std::ofstream(name) << "half a file";
  for (const std::string& name : kept) std::ofstream(name) << "half a file";
  RunArgs args;
  args.scene = "scene.toml";
  args.quiet = true;
  testing::internal::CaptureStdout();
  const int code = run_md(args);
  const std::string out = testing::internal::GetCapturedStdout();
  ASSERT_EQ(code, 0);
  for (const std::string& name : removed) {
    EXPECT_FALSE(fs::exists(name)) << name;
    EXPECT_THAT(out, HasSubstr("note: removed " + name + ", left behind by a write that was killed"));
  }
  for (const std::string& name : kept) EXPECT_TRUE(fs::exists(name)) << name;
  EXPECT_EQ(thermo_rows("thermo.csv"), 30u / 7 + 2);
}
