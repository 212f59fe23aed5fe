// The compiled core of cellforce.Simulation (src/python/cellforce/simulation.py, which adds the
// run loop, reporters and the progress bar): a Context holding an MD state, made from a scene file
// as `cellforce run` makes it (scene/scene_start.h) or from arrays the Python side has checked, and
// the state read where it lives (Context::state_view) or copied (get_state). No physics of its own.
#include "bindings.h"

#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <cellforce/cellforce.hpp>

#include <atomic>
#include <cstdint>
#include <mutex>
#include <optional>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "arrays.h"
#include "physics.h"
#include "scene/scene_start.h"
#include "core/option_table.h"
#include "scene/scene.h"
#include "state/velocities.h"

namespace cellforce::python {
namespace {

namespace cf = cellforce;

using HostDoubles = nb::ndarray<const double, nb::c_contig, nb::device::cpu>;
using HostIndices = nb::ndarray<const uint32_t, nb::c_contig, nb::device::cpu>;

// A type as the Python side gives it: name, sigma, epsilon; a pair: two type indices, sigma, epsilon.

class SimulationCore {
 public:
  // From arrays (the Python side checked their shapes and types): positions (n, dim), type indices
  // (n), masses (n), velocities (n, dim) or None (drawn at initial_temperature with `seed`, else
  // zero). Engine options as set_option takes them, in order.
  SimulationCore(const std::vector<double>& box, nb::handle periodic, double cutoff, const std::string& mode,
                 const std::string& mixing, nb::handle types, nb::handle pairs,
                 const std::vector<std::pair<std::string, std::string>>& options, const std::string& integrator,
                 double dt, double temperature, double friction, uint64_t seed, HostDoubles positions,
                 HostIndices type_index, HostDoubles masses, std::optional<HostDoubles> velocities,
                 std::optional<double> initial_temperature, int64_t step)
      : ctx_(box_dim(box)), dt_(dt), box_(box) {
    const std::size_t dim = box.size(), n = positions.shape(0);
    Physics physics = set_physics(ctx_, box, periodic, cutoff, mode, mixing, types, pairs);
    names_ = std::move(physics.names);
    periodic_ = std::move(physics.periodic);
    for (const auto& [key, value] : options) ctx_.set_option(key, value);
    ctx_.set_integrator(integrator_options(integrator, dt, temperature, friction, seed));
    std::vector<double> v;
    if (velocities) {
      v.assign(velocities->data(), velocities->data() + n * dim);
    } else if (initial_temperature) {
      cf::MdState state;
      state.config.box.dim = int(dim);
      state.config.positions.assign(positions.data(), positions.data() + n * dim);
      state.config.types.assign(type_index.data(), type_index.data() + n);
      const std::vector<double> m(masses.data(), masses.data() + n);
      initialize_velocities(state, m, *initial_temperature, seed, integrator != "langevin");
      v = std::move(state.velocities);
    }
    species_.assign(type_index.data(), type_index.data() + n);
    masses_.assign(masses.data(), masses.data() + n);
    nb::gil_scoped_release release;
    ctx_.set_state(n, positions.data(), v.empty() ? nullptr : v.data(), type_index.data(), masses.data(), step);
  }

  // From a scene file, as `cellforce run` starts it (fresh, step 0); `options` (set_option keys)
  // replace the scene's [run] and [neighbor] values.
  static SimulationCore* from_scene(const std::string& path,
                                    const std::vector<std::pair<std::string, std::string>>& options) {
    cf::Scene scene = cf::read_scene(path);
    for (const auto& [key, value] : options) {
      const cf::OptionSpec* spec = cf::find_option(key);
      if (!spec) throw nb::value_error(("options: unknown engine option '" + key + "'").c_str());
      scene.engine.set(spec->id, value);
    }
    cf::SceneStart start = [&] {
      nb::gil_scoped_release release;
      return cf::start_scene(scene);
    }();
    auto* core = new SimulationCore(std::move(start.ctx), scene.integrator.dt);
    const std::size_t dim = std::size_t(scene.dim);
    core->box_.assign(start.state.config.box.length, start.state.config.box.length + dim);
    core->periodic_.assign(scene.periodic.begin(), scene.periodic.begin() + long(dim));
    for (const cf::ParticleType& t : scene.force_field.types) core->names_.push_back(t.name);
    core->scene_steps_ = scene.steps;
    core->species_ = start.state.config.types;
    core->masses_ = start.masses;
    return core;
  }

