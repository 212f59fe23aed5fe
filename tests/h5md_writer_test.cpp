// The H5MD trajectory writer (src/io/h5md_writer.h): every frame reads back exactly (tolerance:
// none, doubles compared with ==) through read_h5md and the HDF5 layer; restarts append, refuse
// repeated steps and truncate; mismatched restarts and bad frames are refused before the file
// changes; a failed write leaves no frame behind; a run killed after write_frame leaves a
// readable file; per-particle datasets are chunked and compressed. H5mdSample writes files for
// validation/check_h5md.py (h5py, MDAnalysis) when asked to by an environment variable.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/mount.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>

#include "core/error.h"
#include "io/configuration_file.h"
#include "io/h5md_writer.h"
#include "io/hdf5.h"
#include "oracle.h"
#include "temp_folder.h"

namespace {

using namespace cellforce;
using ::testing::HasSubstr;
namespace fs = std::filesystem;
using cftest::error_of;

const std::string kAll = "particles/all";

using H5mdTrajectory = cftest::TempFolder;

// The message of the cellforce::Error that f throws (fails the test when it throws nothing).

// A run's frames, deterministic in (seed, frame index) so that a restarted run can regenerate
// any of them: positions inside the box on periodic axes and beyond it on open ones, velocities,
// forces and observables with all 53 mantissa bits in use.
struct SimRun {
  Box box;
  std::vector<uint32_t> species;
  std::vector<std::string> names;
  H5mdOptions options;
  uint64_t seed = 1;

