// The C API (include/cellforce/cellforce.h) over cellforce::Context: every call runs inside
// guard(), which turns each exception into a status and keeps its message for cf_last_error; no
// exception crosses into the caller.
#include <cellforce/cellforce.h>

#include <cellforce/cellforce.hpp>

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

cf_status cf_set_cutoff(cf_context* ctx, double rc, const char* mode) {
  return on(ctx, [&](cellforce::Context& c) {
    cellforce::CutoffMode m = cellforce::CutoffMode::kTruncate;
    if (mode) {
      const auto parsed = cellforce::parse_name(mode, cellforce::kCutoffModeNames);
      if (!parsed)
        throw cellforce::Error("cutoff mode " + cellforce::quote_excerpt(mode) + " is not one of " +
                               cellforce::name_list(cellforce::kCutoffModeNames));
      m = *parsed;
    }
    c.set_cutoff(rc, m);
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

cf_status cf_compute_device(cf_context* ctx, size_t n, const double* positions, const uint32_t* types,
                            double* forces, double* energy, double* virial, void* stream) {
  return on(ctx, [&](cellforce::Context& c) {
    c.compute_device(n, positions, types, cellforce::Outputs{forces, nullptr, energy, virial}, stream);
  });
}

cf_status cf_synchronize(cf_context* ctx) {
  return on(ctx, [&](cellforce::Context& c) { c.synchronize(); });
}

const char* cf_last_error(const cf_context* ctx) {
  return ctx ? ctx->last_error.c_str() : create_error.c_str();
}

void cf_destroy(cf_context* ctx) { delete ctx; }

}  // extern "C"