  void step(int64_t count, bool observe) {
    if (count < 0) throw nb::value_error(("steps: " + std::to_string(count) + "; expected >= 0").c_str());
    nb::gil_scoped_release release;
    const std::lock_guard<std::mutex> lock(mutex_);
    ctx_.step(count, observe);
  }

  nb::dict thermo() {
    cf::Thermo t;
    int64_t step = 0;
    {
      nb::gil_scoped_release release;
      const std::lock_guard<std::mutex> lock(mutex_);
      t = ctx_.thermo();
      step = ctx_.current_step();
    }
    const std::size_t dim = std::size_t(ctx_.dim());
    std::vector<double> w(t.virial, t.virial + dim * dim);
    nb::dict d;
    d["step"] = step;
    d["time"] = double(step) * dt_;
    d["kinetic"] = t.kinetic;
    d["potential"] = t.potential;
    d["total"] = t.total;
    d["temperature"] = t.temperature;
    d["pressure"] = t.pressure;
    d["virial"] = numpy_array(std::move(w), {dim, dim});
    return d;
  }

  // One array of the state where it lives, read in place (`which`: 0 positions, 1 velocities, 2
  // forces): a NumPy read-only view on the host; on the device, an array of `framework` (0: DLPack,
  // 1: CuPy, 2: PyTorch, 3: JAX).
  nb::object state_view(int which, int framework) {
    if (which < 0 || which > 2) throw nb::value_error("which: 0 (positions), 1 (velocities) or 2 (forces)");
    cf::StateView v;
    {
      nb::gil_scoped_release release;
      const std::lock_guard<std::mutex> lock(mutex_);
      v = ctx_.state_view();
    }
    // Each view's owner holds the simulation and counts as a live view until it goes: set_box,
    // which may give the state new arrays, is refused while one lives (BufferError, as Python
    // refuses to resize a bytearray with exports).
    auto* held = new nb::object(nb::find(this));
    ++views_;
    const nb::capsule owner(held, [](void* p) noexcept {
      auto* simulation = static_cast<nb::object*>(p);
      --nb::inst_ptr<SimulationCore>(*simulation)->views_;
      delete simulation;
    });
    const std::size_t shape[2] = {v.n, std::size_t(v.dim)};
    auto view = [&](const double* data) -> nb::object {
      if (v.device < 0)
        return nb::cast(nb::ndarray<nb::numpy, const double>(data, 2, shape, owner), nb::rv_policy::reference);
      auto* p = const_cast<double*>(data);  // device frameworks take no read-only arrays: not to be written
      const int cuda = nb::device::cuda::value;
      switch (framework) {
        case 1:
          return nb::cast(nb::ndarray<nb::cupy, double>(p, 2, shape, owner, nullptr, nb::dtype<double>(), cuda, v.device),
                          nb::rv_policy::reference);
        case 2:
          return nb::cast(nb::ndarray<nb::pytorch, double>(p, 2, shape, owner, nullptr, nb::dtype<double>(), cuda,
                                                           v.device),
                          nb::rv_policy::reference);
        case 3:
          return nb::cast(nb::ndarray<nb::jax, double>(p, 2, shape, owner, nullptr, nb::dtype<double>(), cuda, v.device),
                          nb::rv_policy::reference);
        default:
          return nb::cast(nb::ndarray<double>(p, 2, shape, owner, nullptr, nb::dtype<double>(), cuda, v.device),
                          nb::rv_policy::reference);
      }
    };
    return view(which == 0 ? v.positions : which == 1 ? v.velocities : v.forces);
  }

  // Host copies of positions, velocities and forces.
  nb::tuple get_state() {
    const std::size_t n = num_particles(), dim = std::size_t(ctx_.dim());
    std::vector<double> x(n * dim), v(n * dim), f(n * dim);
    {
      nb::gil_scoped_release release;
      const std::lock_guard<std::mutex> lock(mutex_);
      ctx_.get_state(x.data(), v.data(), f.data());
    }
    return nb::make_tuple(numpy_array(std::move(x), {n, dim}), numpy_array(std::move(v), {n, dim}),
                          numpy_array(std::move(f), {n, dim}));
  }

