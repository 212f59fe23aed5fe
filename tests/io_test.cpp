// Reading configurations (extended XYZ, H5MD), the forces file, and `cellforce forces` end to end
// against the double-precision brute force. Every malformed input has its expected message.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <tuple>

#include "cli/forces.h"
#include "core/error.h"
#include "core/names.h"
#include "core/option_table.h"
#include "io/configuration_file.h"
#include "io/h5md_writer.h"
#include "io/hdf5.h"
#include "oracle.h"
#include "reference/brute_force.h"

#include "temp_folder.h"

namespace {

using namespace cellforce;
using ::testing::HasSubstr;
namespace fs = std::filesystem;
using cftest::backends_here;
using cftest::error_of;
using TempDir = cftest::TempFolder;


Configuration two_species_liquid(int dim, uint64_t seed) {
  const Box box = cftest::cube(dim, dim == 3 ? 7.3 : 11.9);
  cftest::RandomSpec spec;
  spec.min_distance = 0.9;
  spec.num_types = 2;
  return cftest::random_configuration(box, dim == 3 ? 300 : 100, seed, spec);
}

// ---- extended XYZ ----------------------------------------------------------------------------------

using ExtXyz = TempDir;

TEST_F(ExtXyz, RoundTripIsExactIn3DAnd2D) {
  for (int dim : {3, 2}) {
    const Configuration c = two_species_liquid(dim, 11);
    const std::string p = path("c.xyz");
    write_extxyz(p, c, {"Ar", "Kr"});
    ReadOptions o;
    o.dim = dim;
    const ConfigurationFile r = read_extxyz(p, o);
    ASSERT_EQ(r.config.size(), c.size());
    EXPECT_EQ(r.config.box.dim, dim);
    for (int a = 0; a < dim; ++a) {
      EXPECT_EQ(r.config.box.length[a], c.box.length[a]);
      EXPECT_TRUE(r.config.box.periodic[a]);
    }
    EXPECT_EQ(0, std::memcmp(r.config.positions.data(), c.positions.data(), c.positions.size() * sizeof(double)))
        << "coordinates written with 17 digits read back bitwise";
    // Species are numbered in order of first appearance.
    const uint32_t first = c.types[0];
    for (std::size_t i = 0; i < c.size(); ++i)
      EXPECT_EQ(r.species[r.config.types[i]], c.types[i] == 0 ? "Ar" : "Kr") << i;
    EXPECT_EQ(r.species[0], first == 0 ? "Ar" : "Kr");
  }
}

TEST_F(ExtXyz, ReadsAseHeadersExtraColumnsAndOpenAxes) {
  const std::string p = write("a.xyz",
                              "3\n"
                              "Properties=species:S:1:pos:R:3:forces:R:3 energy=-1.5 Lattice=\"4.0 0.0 0.0 0.0 5.0 0.0 0.0 0.0 6.0\" pbc=\"T T F\" free_flag\n"
                              "Na 0.5 1.5 2.5 0 0 0\n"
                              "Cl 1.0 2.0 -30.0 1 1 1\n"
                              "Na -0.25 4.5 7.0 0 0 0\n");
  const ConfigurationFile r = read_extxyz(p);
  ASSERT_EQ(r.config.size(), 3u);
  EXPECT_EQ(r.species, (std::vector<std::string>{"Na", "Cl"}));
  EXPECT_EQ(r.config.types, (std::vector<uint32_t>{0, 1, 0}));
  EXPECT_TRUE(r.config.box.periodic[0]);
  EXPECT_TRUE(r.config.box.periodic[1]);
  EXPECT_FALSE(r.config.box.periodic[2]);
  EXPECT_EQ(r.config.box.length[0], 4.0);
  EXPECT_EQ(r.config.box.length[1], 5.0);
  EXPECT_EQ(r.config.positions[3 * 1 + 2], -30.0);  // open axis: anywhere
  EXPECT_EQ(r.config.positions[3 * 2 + 0], -0.25);  // periodic axis: any image
}

TEST_F(ExtXyz, ReadsAseQuotingAndBracketsAndSignedNumbers) {
  const std::string p = write("q.xyz",
                              "2\n"
                              "Lattice='4 0 0 0 5 0 0 0 6' pbc=[T, F, T] name=\"a \\\"quoted\\\" word\"\n"
                              "Ar +1.5 1e0 -2\n"
                              "Ar 1 2 3\n");
  const ConfigurationFile r = read_extxyz(p);
  EXPECT_EQ(r.config.box.length[2], 6.0);
  EXPECT_TRUE(r.config.box.periodic[0]);
  EXPECT_FALSE(r.config.box.periodic[1]);
  EXPECT_TRUE(r.config.box.periodic[2]);
  EXPECT_EQ(r.config.positions[0], 1.5);
  EXPECT_EQ(r.config.positions[2], -2.0);
}

TEST_F(ExtXyz, WithoutLatticeEveryAxisIsOpen) {
  const std::string p = write("open.xyz", "2\ncomment without keys\nAr 0 0 0\nAr 1.5 0 0\n");
  const ConfigurationFile r = read_extxyz(p);
  for (int a = 0; a < 3; ++a) EXPECT_FALSE(r.config.box.periodic[a]);
}

TEST_F(ExtXyz, PicksFramesFromEitherEnd) {
  const std::string p = write("traj.xyz",
                              "1\nLattice=\"5 0 0 0 5 0 0 0 5\"\nA 1 1 1\n"
                              "1\nLattice=\"5 0 0 0 5 0 0 0 5\"\nA 2 2 2\n"
                              "1\nLattice=\"6 0 0 0 6 0 0 0 6\"\nA 3 3 3\n\n");
  ReadOptions o;
  EXPECT_EQ(read_extxyz(p, o).config.positions[0], 3.0);  // default: the last frame
  EXPECT_EQ(read_extxyz(p, o).config.box.length[0], 6.0);
  o.frame = 0;
  EXPECT_EQ(read_extxyz(p, o).config.positions[0], 1.0);
  o.frame = -2;
  EXPECT_EQ(read_extxyz(p, o).config.positions[0], 2.0);
  o.frame = 3;
  EXPECT_THAT(error_of([&] { read_extxyz(p, o); }), HasSubstr("frame 3 requested, the file holds 3"));
}

TEST_F(ExtXyz, MalformedFilesNameTheLineAndParticle) {
  struct Case {
    const char* name;
    std::string text;
    int dim;
    std::vector<std::string> expected;  // substrings of the message
  };
  const std::string lat = "Lattice=\"5 0 0 0 5 0 0 0 5\"";
  const std::vector<Case> cases = {
      {"count", "two\n" + lat + "\nA 0 0 0\n", 3, {"bad.xyz:1:", "expected a particle count"}},
      {"short", "5\n" + lat + "\nA 0 0 0\nA 1 1 1\n", 3, {"declares 5 particles", "ends after 2"}},
      {"number", "2\n" + lat + "\nA 0 0 0\nA 1 abc 1\n", 3, {"bad.xyz:4: particle 1", "'abc' is not a number"}},
      {"nan", "2\n" + lat + "\nA 0 0 0\nA 1 nan 1\n", 3, {"bad.xyz:4: particle 1", "coordinate y is nan", "finite"}},
      {"inf", "2\n" + lat + "\nA 0 0 0\nA 1 1 -inf\n", 3, {"bad.xyz:4: particle 1", "coordinate z is -inf"}},
      {"bracket", "1\nLattice=[5 0 0 0 5 0 0 0 5\nA 0 0 0\n", 3, {"unterminated '['"}},
      {"columns", "2\n" + lat + "\nA 0 0 0\nA 1 1\n", 3, {"bad.xyz:4: particle 1", "3 columns, Properties describes 4"}},
      {"triclinic", "1\nLattice=\"5 0 0 1 5 0 0 0 5\"\nA 0 0 0\n", 3, {"bad.xyz:2:", "not orthorhombic", "vector 2"}},
      {"lattice count", "1\nLattice=\"5 5 5\"\nA 0 0 0\n", 3, {"Lattice needs 9 numbers"}},
      {"lattice value", "1\nLattice=\"5 0 0 0 x 0 0 0 5\"\nA 0 0 0\n", 3, {"'x' is not a finite number"}},
      {"pbc without lattice", "1\npbc=\"T F F\"\nA 0 0 0\n", 3, {"axis x periodic but no Lattice"}},
      {"pbc value", "1\n" + lat + " pbc=\"T maybe F\"\nA 0 0 0\n", 3, {"three of T/F"}},
      {"zero length", "1\nLattice=\"0 0 0 0 5 0 0 0 5\" pbc=\"T T T\"\nA 0 0 0\n", 3, {"periodic axis x", "must be > 0"}},
      {"no pos", "1\nProperties=species:S:1:mass:R:1\nA 1\n", 3, {"needs species:S:1 and pos:R:3"}},
      {"pos width", "1\nProperties=species:S:1:pos:R:2\nA 1 1\n", 3, {"pos must be pos:R:3"}},
      {"quote", "1\nLattice=\"5 0 0 0 5 0 0 0 5\nA 0 0 0\n", 3, {"unterminated \" quote"}},
      {"2D z", "3\n" + lat + "\nA 0 0 0\nA 1 1 0\nA 2 2 0.5\n", 2, {"bad.xyz:5: particle 2", "z = 0.5", "2D"}},
      {"empty", "", 3, {"no frame"}},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const std::string p = write("bad.xyz", c.text);
    ReadOptions o;
    o.dim = c.dim;
    const std::string msg = error_of([&] { read_extxyz(p, o); });
    for (const std::string& e : c.expected) EXPECT_THAT(msg, HasSubstr(e));
  }
  EXPECT_THAT(error_of([&] { read_extxyz(path("missing.xyz")); }), HasSubstr("cannot open"));
}

// A column named twice in Properties is refused by its name (it read the last one before).
TEST_F(ExtXyz, PropertiesNamingAColumnTwiceAreRefused) {
  const std::string lat = "Lattice=\"5 0 0 0 5 0 0 0 5\" ";
  for (const auto& [properties, row, name] : std::vector<std::tuple<std::string, std::string, std::string>>{
           {"species:S:1:pos:R:3:pos:R:3", "A 0 0 0 1 1 1", "'pos'"},
           {"species:S:1:pos:R:3:species:S:1", "A 0 0 0 B", "'species'"},
           {"species:S:1:pos:R:3:mass:R:1:MASS:R:1", "A 0 0 0 1 2", "'MASS'"}}) {
    SCOPED_TRACE(properties);
    const std::string p = write("twice.xyz", "1\n" + lat + "Properties=" + properties + "\n" + row + "\n");
    const std::string message = error_of([&] { read_extxyz(p); });
    EXPECT_THAT(message, HasSubstr("twice.xyz:2: Properties: " + name + " is described twice"));
  }
}

// A coordinate beyond a double's range is "out of range", not "not a number"; a compressed file's
// bytes are escaped and named as compressed; a long file name is cut.
TEST_F(ExtXyz, MessagesNameTheRealCause) {
  const std::string lat = "Lattice=\"5 0 0 0 5 0 0 0 5\"";
  const std::string big = error_of([&] { read_extxyz(write("big.xyz", "1\n" + lat + "\nA 1 1e400 1\n")); });
  EXPECT_THAT(big, HasSubstr("big.xyz:3: particle 0: coordinate y: '1e400' is out of range"));
  EXPECT_THAT(big, ::testing::Not(HasSubstr("not a number")));
  EXPECT_THAT(error_of([&] { read_extxyz(write("lat.xyz", "1\nLattice=\"5 0 0 0 -1e999 0 0 0 5\"\nA 1 1 1\n")); }),
              HasSubstr("Lattice: '-1e999' is out of range"));
  // Below the smallest double: 0, as Python reads it.
  EXPECT_EQ(read_extxyz(write("tiny.xyz", "1\n" + lat + "\nA 1 1e-400 1\n")).config.positions[1], 0.0);
  const std::string gz = error_of(
      [&] { read_extxyz(write("conf.xyz", std::string("\x1F\x8B\x08\x08\x8B\x9C\xFE\x5A\x00\x03\x63\x6F", 12))); });
  EXPECT_THAT(gz, HasSubstr("conf.xyz:1: expected a particle count, found '\\x1F\\x8B\\x08\\x08\\x8B\\x9C\\xFE"));
  EXPECT_THAT(gz, HasSubstr("gzip signature: compressed?"));
  const std::string missing = error_of([&] { read_configuration(path(std::string(100000, 'q') + ".xyz")); });
  EXPECT_THAT(missing, HasSubstr("cannot open the file"));
  EXPECT_THAT(missing, HasSubstr("bytes)"));
  EXPECT_LT(missing.size(), 400u);
}

// ---- H5MD ------------------------------------------------------------------------------------------

using H5md = TempDir;

// Writes an H5MD file by hand (the layout of the H5MD 1.1 specification): positions of `frames`
// frames, a box with the given boundary and a time-dependent or fixed edges element, species.
void write_h5md(const std::string& p, const std::vector<Configuration>& frames,
                const std::vector<int64_t>& species, bool box_per_frame,
                const std::vector<std::string>& groups = {"all"}) {
  h5::File f = h5::File::create(p);
  const int dim = frames[0].box.dim;
  const std::size_t n = frames[0].size();
  h5::Handle h5md = h5::create_group(f.id(), "h5md", p);
  h5::write_attribute(h5md.get(), "version", std::vector<double>{1, 1}, p);
  for (const std::string& g : groups) {
    h5::Handle grp = h5::create_group(f.id(), "particles/" + g, p);
    h5::Handle box = h5::create_group(grp.get(), "box", p);
    h5::write_attribute(box.get(), "dimension", int64_t(dim), p);
    std::vector<std::string> boundary;
    for (int a = 0; a < dim; ++a) boundary.push_back(frames[0].box.periodic[a] ? "periodic" : "none");
    h5::write_attribute(box.get(), "boundary", boundary, p);
    std::vector<double> pos, edges, step;
    for (std::size_t k = 0; k < frames.size(); ++k) {
      pos.insert(pos.end(), frames[k].positions.begin(), frames[k].positions.end());
      for (int a = 0; a < dim; ++a) edges.push_back(frames[k].box.length[a]);
      step.push_back(double(100 * k));
    }
    const hsize_t t = frames.size(), hn = n, hd = hsize_t(dim);
    if (box_per_frame) {
      h5::Handle e = h5::create_group(box.get(), "edges", p);
      h5::write_doubles(e.get(), "value", edges, {t, hd}, p);
      h5::write_doubles(e.get(), "step", step, {t}, p);
    } else {
      h5::write_doubles(box.get(), "edges", std::vector<double>(edges.begin(), edges.begin() + dim), {hd}, p);
    }
    h5::Handle position = h5::create_group(grp.get(), "position", p);
    h5::write_doubles(position.get(), "value", pos, {t, hn, hd}, p);
    h5::write_doubles(position.get(), "step", step, {t}, p);
    if (!species.empty()) h5::write_ints(grp.get(), "species", species, {hn}, p);
  }
  f.close();
}

TEST_F(H5md, ReadsTheFrameTheBoxAndTheSpecies) {
  Configuration a = two_species_liquid(3, 3), b = two_species_liquid(3, 4);
  b.box.length[0] = a.box.length[0] * 1.01;
  std::vector<int64_t> species;
  for (uint32_t t : a.types) species.push_back(t == 0 ? 7 : 3);
  const std::string p = path("t.h5");
  write_h5md(p, {a, b}, species, true);
  ReadOptions o;
  ConfigurationFile r = read_configuration(p, o);  // by content: HDF5
  EXPECT_EQ(r.config.positions, b.positions);
  EXPECT_EQ(r.config.box.length[0], b.box.length[0]);
  o.frame = 0;
  r = read_h5md(p, o);
  EXPECT_EQ(r.config.positions, a.positions);
  EXPECT_EQ(r.config.box.length[0], a.box.length[0]);
  for (std::size_t i = 0; i < a.size(); ++i)
    EXPECT_EQ(r.species[r.config.types[i]], a.types[i] == 0 ? "7" : "3");
  for (int ax = 0; ax < 3; ++ax) EXPECT_TRUE(r.config.box.periodic[ax]);
}

// A trajectory that cellforce writes reads back with its type names: the species' attribute names
// (species k is names[k]) names them, and the type indices are the written ones.
TEST_F(H5md, TrajectoryReadsBackWithItsTypeNames) {
  const Configuration c = two_species_liquid(3, 8);
  std::vector<uint32_t> species(c.types.begin(), c.types.end());
  ASSERT_EQ(species[0], 0u);  // the first particle's type first: the read order equals the written
  const std::string p = path("traj.h5");
  {
    H5mdWriter w(p, c.box, species, {"Ar", "Kr"}, H5mdOptions{});
    w.write_frame(0, 0.0, c.positions.data(), nullptr, nullptr, {});
    w.close();
  }
  const ConfigurationFile r = read_configuration(p);
  EXPECT_EQ(r.species, (std::vector<std::string>{"Ar", "Kr"}));
  ASSERT_EQ(r.config.types.size(), species.size());
  EXPECT_EQ(r.config.types, species);
  EXPECT_EQ(r.config.positions, c.positions);

  // Written in the other order (Kr first), each particle keeps its name.
  std::vector<uint32_t> swapped = species;
  for (uint32_t& t : swapped) t = 1 - t;
  const std::string q = path("swapped.h5");
  {
    H5mdWriter w(q, c.box, swapped, {"Kr", "Ar"}, H5mdOptions{});
    w.write_frame(0, 0.0, c.positions.data(), nullptr, nullptr, {});
    w.close();
  }
  const ConfigurationFile s = read_h5md(q);
  for (std::size_t i = 0; i < species.size(); ++i)
    ASSERT_EQ(s.species[s.config.types[i]], species[i] == 0 ? "Ar" : "Kr") << "particle " << i;

  // A species index beyond the names is refused, naming the particle.
  {
    h5::File f = h5::File::open_read_write(q);
    h5::Handle set = h5::open_dataset(f.id(), "particles/all/species", q);
    H5Adelete(set.get(), "names");
    h5::write_attribute(set.get(), "names", std::vector<std::string>{"Kr"}, q);
    f.close();
  }
  const std::size_t first_ar = std::size_t(std::find(swapped.begin(), swapped.end(), 1u) - swapped.begin());
  EXPECT_THAT(error_of([&] { read_h5md(q); }),
              HasSubstr("species: particle " + std::to_string(first_ar) + " has species 1, but the attribute names holds 1 names"));
}

TEST_F(H5md, TwoDimensionsOpenAxesAndNoSpecies) {
  Configuration c = two_species_liquid(2, 5);
  c.box.periodic[1] = false;
  const std::string p = path("t2.h5");
  write_h5md(p, {c}, {}, false);
  const ConfigurationFile r = read_h5md(p);
  EXPECT_EQ(r.config.box.dim, 2);
  EXPECT_TRUE(r.config.box.periodic[0]);
  EXPECT_FALSE(r.config.box.periodic[1]);
  EXPECT_EQ(r.species, std::vector<std::string>{"0"});
  EXPECT_EQ(r.config.positions, c.positions);
}

TEST_F(H5md, ErrorsNameTheFileAndTheObject) {
  const Configuration c = two_species_liquid(3, 6);
  const std::string two = path("two.h5");
  write_h5md(two, {c}, {}, false, {"solvent", "solute"});
  EXPECT_THAT(error_of([&] { read_h5md(two); }), HasSubstr("/particles holds 2 groups (solute, solvent); name one"));
  ReadOptions o;
  o.group = "solute";
  EXPECT_EQ(read_h5md(two, o).config.size(), c.size());
  o.group = "ions";
  EXPECT_THAT(error_of([&] { read_h5md(two, o); }), HasSubstr("/particles/ions: no such group"));
  o = {};
  o.dim = 2;
  o.group = "solute";
  EXPECT_THAT(error_of([&] { read_h5md(two, o); }), HasSubstr("the file is 3D, 2D was asked for"));

  const std::string empty = path("empty.h5");
  h5::File::create(empty).close();
  EXPECT_THAT(error_of([&] { read_h5md(empty); }), HasSubstr("no /particles group"));
  const std::string text = write("text.h5", "not hdf5");
  EXPECT_THAT(error_of([&] { read_h5md(text); }), HasSubstr("not an HDF5 file"));
}


// A minimal H5MD file for one malformation at a time: 2 particles, 2 frames at steps 100 and 200,
// box edges as given (a dataset or, with edge_steps, a time-dependent group).
struct MiniH5md {
  int dim = 3;
  std::vector<std::string> boundary = {"periodic", "periodic", "periodic"};
  std::vector<double> edges = {5, 5, 5};
  std::vector<hsize_t> edges_shape = {3};
  std::vector<double> edge_steps;  // non-empty: edges is a group with value (frames x shape) and step
  std::vector<double> positions = {1, 1, 1, 2.2, 1, 1, 1.5, 1, 1, 2.7, 1, 1};
  std::vector<hsize_t> position_shape = {2, 2, 3};
  std::vector<double> species;  // empty: none written
  bool write_edges = true;