  std::size_t n() const { return species.size(); }
  int64_t step(std::size_t k) const { return int64_t(100 * k); }
  double time(std::size_t k) const { return 0.005 * double(step(k)); }
  std::vector<double> positions(std::size_t k) const {
    cftest::Rng rng(seed * 1000 + k);
    std::vector<double> x(n() * std::size_t(box.dim));
    for (std::size_t i = 0; i < n(); ++i)
      for (int a = 0; a < box.dim; ++a)
        x[i * std::size_t(box.dim) + std::size_t(a)] =
            box.periodic[a] ? rng.uniform(0, box.length[a]) : rng.uniform(-box.length[a], 2 * box.length[a]);
    return x;
  }
  std::vector<double> vector_field(std::size_t k, uint64_t salt, double scale) const {
    cftest::Rng rng(seed * 1000 + k + salt);
    std::vector<double> v(n() * std::size_t(box.dim));
    for (double& c : v) c = rng.uniform(-scale, scale);
    return v;
  }
  std::vector<double> velocities(std::size_t k) const { return vector_field(k, 1u << 20, 2.0); }
  std::vector<double> forces(std::size_t k) const { return vector_field(k, 2u << 20, 50.0); }
  std::vector<double> observables(std::size_t k) const {
    cftest::Rng rng(seed * 1000 + k + (3u << 20));
    std::vector<double> v(options.observables.size());
    for (double& c : v) c = rng.uniform(-1000, 1000);
    return v;
  }
  H5mdWriter open(const std::string& p, bool append = false) const {
    H5mdOptions o = options;
    o.append = append;
    return H5mdWriter(p, box, species, names, o);
  }
  void write(H5mdWriter& w, std::size_t k) const {
    const std::vector<double> x = positions(k), v = velocities(k), f = forces(k);
    w.write_frame(step(k), time(k), x.data(), options.velocities ? v.data() : nullptr,
                  options.forces ? f.data() : nullptr, observables(k));
  }
};

SimRun make_run(const Box& box, std::size_t n, uint64_t seed, bool velocities, bool forces,
             std::vector<std::string> observables) {
  SimRun r;
  r.box = box;
  r.seed = seed;
  cftest::Rng rng(seed);
  for (std::size_t i = 0; i < n; ++i) r.species.push_back(uint32_t(rng.below(3)));
  r.names = {"A", "B", "C"};
  r.options.velocities = velocities;
  r.options.forces = forces;
  r.options.observables = std::move(observables);
  r.options.creator_version = "0.1.0";
  return r;
}

SimRun full_run(uint64_t seed = 7) {
  return make_run(cftest::cube(3, 6.5), 40, seed, true, true,
                  {"potential_energy", "kinetic_energy", "total_energy", "temperature", "pressure"});
}

// A frame of the file: the frame k of a run.
struct Source {
  const SimRun* run;
  std::size_t k;
};

// The file holds exactly these frames (frame j of the file is frames[j]; the box, species and
// elements are those of frames[0]'s run), read through read_h5md and through the HDF5 layer.
void expect_holds(const std::string& p, const std::vector<Source>& frames) {
  ASSERT_FALSE(frames.empty());
  const SimRun& run = *frames[0].run;
  const long count = long(frames.size());
  for (long j = 0; j < count; ++j) {
    SCOPED_TRACE("frame " + std::to_string(j));
    const Source& s = frames[std::size_t(j)];
    for (const long index : {j, j - count}) {  // from the start and from the end
      ReadOptions o;
      o.frame = index;
      const ConfigurationFile r = read_h5md(p, o);
      EXPECT_EQ(r.config.positions, s.run->positions(s.k));
      EXPECT_EQ(r.config.box.dim, run.box.dim);
      for (int a = 0; a < run.box.dim; ++a) {
        EXPECT_EQ(r.config.box.length[a], run.box.length[a]);
        EXPECT_EQ(r.config.box.periodic[a], run.box.periodic[a]);
      }
      ASSERT_EQ(r.config.size(), run.n());
      for (std::size_t i = 0; i < run.n(); ++i)  // read_h5md names species by the names stored
        EXPECT_EQ(r.species[r.config.types[i]], run.names[run.species[i]]);
    }
  }
  h5::File f = h5::File::open_read(p);
  const hid_t root = f.id();
  const std::size_t row = run.n() * std::size_t(run.box.dim);
  // The rows of a dataset of `count` frames, `width` values each.
  const auto rows_of = [&](const std::string& name, std::size_t width) {
    const h5::Array<double> a = h5::read_doubles(root, name, p);
    std::vector<std::vector<double>> out;
    EXPECT_EQ(a.shape.at(0), hsize_t(count)) << name;
    EXPECT_EQ(a.values.size(), std::size_t(count) * width) << name;
    for (long j = 0; j < count && a.values.size() == std::size_t(count) * width; ++j)
      out.emplace_back(a.values.begin() + long(width) * j, a.values.begin() + long(width) * (j + 1));
    out.resize(std::size_t(count));
    return out;
  };
  const std::vector<int64_t> steps = h5::read_ints(root, kAll + "/position/step", p).values;
  const auto times = rows_of(kAll + "/position/time", 1);
  const auto edges = rows_of(kAll + "/box/edges/value", std::size_t(run.box.dim));
  const auto velocities = run.options.velocities ? rows_of(kAll + "/velocity/value", row) : decltype(times){};
  const auto forces = run.options.forces ? rows_of(kAll + "/force/value", row) : decltype(times){};
  std::vector<std::vector<std::vector<double>>> observables;
  for (const std::string& name : run.options.observables) observables.push_back(rows_of("observables/" + name + "/value", 1));
  ASSERT_EQ(steps.size(), std::size_t(count));
  for (std::size_t j = 0; j < std::size_t(count); ++j) {
    SCOPED_TRACE("frame " + std::to_string(j));
    const SimRun& r = *frames[j].run;
    const std::size_t k = frames[j].k;
    EXPECT_EQ(steps[j], r.step(k));
    EXPECT_EQ(times[j], std::vector<double>{r.time(k)});
    EXPECT_EQ(edges[j], std::vector<double>(run.box.length, run.box.length + run.box.dim));
    if (run.options.velocities) {
      EXPECT_EQ(velocities[j], r.velocities(k));
    }
    if (run.options.forces) {
      EXPECT_EQ(forces[j], r.forces(k));
    }
    for (std::size_t o = 0; o < observables.size(); ++o)
      EXPECT_EQ(observables[o][j], std::vector<double>{r.observables(k)[o]}) << run.options.observables[o];
  }
  EXPECT_EQ(h5::read_ints(root, kAll + "/species", p).values,
            std::vector<int64_t>(run.species.begin(), run.species.end()));
}

// The file holds exactly the run's frames from..to-1.
void expect_holds(const std::string& p, const SimRun& run, std::size_t from, std::size_t to) {
  std::vector<Source> frames;
  for (std::size_t k = from; k < to; ++k) frames.push_back({&run, k});
  expect_holds(p, frames);
}

// An attribute's integers and the byte size of its stored type.
std::pair<std::vector<int64_t>, std::size_t> int_attribute(hid_t obj, const std::string& name) {
  h5::Handle attr(H5Aopen(obj, name.c_str(), H5P_DEFAULT));
  h5::Handle type(H5Aget_type(attr.get()));
  h5::Handle space(H5Aget_space(attr.get()));
  EXPECT_EQ(H5Tget_class(type.get()), H5T_INTEGER) << name;
  std::vector<int64_t> v(std::size_t(H5Sget_simple_extent_npoints(space.get())));
  H5Aread(attr.get(), H5T_NATIVE_INT64, v.data());
  return {v, H5Tget_size(type.get())};
}

// True when the attribute holds fixed-length strings (what H5MD asks for).
bool fixed_length_strings(hid_t obj, const std::string& name) {
  h5::Handle attr(H5Aopen(obj, name.c_str(), H5P_DEFAULT));
  h5::Handle type(H5Aget_type(attr.get()));
  return H5Tget_class(type.get()) == H5T_STRING && H5Tis_variable_str(type.get()) == 0;
}

// ---- layout and round trip ---------------------------------------------------------------------

TEST_F(H5mdTrajectory, EveryFrameReadsBackExactlyIn3DAnd2DPeriodicAndOpen) {
  struct Case {
    std::string name;
    SimRun run;
  };
  const std::vector<Case> cases = {
      {"3D periodic, velocities, forces, observables", full_run()},
      {"2D periodic", make_run(cftest::cube(2, 9.25), 30, 2, false, false, {})},
      {"3D open y and z, forces", make_run(cftest::make_box(3, {7.0, 5.5, 3.25}, {true, false, false}), 25, 3,
                                           false, true, {"potential_energy"})},
      {"2D open, velocities", make_run(cftest::cube(2, 4.0, false), 12, 4, true, false, {"temperature"})},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const std::string p = path("t.h5");
    {
      H5mdWriter w = c.run.open(p);
      EXPECT_EQ(w.frames(), 0u);
      EXPECT_FALSE(w.last_step().has_value());
      for (std::size_t k = 0; k < 4; ++k) c.run.write(w, k);
      EXPECT_EQ(w.frames(), 4u);
      EXPECT_EQ(w.last_step(), c.run.step(3));
      w.close();
    }
    expect_holds(p, c.run, 0, 4);
  }
}

TEST_F(H5mdTrajectory, LayoutFollowsH5md11) {
  const SimRun run = full_run();
  const std::string p = path("t.h5");
  {
    H5mdWriter w = run.open(p);
    run.write(w, 0);
  }  // the destructor closes
  h5::File f = h5::File::open_read(p);
  const hid_t root = f.id();
  h5::Handle h5md = h5::open_group(root, "h5md", p);
  EXPECT_EQ(int_attribute(h5md.get(), "version"), (std::pair<std::vector<int64_t>, std::size_t>{{1, 1}, 4}));
  h5::Handle author = h5::open_group(root, "h5md/author", p), creator = h5::open_group(root, "h5md/creator", p);
  EXPECT_EQ(h5::read_string_attribute(author.get(), "name", p), std::vector<std::string>{"cellforce"});
  EXPECT_EQ(h5::read_string_attribute(creator.get(), "name", p), std::vector<std::string>{"cellforce"});
  EXPECT_EQ(h5::read_string_attribute(creator.get(), "version", p), std::vector<std::string>{"0.1.0"});
  EXPECT_TRUE(fixed_length_strings(author.get(), "name"));
  EXPECT_TRUE(fixed_length_strings(creator.get(), "version"));

  h5::Handle box = h5::open_group(root, kAll + "/box", p);
  EXPECT_EQ(int_attribute(box.get(), "dimension"), (std::pair<std::vector<int64_t>, std::size_t>{{3}, 4}));
  EXPECT_EQ(h5::read_string_attribute(box.get(), "boundary", p), (std::vector<std::string>{"periodic", "periodic", "periodic"}));
  EXPECT_TRUE(fixed_length_strings(box.get(), "boundary"));

  // step and time exist once: every time-dependent element links to position's.
  for (const std::string& element : {kAll + "/box/edges", kAll + "/velocity", kAll + "/force",
                                    std::string("observables/pressure"), std::string("observables/potential_energy")})
    for (const char* axis : {"step", "time"})
      EXPECT_TRUE(h5::same_object(root, element + "/" + axis, kAll + "/position/" + axis, p)) << element << "/" << axis;

  h5::Handle species = h5::open_dataset(root, kAll + "/species", p);
  EXPECT_EQ(h5::read_string_attribute(species.get(), "names", p), (std::vector<std::string>{"A", "B", "C"}));
  EXPECT_TRUE(fixed_length_strings(species.get(), "names"));
  const auto type_of = [&](const std::string& name) {
    h5::Handle set = h5::open_dataset(root, name, p);
    h5::Handle type(H5Dget_type(set.get()));
    return std::pair{H5Tget_class(type.get()), H5Tget_size(type.get())};
  };
  EXPECT_EQ(type_of(kAll + "/species"), std::pair(H5T_INTEGER, std::size_t(4)));
  EXPECT_EQ(type_of(kAll + "/position/step"), std::pair(H5T_INTEGER, std::size_t(8)));
  EXPECT_EQ(type_of(kAll + "/position/time"), std::pair(H5T_FLOAT, std::size_t(8)));
  EXPECT_EQ(type_of(kAll + "/position/value"), std::pair(H5T_FLOAT, std::size_t(8)));
  EXPECT_EQ(type_of("observables/temperature/value"), std::pair(H5T_FLOAT, std::size_t(8)));
  // No unit attributes: reduced units have no H5MD unit string.
  h5::Handle position = h5::open_dataset(root, kAll + "/position/value", p);
  EXPECT_FALSE(h5::has_attribute(position.get(), "unit"));
}

TEST_F(H5mdTrajectory, PerParticleDatasetsAreChunkedByFrameAndCompressed) {
  struct Expect {
    std::size_t n;
    hsize_t per_chunk;  // particles per chunk: a frame of at most 1 MiB is one chunk
  };
  // 3D doubles: 43,690 particles fit in 1 MiB; 100,000 split into 3 chunks of 33,334.
  for (const Expect e : {Expect{40, 40}, Expect{100000, 33334}}) {
    SCOPED_TRACE(e.n);
    SimRun run = make_run(cftest::cube(3, 60.0), e.n, 11, true, true, {"pressure"});
    const std::string p = path("t.h5");
    {
      H5mdWriter w = run.open(p);
      run.write(w, 0);
      run.write(w, 1);
    }
    if (e.n > 40) {  // the partly filled last chunk reads back exactly too
      ReadOptions o;
      o.frame = 1;
      EXPECT_EQ(read_h5md(p, o).config.positions, run.positions(1));
    }
    h5::File f = h5::File::open_read(p);
    for (const std::string name : {"position", "velocity", "force"}) {
      h5::Handle set = h5::open_dataset(f.id(), kAll + "/" + name + "/value", p);
      h5::Handle dcpl(H5Dget_create_plist(set.get()));
      ASSERT_EQ(H5Pget_layout(dcpl.get()), H5D_CHUNKED) << name;
      hsize_t chunk[3] = {0, 0, 0};
      ASSERT_EQ(H5Pget_chunk(dcpl.get(), 3, chunk), 3);
      EXPECT_EQ(chunk[0], 1u);
      EXPECT_EQ(chunk[1], e.per_chunk);
      EXPECT_EQ(chunk[2], 3u);
      EXPECT_LE(chunk[1] * chunk[2] * sizeof(double), std::size_t(1) << 20);
      std::vector<hsize_t> max_shape;
      h5::dataset_shape(set.get(), p, &max_shape);
      EXPECT_EQ(max_shape, (std::vector<hsize_t>{H5S_UNLIMITED, e.n, 3}));
      std::vector<H5Z_filter_t> filters;
      for (int k = 0; k < H5Pget_nfilters(dcpl.get()); ++k) {
        unsigned flags = 0, level = 0;
        std::size_t count = 1;
        filters.push_back(H5Pget_filter2(dcpl.get(), unsigned(k), &flags, &count, &level, 0, nullptr, nullptr));
        if (filters.back() == H5Z_FILTER_DEFLATE) {
          EXPECT_EQ(level, 1u);
        }
      }
      if (h5::deflate_available()) {
        EXPECT_EQ(filters, (std::vector<H5Z_filter_t>{H5Z_FILTER_SHUFFLE, H5Z_FILTER_DEFLATE})) << name;
      }
    }
    // The per-frame scalars: chunked along time (1024 frames), uncompressed.
    h5::Handle step = h5::open_dataset(f.id(), kAll + "/position/step", p);
    h5::Handle dcpl(H5Dget_create_plist(step.get()));
    hsize_t chunk = 0;
    ASSERT_EQ(H5Pget_chunk(dcpl.get(), 1, &chunk), 1);
    EXPECT_EQ(chunk, 1024u);
    EXPECT_EQ(H5Pget_nfilters(dcpl.get()), 0);
  }
}

// ---- restarts ----------------------------------------------------------------------------------

TEST_F(H5mdTrajectory, AppendContinuesTheTrajectoryOfARestartedRun) {
  const SimRun run = full_run();
  const std::string p = path("t.h5");
  {
    H5mdWriter w = run.open(p);
    for (std::size_t k = 0; k < 3; ++k) run.write(w, k);
  }
  {
    H5mdWriter w = run.open(p, /*append=*/true);
    EXPECT_EQ(w.frames(), 3u);
    EXPECT_EQ(w.last_step(), run.step(2));
    for (std::size_t k = 3; k < 5; ++k) run.write(w, k);
    w.close();
  }
  expect_holds(p, run, 0, 5);
}

TEST_F(H5mdTrajectory, RepeatedOrEarlierStepsAreRefusedAndLeaveTheFileUnchanged) {
  const SimRun run = full_run();
  const std::string p = path("t.h5");
  {
    H5mdWriter w = run.open(p);
    for (std::size_t k = 0; k < 3; ++k) run.write(w, k);
  }
  {
    H5mdWriter w = run.open(p, true);
    for (const std::size_t k : {2u, 1u, 0u}) {
      EXPECT_THAT(error_of([&] { run.write(w, k); }),
                  HasSubstr(p + ": frame at step " + std::to_string(run.step(k)) +
                            " refused: the trajectory already holds frames up to step 200"));
      EXPECT_EQ(w.frames(), 3u);
    }
    run.write(w, 3);
  }
  expect_holds(p, run, 0, 4);
}

TEST_F(H5mdTrajectory, TruncateAfterDropsTheLaterFramesThenTheRerunAppends) {
  const SimRun run = full_run();
  SimRun rerun = run;
  rerun.seed = 99;  // the rerun's frames differ from the dropped ones
  const std::string p = path("t.h5");
  {
    H5mdWriter w = run.open(p);
    for (std::size_t k = 0; k < 6; ++k) run.write(w, k);  // steps 0 .. 500
  }
  // Restarted from its checkpoint at step 250: the frames after it go, the rerun's follow.
  {
    H5mdWriter w = rerun.open(p, true);
    EXPECT_EQ(w.frames(), 6u);
    w.truncate_after(250);
    EXPECT_EQ(w.frames(), 3u);
    EXPECT_EQ(w.last_step(), 200);
    // On disk at once: every dataset holds the 3 frames kept.
    fs::copy_file(p, path("truncated.h5"));
    expect_holds(path("truncated.h5"), run, 0, 3);
    w.truncate_after(1000);  // no frame after step 1000: no change
    EXPECT_EQ(w.frames(), 3u);
    rerun.write(w, 3);
    rerun.write(w, 4);
  }
  expect_holds(p, {{&run, 0}, {&run, 1}, {&run, 2}, {&rerun, 3}, {&rerun, 4}});

  // Truncating everything leaves an empty trajectory that a run from step 0 refills.
  {
    H5mdWriter w = run.open(p, true);
    w.truncate_after(-1);
    EXPECT_EQ(w.frames(), 0u);
    EXPECT_FALSE(w.last_step().has_value());
    run.write(w, 0);
    run.write(w, 1);
  }
  expect_holds(p, run, 0, 2);
}

TEST_F(H5mdTrajectory, AppendRefusesARunThatDoesNotMatchTheFile) {
  const SimRun run = full_run();
  const std::string p = path("t.h5");
  {
    H5mdWriter w = run.open(p);
    run.write(w, 0);
  }
  const auto file_size = fs::file_size(p);
  struct Case {
    std::string name;
    std::function<void(SimRun&)> change;
    std::string message;
  };
  const std::vector<Case> cases = {
      {"particles", [](SimRun& r) { r.species.push_back(0); }, "the file holds 40 particles, this run 41"},
      {"dimension", [](SimRun& r) { r.box.dim = 2; }, "the file is 3D, this run 2D"},
      {"boundary", [](SimRun& r) { r.box.periodic[2] = false; },
       "the boundaries differ (file: periodic, periodic, periodic; run: periodic, periodic, none)"},
      {"species", [](SimRun& r) { r.species[5] = (r.species[5] + 1) % 3; }, "particle 5 has species"},
      {"names", [](SimRun& r) { r.names[1] = "Kr"; }, "the species names differ (file: A, B, C; run: A, Kr, C)"},
      {"no velocities", [](SimRun& r) { r.options.velocities = false; }, "the file holds velocity values, this run writes none"},
      {"no forces", [](SimRun& r) { r.options.forces = false; }, "the file holds force values, this run writes none"},
      {"observables", [](SimRun& r) { r.options.observables.pop_back(); }, "the observables differ (file: kinetic_energy, potential_energy, pressure, temperature, total_energy; run: kinetic_energy, potential_energy, temperature, total_energy)"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    SimRun other = run;
    c.change(other);
    const std::string msg = error_of([&] { other.open(p, true); });
    EXPECT_THAT(msg, HasSubstr(p + ": cannot append to this trajectory: "));
    EXPECT_THAT(msg, HasSubstr(c.message));
  }
  EXPECT_EQ(fs::file_size(p), file_size);
  expect_holds(p, run, 0, 1);

  // A run without velocities, appending to a file with velocities, and the other way round.
  SimRun plain = make_run(cftest::cube(3, 6.5), 40, 7, false, false, {});
  const std::string q = path("plain.h5");
  { H5mdWriter w = plain.open(q); }
  plain.options.velocities = true;
  EXPECT_THAT(error_of([&] { plain.open(q, true); }), HasSubstr("this run writes velocity values, the file holds none"));

  EXPECT_THAT(error_of([&] { run.open(path("missing.h5"), true); }), HasSubstr(path("missing.h5") + ": no such file"));
  const std::string empty = path("empty.h5");
  h5::File::create(empty).close();
  EXPECT_THAT(error_of([&] { run.open(empty, true); }), HasSubstr("it has no /h5md or no /particles/all/position"));
  const std::string text = path("text.h5");
  std::ofstream(text) << "not hdf5";
  EXPECT_THAT(error_of([&] { run.open(text, true); }), HasSubstr(text + ": not an HDF5 file"));
}

// ---- refused input -------------------------------------------------------------------------------

TEST_F(H5mdTrajectory, BadArgumentsAreRefusedBeforeTheFileChanges) {
  const SimRun run = full_run();
  const std::string p = path("t.h5");
  {
    H5mdWriter w = run.open(p);
    run.write(w, 0);
  }
  const auto file_size = fs::file_size(p);
  struct Case {
    std::string name;
    std::function<void(SimRun&)> change;
    std::string message;
  };
  const std::vector<Case> constructor_cases = {
      {"species index", [](SimRun& r) { r.species[3] = 3; }, "particle 3 has species 3 but 3 species names are given"},
      {"no particles", [](SimRun& r) { r.species.clear(); }, "a trajectory needs at least one particle"},
      {"dimension", [](SimRun& r) { r.box.dim = 1; }, "the box is 1-dimensional"},
      {"periodic length", [](SimRun& r) { r.box.length[1] = 0; }, "the periodic axis y has length 0"},
      {"empty name", [](SimRun& r) { r.names[0] = ""; }, "a species name is empty"},
      {"observable twice", [](SimRun& r) { r.options.observables.push_back("pressure"); }, "observable 'pressure' is named twice"},
      {"observable path", [](SimRun& r) { r.options.observables.push_back("a/b"); }, "'a/b' cannot name an observable"},
  };
  for (const Case& c : constructor_cases) {
    SCOPED_TRACE(c.name);
    SimRun other = run;
    c.change(other);
    for (const bool append : {false, true})
      EXPECT_THAT(error_of([&] { other.open(p, append); }), HasSubstr(p + ": " + c.message));
  }
  EXPECT_EQ(fs::file_size(p), file_size);  // not truncated by a refused constructor

  H5mdWriter w = run.open(p, true);
  const std::vector<double> x = run.positions(1), v = run.velocities(1), f = run.forces(1);
  const std::vector<double> obs = run.observables(1);
  EXPECT_THAT(error_of([&] { w.write_frame(100, 0.5, nullptr, v.data(), f.data(), obs); }), HasSubstr("without positions"));
  EXPECT_THAT(error_of([&] { w.write_frame(100, 0.5, x.data(), nullptr, f.data(), obs); }),
              HasSubstr(p + ": this trajectory stores velocities; none were given"));
  EXPECT_THAT(error_of([&] { w.write_frame(100, 0.5, x.data(), v.data(), nullptr, obs); }),
              HasSubstr(p + ": this trajectory stores forces; none were given"));
  EXPECT_THAT(error_of([&] { w.write_frame(100, 0.5, x.data(), v.data(), f.data(), {1.0}); }),
              HasSubstr("1 observable values for 5 observables (potential_energy, kinetic_energy, total_energy, temperature, pressure)"));
  EXPECT_THAT(error_of([&] { w.write_frame(100, NAN, x.data(), v.data(), f.data(), obs); }), HasSubstr("has time nan"));
  EXPECT_THAT(error_of([&] { w.write_frame(100, -0.5, x.data(), v.data(), f.data(), obs); }),
              HasSubstr("has time -0.500000, before the last stored frame's 0.000000"));
  EXPECT_EQ(w.frames(), 1u);
  w.close();
  EXPECT_THAT(error_of([&] { run.write(w, 1); }), HasSubstr(p + ": the H5MD trajectory is closed"));
  EXPECT_THAT(error_of([&] { w.truncate_after(0); }), HasSubstr("closed"));
  w.close();  // closing twice is harmless
  expect_holds(p, run, 0, 1);
}

using cftest::FileSizeLimit;

// A frame whose writing fails (here: the disk refuses to grow the file) is reported and not
// counted; where HDF5 cannot shrink the datasets back (it cannot, after a failed write of a
// compressed chunk), later frames are refused, and reopening with append drops the incomplete
// frame: the restarted run continues from the last complete one.
TEST_F(H5mdTrajectory, AFailedWriteFrameLeavesNoFrameBehind) {
  const SimRun run = full_run();
  const std::string p = path("t.h5");
  H5mdWriter w = run.open(p);
  run.write(w, 0);
  run.write(w, 1);
  {
    const FileSizeLimit limit(fs::file_size(p));
    EXPECT_THAT(error_of([&] { run.write(w, 2); }), HasSubstr(p + ": cannot write the HDF5 file: the file is larger than the system allows"));
    EXPECT_EQ(w.frames(), 2u);
    EXPECT_EQ(w.last_step(), run.step(1));
  }
  // Either the undo worked and the next frame is accepted, or it is refused with the remedy.
  bool refused = false;
  try {
    run.write(w, 2);
  } catch (const Error& e) {
    refused = true;
    EXPECT_THAT(e.what(), HasSubstr("the failed frame at step 200 could not be undone"));
    EXPECT_THAT(e.what(), HasSubstr("reopen it with append"));
  }
  RecordProperty("undo", refused ? "failed: later frames refused" : "worked");
  w.close();
  H5mdWriter again = run.open(p, true);
  EXPECT_EQ(again.frames(), refused ? 2u : 3u);
  for (std::size_t k = again.frames(); k < 4; ++k) run.write(again, k);
  again.close();
  expect_holds(p, run, 0, 4);
}

// Reopening with append cuts datasets of unequal length (a run killed inside write_frame) back to
// the frames that all of them hold.
TEST_F(H5mdTrajectory, AppendDropsAnIncompleteLastFrame) {
  const SimRun run = full_run();
  const std::string p = path("t.h5");
  for (const std::string& grown : {kAll + "/position/value", kAll + "/force/value", std::string("observables/pressure/value")}) {
    SCOPED_TRACE(grown);
    {
      H5mdWriter w = run.open(p);
      for (std::size_t k = 0; k < 3; ++k) run.write(w, k);
    }
    {
      h5::File f = h5::File::open_read_write(p);
      h5::Handle set = h5::open_dataset(f.id(), grown, p);
      h5::set_rows(set.get(), 4, p);  // one dataset grew, the run died before the others did
    }
    {
      H5mdWriter w = run.open(p, true);
      EXPECT_EQ(w.frames(), 3u);
      EXPECT_EQ(w.dropped_incomplete_frames(), 1u);
      EXPECT_EQ(w.last_step(), run.step(2));
      run.write(w, 3);
    }
    expect_holds(p, run, 0, 4);
  }
}

// ---- interrupted runs ----------------------------------------------------------------------------

// The file on disk after write_frame returns, while the writer still holds it open (a copy: the
// writer's file lock keeps others from opening the original), holds every frame written.
TEST_F(H5mdTrajectory, TheFileOnDiskHoldsEveryFrameAfterEachWriteFrame) {
  const SimRun run = full_run();
  const std::string p = path("t.h5");
  H5mdWriter w = run.open(p);
  for (std::size_t k = 0; k < 4; ++k) {
    SCOPED_TRACE("after frame " + std::to_string(k));
    run.write(w, k);
    const std::string copy = path("copy-" + std::to_string(k) + ".h5");
    fs::copy_file(p, copy);
    expect_holds(copy, run, 0, k + 1);
  }
}

// A run killed (SIGKILL: no destructor, no HDF5 shutdown) right after write_frame leaves a file
// that reads back with every frame written, and that a restarted run can append to.
TEST_F(H5mdTrajectory, ARunKilledAfterWriteFrameLeavesAReadableFile) {
  const SimRun run = full_run();
  const std::string p = path("t.h5");
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    try {
      H5mdWriter w = run.open(p);
      for (std::size_t k = 0; k < 3; ++k) run.write(w, k);
      ::raise(SIGKILL);
    } catch (...) {
    }
    ::_exit(3);  // only reached when writing failed
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL) << "the child did not reach its kill";
  expect_holds(p, run, 0, 3);
  {
    H5mdWriter w = run.open(p, true);
    EXPECT_EQ(w.frames(), 3u);
    run.write(w, 3);
  }
  expect_holds(p, run, 0, 4);
}

// ---- sample files for validation/check_h5md.py -----------------------------------------------------

// CELLFORCE_H5MD_SAMPLE=FILE.h5: a 3D periodic trajectory of 500 particles (2 species) with
// velocities, forces and five observables, written as a run that was restarted with
// truncate_after: 8 frames at steps 0, 100, ..., 700. Skipped without the variable.
TEST(H5mdSample, ThreeDimensionalRestartedRun) {
  const char* out = std::getenv("CELLFORCE_H5MD_SAMPLE");
  if (!out || !*out) GTEST_SKIP() << "set CELLFORCE_H5MD_SAMPLE=FILE.h5 to write the sample for validation/check_h5md.py";
  SimRun run = make_run(cftest::cube(3, 8.4), 500, 5, true, true,
                     {"potential_energy", "kinetic_energy", "total_energy", "temperature", "pressure"});
  for (uint32_t& s : run.species) s %= 2;
  run.names = {"Ar", "Kr"};
  SimRun rerun = run;
  rerun.seed = 6;
  {
    H5mdWriter w = run.open(out);
    for (std::size_t k = 0; k < 6; ++k) run.write(w, k);
  }
  H5mdWriter w = rerun.open(out, true);
  w.truncate_after(300);
  for (std::size_t k = 4; k < 8; ++k) rerun.write(w, k);
  w.close();
  EXPECT_EQ(w.frames(), 8u);
  std::printf("wrote %s: 8 frames, 500 particles, 3D periodic\n", out);
}

// CELLFORCE_H5MD_SAMPLE_2D=FILE.h5: 2D, x periodic and y open, 64 particles, positions only,
// 5 frames. Skipped without the variable.
TEST(H5mdSample, TwoDimensionalOpenAxis) {
  const char* out = std::getenv("CELLFORCE_H5MD_SAMPLE_2D");
  if (!out || !*out) GTEST_SKIP() << "set CELLFORCE_H5MD_SAMPLE_2D=FILE.h5 to write the sample for validation/check_h5md.py";
  const SimRun run = make_run(cftest::make_box(2, {10.0, 6.0, 0.0}, {true, false, false}), 64, 8, false, false, {});
  H5mdWriter w = run.open(out);
  for (std::size_t k = 0; k < 5; ++k) run.write(w, k);
  w.close();
  std::printf("wrote %s: 5 frames, 64 particles, 2D\n", out);
}

}  // namespace

