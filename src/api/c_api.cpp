// The C API (include/cellforce/cellforce.h) over cellforce::Context: every call runs inside
// guard(), which turns each exception into a status and keeps its message for cf_last_error; no
// exception crosses into the caller.
#include <cellforce/cellforce.h>

#include <cellforce/cellforce.hpp>

#include <cstring>
#include <new>
#include <string>

#include "core/names.h"
#include "core/text.h"

struct cf_context {
  cellforce::Context context;
  std::string last_error;
  explicit cf_context(int dim) : context(dim) {}
};

namespace {

thread_local std::string create_error;  // cf_last_error(NULL)

template <class F>
cf_status guard(std::string& message, F&& f) noexcept {
  try {
    message.clear();
    f();
    return CF_OK;
  } catch (const cellforce::DeviceError& e) {
    message = e.message();
    return CF_ERROR_DEVICE;
  } catch (const cellforce::Error& e) {
    message = e.message();
    return CF_ERROR_INPUT;
  } catch (const std::bad_alloc&) {
    message = "out of memory";
    return CF_ERROR_INTERNAL;
  } catch (const std::exception& e) {
    message = std::string("internal error: ") + e.what();
    return CF_ERROR_INTERNAL;
  } catch (...) {
    message = "internal error: an unknown exception";
    return CF_ERROR_INTERNAL;
  }
}

// A call on ctx: a null ctx is an input error that has nowhere to keep its message but
// cf_last_error(NULL).
template <class F>
cf_status on(cf_context* ctx, F&& f) noexcept {
  if (!ctx) {
    create_error = "the context is a null pointer";
    return CF_ERROR_INPUT;
  }
  return guard(ctx->last_error, [&] { f(ctx->context); });
}

void require(const void* p, const char* what) {
  if (!p) throw cellforce::Error(std::string(what) + " is a null pointer");
}

constexpr cellforce::Named<cellforce::Integrator> kIntegratorNames[] = {{"verlet", cellforce::Integrator::kVerlet},
                                                                        {"langevin", cellforce::Integrator::kLangevin}};

// Throws unless the MD state holds n particles (the length of the caller's arrays).
void require_particles(const cellforce::Context& c, size_t n, const char* call) {
  const std::size_t held = c.num_particles();
  if (n != held)
    throw cellforce::Error(std::string(call) + ": n is " + std::to_string(n) + " but the MD state holds " +
                           std::to_string(held) + " particles");
}

}  // namespace