  void write(const std::string& p) const {
    h5::File f = h5::File::create(p);
    h5::Handle grp = h5::create_group(f.id(), "particles/all", p);
    h5::Handle box = h5::create_group(grp.get(), "box", p);
    h5::write_attribute(box.get(), "dimension", int64_t(dim), p);
    h5::write_attribute(box.get(), "boundary", boundary, p);
    if (write_edges && edge_steps.empty()) h5::write_doubles(box.get(), "edges", edges, edges_shape, p);
    if (write_edges && !edge_steps.empty()) {
      h5::Handle e = h5::create_group(box.get(), "edges", p);
      std::vector<hsize_t> shape = {hsize_t(edge_steps.size())};
      shape.insert(shape.end(), edges_shape.begin(), edges_shape.end());
      h5::write_doubles(e.get(), "value", edges, shape, p);
      h5::write_doubles(e.get(), "step", edge_steps, {hsize_t(edge_steps.size())}, p);
    }
    h5::Handle pos = h5::create_group(grp.get(), "position", p);
    h5::write_doubles(pos.get(), "value", positions, position_shape, p);
    if (position_shape.size() == 3) h5::write_doubles(pos.get(), "step", {100, 200}, {2}, p);
    if (!species.empty()) h5::write_doubles(grp.get(), "species", species, {hsize_t(species.size())}, p);
    f.close();
  }
};

TEST_F(H5md, TimeDependentEdgesAreMatchedByStep) {
  MiniH5md m;
  m.edges = {4, 4, 4, 5, 5, 5, 6, 6, 6};  // steps 0, 100, 200
  m.edges_shape = {3};
  m.edge_steps = {0, 100, 200};
  const std::string p = path("steps.h5");
  m.write(p);
  ReadOptions o;
  o.frame = 0;  // step 100
  EXPECT_EQ(read_h5md(p, o).config.box.length[0], 5.0);
  o.frame = 1;  // step 200
  EXPECT_EQ(read_h5md(p, o).config.box.length[0], 6.0);
  m.edge_steps = {0, 50, 100};
  m.write(p);
  EXPECT_THAT(error_of([&] { read_h5md(p, o); }), HasSubstr("'edges' has no value at step 200"));
}

TEST_F(H5md, DiagonalBoxMatrixAndInformativeOpenEdges) {
  MiniH5md m;
  m.edges = {5, 0, 0, 0, 6, 0, 0, 0, 7};
  m.edges_shape = {3, 3};
  const std::string p = path("matrix.h5");
  m.write(p);
  const ConfigurationFile r = read_h5md(p);
  EXPECT_EQ(r.config.box.length[1], 6.0);
  EXPECT_EQ(r.config.box.length[2], 7.0);
  m.edges = {5, 0, 0, 0.5, 6, 0, 0, 0, 7};
  m.write(p);
  EXPECT_THAT(error_of([&] { read_h5md(p); }), HasSubstr("box vector 2 is not along its axis"));
  // An open axis's edge only informs: an infinite one is ignored, not an error.
  m.boundary = {"periodic", "periodic", "none"};
  m.edges = {5, 6, INFINITY};
  m.edges_shape = {3};
  m.write(p);
  const ConfigurationFile open = read_h5md(p);
  EXPECT_FALSE(open.config.box.periodic[2]);
  EXPECT_TRUE(std::isfinite(open.config.box.length[2]));
}

TEST_F(H5md, MalformedFilesNameTheObject) {
  struct Case {
    const char* name;
    std::function<void(MiniH5md&)> change;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {"boundary word", [](MiniH5md& m) { m.boundary[1] = "wrapped"; }, "boundary 'wrapped' is neither"},
      {"boundary count", [](MiniH5md& m) { m.boundary.pop_back(); }, "boundary names 2 axes, dimension is 3"},
      {"dimension", [](MiniH5md& m) { m.dim = 2; }, "dimension 2 but positions have 3 components"},
      {"no edges", [](MiniH5md& m) { m.write_edges = false; }, "periodic axes but no edges"},
      {"periodic zero edge", [](MiniH5md& m) { m.edges = {5, 0, 5}; }, "the periodic axis y has length"},
      {"edges shape", [](MiniH5md& m) { m.edges = {5, 5}; m.edges_shape = {2}; }, "expected 3 lengths or a 3 x 3 matrix"},
      {"position rank", [](MiniH5md& m) { m.position_shape = {4, 3}; m.positions.resize(12); }, "frames x particles x dimension"},
      {"species count", [](MiniH5md& m) { m.species = {0, 1, 1}; }, "3 values for 2 particles"},
      {"species value", [](MiniH5md& m) { m.species = {0, 1.5}; }, "particle 1 has species 1.5"},
      {"species range", [](MiniH5md& m) { m.species = {0, 1e30}; }, "particle 1 has species"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    MiniH5md m;
    c.change(m);
    const std::string p = path("bad.h5");
    m.write(p);
    const std::string msg = error_of([&] { read_h5md(p); });
    EXPECT_THAT(msg, HasSubstr(p));
    EXPECT_THAT(msg, HasSubstr(c.expected));
  }
}

// ---- cellforce forces ---------------------------------------------------------------------------

using ForcesCommand = TempDir;

struct ForcesFile {
  h5::Array<double> forces, energies, energy, virial;
  std::string backend, precision, mode;
};

ForcesFile read_forces_file(const std::string& p) {
  h5::File f = h5::File::open_read(p);
  ForcesFile out;
  out.forces = h5::read_doubles(f.id(), "forces", p);
  out.energies = h5::read_doubles(f.id(), "energies", p);
  out.energy = h5::read_doubles(f.id(), "energy", p);
  out.virial = h5::read_doubles(f.id(), "virial", p);
  out.backend = h5::read_string_attribute(f.id(), "backend", p).at(0);
  out.precision = h5::read_string_attribute(f.id(), "precision", p).at(0);
  out.mode = h5::read_string_attribute(f.id(), "cutoff_mode", p).at(0);
  return out;
}

// The file holds what the brute force computes, in the input's order and shapes, for a binary
// mixture with Lorentz-Berthelot mixing and an explicit pair, in 3D and 2D, on every backend here.
TEST_F(ForcesCommand, FileMatchesTheBruteForceInInputOrder) {
  for (int dim : {3, 2}) {
    const Configuration c = two_species_liquid(dim, 21 + uint64_t(dim));
    const std::string xyz = path("in.xyz");
    write_extxyz(xyz, c, {"A", "B"});
    for (const std::string& backend : backends_here()) {
      SCOPED_TRACE(backend + " " + std::to_string(dim) + "D");
      ForcesArgs args;
      args.input = xyz;
      args.out = path("out.h5");
      args.overwrite = true;  // one file for every backend and dimension
      args.cutoff = 2.5;
      args.mode = CutoffMode::kForceShift;
      args.types = {"A:1.0:1.0", "B:0.88:0.5"};
      args.pairs = {"A:B:0.8:1.5"};
      args.read.dim = dim;
      args.engine.set(OptionId::kBackend, backend);
      args.quiet = true;
      ASSERT_EQ(run_forces(args), 0);

      ForceField ff;
      ff.cutoff = 2.5;
      ff.mode = CutoffMode::kForceShift;
      ff.types = {ParticleType{"A", 1.0, 1.0}, ParticleType{"B", 0.88, 0.5}};
      ff.overrides = {PairOverride{0, 1, 0.8, 1.5}};
      ForceResult ref;
      brute_force(c.view(), ff, Request{true, true}, ref);

      const ForcesFile f = read_forces_file(args.out);
      EXPECT_EQ(f.backend, backend);
      EXPECT_EQ(f.precision, "double");
      EXPECT_EQ(f.mode, "force-shift");
      ASSERT_EQ(f.forces.shape, (std::vector<hsize_t>{c.size(), hsize_t(dim)}));
      ASSERT_EQ(f.energies.shape, (std::vector<hsize_t>{c.size()}));
      ASSERT_EQ(f.virial.shape, (std::vector<hsize_t>{hsize_t(dim), hsize_t(dim)}));
      EXPECT_TRUE(f.energy.shape.empty());
      ForceResult got;
      got.dim = dim;
      got.forces = f.forces.values;
      got.energies = f.energies.values;
      got.energy = f.energy.values.at(0);
      for (int a = 0; a < dim; ++a)
        for (int b = 0; b < dim; ++b) got.virial[a][b] = f.virial.values[std::size_t(a * dim + b)];
      // Double precision against the double brute force: summation order only (1e-12).
      EXPECT_TRUE(cftest::forces_match(ref, got, 1e-12));
      EXPECT_TRUE(cftest::energies_match(ref, got, 1e-12));
      EXPECT_TRUE(cftest::total_energy_matches(ref, got, 1e-12));
      EXPECT_TRUE(cftest::virial_matches(ref, got, 1e-12));
    }
  }
}

TEST_F(ForcesCommand, SingleSpeciesNeedsNoType) {
  const std::string p = write("one.xyz", "2\nLattice=\"6 0 0 0 6 0 0 0 6\"\nAr 1 1 1\nAr 2.2 1 1\n");
  ForcesArgs args;
  args.input = p;
  args.out = path("o.h5");
  args.engine.set(OptionId::kBackend, "cpu");
  args.quiet = true;
  ASSERT_EQ(run_forces(args), 0);
  // Analytic: U(1.2) with sigma = epsilon = 1, truncated at 2.5.
  const double r = 1.2, u = 4 * (std::pow(r, -12) - std::pow(r, -6));
  const double f = 24 * (2 * std::pow(r, -13) - std::pow(r, -7));
  const ForcesFile out = read_forces_file(args.out);
  // f < 0 (attractive at r = 1.2): particle 0 feels -f along x, towards particle 1.
  EXPECT_NEAR(out.energy.values[0], u, 1e-14 * std::abs(u));
  EXPECT_NEAR(out.forces.values[0], -f, 1e-14 * std::abs(f));
  EXPECT_NEAR(out.forces.values[3], f, 1e-14 * std::abs(f));
  EXPECT_NEAR(out.virial.values[0], r * f, 1e-14 * std::abs(r * f));  // W_xx = x_01 f_01 = (-r)(-f)
}

// Bad input is refused with the offending spec, type or particle named, and no output file (not
// even a partial one) is left behind.
TEST_F(ForcesCommand, BadInputNamesTheCauseAndWritesNothing) {
  const std::string two = write("two.xyz",
                                "3\nLattice=\"6 0 0 0 6 0 0 0 6\"\nA 1 1 1\nB 2.2 1 1\nC 1 3 1\n");
  const std::string coincident = write("co.xyz",
                                       "3\nLattice=\"6 0 0 0 6 0 0 0 6\"\nA 1 1 1\nA 3 3 3\nA 3 3 3\n");
  const std::string small_box = write("small.xyz", "1\nLattice=\"4 0 0 0 4 0 0 0 4\"\nA 1 1 1\n");
  struct Case {
    const char* name;
    std::string input;
    std::vector<std::string> types, pairs;
    double cutoff;
    std::vector<std::string> expected;
  };
  const std::vector<Case> cases = {
      {"no types for several species", two, {}, {}, 2.5, {"holds species 'A', 'B', 'C'", "--type NAME:SIGMA:EPSILON"}},
      {"species without type", two, {"A:1:1", "B:1:1"}, {}, 2.5, {"particle 2 has species 'C'", "no --type"}},
      {"malformed type", two, {"A:1"}, {}, 2.5, {"--type A:1", "NAME:SIGMA:EPSILON"}},
      {"type number", two, {"A:one:1"}, {}, 2.5, {"'one' is not a number"}},
      {"type number out of range", two, {"A:1e400:1"}, {}, 2.5, {"--type 'A:1e400:1': '1e400' is out of range"}},
      {"duplicate type", two, {"A:1:1", "A:1:2"}, {}, 2.5, {"type 'A' is given twice"}},
      {"negative sigma", two, {"A:-1:1", "B:1:1", "C:1:1"}, {}, 2.5, {"A", "sigma"}},
      {"pair type", two, {"A:1:1", "B:1:1", "C:1:1"}, {"A:D:1:1"}, 2.5, {"--pair A:D:1:1", "type 'D'"}},
      {"pair twice", two, {"A:1:1", "B:1:1", "C:1:1"}, {"A:B:1:1", "B:A:2:1"}, 2.5,
       {"--pair B:A:2:1", "already given by --pair A:B:1:1"}},
      {"pair shape", two, {"A:1:1", "B:1:1", "C:1:1"}, {"A:B:1"}, 2.5, {"A:B:SIGMA:EPSILON"}},
      {"coincident", coincident, {}, {}, 2.5, {"co.xyz: particles 1 and 2 are at the same position"}},
      {"cutoff beyond half the box", small_box, {}, {}, 2.5, {"small.xyz", "cutoff 2.5 exceeds half the periodic box edge x"}},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    ForcesArgs args;
    args.input = c.input;
    args.out = path("never.h5");
    args.types = c.types;
    args.pairs = c.pairs;
    args.cutoff = c.cutoff;
    args.engine.set(OptionId::kBackend, "cpu");
    args.quiet = true;
    const std::string msg = error_of([&] { run_forces(args); });
    for (const std::string& e : c.expected) EXPECT_THAT(msg, HasSubstr(e));
    EXPECT_FALSE(fs::exists(args.out));
    EXPECT_FALSE(fs::exists(args.out + ".partial"));
  }
  // A coincident pair names both particles.
  ForcesArgs args;
  args.input = coincident;
  args.out = path("never.h5");
  args.engine.set(OptionId::kBackend, "cpu");
  const std::string msg = error_of([&] { run_forces(args); });
  EXPECT_TRUE(cftest::contains_number(msg, 1) && cftest::contains_number(msg, 2)) << msg;
}

// A failed run leaves an existing output file as it was, even with --overwrite; --out is checked
// before any work.
TEST_F(ForcesCommand, ExistingOutputSurvivesAndBadOutputPathsAreRefusedFirst) {
  const std::string coincident = write("co.xyz", "2\nLattice=\"6 0 0 0 6 0 0 0 6\"\nA 1 1 1\nA 1 1 1\n");
  const std::string precious = write("old.h5", "results of an earlier run");
  ForcesArgs args;
  args.input = coincident;
  args.out = precious;
  args.engine.set(OptionId::kBackend, "cpu");
  args.quiet = true;
  args.overwrite = true;
  EXPECT_THAT(error_of([&] { run_forces(args); }), HasSubstr("same position"));
  std::ifstream in(precious);
  const std::string kept((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(kept, "results of an earlier run");
  for (const auto& entry : fs::directory_iterator(dir_))  // no temporary left behind
    EXPECT_EQ(entry.path().string().find(".partial"), std::string::npos) << entry.path();

  args.out = dir_.string();
  EXPECT_THAT(error_of([&] { run_forces(args); }), HasSubstr("is a folder"));
  args.out = coincident;
  EXPECT_THAT(error_of([&] { run_forces(args); }), HasSubstr("--out names the input file"));
  EXPECT_TRUE(fs::is_regular_file(coincident));
  EXPECT_FALSE(h5::File::is_hdf5(coincident));
}

// Attributes and timing series as the parity scripts read them, at full precision.
TEST_F(ForcesCommand, RecordsHowTheResultsWereComputed) {
  const std::string p = write("one.xyz", "2\nLattice=\"6 0 0 0 6 0 0 0 6\" pbc=\"T T F\"\n"
                                         "Argon_with_a_long_name 1 1 1\nArgon_with_a_long_name 2.2 1 1\n");
  ForcesArgs args;
  args.input = p;
  args.out = path("o.h5");
  args.types = {"Argon_with_a_long_name:0.123456789012345678:1.5"};
  args.engine.set(OptionId::kBackend, "cpu");
  args.engine.set(OptionId::kPrecision, "mixed");
  args.mode = CutoffMode::kShift;
  args.repeats = 3;
  args.quiet = true;
  ASSERT_EQ(run_forces(args), 0);
  h5::File f = h5::File::open_read(args.out);
  const auto attr = [&](const char* name) { return h5::read_string_attribute(f.id(), name, args.out).at(0); };
  EXPECT_EQ(attr("backend"), "cpu");
  EXPECT_EQ(attr("precision"), "mixed");
  EXPECT_EQ(attr("cutoff_mode"), "shift");
  EXPECT_EQ(attr("periodic"), "T T F");
  EXPECT_EQ(attr("types"), "Argon_with_a_long_name:0.12345678901234568:1.5");
  EXPECT_EQ(h5::read_int_attribute(f.id(), "repeats", args.out), 3);
  EXPECT_EQ(h5::read_int_attribute(f.id(), "pairs_within_cutoff", args.out), 1);
  const h5::Array<double> times = h5::read_doubles(f.id(), "evaluation_times", args.out);
  ASSERT_EQ(times.values.size(), 3u);
  for (double t : times.values) EXPECT_GT(t, 0.0);
}

TEST_F(ForcesCommand, UnwritableOutputIsAnErrorNamingThePath) {
  const std::string p = write("one.xyz", "2\nLattice=\"6 0 0 0 6 0 0 0 6\"\nAr 1 1 1\nAr 2.2 1 1\n");
  ForcesArgs args;
  args.input = p;
  args.out = path("no/such/folder/o.h5");
  args.engine.set(OptionId::kBackend, "cpu");
  args.quiet = true;
  EXPECT_THAT(error_of([&] { run_forces(args); }), HasSubstr("no/such/folder/o.h5"));
}

}  // namespace