namespace {

// The rows of every dataset that grows by one row per frame, by name.
std::map<std::string, hsize_t> growing_rows(const std::string& p, const SimRun& run) {
  h5::File f = h5::File::open_read(p);
  std::vector<std::string> names = {kAll + "/position/step", kAll + "/position/time", kAll + "/position/value",
                                    kAll + "/box/edges/value"};
  if (run.options.velocities) names.push_back(kAll + "/velocity/value");
  if (run.options.forces) names.push_back(kAll + "/force/value");
  for (const std::string& o : run.options.observables) names.push_back("observables/" + o + "/value");
  std::map<std::string, hsize_t> rows;
  for (const std::string& name : names) rows[name] = h5::dataset_shape(f.id(), name, p).at(0);
  return rows;
}

// A disk that fills in the middle of a frame (here: a file-size limit, at several points of the
// frame's writing and of the file's closing) leaves a file whose frames are whole: every dataset
// holds the frames before it, or every dataset holds it too, and readers (h5py, MDAnalysis,
// read_h5md) read the file as it is, without a restart's repair. The error names the reason.
TEST_F(H5mdTrajectory, ADiskFullInMidFrameLeavesTheFrameWholeOrAbsent) {
  const SimRun run = make_run(cftest::cube(3, 30.0), 3000, 9, true, true,
                              {"potential_energy", "kinetic_energy", "total_energy", "temperature", "pressure"});
  const std::string p = path("t.h5");
  std::uintmax_t full = 0;
  {
    H5mdWriter w = run.open(p);
    for (std::size_t k = 0; k < 3; ++k) run.write(w, k);
    w.close();
    full = fs::file_size(p);
  }
  std::uintmax_t two = 0;
  {
    H5mdWriter w = run.open(p);
    for (std::size_t k = 0; k < 2; ++k) run.write(w, k);
    w.close();
    two = fs::file_size(p);
  }
  for (const std::uintmax_t limit : {two, two + 512, two + (full - two) / 3, two + (full - two) / 2,
                                     two + 2 * (full - two) / 3, full - 512, full - 1}) {
    SCOPED_TRACE("limit " + std::to_string(limit) + " (2 frames: " + std::to_string(two) + " bytes, 3: " +
                 std::to_string(full) + ")");
    fs::remove(p);
    H5mdWriter w = run.open(p);
    for (std::size_t k = 0; k < 2; ++k) run.write(w, k);
    std::string msg;
    {
      const cftest::FileSizeLimit limited(limit);
      ASSERT_TRUE(limited.ok());
      try {
        run.write(w, 2);
      } catch (const Error& e) {
        msg = e.what();
      }
      try {
        w.close();  // the disk is still full
      } catch (const Error& e) {
        if (msg.empty()) msg = e.what();
      }
    }
    EXPECT_THAT(msg, HasSubstr(p + ": cannot write the HDF5 file: the file is larger than the system allows"));
    const std::map<std::string, hsize_t> rows = growing_rows(p, run);
    const hsize_t frames = rows.begin()->second;
    for (const auto& [name, n] : rows) EXPECT_EQ(n, frames) << name;
    EXPECT_TRUE(frames == 2 || frames == 3) << frames;
    expect_holds(p, run, 0, std::size_t(frames));
  }
}

// The same on a full disk where this machine lets the test mount a small tmpfs (root, or a
// container with the capability): the free space runs out at points inside the third frame.
TEST_F(H5mdTrajectory, AFullTmpfsInMidFrameLeavesTheFrameWholeOrAbsent) {
  const fs::path mount_point = dir_ / "small";
  fs::create_directories(mount_point);
  if (::mount("tmpfs", mount_point.c_str(), "tmpfs", 0, "size=2m") != 0)
    GTEST_SKIP() << "cannot mount a tmpfs here (" << std::strerror(errno) << "); the file-size-limit test covers it";
  struct Unmount {
    fs::path p;
    ~Unmount() { ::umount(p.c_str()); }
  } unmount{mount_point};
  const SimRun run = make_run(cftest::cube(3, 30.0), 3000, 9, true, true,
                              {"potential_energy", "kinetic_energy", "total_energy", "temperature", "pressure"});
  const std::string p = (mount_point / "t.h5").string();
  const std::string filler = (mount_point / "filler").string();
  for (const std::size_t free_kb : {4, 64, 128, 192, 256}) {
    SCOPED_TRACE(std::to_string(free_kb) + " KB free after two frames");
    fs::remove(p);
    fs::remove(filler);
    H5mdWriter w = run.open(p);
    for (std::size_t k = 0; k < 2; ++k) run.write(w, k);
    const fs::space_info space = fs::space(mount_point);
    if (space.available > free_kb * 1024)
      std::ofstream(filler) << std::string(space.available - free_kb * 1024, 'f');
    std::string msg;
    try {
      run.write(w, 2);
    } catch (const Error& e) {
      msg = e.what();
    }
    try {
      w.close();
    } catch (const Error& e) {
      if (msg.empty()) msg = e.what();
    }
    EXPECT_THAT(msg, HasSubstr(p + ": cannot write the HDF5 file: no space left on the device (the disk is full)"));
    const std::map<std::string, hsize_t> rows = growing_rows(p, run);
    for (const auto& [name, n] : rows) EXPECT_EQ(n, 2u) << name;
    expect_holds(p, run, 0, 2);
  }
}

}  // namespace
