// cellforce::Context's molecular dynamics (include/cellforce/cellforce.hpp): the MD state on its
// engine (src/backends), and the changes of physics and engine carried into it while it exists.
#include <cellforce/cellforce.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "api/context_impl.h"
#include "core/error.h"
#include "core/text.h"
#include "md/minimize.h"
#include "state/stable_start.h"

namespace cellforce {

namespace {

// Velocities (n x dim) finite, else the first particle that has one not is named.
void check_velocities(const std::vector<double>& velocities, int dim) {
  for (std::size_t k = 0; k < velocities.size(); ++k)
    if (!std::isfinite(velocities[k]))
      throw Error("particle " + std::to_string(k / std::size_t(dim)) + " has a non-finite velocity (" +
                  format_number(velocities[k]) + ")");
}

// Positions on periodic axes of `box` wrapped into [0, L) (non-finite ones are left for the
// engine's check, which names the particle).
void wrap_positions(std::vector<double>& positions, const Box& box) {
  const std::size_t dim = std::size_t(box.dim);
  for (std::size_t k = 0; k < positions.size(); ++k) {
    const std::size_t a = k % dim;
    if (box.periodic[a] && std::isfinite(positions[k])) positions[k] = wrap_coordinate(positions[k], box.length[a]);
  }
}

}  // namespace

IntegratorSettings Context::Impl::settings() const {
  IntegratorSettings s;
  s.langevin = integrator.kind == Integrator::kLangevin;
  s.dt = integrator.dt;
  s.kT = integrator.temperature;
  s.friction = integrator.friction;
  s.seed = integrator.seed;
  return s;
}

// The state is downloaded, put under the new box (wrapped, not scaled) and set on the engine as
// set_state sets a state, so that the next step is the one a fresh context with the new setting
// would take from it. What the engine alone finds (a pair whose force overflows) can fail after
// the engine took the state: then the state before is set on it again.
void Context::Impl::carry(const Box& b, const ForceField& f, const EngineChoice& c, bool new_engine,
                          const std::string& setting, const double* scale) {
  check_external_engine(c, setting);
  MdState before;
  md->get_state(before);
  before.config.box = md_box;
  before.config.types = types;
  MdState state = before;
  state.config.box = b;
  if (scale)
    for (std::size_t k = 0; k < state.config.positions.size(); ++k)
      state.config.positions[k] *= scale[k % std::size_t(b.dim)];
  wrap_positions(state.config.positions, b);
  const ListMemory memory = md_list_memory(c, masses.size());
  EngineChoice next = resolved(c, b, f.cutoff, true, memory);
  bool dropped = false;  // the state before could not be set again either
  try {
    // The checks set_state makes, before any engine is touched.
    validate_system(state.config.view(), f);
    check_precision_range(f, c.precision);
    check_step_arithmetic(integrator.dt, masses, types, f);
    if (!new_engine && same_reuse(next.reuse, md_reuse)) {
      try {
        md->set_state(state, masses, f);
      } catch (...) {
        try {
          md->set_state(before, masses, md_ff);
        } catch (...) {
          md.reset();  // no half-set state: the next step() asks for set_state again
          dropped = true;
        }
        throw;
      }
    } else {
      // A new engine beside the old one, on the stream of its device (the old stream lives until
      // the old engines are gone); the old engine stays the state's until the new one holds it.
      const std::shared_ptr<void> old_stream = stream;
      const int old_device = stream_device;
      std::unique_ptr<MdEngine> fresh;
      try {
        fresh = make_md_engine(with_stream(next, true));
        fresh->set_external_force(external);
        fresh->set_state(state, masses, f);
      } catch (...) {
        fresh.reset();
        stream = old_stream;
        stream_device = old_device;
        throw;
      }
      if (new_engine) {  // the force calls' engine is made again with the new choices
        engine.reset();
        device_pending = false;
      }
      md = std::move(fresh);  // the old engine goes before its stream
      md_reuse = next.reuse;
      md_memory = memory;
    }
  } catch (const Error& e) {
    rethrow_with(setting + (dropped      ? ": the MD state cannot take it, nor be set again as it was, and is dropped "
                                           "(call set_state): "
                            : new_engine ? ": the MD state cannot move to an engine with it, and stays where it was: "
                                         : ": the MD state cannot take it, and stays as it was: "),
                 e);
  }
  box = md_box = b;
  ff = md_ff = f;
  choice = c;
}

void Context::set_integrator(const IntegratorOptions& o) {
  if (o.kind != Integrator::kVerlet && o.kind != Integrator::kLangevin)
    throw Error("integrator " + std::to_string(int(o.kind)) + " is not an Integrator");
  if (!std::isfinite(o.dt) || o.dt <= 0) throw Error("dt is " + format_number(o.dt) + "; it must be finite and > 0");
  if (o.kind == Integrator::kLangevin) {
    if (!std::isfinite(o.temperature) || o.temperature < 0)
      throw Error("temperature is " + format_number(o.temperature) + "; it must be finite and >= 0");
    if (!std::isfinite(o.friction) || o.friction <= 0)
      throw Error("friction is " + format_number(o.friction) + "; it must be finite and > 0");
  }
  Impl& s = self();
  if (s.md) check_step_arithmetic(o.dt, s.masses, s.types, s.md_ff);
  s.integrator = o;
}

void Context::set_state(std::size_t n, const double* positions, const double* velocities, const uint32_t* types,
                        const double* masses, int64_t step) {
  Impl& s = self();
  s.check_ready();
  check_output(positions, "positions", n);
  check_output(masses, "masses", n);
  if (step < 0) throw Error("step " + std::to_string(step) + ": expected a step >= 0");
  const std::size_t dim = std::size_t(s.dim);
  MdState state;
  state.config.box = s.box;
  state.config.positions.assign(positions, positions + n * dim);
  state.config.types = types ? std::vector<uint32_t>(types, types + n) : std::vector<uint32_t>(n, 0);
  state.velocities = velocities ? std::vector<double>(velocities, velocities + n * dim) : std::vector<double>(n * dim, 0.0);
  wrap_positions(state.config.positions, s.box);
  check_velocities(state.velocities, s.dim);
  state.step = step;
  state.time = double(step) * s.integrator.dt;
  std::vector<double> m(masses, masses + n);
  validate_masses(m, n);
  s.check_external(n, "set_state");
  s.check_external_engine(s.choice, "set_state");
  check_step_arithmetic(s.integrator.dt, m, state.config.types, s.ff);
  const ListMemory memory = md_list_memory(s.choice, n);
  const EngineChoice resolved = s.resolved(s.box, true, memory);
  // An automatic skin for another box, or another memory mode (another particle count)
  if (s.md && !Impl::same_reuse(resolved.reuse, s.md_reuse)) s.md.reset();
  if (!s.md) {
    s.md = make_md_engine(s.with_stream(resolved));
    s.md_reuse = resolved.reuse;
    s.md->set_external_force(s.external);
  }
  s.md_memory = memory;
  try {
    s.md->set_state(state, m, s.ff);
  } catch (...) {
    s.md.reset();  // no half-set state: the next step() asks for set_state again
    throw;
  }
  s.md_box = s.box;
  s.md_ff = s.ff;
  s.masses = std::move(m);
  s.types = std::move(state.config.types);
}

void Context::step(int64_t count, bool observe) {
  if (count < 0) throw Error("step count " + std::to_string(count) + ": expected >= 0");
  Impl& s = self();
  s.get_md().advance(count, s.settings(), observe);
}

int64_t Context::current_step() const {
  const Impl& s = self();
  if (!s.md) throw Error("no MD state: call set_state first");
  return s.md->step();
}

bool Context::has_state() const { return self().md != nullptr; }

std::size_t Context::num_particles() const {
  const Impl& s = self();
  if (!s.md) throw Error("no MD state: call set_state first");
  return s.masses.size();
}

namespace {

// n arrays' worth of n x dim host values for the state of `held` particles.
std::vector<double> state_array(const double* values, std::size_t n, std::size_t held, int dim, const char* what) {
  if (n != held)
    throw Error(std::string(what) + ": " + std::to_string(n) + " particles given for a state of " +
                std::to_string(held));
  check_output(values, what, n);
  return std::vector<double>(values, values + n * std::size_t(dim));
}

}  // namespace

void Context::set_positions(std::size_t n, const double* positions) {
  Impl& s = self();
  MdEngine& md = s.get_md();
  std::vector<double> p = state_array(positions, n, s.masses.size(), s.dim, "positions");
  wrap_positions(p, s.md_box);
  md.set_positions(p);
}

void Context::set_velocities(std::size_t n, const double* velocities) {
  Impl& s = self();
  MdEngine& md = s.get_md();
  const std::vector<double> v = state_array(velocities, n, s.masses.size(), s.dim, "velocities");
  check_velocities(v, s.dim);
  md.set_velocities(v);
}

void Context::get_state(double* positions, double* velocities, double* forces) {
  MdState state;
  self().get_md().get_state(state);
  const std::size_t count = state.config.positions.size();
  if (positions) std::memcpy(positions, state.config.positions.data(), count * sizeof(double));
  if (velocities) std::memcpy(velocities, state.velocities.data(), count * sizeof(double));
  if (forces) std::memcpy(forces, state.forces.data(), count * sizeof(double));
}

StateView Context::state_view() {
  Impl& s = self();
  const MdEngine::StateArrays a = s.get_md().state_arrays();
  StateView v;
  v.positions = a.positions;
  v.velocities = a.velocities;
  v.forces = a.forces;
  v.n = s.masses.size();
  v.dim = s.md_box.dim;
  v.device = a.device;
  return v;
}

void Context::Impl::check_external(std::size_t n, const char* what) const {
  if (external_n != 0 && n != external_n)
    throw Error(std::string(what) + ": " + std::to_string(n) + " particles, but the external force set holds " +
                std::to_string(external_n) + " (set one for " + std::to_string(n) + ", or clear_external_force)");
}

void Context::Impl::check_external_engine(const EngineChoice& c, const std::string& what) const {
  if (!external.device) return;
  if (resolve_backend(c.backend) != Backend::kCuda || c.device != external_device)
    throw Error(what + ": the external force is a device array on CUDA device " + std::to_string(external_device) +
                ", which the state's engine would not run on; clear_external_force (or set it as a host array) "
                "first");
}

void Context::Impl::set_external(ExternalForce e, std::size_t n) {
  if (md) {
    md->set_external_force(e);
    try {
      md->reevaluate();  // the state's forces with it
    } catch (...) {
      md->set_external_force(external);  // the one before, as the state had it
      throw;
    }
  }
  external = std::move(e);
  external_n = n;
}

void Context::Impl::check_external_count(std::size_t n, const char* what) const {
  if (md && n != masses.size())
    throw Error(std::string(what) + ": " + std::to_string(n) + " particles given for a state of " +
                std::to_string(masses.size()));
  if (n == 0) throw Error(std::string(what) + ": no particles (clear_external_force clears it)");
}

void Context::set_external_forces(std::size_t n, const double* forces) {
  Impl& s = self();
  s.check_external_count(n, "set_external_forces");
  if (!forces) throw Error("set_external_forces: external forces is a null pointer (" + std::to_string(n) + " particles)");
  const std::size_t dim = std::size_t(s.dim);
  ExternalForce e;
  e.values.assign(forces, forces + n * dim);
  for (std::size_t k = 0; k < e.values.size(); ++k)
    if (!std::isfinite(e.values[k]))
      throw Error("set_external_forces: particle " + std::to_string(k / dim) + " has a non-finite external force (" +
                  format_number(e.values[k]) + ") along axis " + std::to_string(k % dim));
  s.set_external(std::move(e), n);
}

void Context::set_external_forces_device(std::size_t n, const double* forces) {
  Impl& s = self();
  s.check_external_count(n, "set_external_forces_device");
  if (resolve_backend(s.choice.backend) != Backend::kCuda)
    throw Error("set_external_forces_device: the cpu backend holds the state in host memory; use set_external_forces");
  if (!forces) throw Error("set_external_forces_device: external forces is a null pointer");
#ifdef CELLFORCE_HAVE_CUDA
  if (!cuda_device_pointer(forces))
    throw Error("set_external_forces_device: external forces is not a device pointer (use set_external_forces "
                "for a host array)");
#endif
  ExternalForce e;
  e.device = forces;
  const int before = s.external_device;
  s.external_device = s.choice.device;
  try {
    s.set_external(std::move(e), n);
  } catch (...) {
    s.external_device = before;
    throw;
  }
}

void Context::set_external_force_callback(ExternalForceFn callback, void* user) {
  ExternalForce e;
  e.callback = callback;
  e.user = callback ? user : nullptr;
  self().set_external(std::move(e), 0);
}

void Context::clear_external_force() { self().set_external(ExternalForce{}, 0); }

Thermo Context::thermo() {
  Impl& s = self();
  const Observables o = s.get_md().observables();
  const int dim = s.md_box.dim;
  const bool com_conserved = s.integrator.kind == Integrator::kVerlet;
  Thermo t;
  t.kinetic = o.kinetic;
  t.potential = o.potential;
  t.total = t.kinetic + t.potential;
  t.temperature = 2.0 * t.kinetic / degrees_of_freedom(s.masses.size(), dim, com_conserved);
  double trace = 0;
  bool closed = true;
  for (int a = 0; a < dim; ++a) {
    trace += o.virial[a][a];
    closed = closed && s.md_box.periodic[a];
    for (int b = 0; b < dim; ++b) t.virial[a * dim + b] = o.virial[a][b];
  }
  t.pressure = closed ? (2.0 * t.kinetic + trace) / (dim * s.md_box.volume()) : std::nan("");
  return t;
}

MinimizeResult Context::minimize(const MinimizeOptions& options) {
  FireSettings fire;
  fire.force_tolerance = options.force_tolerance;
  fire.max_steps = options.max_steps;
  fire.dt = options.dt;
  fire.dt_max = options.dt_max;
  fire.max_displacement = options.max_displacement;
  if (self().external.any())
    throw Error("minimize: an external force is set, and FIRE needs the energy, which it does not give; "
                "clear_external_force first");
  // In place where the state lives (CUDA: kernels on the device); after a throw the engine holds
  // the state it had, with its forces.
  const FireResult r = self().get_md().minimize(fire);
  MinimizeResult out;
  out.steps = r.steps;
  out.initial_energy = r.initial_energy;
  out.final_energy = r.final_energy;
  out.initial_max_force = r.initial_max_force;
  out.final_max_force = r.final_max_force;
  out.final_max_force_particle = r.final_max_force_particle;
  return out;
}

const double* Context::held_neighbor_state(std::size_t* coordinates, int64_t* served) {
  Impl& s = self();
  s.held_neighbor = s.get_md().forces().reuse_state();
  *coordinates = s.held_neighbor.build_positions.size();
  *served = s.held_neighbor.served;
  return s.held_neighbor.build_positions.data();
}

void Context::restore_neighbor_arrays(const double* build_positions, std::size_t coordinates, int64_t served) {
  Impl& s = self();
  MdEngine& md = s.get_md();
  const std::size_t n = s.masses.size();
  if (coordinates != n * std::size_t(s.md_box.dim))
    throw Error("neighbour state of " + std::to_string(coordinates) + " coordinates for " + std::to_string(n) +
                " particles in " + std::to_string(s.md_box.dim) + "D");
  check_output(build_positions, "the neighbour state's build positions", n);
  const SystemView built{s.md_box, n, build_positions, s.types.data()};
  md.forces().restore_reuse(built, s.md_ff, served);
  md.reevaluate();  // the current forces from the restored structure, as the uninterrupted run had them
}

RunStatistics Context::run_statistics() const {
  RunStatistics r;
  const Impl& s = self();
  if (!s.md) return r;
  const MdCounters& c = s.md->counters();
  r.steps = c.steps;
  r.evaluations = c.evaluations;
  r.force_seconds = c.force_seconds;
  r.integration_seconds = c.integration_seconds;
  r.step_call_seconds = c.host_wait_seconds;
  r.bytes_to_host = c.bytes_to_host;
  r.bytes_to_device = c.bytes_to_device;
  r.builds = c.builds;
  r.largest_served_displacement = c.served;
  r.dangerous_builds = c.dangerous_builds;
  r.missed_pairs = c.missed_pairs;
  r.repeated_pairs = c.repeated_pairs;
  r.buffer_bytes = s.md->forces().stats().buffer_bytes;
  r.state_bytes = s.md->state_bytes();
  return r;
}

void Context::reset_run_statistics() {
  Impl& s = self();
  if (s.md) s.md->reset_counters();
}

}  // namespace cellforce
