// Scene files: every value read where it is written, every malformed scene refused with its
// file, line and key, the scenes in systems/ all valid, and the configurations they build.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <map>

#include "core/error.h"
#include "core/option_table.h"
#include "scene/scene.h"
#include "temp_folder.h"

namespace {

using namespace cellforce;
using ::testing::HasSubstr;

std::string error_of(const std::string& text) {
  try {
    parse_scene(text, "bad.toml");
  } catch (const Error& e) {
    return e.what();
  }
  ADD_FAILURE() << "no error for:\n" << text;
  return {};
}

const char* kMinimal = "[[types]]\nname = \"A\"\n";

TEST(Scene, ReadsEveryKey) {
  const Scene s = parse_scene(R"(
[system]
dimension = 3
periodic = [true, true, false]
[particles]
source = "lattice"
lattice = "bcc"
cells = [3, 4, 5]
lattice_constant = 1.5
box = [10, 10, 20]
offset = [0.5, 0.5, 1.0]
composition = { A = 3, B = 1 }
[[types]]
name = "A"
mass = 2.0
sigma = 1.1
epsilon = 0.9
[[types]]
name = "B"
sigma = 0.8
[interactions]
cutoff = 2.0
mode = "force-shift"
mixing = "geometric"
[[interactions.pairs]]
types = ["B", "A"]
sigma = 0.7
epsilon = 1.4
[initial]
temperature = 0.8
seed = 42
[integrator]
kind = "langevin"
dt = 0.002
temperature = 0.9
friction = 2.0
[run]
steps = 123
backend = "cpu"
precision = "single"
[output]
thermo_every = 7
thermo_file = "t.csv"
trajectory = "t.h5"
trajectory_every = 11
velocities = true
forces = true
checkpoint = "c.h5"
checkpoint_every = 50
)", "full.toml");
  EXPECT_EQ(s.dim, 3);
  EXPECT_FALSE(s.periodic[2]);
  EXPECT_EQ(s.particles.lattice, Lattice::kBcc);
  EXPECT_EQ(s.particles.cells, (std::array<int, 3>{3, 4, 5}));
  EXPECT_EQ(s.particles.lattice_constant, 1.5);
  EXPECT_EQ(s.particles.box[2], 20.0);
  EXPECT_EQ(s.particles.offset[2], 1.0);
  ASSERT_EQ(s.particles.composition.size(), 2u);
  EXPECT_DOUBLE_EQ(s.particles.composition[0].second, 0.75);
  EXPECT_EQ(s.masses, (std::vector<double>{2.0, 1.0}));
  EXPECT_EQ(s.force_field.types[0].sigma, 1.1);
  EXPECT_EQ(s.force_field.types[1].epsilon, 1.0);
  EXPECT_EQ(s.force_field.mode, CutoffMode::kForceShift);
  EXPECT_EQ(s.force_field.mixing, Mixing::kGeometric);
  ASSERT_EQ(s.force_field.overrides.size(), 1u);
  EXPECT_EQ(s.force_field.pair_sigma(0, 1), 0.7);
  EXPECT_EQ(s.initial_temperature, 0.8);
  EXPECT_EQ(s.seed, 42u);
  EXPECT_EQ(s.integrator.kind, IntegratorKind::kLangevin);
  EXPECT_EQ(s.integrator.friction, 2.0);
  EXPECT_EQ(s.steps, 123);
  EXPECT_EQ(s.engine.value(OptionId::kBackend), "cpu");
  EXPECT_EQ(s.engine.value(OptionId::kPrecision), "single");
  EXPECT_EQ(s.output.trajectory_every, 11);
  EXPECT_TRUE(s.output.velocities);
  EXPECT_EQ(s.output.checkpoint_every, 50);

  const Configuration c = build_configuration(s);
  EXPECT_EQ(c.size(), std::size_t(2 * 3 * 4 * 5));
  EXPECT_EQ(c.box.length[0], 10.0);
  EXPECT_FALSE(c.box.periodic[2]);
  std::size_t b = 0;
  for (uint32_t t : c.types) b += t;
  EXPECT_EQ(b, c.size() / 4) << "composition A 3 : B 1, exact counts";
  EXPECT_EQ(c.positions[2], 1.0) << "first site at the offset";
}

TEST(Scene, MalformedScenesNameFileLineAndKey) {
  struct Case {
    const char* name;
    std::string text;
    std::vector<std::string> expected;
  };
  const std::string types = kMinimal;
  const std::vector<Case> cases = {
      {"toml syntax", types + "[run]\nsteps = = 3\n", {"bad.toml:4"}},
      {"unknown section", types + "[runn]\nsteps = 3\n", {"bad.toml:3", "unknown section or key 'runn'"}},
      {"unknown key", types + "[run]\nstep = 3\n", {"bad.toml:4", "unknown key 'run.step'"}},
      {"unknown type key", "[[types]]\nname = \"A\"\nsigmaa = 1\n", {"bad.toml:3", "unknown key 'types.sigmaa'"}},
      {"no types", "[run]\nsteps = 3\n", {"no [[types]]"}},
      {"type without name", "[[types]]\nsigma = 1\n", {"bad.toml:1", "needs a name"}},
      {"type twice", types + "[[types]]\nname = \"A\"\n", {"bad.toml:4", "defined twice"}},
      {"negative sigma", "[[types]]\nname = \"A\"\nsigma = -1\n", {"bad.toml:3", "[types] sigma", "> 0"}},
      {"wrong type", types + "[run]\nsteps = \"many\"\n", {"bad.toml:4", "[run] steps", "expected an integer"}},
      {"negative steps", types + "[run]\nsteps = -5\n", {"bad.toml:4", "at least 0"}},
      {"zero dt", types + "[integrator]\ndt = 0.0\n", {"bad.toml:4", "[integrator] dt", "> 0"}},
      {"bad choice", types + "[integrator]\nkind = \"nvt\"\n", {"bad.toml:4", "'nvt' is not one of langevin, nve"}},
      {"langevin without T", types + "[integrator]\nkind = \"langevin\"\n", {"needs its temperature"}},
      {"dimension", types + "[system]\ndimension = 4\n", {"bad.toml:4", "must be 2 or 3"}},
      {"periodic length", types + "[system]\nperiodic = [true, true]\n", {"bad.toml:4", "array of 3"}},
      {"lattice dimension", types + "[system]\ndimension = 2\n[particles]\nlattice = \"fcc\"\n",
       {"bad.toml:6", "2D lattice"}},
      {"density and constant", types + "[particles]\ndensity = 1\nlattice_constant = 1\n",
       {"give density or lattice_constant, not both"}},
      {"zero cells", types + "[particles]\ncells = [2, 0, 2]\n", {"bad.toml:4", "at least one unit cell"}},
      {"random without box", types + "[particles]\nsource = \"random\"\ncount = 10\n", {"needs box"}},
      {"random without count", types + "[particles]\nsource = \"random\"\nbox = [5, 5, 5]\n", {"needs count"}},
      {"file without path", types + "[particles]\nsource = \"file\"\n", {"needs path"}},
      {"composition type", types + "[particles]\ncomposition = { A = 1, C = 1 }\n", {"bad.toml:4", "type 'C'"}},
      {"pair type", types + "[interactions]\n[[interactions.pairs]]\ntypes = [\"A\", \"Z\"]\nsigma = 1\nepsilon = 1\n",
       {"bad.toml:5", "type 'Z' is not defined"}},
      {"pair values", types + "[interactions]\n[[interactions.pairs]]\ntypes = [\"A\", \"A\"]\n",
       {"needs sigma and epsilon"}},
      {"cutoff", types + "[interactions]\ncutoff = 0\n", {"bad.toml:4", "cutoff", "> 0"}},
      {"thermo every", types + "[output]\nthermo_every = 0\n", {"bad.toml:4", "at least 1"}},
      {"key of another source", types + "[particles]\ncount = 10\n",
       {"bad.toml:4", "'particles.count' applies only to source = \"random\""}},
      {"langevin key under nve", types + "[integrator]\ntemperature = 1.0\n",
       {"bad.toml:4", "'integrator.temperature' applies only to kind = \"langevin\""}},
      {"trajectory cadence without trajectory", types + "[output]\ntrajectory_every = 10\n",
       {"bad.toml:4", "applies only with a trajectory"}},
      {"checkpoint cadence without checkpoint", types + "[output]\ncheckpoint_every = 10\n",
       {"bad.toml:4", "applies only with a checkpoint"}},
      {"non-finite box", types + "[particles]\nbox = [nan, 10, 10]\n", {"bad.toml:4", "[particles] box", "finite"}},
      {"section not table", "run = 5\n" + types, {"bad.toml:1", "'run' must be a table"}},
      {"key after array of tables", types + "run = 5\n", {"bad.toml:3", "unknown key 'types.run'"}},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const std::string msg = error_of(c.text);
    for (const std::string& e : c.expected) EXPECT_THAT(msg, HasSubstr(e));
  }
}

// Runtime errors of the configuration name the scene too.
// [neighbor]: the skin and its policy reach the backend; values that cannot work are refused
// with the file, line and key.
TEST(Scene, NeighborSection) {
  const Scene plain = parse_scene(kMinimal, "plain.toml");
  EXPECT_EQ(plain.engine.value(OptionId::kSkin), "auto") << "no [neighbor]: skin auto (no length)";
  EXPECT_EQ(plain.engine.value(OptionId::kNeighborList), "false");
  EXPECT_EQ(cellforce::default_scene().engine.value(OptionId::kSkin), "auto");
  const Scene named = parse_scene(std::string(kMinimal) + "[neighbor]\nskin = \"auto\"\ncheck = false\nevery = 9\n",
                                  "auto.toml");
  EXPECT_EQ(named.engine.value(OptionId::kSkin), "auto");
  EXPECT_EQ(named.engine.value(OptionId::kNeighborCheck), "false");
  EXPECT_EQ(named.engine.value(OptionId::kNeighborEvery), "9");
  const Scene off = parse_scene(std::string(kMinimal) + "[neighbor]\nskin = 0\n", "off.toml");
  EXPECT_EQ(off.engine.value(OptionId::kSkin), "0") << "a length, not auto";
  const Scene s = parse_scene(std::string(kMinimal) +
                                  "[neighbor]\nskin = 0.3\ncheck = false\nevery = 10\naudit = true\nlist = true\n",
                              "n.toml");
  EXPECT_EQ(s.engine.value(OptionId::kNeighborList), "true");
  EXPECT_EQ(s.engine.value(OptionId::kSkin), "0.3");
  EXPECT_EQ(s.engine.value(OptionId::kNeighborCheck), "false");
  EXPECT_EQ(s.engine.value(OptionId::kNeighborEvery), "10");
  EXPECT_EQ(s.engine.value(OptionId::kNeighborAudit), "true");
  EXPECT_EQ(scene_fingerprint(s), scene_fingerprint(plain)) << "reuse is exact: not part of the fingerprint";
  const std::string base = std::string(kMinimal) + "[neighbor]\n";
  EXPECT_THAT(error_of(base + "skin = -0.1\n"), HasSubstr("bad.toml:4"));
  EXPECT_THAT(error_of(base + "skin = -0.1\n"), HasSubstr("skin"));
  EXPECT_THAT(error_of(base + "skin = 0.3\nevery = -1\n"), HasSubstr("every"));
  EXPECT_THAT(error_of(base + "skin = 0.3\ncheck = \"yes\"\n"), HasSubstr("check"));
  EXPECT_THAT(error_of(base + "skin = 0\nevery = 5\n"), HasSubstr("applies only with a skin"));
  EXPECT_THAT(error_of(base + "skin = 0\nlist = true\n"), HasSubstr("applies only with a skin"));
  EXPECT_THAT(error_of(base + "list = true\n"), HasSubstr("chooses pair lists itself"));
  EXPECT_THAT(error_of(base + "skin = \"thick\"\n"), HasSubstr("expected \"auto\" or a length"));
  EXPECT_THAT(error_of(base + "skin = 0.3\nlist = 1\n"), HasSubstr("list"));
  EXPECT_THAT(error_of(base + "skin = 0.3\ncheck = false\n"), HasSubstr("never rebuilds"));
  EXPECT_THAT(error_of(base + "skin = 0.3\nsize = 2\n"), HasSubstr("size"));
}

TEST(Scene, ImpossibleConfigurationsAreRefused) {
  Scene dense = parse_scene(std::string(kMinimal) +
                                "[particles]\nsource = \"random\"\ncount = 1000\nbox = [5, 5, 5]\nmin_distance = 1\n",
                            "dense.toml");
  try {
    build_configuration(dense);
    ADD_FAILURE() << "1000 particles 1 apart in a 5^3 box";
  } catch (const Error& e) {
    EXPECT_THAT(std::string(e.what()), HasSubstr("found no place"));
  }
  Scene small = parse_scene(std::string(kMinimal) + "[particles]\ncells = [4, 4, 4]\nbox = [1, 1, 1]\n", "small.toml");
  try {
    build_configuration(small);
    ADD_FAILURE() << "box smaller than the lattice";
  } catch (const Error& e) {
    EXPECT_THAT(std::string(e.what()), HasSubstr("smaller than the lattice"));
  }
}

// Random placement keeps its minimum distance (minimum image) and is the same for a seed.
TEST(Scene, RandomPlacementKeepsItsDistance) {
  const Scene s = parse_scene(std::string(kMinimal) +
                                  "[particles]\nsource = \"random\"\ncount = 400\nbox = [12, 12, 12]\nmin_distance = 1\n",
                              "random.toml");
  const Configuration c = build_configuration(s);
  ASSERT_EQ(c.size(), 400u);
  double min2 = INFINITY;
  for (std::size_t i = 0; i < c.size(); ++i)
    for (std::size_t j = i + 1; j < c.size(); ++j) {
      double r2 = 0;
      for (int a = 0; a < 3; ++a) {
        double d = c.positions[3 * i + a] - c.positions[3 * j + a];
        d -= 12.0 * std::rint(d / 12.0);
        r2 += d * d;
      }
      min2 = std::min(min2, r2);
    }
  EXPECT_GE(std::sqrt(min2), 1.0);
  EXPECT_EQ(build_configuration(s).positions, c.positions);
}

// Lattice densities: N / V equals the density asked for, in 3D and 2D.
TEST(Scene, LatticesHaveTheirDensity) {
  for (const auto& [lattice, dim] : std::vector<std::pair<Lattice, int>>{
           {Lattice::kFcc, 3}, {Lattice::kBcc, 3}, {Lattice::kSimpleCubic, 3}, {Lattice::kSquare, 2}, {Lattice::kHexagonal, 2}}) {
    const Configuration c = make_lattice_cells(lattice, {4, 5, 6}, lattice_constant_for(lattice, 0.7));
    EXPECT_EQ(c.box.dim, dim);
    EXPECT_NEAR(double(c.size()) / c.box.volume(), 0.7, 1e-12);
  }
  // Hexagonal nearest-neighbour distance is the lattice constant for all six neighbours.
  const Configuration h = make_lattice_cells(Lattice::kHexagonal, {4, 4, 1}, 1.3);
  int neighbours = 0;
  for (std::size_t j = 1; j < h.size(); ++j) {
    double r2 = 0;
    for (int a = 0; a < 2; ++a) {
      double d = h.positions[2 * j + a] - h.positions[a];
      d -= h.box.length[a] * std::rint(d / h.box.length[a]);
      r2 += d * d;
    }
    if (std::abs(std::sqrt(r2) - 1.3) < 1e-12) ++neighbours;
  }
  EXPECT_EQ(neighbours, 6);
}

// A scene can start from a configuration file (path relative to the scene's folder); species must
// name scene types and the periodicity must agree.
TEST(Scene, StartsFromAFile) {
  const std::string folder = (cftest::data_dir() / "systems").string();
  const Scene s = parse_scene("[particles]\nsource = \"file\"\npath = \"validation/binary_lb.xyz\"\n"
                              "[[types]]\nname = \"A\"\n[[types]]\nname = \"B\"\nsigma = 0.88\nepsilon = 0.5\n",
                              "file.toml", folder);
  const Configuration c = build_configuration(s);
  EXPECT_EQ(c.size(), 2000u);
  std::size_t b = 0;
  for (uint32_t t : c.types) b += t;
  EXPECT_EQ(b, 400u) << "80:20 A/B";
  const Scene missing = parse_scene("[particles]\nsource = \"file\"\npath = \"validation/binary_lb.xyz\"\n"
                                    "[[types]]\nname = \"A\"\n", "file.toml", folder);
  try {
    build_configuration(missing);
    ADD_FAILURE() << "species B has no type";
  } catch (const Error& e) {
    EXPECT_THAT(std::string(e.what()), HasSubstr("has species 'B', which no [[types]] names"));
  }
  const Scene open = parse_scene("[system]\nperiodic = [false, false, false]\n[particles]\nsource = \"file\"\n"
                                 "path = \"validation/lj_liquid.xyz\"\n[[types]]\nname = \"A\"\n", "file.toml", folder);
  try {
    build_configuration(open);
    ADD_FAILURE() << "periodicity differs from the file";
  } catch (const Error& e) {
    EXPECT_THAT(std::string(e.what()), HasSubstr("axis x is open in the scene but not in"));
  }
}

// Fractions whose sum overflows a double keep their proportions: 1.5e308 and 0.5e308 are 3 : 1,
// not 1 : 1 (their sum, inf, made every share 0 and the counts equal).
TEST(Scene, CompositionBeyondTheLargestDoubleKeepsItsShares) {
  const std::string types = "[[types]]\nname = \"A\"\n[[types]]\nname = \"B\"\n";
  const Scene s = parse_scene(types + "[particles]\ncells = [2, 2, 2]\ncomposition = { A = 1.5e308, B = 0.5e308 }\n",
                              "huge.toml");
  ASSERT_EQ(s.particles.composition.size(), 2u);
  EXPECT_EQ(s.particles.composition[0].second, 0.75);
  EXPECT_EQ(s.particles.composition[1].second, 0.25);
  const Configuration c = build_configuration(s);  // 32 fcc sites
  std::size_t b = 0;
  for (uint32_t t : c.types) b += t;
  EXPECT_EQ(b, 8u) << "a quarter of 32 are B";
  // Ordinary fractions read as before (the scaling is by a power of two: exact).
  const Scene plain = parse_scene(types + "[particles]\ncomposition = { A = 0.8, B = 0.2 }\n", "plain.toml");
  EXPECT_EQ(plain.particles.composition[0].second, 0.8 / (0.8 + 0.2));
  EXPECT_EQ(plain.particles.composition[1].second, 0.2 / (0.8 + 0.2));
  EXPECT_THAT(error_of(types + "[particles]\ncomposition = { A = 0, B = 0.0 }\n"), HasSubstr("more than 0"));
}

// A number beyond its type in a scene is "out of range" (as on the command line), not a value that
// "could not be interpreted"; a compressed scene file is named as such.
TEST(Scene, NumbersOutOfRangeAndCompressedFilesAreNamed) {
  const std::string big = error_of(std::string(kMinimal) + "[particles]\ndensity = 1e400\n");
  EXPECT_THAT(big, HasSubstr("bad.toml:4: '1e400' is out of range"));
  EXPECT_THAT(big, ::testing::Not(HasSubstr("could not be interpreted")));
  EXPECT_THAT(error_of(std::string(kMinimal) + "[system]\nperiodic = [true, true, true]\n[particles]\nbox = [5, -2e999, 5]\n"),
              HasSubstr("bad.toml:6: '-2e999' is out of range"));
  EXPECT_THAT(error_of(std::string(kMinimal) + "[run]\nsteps = 99999999999999999999\n"),
              HasSubstr("bad.toml:4: '99999999999999999999' is out of range (-9223372036854775808 .. "
                        "9223372036854775807)"));
  // A syntax error that is not a number keeps toml++'s words.
  EXPECT_THAT(error_of(std::string(kMinimal) + "[run]\nsteps = 12abc\n"), HasSubstr("bad.toml:4"));
  const std::string gz = error_of(std::string("\x1F\x8B\x08\x00\x00\x00\x00\x00\x00\x03\xAB", 11));
  EXPECT_THAT(gz, HasSubstr("bad.toml:1"));
  EXPECT_THAT(gz, HasSubstr("gzip signature: compressed?"));
}

// A scene file's name is shown cut and escaped in messages (a 100 KB name is not echoed whole).
TEST(Scene, LongFileNamesAreCut) {
  const std::string name = "/nonexistent/" + std::string(100000, 'x') + ".toml";
  try {
    read_scene(name);
    ADD_FAILURE() << "no such file";
  } catch (const Error& e) {
    const std::string message = e.what();
    EXPECT_THAT(message, HasSubstr("cannot open the scene file"));
    EXPECT_THAT(message, HasSubstr("(100018 bytes)"));
    EXPECT_LT(message.size(), 400u);
  }
}

// Choice names are read in any letter case, as the command line and the API read them.
TEST(Scene, NamesInAnyLetterCase) {
  const Scene s = parse_scene(std::string(kMinimal) +
                                  "[particles]\nlattice = \"FCC\"\n[interactions]\nmode = \"Force-Shift\"\n"
                                  "[neighbor]\nskin = \"AUTO\"\n[run]\nbackend = \"CPU\"\nprecision = \"Double\"\n",
                              "case.toml");
  EXPECT_EQ(s.particles.lattice, Lattice::kFcc);
  EXPECT_EQ(s.force_field.mode, CutoffMode::kForceShift);
  EXPECT_EQ(s.engine.value(OptionId::kSkin), "auto");
  EXPECT_EQ(s.engine.value(OptionId::kBackend), "cpu");
  EXPECT_EQ(s.engine.value(OptionId::kPrecision), "double");
  EXPECT_THAT(error_of(std::string(kMinimal) + "[run]\nbackend = \"gpu\"\n"), HasSubstr("'gpu' is not one of auto, cpu, cuda"));
}

// A file of no particles is refused as a lattice that places none is.
using SceneFiles = cftest::TempFolder;
TEST_F(SceneFiles, AFileOfNoParticlesIsRefused) {
  const std::string file = write("empty.xyz", "0\nLattice=\"5 0 0 0 5 0 0 0 5\"\n");
  const Scene s = parse_scene(std::string(kMinimal) + "[particles]\nsource = \"file\"\npath = \"empty.xyz\"\n",
                              "empty.toml", std::filesystem::path(file).parent_path().string());
  try {
    build_configuration(s);
    ADD_FAILURE() << "a file of no particles";
  } catch (const Error& e) {
    EXPECT_THAT(std::string(e.what()), HasSubstr("[particles] path: the scene places no particle"));
    EXPECT_THAT(std::string(e.what()), HasSubstr("empty.xyz holds none"));
  }
}

// Every scene shipped in systems/ is valid and builds its configuration.
TEST(Scene, SystemsScenesAreValid) {
  const std::filesystem::path dir = cftest::data_dir() / "systems";
  std::map<std::string, std::size_t> sizes;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.path().extension() != ".toml") continue;
    SCOPED_TRACE(entry.path().string());
    const Scene s = read_scene(entry.path().string());
    const Configuration c = build_configuration(s);
    sizes[entry.path().stem().string()] = c.size();
    EXPECT_GT(c.size(), 0u);
  }
  for (const char* name : {"lj_liquid", "lj_gas", "lj_solid", "kob_andersen", "lj_2d", "lj_slab", "lj_droplet"})
    EXPECT_TRUE(sizes.count(name)) << name << ".toml is missing from systems/";
  EXPECT_EQ(sizes["lj_liquid"], 32000u);
  // The built-in default scene is systems/lj_liquid.toml's physics.
  EXPECT_EQ(scene_fingerprint(default_scene()), scene_fingerprint(read_scene((dir / "lj_liquid.toml").string())));
  EXPECT_NE(scene_fingerprint(default_scene()), scene_fingerprint(read_scene((dir / "lj_solid.toml").string())));
}

}  // namespace