extern "C" {

const char* cf_version(void) { return cellforce::version(); }

cf_status cf_create(cf_context** ctx, int dim) {
  return guard(create_error, [&] {
    require(ctx, "ctx (where the new context goes)");
    *ctx = nullptr;
    *ctx = new cf_context(dim);
  });
}

cf_status cf_set_box(cf_context* ctx, const double* lengths, const int* periodic) {
  return on(ctx, [&](cellforce::Context& c) {
    require(lengths, "box lengths");
    require(periodic, "box periodic");
    bool p[3] = {false, false, false};
    for (int a = 0; a < c.dim(); ++a) p[a] = periodic[a] != 0;
    c.set_box(lengths, p);
  });
}

cf_status cf_set_box_scaled(cf_context* ctx, const double* lengths, const int* periodic) {
  return on(ctx, [&](cellforce::Context& c) {
    require(lengths, "box lengths");
    require(periodic, "box periodic");
    bool p[3] = {false, false, false};
    for (int a = 0; a < c.dim(); ++a) p[a] = periodic[a] != 0;
    c.set_box(lengths, p, true);
  });
}

cf_status cf_set_cutoff(cf_context* ctx, double rc, const char* mode) {
  return on(ctx, [&](cellforce::Context& c) {
    if (!mode) return c.set_cutoff(rc);  // the mode as it is
    const auto parsed = cellforce::parse_name(mode, cellforce::kCutoffModeNames);
    if (!parsed)
      throw cellforce::Error("cutoff mode " + cellforce::quote_excerpt(mode) + " is not one of " +
                             cellforce::name_list(cellforce::kCutoffModeNames));
    c.set_cutoff(rc, *parsed);
  });
}

cf_status cf_add_type(cf_context* ctx, const char* name, double sigma, double epsilon, uint32_t* index) {
  return on(ctx, [&](cellforce::Context& c) {
    require(name, "type name");
    const uint32_t i = c.add_type(name, sigma, epsilon);
    if (index) *index = i;
  });
}

cf_status cf_set_pair(cf_context* ctx, uint32_t a, uint32_t b, double sigma, double epsilon) {
  return on(ctx, [&](cellforce::Context& c) { c.set_pair(a, b, sigma, epsilon); });
}

cf_status cf_set_option(cf_context* ctx, const char* key, const char* value) {
  return on(ctx, [&](cellforce::Context& c) {
    require(key, "option key");
    require(value, (std::string("value of option ") + key).c_str());
    c.set_option(key, value);
  });
}

cf_status cf_set_threads(cf_context* ctx, int threads) {
  return on(ctx, [&](cellforce::Context& c) { c.set_option("threads", std::to_string(threads)); });
}

cf_status cf_compute(cf_context* ctx, size_t n, const double* positions, const uint32_t* types,
                     double* forces, double* energy, double* virial) {
  return on(ctx, [&](cellforce::Context& c) {
    c.compute(n, positions, types, cellforce::Outputs{forces, nullptr, energy, virial});
  });
}

cf_status cf_compute_energies(cf_context* ctx, size_t n, const double* positions, const uint32_t* types,
                              double* forces, double* energies, double* energy, double* virial) {
  return on(ctx, [&](cellforce::Context& c) {
    c.compute(n, positions, types, cellforce::Outputs{forces, energies, energy, virial});
  });
}

cf_status cf_compute_local(cf_context* ctx, size_t n_local, size_t n_ghost, const double* positions,
                           const uint32_t* types, double* forces, double* energy, double* virial) {
  return on(ctx, [&](cellforce::Context& c) {
    cellforce::LocalOutputs out;
    out.forces = forces;
    out.energy = energy;
    out.virial = virial;
    c.compute_local(n_local, n_ghost, positions, types, out);
  });
}

cf_status cf_compute_local_full(cf_context* ctx, size_t n_local, size_t n_ghost, const double* positions,
                                const uint32_t* types, double* forces, double* energies, double* energy,
                                double* virial, double* virials, int accumulate) {
  return on(ctx, [&](cellforce::Context& c) {
    c.compute_local(n_local, n_ghost, positions, types,
                    cellforce::LocalOutputs{forces, energies, energy, virial, virials, accumulate != 0});
  });
}

cf_status cf_compute_device(cf_context* ctx, size_t n, const double* positions, const uint32_t* types,
                            double* forces, double* energy, double* virial, void* stream) {
  return on(ctx, [&](cellforce::Context& c) {
    c.compute_device(n, positions, types, cellforce::Outputs{forces, nullptr, energy, virial}, stream);
  });
}

namespace {

cellforce::Positions positions_as_held(const void* data, cf_scalar scalar, size_t stride) {
  if (scalar != CF_FLOAT64 && scalar != CF_FLOAT32)
    throw cellforce::Error("positions' scalar " + std::to_string(int(scalar)) +
                           " is neither CF_FLOAT64 (0) nor CF_FLOAT32 (1)");
  return {data, scalar == CF_FLOAT32 ? cellforce::Scalar::kFloat32 : cellforce::Scalar::kFloat64, stride};
}

cellforce::Types types_as_held(const void* data, cf_index index) {
  if (index != CF_UINT32 && index != CF_INT32)
    throw cellforce::Error("types' index " + std::to_string(int(index)) + " is neither CF_UINT32 (0) nor CF_INT32 (1)");
  return {data, index == CF_INT32 ? cellforce::Index::kInt32 : cellforce::Index::kUInt32};
}

}  // namespace

cf_status cf_compute_layout(cf_context* ctx, size_t n, const void* positions, cf_scalar scalar, size_t stride,
                            const void* types, cf_index index, double* forces, double* energies, double* energy,
                            double* virial) {
  return on(ctx, [&](cellforce::Context& c) {
    c.compute(n, positions_as_held(positions, scalar, stride), types_as_held(types, index),
              cellforce::Outputs{forces, energies, energy, virial});
  });
}

cf_status cf_compute_device_layout(cf_context* ctx, size_t n, const void* positions, cf_scalar scalar, size_t stride,
                                   const void* types, cf_index index, double* forces, double* energies,
                                   double* energy, double* virial, void* stream) {
  return on(ctx, [&](cellforce::Context& c) {
    c.compute_device(n, positions_as_held(positions, scalar, stride), types_as_held(types, index),
                     cellforce::Outputs{forces, energies, energy, virial}, stream);
  });
}

cf_status cf_statistics_json(cf_context* ctx, char* buffer, size_t capacity, size_t* length) {
  return on(ctx, [&](cellforce::Context& c) {
    const std::string text = c.statistics_json();
    if (length) *length = text.size();
    if (!buffer) return;
    if (capacity < text.size() + 1)
      throw cellforce::Error("statistics: a buffer of " + std::to_string(capacity) + " bytes cannot hold the " +
                             std::to_string(text.size() + 1) + " bytes of the JSON text (its length is in *length)");
    std::memcpy(buffer, text.c_str(), text.size() + 1);
  });
}

cf_status cf_synchronize(cf_context* ctx) {
  return on(ctx, [&](cellforce::Context& c) { c.synchronize(); });
}

cf_status cf_set_integrator(cf_context* ctx, const char* kind, double dt, double temperature, double friction,
                            uint64_t seed) {
  return on(ctx, [&](cellforce::Context& c) {
    require(kind, "integrator kind");
    const auto parsed = cellforce::parse_name(kind, kIntegratorNames);
    if (!parsed)
      throw cellforce::Error("integrator kind " + cellforce::quote_excerpt(kind) + " is not one of " +
                             cellforce::name_list(kIntegratorNames));
    cellforce::IntegratorOptions o;
    o.kind = *parsed;
    o.dt = dt;
    o.temperature = temperature;
    o.friction = friction;
    o.seed = seed;
    c.set_integrator(o);
  });
}

cf_status cf_set_state(cf_context* ctx, size_t n, const double* positions, const double* velocities,
                       const uint32_t* types, const double* masses, int64_t step) {
  return on(ctx, [&](cellforce::Context& c) { c.set_state(n, positions, velocities, types, masses, step); });
}

cf_status cf_step(cf_context* ctx, int64_t count) {
  return on(ctx, [&](cellforce::Context& c) { c.step(count); });
}

cf_status cf_set_positions(cf_context* ctx, size_t n, const double* positions) {
  return on(ctx, [&](cellforce::Context& c) { c.set_positions(n, positions); });
}

cf_status cf_set_velocities(cf_context* ctx, size_t n, const double* velocities) {
  return on(ctx, [&](cellforce::Context& c) { c.set_velocities(n, velocities); });
}

cf_status cf_set_external_forces(cf_context* ctx, size_t n, const double* forces) {
  return on(ctx, [&](cellforce::Context& c) { c.set_external_forces(n, forces); });
}

cf_status cf_set_external_forces_device(cf_context* ctx, size_t n, const double* forces) {
  return on(ctx, [&](cellforce::Context& c) { c.set_external_forces_device(n, forces); });
}

cf_status cf_set_external_force_callback(cf_context* ctx, cf_external_force_fn fn, void* user) {
  return on(ctx, [&](cellforce::Context& c) { c.set_external_force_callback(fn, user); });
}

cf_status cf_clear_external_force(cf_context* ctx) {
  return on(ctx, [&](cellforce::Context& c) { c.clear_external_force(); });
}

cf_status cf_get_state(cf_context* ctx, size_t n, double* positions, double* velocities, double* forces) {
  return on(ctx, [&](cellforce::Context& c) {
    require_particles(c, n, "cf_get_state");
    c.get_state(positions, velocities, forces);
  });
}

cf_status cf_state_view(cf_context* ctx, const double** positions, const double** velocities, const double** forces,
                        int* device) {
  return on(ctx, [&](cellforce::Context& c) {
    const cellforce::StateView v = c.state_view();
    if (positions) *positions = v.positions;
    if (velocities) *velocities = v.velocities;
    if (forces) *forces = v.forces;
    if (device) *device = v.device;
  });
}

cf_status cf_thermo(cf_context* ctx, double* kinetic, double* potential, double* temperature, double* pressure) {
  return on(ctx, [&](cellforce::Context& c) {
    const cellforce::Thermo t = c.thermo();
    if (kinetic) *kinetic = t.kinetic;
    if (potential) *potential = t.potential;
    if (temperature) *temperature = t.temperature;
    if (pressure) *pressure = t.pressure;
  });
}

const char* cf_last_error(const cf_context* ctx) {
  return ctx ? ctx->last_error.c_str() : create_error.c_str();
}

void cf_destroy(cf_context* ctx) { delete ctx; }

}  // extern "C"
