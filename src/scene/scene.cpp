#include "scene/scene.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <sstream>
#include <toml++/toml.h>

#include "core/error.h"
#include "core/memory.h"
#include "core/names.h"
#include "core/numbers.h"
#include "core/option_table.h"
#include "core/text.h"
#include "io/configuration_file.h"

namespace cellforce {
namespace {

// Reads one table's keys, checks their types, and at the end refuses the keys nobody read.
class Section {
 public:
  Section(const toml::table* table, std::string name, std::string file, int64_t line)
      : table_(table), name_(std::move(name)), file_(std::move(file)), line_(line) {}

  bool present() const { return table_ != nullptr; }

  // file:line of a key (or of the table when the key is absent).
  std::string where(const std::string& key) const {
    int64_t line = line_;
    if (table_)
      if (const toml::node* n = table_->get(key)) line = int64_t(n->source().begin.line);
    return file_ + ":" + std::to_string(line) + ": " + (name_.empty() ? "" : "[" + name_ + "] ") + key;
  }
  [[noreturn]] void fail(const std::string& key, const std::string& what) const {
    throw Error(where(key) + ": " + what);
  }

  const toml::node* node(const std::string& key) {
    if (!table_) return nullptr;
    used_.insert(key);
    return table_->get(key);
  }

  double number(const std::string& key, double fallback) {
    const toml::node* n = node(key);
    if (!n) return fallback;
    if (auto v = n->value<double>(); v && (n->is_integer() || n->is_floating_point())) return *v;
    fail(key, "expected a number");
  }
  double positive(const std::string& key, double fallback) {
    const double v = number(key, fallback);
    if (!(v > 0) || !std::isfinite(v)) fail(key, "must be a finite number > 0, got " + format_number(v));
    return v;
  }
  double non_negative(const std::string& key, double fallback) {
    const double v = number(key, fallback);
    if (!(v >= 0) || !std::isfinite(v)) fail(key, "must be a finite number >= 0, got " + format_number(v));
    return v;
  }
  // An integer in [min, max]; every caller passes the range of the type it stores the value in,
  // so that no value wraps (cells = 4294967301 is not 5).
  int64_t integer(const std::string& key, int64_t fallback, int64_t min,
                  int64_t max = std::numeric_limits<int64_t>::max()) {
    const toml::node* n = node(key);
    if (!n) return fallback;
    if (!n->is_integer()) fail(key, "expected an integer");
    const int64_t v = *n->value<int64_t>();
    if (v < min) fail(key, "must be at least " + std::to_string(min) + ", got " + std::to_string(v));
    if (v > max) fail(key, "must be at most " + std::to_string(max) + ", got " + std::to_string(v));
    return v;
  }
  bool boolean(const std::string& key, bool fallback) {
    const toml::node* n = node(key);
    if (!n) return fallback;
    if (!n->is_boolean()) fail(key, "expected true or false");
    return *n->value<bool>();
  }
  std::string string(const std::string& key, const std::string& fallback) {
    const toml::node* n = node(key);
    if (!n) return fallback;
    if (!n->is_string()) fail(key, "expected a string");
    return *n->value<std::string>();
  }
  template <class T>
  T choice(const std::string& key, T fallback, const std::map<std::string, T>& names) {
    const toml::node* n = node(key);
    if (!n) return fallback;
    const std::string s = string(key, "");
    const auto it = std::find_if(names.begin(), names.end(), [&](const auto& entry) { return same_name(s, entry.first); });
    if (it == names.end()) {
      std::string list;
      for (const auto& [k, v] : names) list += (list.empty() ? "" : ", ") + k;
      fail(key, quote_excerpt(s) + " is not one of " + list);
    }
    return it->second;
  }
  // An engine option whose key in the file is the option's own (option_table.h): one of its names
  // in any letter case, returned as the table spells it.
  std::string option(OptionId id, const char* fallback) {
    std::map<std::string, const char*> names;  // the names in order, as messages list them
    for (const char* name : option_spec(id).names) names.emplace(name, name);
    return choice(option_key(id), fallback, names);
  }
  // An array of `count` numbers (count = the dimension; a 3D array is accepted in 2D when its
  // third entry is 0 or absent).
  template <class T>
  std::optional<std::array<T, 3>> vector(const std::string& key, int dim) {
    const toml::node* n = node(key);
    if (!n) return std::nullopt;
    const toml::array* a = n->as_array();
    if (!a || (a->size() != std::size_t(dim) && !(dim == 2 && a->size() == 3)))
      fail(key, "expected an array of " + std::to_string(dim) + " values");
    std::array<T, 3> out{};
    for (std::size_t k = 0; k < a->size(); ++k) {
      const toml::node& e = *a->get(k);
      if constexpr (std::is_same_v<T, bool>) {
        if (!e.is_boolean()) fail(key, "expected true or false in every entry");
        out[k] = *e.value<bool>();
      } else if constexpr (std::is_integral_v<T>) {
        if (!e.is_integer()) fail(key, "expected integers");
        const int64_t v = *e.value<int64_t>();
        if (v < int64_t(std::numeric_limits<T>::min()) || v > int64_t(std::numeric_limits<T>::max()))
          fail(key, "entry " + std::to_string(k + 1) + " is " + std::to_string(v) + ", outside " +
                        std::to_string(std::numeric_limits<T>::min()) + " .. " +
                        std::to_string(std::numeric_limits<T>::max()));
        out[k] = T(v);
      } else {
        if (!(e.is_integer() || e.is_floating_point())) fail(key, "expected numbers");
        out[k] = T(*e.value<double>());
        if (!std::isfinite(double(out[k]))) fail(key, "entries must be finite numbers");
      }
    }
    if (dim == 2 && a->size() == 3 && out[2] != T{}) fail(key, "a 2D scene has no third component");
    return out;
  }
  const toml::table* table(const std::string& key) {
    const toml::node* n = node(key);
    if (!n) return nullptr;
    if (!n->is_table()) fail(key, "expected a table");
    return n->as_table();
  }
  const toml::array* array(const std::string& key) {
    const toml::node* n = node(key);
    if (!n) return nullptr;
    if (!n->is_array()) fail(key, "expected an array");
    return n->as_array();
  }