  void set_positions(HostDoubles x) {
    nb::gil_scoped_release release;
    const std::lock_guard<std::mutex> lock(mutex_);
    ctx_.set_positions(x.shape(0), x.data());
  }
  void set_velocities(HostDoubles v) {
    nb::gil_scoped_release release;
    const std::lock_guard<std::mutex> lock(mutex_);
    ctx_.set_velocities(v.shape(0), v.data());
  }
  void set_box(const std::vector<double>& lengths, const std::vector<bool>& periodic, bool scale_positions) {
    if (lengths.size() != std::size_t(ctx_.dim()) || periodic.size() != lengths.size())
      throw nb::value_error(("box: " + std::to_string(lengths.size()) + " edge lengths for a system of " +
                             std::to_string(ctx_.dim()) + " axes")
                                .c_str());
    if (views_ > 0)
      throw nb::buffer_error((std::to_string(views_.load()) + " view(s) of the state (positions, velocities, forces) "
                              "are alive, and a new box may give the state new arrays: drop them (del) first, or "
                              "read copies with get_state()")
                                 .c_str());
    bool p[3] = {true, true, true};
    for (std::size_t a = 0; a < periodic.size(); ++a) p[a] = periodic[a];
    {
      nb::gil_scoped_release release;
      const std::lock_guard<std::mutex> lock(mutex_);
      ctx_.set_box(lengths.data(), p, scale_positions);
    }
    box_ = lengths;
    periodic_ = periodic;
  }

  nb::dict minimize(double force_tolerance, int64_t max_steps, double dt, double dt_max, double max_displacement) {
    cf::MinimizeOptions o;
    o.force_tolerance = force_tolerance;
    o.max_steps = max_steps;
    o.dt = dt;
    o.dt_max = dt_max;
    o.max_displacement = max_displacement;
    cf::MinimizeResult r;
    {
      nb::gil_scoped_release release;
      const std::lock_guard<std::mutex> lock(mutex_);
      r = ctx_.minimize(o);
    }
    nb::dict d;
    d["steps"] = r.steps;
    d["initial_energy"] = r.initial_energy;
    d["final_energy"] = r.final_energy;
    d["initial_max_force"] = r.initial_max_force;
    d["final_max_force"] = r.final_max_force;
    d["final_max_force_particle"] = r.final_max_force_particle;
    return d;
  }

  std::string statistics_json() {
    const std::lock_guard<std::mutex> lock(mutex_);
    return ctx_.statistics_json();
  }
  std::size_t num_particles() const { return species_.size(); }
  int dim() const { return int(box_.size()); }
  int64_t current_step() {
    const std::lock_guard<std::mutex> lock(mutex_);
    return ctx_.current_step();
  }
  int live_views() const { return views_; }
  double dt() const { return dt_; }
  const std::vector<double>& box() const { return box_; }
  const std::vector<bool>& periodic() const { return periodic_; }
  const std::vector<std::string>& type_names() const { return names_; }
  nb::object species() const {
    auto* copy = new std::vector<uint32_t>(species_);
    nb::capsule owner(copy, [](void* p) noexcept { delete static_cast<std::vector<uint32_t>*>(p); });
    const std::size_t shape[1] = {copy->size()};
    return nb::cast(nb::ndarray<nb::numpy, uint32_t>(copy->data(), 1, shape, owner), nb::rv_policy::reference);
  }
  nb::object masses() const { return numpy_array(masses_, {masses_.size()}); }
  std::optional<int64_t> scene_steps() const { return scene_steps_; }
  std::string backend() {
    const std::lock_guard<std::mutex> lock(mutex_);
    return ctx_.backend_name();
  }
  std::string description() {
    const std::lock_guard<std::mutex> lock(mutex_);
    return ctx_.description();
  }
  std::string neighbor() {
    const std::lock_guard<std::mutex> lock(mutex_);
    return ctx_.neighbor();
  }

 private:
  SimulationCore(cf::Context&& ctx, double dt) : ctx_(std::move(ctx)), dt_(dt) {}