  // Every key of the table must have been read; `hints` explain keys that exist but do not apply.
  void finish(const std::map<std::string, std::string>& hints = {}) const {
    if (!table_) return;
    for (const auto& [key, value] : *table_) {
      const std::string k(key.str());
      if (used_.count(k)) continue;
      const auto hint = hints.find(k);
      throw Error(file_ + ":" + std::to_string(value.source().begin.line) + ": " +
                  (hint != hints.end() ? "'" + name_ + "." + k + "' " + hint->second
                                       : "unknown key '" + (name_.empty() ? "" : name_ + ".") + k + "'"));
    }
  }

 private:
  const toml::table* table_;
  std::string name_, file_;
  int64_t line_;
  std::set<std::string> used_;
};

const std::map<std::string, Lattice> kLattices = name_map(kLatticeNames);
const std::map<std::string, ParticleSource> kSources = {
    {"lattice", ParticleSource::kLattice}, {"random", ParticleSource::kRandom}, {"file", ParticleSource::kFile}};
const std::map<std::string, CutoffMode> kModes = name_map(kCutoffModeNames);
const std::map<std::string, Mixing> kMixings = name_map(kMixingNames);
const std::map<std::string, IntegratorKind> kIntegrators = {{"nve", IntegratorKind::kNve},
                                                            {"langevin", IntegratorKind::kLangevin}};

// A section of the root table; absent sections read as empty (every key at its default).
Section section(const toml::table& root, const std::string& name, const std::string& file) {
  const toml::node* n = root.get(name);
  if (n && !n->is_table())
    throw Error(file + ":" + std::to_string(n->source().begin.line) + ": '" + name + "' must be a table ([" + name + "])");
  return Section(n ? n->as_table() : nullptr, name, file, n ? int64_t(n->source().begin.line) : 1);
}

}  // namespace

Scene default_scene() {
  Scene s;
  s.source = "built-in default (LAMMPS in.lj)";
  s.particles.source = ParticleSource::kLattice;
  s.particles.lattice = Lattice::kFcc;
  s.particles.cells = {20, 20, 20};
  s.particles.density = 0.8442;
  s.masses = {1.0};
  s.force_field.cutoff = 2.5;
  s.force_field.mode = CutoffMode::kTruncate;
  s.initial_temperature = 1.44;
  s.seed = 87287;  // in.lj's velocity seed
  s.integrator.kind = IntegratorKind::kNve;
  s.integrator.dt = 0.005;
  s.steps = 1000;
  s.engine.set(OptionId::kBackend, name_of(Backend::kAuto, kBackendNames));
  s.engine.set(OptionId::kPrecision, name_of(Precision::kMixed, kPrecisionNames));
  s.engine.set(OptionId::kSkin, kAutoSkin);  // as a scene without [neighbor]
  s.output.thermo_every = 100;
  return s;
}

namespace {

// [system]: dimension and periodicity.
void read_system(const toml::table& root, const std::string& name, Scene& scene) {
  Section sys = section(root, "system", name);
  const int64_t dimension = sys.integer("dimension", 3, 2);
  if (dimension != 2 && dimension != 3) sys.fail("dimension", "must be 2 or 3, got " + std::to_string(dimension));
  scene.dim = int(dimension);
  if (auto p = sys.vector<bool>("periodic", scene.dim)) scene.periodic = *p;
  if (scene.dim == 2) scene.periodic[2] = false;
  sys.finish();
}

// [[types]]: names, sigma, epsilon, mass; returns each name's index (composition and pairs refer
// to types by name).
std::map<std::string, std::size_t> read_types(const toml::table& root, const std::string& name, Scene& scene) {
  const toml::node* types_node = root.get("types");
  if (!types_node) throw Error(name + ":1: no [[types]]: a scene needs at least one particle type");
  const toml::array* types = types_node->as_array();
  if (!types || !types->is_array_of_tables())
    throw Error(name + ":" + std::to_string(types_node->source().begin.line) + ": 'types' must be [[types]] tables");
  ForceField& ff = scene.force_field;
  ff.types.clear();
  std::map<std::string, std::size_t> type_index;
  for (std::size_t k = 0; k < types->size(); ++k) {
    const toml::table* t = types->get(k)->as_table();
    Section ts(t, "types", name, int64_t(t->source().begin.line));
    const std::string type_name = ts.string("name", "");
    if (type_name.empty()) ts.fail("name", "every [[types]] needs a name");
    if (!type_index.emplace(type_name, ff.types.size()).second) ts.fail("name", "type " + quote_excerpt(type_name) + " is defined twice");
    ParticleType pt{type_name, ts.positive("sigma", 1.0), ts.non_negative("epsilon", 1.0)};
    ff.types.push_back(pt);
    scene.masses.push_back(ts.positive("mass", 1.0));
    ts.finish();
  }
  return type_index;
}

// [interactions]: cutoff, mode, mixing and explicit pairs.
void read_interactions(const toml::table& root, const std::string& name, Scene& scene,
                       const std::map<std::string, std::size_t>& type_index) {
  ForceField& ff = scene.force_field;
  Section in = section(root, "interactions", name);
  ff.cutoff = in.positive("cutoff", 2.5);
  ff.mode = in.choice("mode", CutoffMode::kTruncate, kModes);
  ff.mixing = in.choice("mixing", Mixing::kLorentzBerthelot, kMixings);
  if (const toml::array* pairs = in.array("pairs")) {
    if (!pairs->is_array_of_tables()) in.fail("pairs", "expected [[interactions.pairs]] tables");
    for (std::size_t k = 0; k < pairs->size(); ++k) {
      const toml::table* t = pairs->get(k)->as_table();
      Section ps(t, "interactions.pairs", name, int64_t(t->source().begin.line));
      const toml::array* names = ps.array("types");
      if (!names || names->size() != 2 || !names->is_homogeneous(toml::node_type::string))
        ps.fail("types", "expected two type names, e.g. types = [\"A\", \"B\"]");
      std::size_t ab[2];
      for (std::size_t e = 0; e < 2; ++e) {
        const std::string tn = *names->get(e)->value<std::string>();
        const auto it = type_index.find(tn);
        if (it == type_index.end()) ps.fail("types", "type " + quote_excerpt(tn) + " is not defined in [[types]]");
        ab[e] = it->second;
      }
      for (const PairOverride& o : ff.overrides)
        if ((o.a == ab[0] && o.b == ab[1]) || (o.a == ab[1] && o.b == ab[0]))
          ps.fail("types", "this pair is given twice");
      if (!ps.node("sigma") || !ps.node("epsilon")) ps.fail("types", "a pair needs sigma and epsilon");
      ff.overrides.push_back(PairOverride{ab[0], ab[1], ps.positive("sigma", 1.0), ps.non_negative("epsilon", 1.0)});
      ps.finish();
    }
  }
  in.finish();
}

// [particles]: a lattice, random placement or a file.
void read_particles(const toml::table& root, const std::string& name, const std::string& folder, Scene& scene,
                    const std::map<std::string, std::size_t>& type_index) {
  Section pa = section(root, "particles", name);
  SceneParticles& p = scene.particles;
  p.source = pa.choice("source", ParticleSource::kLattice, kSources);
  const int dim = scene.dim;
  auto composition = [&] {
    const toml::table* c = pa.table("composition");
    if (!c) return;
    double largest = 0;
    for (const auto& [key, value] : *c) {
      const std::string tn(key.str());
      if (!type_index.count(tn))
        throw Error(name + ":" + std::to_string(value.source().begin.line) + ": [particles] composition: type " +
                    quote_excerpt(tn) + " is not defined in [[types]]");
      const std::optional<double> f = value.value<double>();
      if (!f || !(*f >= 0) || !std::isfinite(*f))
        throw Error(name + ":" + std::to_string(value.source().begin.line) + ": [particles] composition." + tn +
                    ": expected a fraction >= 0");
      p.composition.emplace_back(tn, *f);
      largest = std::max(largest, *f);
    }
    if (!(largest > 0)) pa.fail("composition", "the fractions must add up to more than 0");
    // Scaled first by the power of two at the largest fraction (exact), so that the sum stays finite
    // (1.5e308 + 0.5e308 would be inf, and every share 0 or NaN) and the shares are those of the
    // unscaled fractions.
    int exponent = 0;
    std::frexp(largest, &exponent);
    double total = 0;
    for (auto& entry : p.composition) total += entry.second = std::ldexp(entry.second, -exponent);
    for (auto& entry : p.composition) entry.second /= total;
  };
  if (p.source == ParticleSource::kLattice) {
    p.lattice = pa.choice("lattice", dim == 3 ? Lattice::kFcc : Lattice::kHexagonal, kLattices);
    const bool lattice_2d = p.lattice == Lattice::kSquare || p.lattice == Lattice::kHexagonal;
    if (lattice_2d != (dim == 2))
      pa.fail("lattice", std::string("a ") + (dim == 2 ? "2D" : "3D") + " scene needs a " +
                             (dim == 2 ? "2D lattice (square, hexagonal)" : "3D lattice (sc, bcc, fcc)"));
    if (auto c = pa.vector<int>("cells", dim)) p.cells = *c;
    for (int a = 0; a < dim; ++a)
      if (p.cells[std::size_t(a)] < 1) pa.fail("cells", "needs at least one unit cell per axis");
    if (dim == 2) p.cells[2] = 1;
    std::string cells_text;
    for (int a = 0; a < dim; ++a) cells_text += (a ? ", " : "") + std::to_string(p.cells[std::size_t(a)]);
    check_particle_count(lattice_site_count(p.lattice, p.cells), dim, pa.where("cells") + " = [" + cells_text + "]");
    const bool has_density = pa.node("density") != nullptr, has_constant = pa.node("lattice_constant") != nullptr;
    if (has_density && has_constant) pa.fail("lattice_constant", "give density or lattice_constant, not both");
    p.density = pa.positive("density", 0.8442);
    p.lattice_constant = pa.positive("lattice_constant", 1.0) * (has_constant ? 1.0 : 0.0);
    if (auto b = pa.vector<double>("box", dim)) p.box = *b;
    if (auto o = pa.vector<double>("offset", dim)) p.offset = *o;
    p.sphere_radius = pa.non_negative("sphere_radius", 0.0);
    composition();
  } else if (p.source == ParticleSource::kRandom) {
    p.count = std::size_t(pa.integer("count", 0, 1));
    if (!pa.node("count")) pa.fail("count", "random placement needs count");
    check_particle_count(double(p.count), dim, pa.where("count") + " = " + std::to_string(p.count));
    auto b = pa.vector<double>("box", dim);
    if (!b) pa.fail("box", "random placement needs box = [Lx, Ly" + std::string(dim == 3 ? ", Lz]" : "]"));
    p.box = *b;
    p.min_distance = pa.non_negative("min_distance", 0.0);
    composition();
  } else {
    const std::string file = pa.string("path", "");
    if (file.empty()) pa.fail("path", "source = \"file\" needs path");
    p.path = (std::filesystem::path(file).is_absolute() ? std::filesystem::path(file)
                                                         : std::filesystem::path(folder) / file).string();
    p.frame = long(pa.integer("frame", -1, std::numeric_limits<int64_t>::min()));
  }
  for (int a = 0; a < dim; ++a)
    if (p.source != ParticleSource::kFile && p.box[std::size_t(a)] < 0) pa.fail("box", "lengths must be >= 0");
  const std::string lattice_only = "applies only to source = \"lattice\"";
  const std::string random_only = "applies only to source = \"random\"";
  const std::string file_only = "applies only to source = \"file\"";
  pa.finish({{"lattice", lattice_only}, {"cells", lattice_only}, {"density", lattice_only},
             {"lattice_constant", lattice_only}, {"offset", lattice_only}, {"sphere_radius", lattice_only},
             {"count", random_only}, {"min_distance", random_only}, {"path", file_only}, {"frame", file_only},
             {"composition", "does not apply to source = \"file\" (the file's species give the types)"},
             {"box", "does not apply to source = \"file\" (the file gives the box)"}});
}

// [initial] and [integrator].
void read_dynamics(const toml::table& root, const std::string& name, Scene& scene) {
  Section init = section(root, "initial", name);
  scene.initial_temperature = init.non_negative("temperature", 1.0);
  scene.seed = uint64_t(init.integer("seed", 1, 0));
  init.finish();

  Section integ = section(root, "integrator", name);
  scene.integrator.kind = integ.choice("kind", IntegratorKind::kNve, kIntegrators);
  scene.integrator.dt = integ.positive("dt", 0.005);
  if (scene.integrator.kind == IntegratorKind::kLangevin) {
    if (!integ.node("temperature")) integ.fail("temperature", "a Langevin integrator needs its temperature");
    scene.integrator.temperature = integ.non_negative("temperature", 1.0);
    scene.integrator.friction = integ.positive("friction", 1.0);
  }
  integ.finish({{"temperature", "applies only to kind = \"langevin\" (the initial one is [initial] temperature)"},
                {"friction", "applies only to kind = \"langevin\""}});
}

// [minimize]: FIRE before the dynamics.
void read_minimize(const toml::table& root, const std::string& name, Scene& scene) {
  Section mini = section(root, "minimize", name);
  if (mini.present()) {
    SceneMinimize& m = scene.minimize;
    m.enabled = true;
    m.force_tolerance = mini.positive("force_tolerance", 100.0);
    m.max_steps = mini.integer("max_steps", 10000, 1);
    m.dt = mini.positive("dt", 0.001);
    m.dt_max = mini.positive("dt_max", 10.0 * m.dt);
    if (m.dt_max < m.dt) {
      std::ostringstream what;
      what << "must be at least dt (" << m.dt << "), got " << m.dt_max;
      mini.fail("dt_max", what.str());
    }
    m.max_displacement = mini.positive("max_displacement", 0.1);
  }
  mini.finish();
}

// [neighbor]: skin reuse of the cell structure, as the engine options skin, neighbor-check,
// neighbor-every, neighbor-audit and neighbor-list.
void read_neighbor(const toml::table& root, const std::string& name, Scene& scene) {
  Section neighbor = section(root, "neighbor", name);
  // skin: "auto" (also when absent) lets the engine choose (resolve_reuse), or a length.
  const toml::node* skin = neighbor.node("skin");
  const bool automatic = !skin || (skin->is_string() && same_name(*skin->value<std::string>(), kAutoSkin));
  if (skin && skin->is_string() && !automatic)
    neighbor.fail("skin", "expected \"auto\" or a length >= 0, got " + quote_excerpt(*skin->value<std::string>()));
  const double length = automatic ? 0.0 : neighbor.non_negative("skin", 0.0);
  const bool check = neighbor.boolean("check", true);
  const int64_t every = neighbor.integer("every", 0, 0);
  const bool audit = neighbor.boolean("audit", false);
  const bool list = neighbor.boolean("list", false);
  if (automatic && neighbor.node("list"))
    neighbor.fail("list", "applies to a skin given as a length (skin = \"auto\", the default, chooses pair lists "
                          "itself where they pay: CUDA with Jacobi accumulation)");
  if (!automatic && length == 0.0)
    for (const char* key : {"check", "every", "audit", "list"})
      if (neighbor.node(key)) neighbor.fail(key, "applies only with a skin (skin > 0 or \"auto\")");
  if (!check && every == 0 && !audit)
    neighbor.fail("check", "false with every = 0 never rebuilds the cell structure: give every = N (LAMMPS's "
                           "'neigh_modify every N check no'), keep the check, or set audit = true to count "
                           "the pairs that reuse misses");
  neighbor.finish();
  OptionList& engine = scene.engine;
  engine.set(OptionId::kSkin, automatic ? std::string(kAutoSkin) : format_number(length));
  engine.set(OptionId::kNeighborCheck, name_of(check, kBooleanNames));
  engine.set(OptionId::kNeighborEvery, std::to_string(every));
  engine.set(OptionId::kNeighborAudit, name_of(audit, kBooleanNames));
  if (!automatic) engine.set(OptionId::kNeighborList, name_of(list, kBooleanNames));
}

// [run] and [output].
void read_run_and_output(const toml::table& root, const std::string& name, Scene& scene) {
  Section run = section(root, "run", name);
  scene.steps = run.integer("steps", 1000, 0);
  scene.engine.set(OptionId::kBackend, run.option(OptionId::kBackend, name_of(Backend::kAuto, kBackendNames)));
  scene.engine.set(OptionId::kPrecision, run.option(OptionId::kPrecision, name_of(Precision::kMixed, kPrecisionNames)));
  run.finish();

  Section out = section(root, "output", name);
  scene.output.thermo_every = out.integer("thermo_every", 100, 1);
  scene.output.thermo_file = out.string("thermo_file", "");
  scene.output.trajectory = out.string("trajectory", "");
  scene.output.trajectory_every = out.integer("trajectory_every", 1000, 1);
  scene.output.velocities = out.boolean("velocities", false);
  scene.output.forces = out.boolean("forces", false);
  scene.output.checkpoint = out.string("checkpoint", "");
  scene.output.checkpoint_every = out.integer("checkpoint_every", 0, 0);
  if (scene.output.trajectory.empty())
    for (const char* key : {"trajectory_every", "velocities", "forces"})
      if (out.node(key)) out.fail(key, "applies only with a trajectory (trajectory = \"FILE.h5\")");
  if (scene.output.checkpoint.empty() && out.node("checkpoint_every"))
    out.fail("checkpoint_every", "applies only with a checkpoint (checkpoint = \"FILE.h5\")");
  out.finish();
}

// What toml++ says of a syntax error, except for a number too large for its type: toml++ calls
// 1e400 "could not be interpreted as a value", which reads as if it were no number; that is said
// as out of range, as the command line says it. toml++ places such an error just after the number.
std::string parse_error_text(std::string_view text, const toml::parse_error& e) {
  const std::string description(e.description());
  std::size_t line_start = 0;
  for (auto line = e.source().begin.line; line > 1 && line_start != std::string_view::npos; --line) {
    line_start = text.find('\n', line_start);
    if (line_start != std::string_view::npos) ++line_start;
  }
  if (line_start == std::string_view::npos || e.source().begin.column < 2) return description;
  const std::size_t end = std::min(text.size(), line_start + e.source().begin.column - 1);
  std::size_t begin = end;
  while (begin > line_start && std::string_view(" \t=[,{").find(text[begin - 1]) == std::string_view::npos) --begin;
  const std::string_view token = text.substr(begin, end - begin);
  double real = 0;
  int64_t integer = 0;
  if (read_real(token, real) == NumberText::kOutOfRange) return real_problem(token, NumberText::kOutOfRange);
  if (read_decimal(token, integer) == NumberText::kOutOfRange)
    return integer_problem<int64_t>(token, NumberText::kOutOfRange);
  return description;
}

}  // namespace

Scene parse_scene(const std::string& text, const std::string& name, const std::string& folder) {
  toml::table root;
  try {
    root = toml::parse(text, name);
  } catch (const toml::parse_error& e) {
    throw Error(name + ":" + std::to_string(e.source().begin.line) + ": " + parse_error_text(text, e) +
                compressed_hint(text));
  }
  Scene scene;
  scene.source = name;
  scene.text = text;
  static const std::set<std::string> kSections = {"system", "particles", "types", "interactions",
                                                  "initial", "integrator", "run", "output", "minimize",
                                                  "neighbor"};
  for (const auto& [key, value] : root)
    if (!kSections.count(std::string(key.str())))
      throw Error(name + ":" + std::to_string(value.source().begin.line) + ": unknown section or key " +
                  quote_excerpt(key.str()));
  read_system(root, name, scene);
  const std::map<std::string, std::size_t> type_index = read_types(root, name, scene);
  read_interactions(root, name, scene, type_index);
  read_particles(root, name, folder, scene, type_index);
  read_dynamics(root, name, scene);
  read_minimize(root, name, scene);
  read_neighbor(root, name, scene);
  read_run_and_output(root, name, scene);
  with_context(name, [&] { scene.force_field.validate(); });
  return scene;
}

uint64_t scene_fingerprint(const Scene& scene) {
  std::ostringstream t;
  t.precision(17);
  const SceneParticles& p = scene.particles;
  t << scene.dim << '|' << scene.periodic[0] << scene.periodic[1] << scene.periodic[2] << '|' << int(p.source) << '|'
    << int(p.lattice) << '|' << p.cells[0] << ',' << p.cells[1] << ',' << p.cells[2] << '|' << p.density << '|'
    << p.lattice_constant << '|';
  for (int a = 0; a < 3; ++a) t << p.box[std::size_t(a)] << ',' << p.offset[std::size_t(a)] << ',';
  t << '|' << p.sphere_radius << '|' << p.count << '|' << p.min_distance << '|' << p.path << '|' << p.frame << '|';
  for (const auto& [name, f] : p.composition) t << name << '=' << f << ',';
  const ForceField& ff = scene.force_field;
  for (std::size_t k = 0; k < ff.types.size(); ++k)
    t << '|' << ff.types[k].name << ':' << scene.masses[k] << ':' << ff.types[k].sigma << ':' << ff.types[k].epsilon;
  t << '|' << ff.cutoff << '|' << int(ff.mode) << '|' << int(ff.mixing);
  for (const PairOverride& o : ff.overrides) t << '|' << o.a << '-' << o.b << ':' << o.sigma << ':' << o.epsilon;
  t << '|' << scene.initial_temperature << '|' << scene.seed << '|' << int(scene.integrator.kind) << '|'
    << scene.integrator.dt << '|' << scene.integrator.temperature << '|' << scene.integrator.friction;
  // Only when present, so that the fingerprints (and checkpoints) of scenes without it stay valid.
  if (const SceneMinimize& m = scene.minimize; m.enabled)
    t << "|minimize:" << m.force_tolerance << ',' << m.max_steps << ',' << m.dt << ',' << m.dt_max << ','
      << m.max_displacement;
  uint64_t h = 0xcbf29ce484222325ull;  // FNV-1a: the same on every machine and compiler
  for (unsigned char c : t.str()) h = (h ^ c) * 0x100000001b3ull;
  return h;
}

Scene read_scene(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error(display_path(path) + ": cannot open the scene file");
  std::stringstream text;
  text << in.rdbuf();
  const std::filesystem::path folder = std::filesystem::path(path).parent_path();
  return parse_scene(text.str(), display_path(path), folder.empty() ? "." : folder.string());
}

namespace {

// Deterministic type assignment: exact counts from the fractions (largest remainders), then a
// shuffle with the scene's seed.
std::vector<uint32_t> assign_types(const Scene& scene, std::size_t n) {
  const auto& comp = scene.particles.composition;
  std::vector<uint32_t> types(n, 0);
  if (comp.empty() || n == 0) return types;
  std::vector<std::size_t> count(comp.size());
  std::vector<std::pair<double, std::size_t>> remainder;
  std::size_t assigned = 0;
  for (std::size_t k = 0; k < comp.size(); ++k) {
    const double exact = comp[k].second * double(n);
    count[k] = std::size_t(std::floor(exact));
    assigned += count[k];
    remainder.emplace_back(exact - std::floor(exact), k);
  }
  std::stable_sort(remainder.begin(), remainder.end(), [](auto& a, auto& b) { return a.first > b.first; });
  for (std::size_t k = 0; assigned < n; ++k, ++assigned) ++count[remainder[k % remainder.size()].second];
  std::size_t at = 0;
  for (std::size_t k = 0; k < comp.size(); ++k) {
    std::size_t index = 0;
    while (scene.force_field.types[index].name != comp[k].first) ++index;
    for (std::size_t c = 0; c < count[k]; ++c) types[at++] = uint32_t(index);
  }
  std::mt19937_64 rng(scene.seed ^ 0x7f4a7c159e3779b9ull);
  std::shuffle(types.begin(), types.end(), rng);
  return types;
}

}  // namespace

namespace {

// Wraps every coordinate on a periodic axis into [0, L), exactly (wrap_coordinate); returns the
// number of particles that moved.
std::size_t wrap_into_box(Configuration& c) {
  const int dim = c.box.dim;
  std::size_t moved = 0;
  for (std::size_t i = 0; i < c.size(); ++i) {
    bool outside = false;
    for (int a = 0; a < dim; ++a) {
      if (!c.box.periodic[a]) continue;
      double& x = c.positions[i * std::size_t(dim) + std::size_t(a)];
      const double w = wrap_coordinate(x, c.box.length[a]);
      outside = outside || (std::isfinite(x) && w != x);
      x = w;
    }
    moved += outside ? 1 : 0;
  }
  return moved;
}

}  // namespace

Configuration build_configuration(const Scene& scene, std::size_t* wrapped) {
  const SceneParticles& p = scene.particles;
  if (wrapped) *wrapped = 0;
  const int dim = scene.dim;
  Configuration c;
  if (p.source == ParticleSource::kFile) {
    ReadOptions o;
    o.dim = dim;
    o.frame = p.frame;
    ConfigurationFile f = read_configuration(p.path, o);
    if (f.config.size() == 0)
      throw Error("[particles] path: the scene places no particle (" + f.source + " holds none)");
    std::map<std::string, uint32_t> index;
    for (std::size_t k = 0; k < scene.force_field.types.size(); ++k) index[scene.force_field.types[k].name] = uint32_t(k);
    std::vector<uint32_t> type_of_species;
    for (const std::string& s : f.species) {
      const auto it = index.find(s);
      if (it == index.end()) {
        std::size_t first = 0;
        while (f.species[f.config.types[first]] != s) ++first;
        throw Error("[particles] path: particle " + std::to_string(first) + " of " + f.source +
                    " has species " + quote_excerpt(s) + ", which no [[types]] names");
      }
      type_of_species.push_back(it->second);
    }
    for (uint32_t& t : f.config.types) t = type_of_species[t];
    for (int a = 0; a < dim; ++a)
      if (f.config.box.periodic[a] != scene.periodic[std::size_t(a)])
        throw Error("[system] periodic: axis " + std::string(1, "xyz"[a]) + " is " +
                    (scene.periodic[std::size_t(a)] ? "periodic" : "open") + " in the scene but not in " + f.source);
    // Not-finite coordinates stay as they are, for validate_system to name the particle.
    const std::size_t moved = wrap_into_box(f.config);
    if (wrapped) *wrapped = moved;
    return f.config;
  }
  if (p.source == ParticleSource::kLattice) {
    c = make_lattice_cells(p.lattice, {p.cells[0], p.cells[1], p.cells[2]},
                           p.lattice_constant > 0 ? p.lattice_constant : lattice_constant_for(p.lattice, p.density));
    // Box: the lattice's extent unless the scene gives a larger one; the lattice sits at offset.
    for (int a = 0; a < dim; ++a) {
      if (p.box[std::size_t(a)] > 0) {
        if (p.box[std::size_t(a)] < c.box.length[a] * (1 - 1e-12))
          throw Error("[particles] box: axis " + std::string(1, "xyz"[a]) + " is " +
                      format_number(p.box[std::size_t(a)]) + ", smaller than the lattice's " +
                      format_number(c.box.length[a]));
        c.box.length[a] = p.box[std::size_t(a)];
      }
    }
    std::vector<double> kept;
    double centre[3] = {};
    for (int a = 0; a < dim; ++a) {
      double lo = INFINITY, hi = -INFINITY;
      for (std::size_t i = 0; i < c.size(); ++i) {
        lo = std::min(lo, c.positions[i * dim + a]);
        hi = std::max(hi, c.positions[i * dim + a]);
      }
      centre[a] = 0.5 * (lo + hi);
    }
    for (std::size_t i = 0; i < c.size(); ++i) {
      double r2 = 0;
      for (int a = 0; a < dim; ++a) r2 += (c.positions[i * dim + a] - centre[a]) * (c.positions[i * dim + a] - centre[a]);
      if (p.sphere_radius > 0 && r2 > p.sphere_radius * p.sphere_radius) continue;
      for (int a = 0; a < dim; ++a) kept.push_back(c.positions[i * dim + a] + p.offset[std::size_t(a)]);
    }
    c.positions = std::move(kept);
    c.types.assign(c.positions.size() / std::size_t(dim), 0);
  } else {
    Box box;
    box.dim = dim;
    for (int a = 0; a < kMaxDim; ++a) {
      box.length[a] = a < dim ? p.box[std::size_t(a)] : 0.0;
      box.periodic[a] = a < dim && scene.periodic[std::size_t(a)];
      if (a < dim && !(box.length[a] > 0))
        throw Error("[particles] box: random placement needs every length > 0");
    }
    c = make_random_spaced(box, p.count, p.min_distance, scene.seed);
  }
  for (int a = 0; a < kMaxDim; ++a) c.box.periodic[a] = a < dim && scene.periodic[std::size_t(a)];
  if (c.size() == 0) throw Error("[particles]: the scene places no particle (sphere_radius too small?)");
  // Periodic axes: every particle in [0, L), as the integrator keeps them.
  wrap_into_box(c);
  c.types = assign_types(scene, c.size());
  return c;
}

}  // namespace cellforce