  static cf::IntegratorOptions integrator_options(const std::string& kind, double dt, double temperature,
                                                  double friction, uint64_t seed) {
    cf::IntegratorOptions o;
    if (kind == "nve" || kind == "verlet") o.kind = cf::Integrator::kVerlet;
    else if (kind == "langevin") o.kind = cf::Integrator::kLangevin;
    else throw nb::value_error(("integrator: '" + kind + "'; expected 'nve' or 'langevin'").c_str());
    o.dt = dt;
    o.temperature = temperature;
    o.friction = friction;
    o.seed = seed;
    return o;
  }

  cf::Context ctx_;  // one thread at a time (mutex_): the long calls release the GIL
  std::mutex mutex_;
  double dt_ = 0;
  std::vector<double> box_;     // the box now (set_box changes it)
  std::vector<bool> periodic_;
  std::vector<std::string> names_;
  std::vector<uint32_t> species_;  // each particle's type index
  std::vector<double> masses_;     // each particle's mass
  std::optional<int64_t> scene_steps_;
  std::atomic<int> views_{0};  // views of the state alive (state_view's arrays)
};

}  // namespace

void bind_simulation(nb::module_& m) {
  nb::class_<SimulationCore>(m, "SimulationCore",
                             "The compiled core of cellforce.Simulation (use that class): a Context holding an MD "
                             "state")
      .def(nb::init<const std::vector<double>&, nb::handle, double, const std::string&, const std::string&,
                    nb::handle, nb::handle, const std::vector<std::pair<std::string, std::string>>&,
                    const std::string&, double, double, double, uint64_t, HostDoubles, HostIndices, HostDoubles,
                    std::optional<HostDoubles>, std::optional<double>, int64_t>(),
           nb::arg("box"), nb::arg("periodic").none(), nb::arg("cutoff"), nb::arg("mode"), nb::arg("mixing"),
           nb::arg("types").none(), nb::arg("pairs").none(),
           nb::arg("options"), nb::arg("integrator"), nb::arg("dt"), nb::arg("temperature"), nb::arg("friction"),
           nb::arg("seed"), nb::arg("positions"), nb::arg("type_index"), nb::arg("masses"),
           nb::arg("velocities").none(), nb::arg("initial_temperature").none(), nb::arg("step"))
      .def_static("from_scene", &SimulationCore::from_scene, nb::arg("path"), nb::arg("options"),
                  nb::rv_policy::take_ownership)
      .def("step", &SimulationCore::step, nb::arg("count"), nb::arg("observe"))
      .def("thermo", &SimulationCore::thermo)
      .def("state_view", &SimulationCore::state_view, nb::arg("which"), nb::arg("framework"))
      .def_prop_ro("views", [](const SimulationCore& c) { return c.live_views(); })
      .def("get_state", &SimulationCore::get_state)
      .def("set_positions", &SimulationCore::set_positions, nb::arg("positions"))
      .def("set_velocities", &SimulationCore::set_velocities, nb::arg("velocities"))
      .def("set_box", &SimulationCore::set_box, nb::arg("lengths"), nb::arg("periodic"), nb::arg("scale_positions"))
      .def("minimize", &SimulationCore::minimize, nb::arg("force_tolerance"), nb::arg("max_steps"), nb::arg("dt"),
           nb::arg("dt_max"), nb::arg("max_displacement"))
      .def("statistics_json", &SimulationCore::statistics_json)
      .def_prop_ro("n", &SimulationCore::num_particles)
      .def_prop_ro("dim", &SimulationCore::dim)
      .def_prop_ro("step_count", &SimulationCore::current_step)
      .def_prop_ro("dt", &SimulationCore::dt)
      .def_prop_ro("box", &SimulationCore::box)
      .def_prop_ro("periodic", &SimulationCore::periodic)
      .def_prop_ro("type_names", &SimulationCore::type_names)
      .def_prop_ro("species", &SimulationCore::species)
      .def_prop_ro("masses", &SimulationCore::masses)
      .def_prop_ro("scene_steps", &SimulationCore::scene_steps)
      .def_prop_ro("backend", &SimulationCore::backend)
      .def_prop_ro("description", &SimulationCore::description)
      .def_prop_ro("neighbor", &SimulationCore::neighbor);
}

}  // namespace cellforce::python
