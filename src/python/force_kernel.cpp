// ForceKernel: the public C++ API's force calls (include/cellforce/cellforce.hpp) on the caller's
// arrays where they live. Host arrays (NumPy) go through Context::compute or compute_local and give
// NumPy results; device arrays go through Context::compute_device, queued on the call's stream,
// and give arrays on that device (arrays.h). No physics of its own. Bad input is a TypeError (an
// array's type, layout or place) or a ValueError (its shape, or what the library refuses, with the
// library's message naming the particle or parameter), never a crash.
#include "bindings.h"

#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <cellforce/cellforce.hpp>

#include <algorithm>
#include <cstdint>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "arrays.h"
#include "physics.h"

namespace cellforce::python {
namespace {

namespace cf = cellforce;

// What one compute() returns, where the positions live: NumPy arrays for host positions, arrays on
// the positions' device for device positions (0-d arrays for the energy there).
struct Result {
  nb::object forces = nb::none();
  nb::object energies = nb::none();
  nb::object energy = nb::none();
  nb::object virial = nb::none();
  nb::object virials = nb::none();
};

std::string text(const char* name, const std::string& what) { return std::string(name) + ": " + what; }

class ForceKernel {
 public:
  ForceKernel(const std::vector<double>& box, nb::object periodic, double cutoff, nb::object types, nb::object pairs,
              const std::string& mixing, const std::string& mode, const std::string& precision,
              const std::string& backend, int device)
      : ctx_(box_dim(box)), device_(device), order_(device) {
    names_ = set_physics(ctx_, box, periodic, cutoff, mode, mixing, types, pairs).names;
    ctx_.set_option("precision", precision);
    ctx_.set_option("device", std::to_string(device));
    ctx_.set_option("backend", backend);
  }

  int dim() const { return ctx_.dim(); }
  int device() const { return device_; }
  const std::vector<std::string>& type_names() const { return names_; }
  std::string backend() {
    const std::lock_guard<std::mutex> lock(mutex_);
    return ctx_.backend_name();
  }
  std::string description() {
    const std::lock_guard<std::mutex> lock(mutex_);
    return ctx_.description();
  }
  nb::object statistics() {
    std::string json;
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      json = ctx_.statistics_json();
    }
    return nb::module_::import_("json").attr("loads")(json);
  }
  void synchronize() {
    {
      nb::gil_scoped_release release;
      const std::lock_guard<std::mutex> lock(mutex_);
      ctx_.synchronize();
    }
    order_.release_done();  // the calls have run: their arrays go
  }

  Result compute(nb::handle positions, nb::handle types, bool energy, bool virial, int64_t ghosts,
                 nb::handle forces, nb::handle energies, nb::handle stream) {
    const std::optional<uintptr_t> given_stream = stream_argument(stream);
    ArrayRef pos = take_array(positions, "positions", false, given_stream.value_or(1));
    const std::size_t dim = std::size_t(ctx_.dim());
    if (pos.shape.size() != 2 || pos.shape[1] != dim)
      throw nb::value_error(text("positions", "shape " + shape_text(pos.shape) + "; expected (n, " +
                                                  std::to_string(dim) + ")")
                                .c_str());
    if (pos.dtype != Dtype::kFloat64 && pos.dtype != Dtype::kFloat32)
      throw nb::type_error(text("positions", std::string("expected float64 or float32 values, not ") +
                                                 dtype_name(pos.dtype))
                               .c_str());
    const std::size_t n = pos.shape[0];
    if (ghosts < 0 || std::size_t(ghosts) > n)
      throw nb::value_error(text("n_ghost", std::to_string(ghosts) + " ghosts of " + std::to_string(n) +
                                                " particles")
                                .c_str());
    if (pos.device == -1) {
      if (given_stream)
        throw nb::value_error("stream: host positions are computed before compute() returns; a stream is for "
                              "device arrays");
      return compute_host(pos, types, energy, virial, std::size_t(ghosts), forces, energies);
    }
    if (ghosts > 0)
      throw nb::value_error("n_ghost: ghosts are computed from host arrays (NumPy); these positions are on a CUDA "
                            "device");
    return compute_device(pos, types, energy, virial, forces, energies,
                          given_stream.value_or(pos.stream.value_or(1)));
  }

 private:
  // The types argument: an int32 or uint32 array where the positions are, or (host positions) a
  // sequence of type names.
  struct TypeIndices {
    const void* data = nullptr;
    cf::Index index = cf::Index::kUInt32;
    std::vector<uint32_t> from_names;
    ArrayRef array;
  };
  TypeIndices take_types(nb::handle obj, std::size_t n, int device, uintptr_t stream) const {
    TypeIndices t;
    if (obj.is_none()) return t;
    if (nb::ndarray_check(obj) || nb::hasattr(obj, "__cuda_array_interface__")) {
      std::optional<ArrayRef> a;
      try {
        a = take_array(obj, "types", false, stream);
      } catch (const nb::builtin_exception& e) {
        // not an array of numbers (NumPy's strings, say): names, with host positions only
        if (e.type() != nb::exception_type::type_error || device != -1) throw;
      }
      if (a && (a->dtype == Dtype::kInt32 || a->dtype == Dtype::kUInt32)) {
        if (a->device != device && !(a->device == -2 && device >= 0))
          throw nb::type_error(text("types", std::string("an array ") + where(a->device) + "; the positions are " +
                                                 where(device))
                                   .c_str());
        if (a->shape.size() != 1 || a->shape[0] != n)
          throw nb::value_error(text("types", "shape " + shape_text(a->shape) + "; expected (" +
                                                  std::to_string(n) + ",)")
                                    .c_str());
        t.data = a->data;
        t.index = a->dtype == Dtype::kInt32 ? cf::Index::kInt32 : cf::Index::kUInt32;
        t.array = std::move(*a);
        return t;
      }
      if (a)  // an array of numbers of another type
        throw nb::type_error(text("types", std::string("expected int32 or uint32 indices, not ") +
                                               dtype_name(a->dtype))
                                 .c_str());
    }
    if (device != -1)
      throw nb::type_error("types: with positions on a CUDA device, None or an int32 or uint32 array of indices on "
                           "the same device");
    std::vector<std::string> names;
    if (!nb::try_cast(obj, names))
      throw nb::type_error("types: expected None, an int32 or uint32 array of indices, or a sequence of type names");
    if (names.size() != n)
      throw nb::value_error(text("types", std::to_string(names.size()) + " names for " + std::to_string(n) +
                                              " particles")
                                .c_str());
    t.from_names.reserve(n);
    for (std::size_t i = 0; i < n; ++i) {
      const auto it = std::find(names_.begin(), names_.end(), names[i]);
      if (it == names_.end())
        throw nb::value_error(text("types", "particle " + std::to_string(i) + " has the unknown type '" + names[i] +
                                                "'")
                                  .c_str());
      t.from_names.push_back(uint32_t(it - names_.begin()));
    }
    t.data = t.from_names.data();
    return t;
  }

  static std::string where(int device) {
    return device == -1 ? "on the host" : "on CUDA device " + std::to_string(device);
  }

  // A caller's output array (forces=, energies=): float64, C order, writable, `shape`, where the
  // positions are.
  static ArrayRef take_output(nb::handle obj, const char* name, const std::vector<std::size_t>& shape, int device,
                              uintptr_t stream) {
    ArrayRef a = take_array(obj, name, true, stream);
    if (a.device != device && !(a.device == -2 && device >= 0))
      throw nb::type_error(text(name, "an array " + where(a.device) + "; the positions are " + where(device)).c_str());
    if (a.dtype != Dtype::kFloat64)
      throw nb::type_error(text(name, std::string("expected float64, not ") + dtype_name(a.dtype)).c_str());
    if (a.shape != shape)
      throw nb::value_error(text(name, "shape " + shape_text(a.shape) + "; expected " + shape_text(shape)).c_str());
    return a;
  }

  Result compute_host(const ArrayRef& pos, nb::handle types, bool energy, bool virial, std::size_t n_ghost,
                      nb::handle forces, nb::handle energies) {
    const std::size_t dim = std::size_t(ctx_.dim()), n = pos.shape[0], n_local = n - n_ghost;
    const TypeIndices typ = take_types(types, n, -1, 1);
    // The caller's output arrays where given, else new ones.
    std::optional<ArrayRef> f_out, e_out;
    if (!forces.is_none()) f_out = take_output(forces, "forces", {n_local, dim}, -1, 1);
    if (!energies.is_none()) {
      if (!energy) throw nb::value_error("energies: given, but energy=False");
      e_out = take_output(energies, "energies", {n_local}, -1, 1);
    }
    std::vector<double> f(f_out ? 0 : n_local * dim), e(energy && !e_out ? n_local : 0), w(virial ? dim * dim : 0);
    double* f_data = f_out ? static_cast<double*>(f_out->data) : f.data();
    double* e_data = energy ? (e_out ? static_cast<double*>(e_out->data) : e.data()) : nullptr;
    double u = 0;
    Result r;
    if (n_ghost == 0) {
      cf::Outputs out;
      out.forces = f_data;
      out.energies = e_data;
      out.energy = energy ? &u : nullptr;
      out.virial = virial ? w.data() : nullptr;
      cf::Types t;
      t.data = typ.data;
      t.index = typ.index;
      cf::Positions p;
      p.data = pos.data;
      p.scalar = pos.dtype == Dtype::kFloat32 ? cf::Scalar::kFloat32 : cf::Scalar::kFloat64;
      {
        nb::gil_scoped_release release;  // the arrays are held (pos, typ); one thread at a time in the context
        const std::lock_guard<std::mutex> lock(mutex_);
        ctx_.compute(n, p, t, out);
      }
    } else {
      // compute_local takes float64 rows and uint32 types: the others are converted here.
      std::vector<double> x;
      const double* xs = static_cast<const double*>(pos.data);
      if (pos.dtype == Dtype::kFloat32) {
        const auto* single = static_cast<const float*>(pos.data);
        x.assign(single, single + n * dim);
        xs = x.data();
      }
      std::vector<uint32_t> ids;
      const uint32_t* ts = static_cast<const uint32_t*>(typ.data);
      if (typ.data && typ.index == cf::Index::kInt32) {
        const auto* signed_ids = static_cast<const int32_t*>(typ.data);
        ids.resize(n);
        for (std::size_t i = 0; i < n; ++i) {
          if (signed_ids[i] < 0)
            throw nb::value_error(text("types", "particle " + std::to_string(i) + " has type index " +
                                                    std::to_string(signed_ids[i]))
                                      .c_str());
          ids[i] = uint32_t(signed_ids[i]);
        }
        ts = ids.data();
      }
      std::vector<double> shares(virial ? n_local * dim * dim : 0);
      cf::LocalOutputs out;
      out.forces = f_data;
      out.energies = e_data;
      out.energy = energy ? &u : nullptr;
      out.virial = virial ? w.data() : nullptr;
      out.virials = virial ? shares.data() : nullptr;
      {
        nb::gil_scoped_release release;
        const std::lock_guard<std::mutex> lock(mutex_);
        ctx_.compute_local(n_local, n_ghost, xs, ts, out);
      }
      if (virial) r.virials = numpy_array(std::move(shares), {n_local, dim, dim});
    }
    r.forces = f_out ? nb::borrow(forces) : numpy_array(std::move(f), {n_local, dim});
    if (energy) {
      r.energies = e_out ? nb::borrow(energies) : numpy_array(std::move(e), {n_local});
      r.energy = nb::float_(u);
    }
    if (virial) r.virial = numpy_array(std::move(w), {dim, dim});
    return r;
  }

  Result compute_device(const ArrayRef& pos, nb::handle types, bool energy, bool virial, nb::handle forces,
                        nb::handle energies, uintptr_t stream) {
    if (!cuda_) {
      const std::lock_guard<std::mutex> lock(mutex_);
      cuda_ = ctx_.backend_name() == "cuda";
    }
    if (!*cuda_)
      throw nb::type_error("positions: an array on a CUDA device, but this kernel computes on the cpu backend "
                           "(ForceKernel(backend='cuda') takes device arrays)");
    if (pos.device != device_ && pos.device != -2)
      throw nb::type_error(text("positions", "an array on CUDA device " + std::to_string(pos.device) +
                                                 "; this kernel computes on device " + std::to_string(device_) +
                                                 " (ForceKernel(device=...))")
                               .c_str());
    order_.release_done();
    const std::size_t dim = std::size_t(ctx_.dim()), n = pos.shape[0];
    TypeIndices typ = take_types(types, n, device_, stream);
    std::optional<ArrayRef> f_out, e_out;
    if (!forces.is_none()) f_out = take_output(forces, "forces", {n, dim}, device_, stream);
    if (!energies.is_none()) {
      if (!energy) throw nb::value_error("energies: given, but energy=False");
      e_out = take_output(energies, "energies", {n}, device_, stream);
    }
    // The call's stream after the work on the streams the arrays' interfaces name (CAI v3: the
    // producer's stream), and the arrays held until the call has run.
    std::vector<ArrayRef> used{pos};
    if (typ.data) used.push_back(typ.array);
    if (f_out) used.push_back(*f_out);
    if (e_out) used.push_back(*e_out);
    for (const ArrayRef& a : used)
      if (a.stream) order_.after(*a.stream, stream);
    DeviceResults made(device_, stream, pos.framework);
    std::vector<std::vector<std::size_t>> shapes;
    cf::Outputs out;
    auto make = [&](std::vector<std::size_t> shape) {
      std::size_t count = 1;
      for (const std::size_t s : shape) count *= s;
      shapes.push_back(std::move(shape));
      return made.allocate(count);
    };
    out.forces = f_out ? static_cast<double*>(f_out->data) : make({n, dim});
    if (energy) {
      out.energies = e_out ? static_cast<double*>(e_out->data) : make({n});
      out.energy = make({});
    }
    if (virial) out.virial = make({dim, dim});
    cf::Positions p;
    p.data = pos.data;
    p.scalar = pos.dtype == Dtype::kFloat32 ? cf::Scalar::kFloat32 : cf::Scalar::kFloat64;
    cf::Types t;
    t.data = typ.data;
    t.index = typ.index;
    {
      nb::gil_scoped_release release;
      const std::lock_guard<std::mutex> lock(mutex_);
      ctx_.compute_device(n, p, t, out, runtime_stream(stream));
    }
    order_.hold(stream, std::move(used));
    std::vector<nb::object> arrays = made.finish(shapes);
    std::size_t next = 0;
    Result r;
    r.forces = f_out ? nb::borrow(forces) : arrays[next++];
    if (energy) {
      r.energies = e_out ? nb::borrow(energies) : arrays[next++];
      r.energy = arrays[next++];
    }
    if (virial) r.virial = arrays[next++];
    return r;
  }

  cf::Context ctx_;  // one thread at a time (mutex_): compute releases the GIL
  std::mutex mutex_;
  int device_ = 0;
  CallOrder order_;           // the device calls against the caller's streams, their arrays held
  std::optional<bool> cuda_;  // whether the backend resolved to cuda (asked at the first device call)
  std::vector<std::string> names_;
};

}  // namespace

void bind_force_kernel(nb::module_& m) {
  nb::class_<Result>(m, "Result",
                     "What ForceKernel.compute returns, in the caller's particle order (the locals only where "
                     "there are ghosts) and units, where the positions live: NumPy arrays for host positions; "
                     "for positions on a CUDA device, arrays on that device (CuPy's, PyTorch's or JAX's where the "
                     "positions were, else DLPack arrays, each taken once by a framework's from_dlpack), ready "
                     "once the call's stream reaches the call.")
      .def_ro("forces", &Result::forces,
              "(n_local, dim) float64: the force on each particle (energy / length); the forces= array where given")
      .def_ro("energies", &Result::energies,
              "(n_local,) float64 or None: each particle's share of the potential energy (half of each of its "
              "pairs); None unless energy=True")
      .def_ro("energy", &Result::energy,
              "the total potential energy (the locals' shares with ghosts): a float for host positions, a 0-d "
              "float64 device array for device positions; None unless energy=True")
      .def_ro("virial", &Result::virial,
              "(dim, dim) float64 or None: sum over pairs of r_ij (x) f_ij, energy units (with ghosts, the locals' "
              "shares); None unless virial=True")
      .def_ro("virials", &Result::virials,
              "(n_local, dim, dim) float64 or None: each local's share of the virial, with ghosts (n_ghost > 0) "
              "and virial=True");

  nb::class_<ForceKernel>(m, "ForceKernel",
                          "Lennard-Jones forces by cellforce's cell search (CPU or CUDA). The physics is fixed "
                          "at construction; compute() takes positions as NumPy arrays on the host or as device "
                          "arrays (CuPy, PyTorch, JAX, Numba: __cuda_array_interface__ or DLPack).")
      .def(nb::init<const std::vector<double>&, nb::object, double, nb::object, nb::object, const std::string&,
                    const std::string&, const std::string&, const std::string&, int>(),
           nb::arg("box"), nb::arg("periodic") = nb::none(), nb::arg("cutoff") = 2.5, nb::arg("types") = nb::none(),
           nb::arg("pairs") = nb::none(), nb::arg("mixing") = "lorentz-berthelot", nb::arg("mode") = "truncate",
           nb::arg("precision") = "double", nb::arg("backend") = "auto", nb::arg("device") = 0,
           "box: the edge lengths (2 or 3, length units); periodic: which axes wrap (default all); cutoff: "
           "pairs interact for r < cutoff; types: {name: (sigma, epsilon)} (default one type 'A': (1, 1)), "
           "indexed in the dict's order; pairs: {(a, b): (sigma, epsilon)} explicit pair values; mixing: "
           "'lorentz-berthelot' or 'geometric'; mode: 'truncate', 'shift' or 'force-shift'; precision: "
           "'single', 'mixed' or 'double'; backend: 'cpu', 'cuda' or 'auto'; device: the CUDA device's ordinal")
      .def("compute", &ForceKernel::compute, nb::arg("positions"), nb::arg("types") = nb::none(),
           nb::arg("energy") = false, nb::arg("virial") = false, nb::arg("n_ghost") = 0,
           nb::arg("forces") = nb::none(), nb::arg("energies") = nb::none(), nb::arg("stream") = nb::none(),
           "positions: (n, dim) float64 or float32, C order (length units, any periodic image), used in place: "
           "a NumPy array on the host, or an array on the kernel's CUDA device (backend 'cuda'); types: None "
           "(all the first type), (n,) int32 or uint32 indices where the positions are, or (host positions) n "
           "type names; energy, virial: also compute them; n_ghost (host positions): the last n_ghost rows are "
           "ghosts (an axis they stand in for must be open): results for the others only, a pair with a ghost "
           "counted half; forces, energies: float64 arrays where the positions are to write the results into "
           "(else new ones are made); stream (device positions): the CUDA stream to queue the call on (an "
           "integer cudaStream_t, or a CuPy, PyTorch or CUDA Python stream); default: the stream the positions' "
           "__cuda_array_interface__ names, else the legacy default stream. Host positions: returns when the "
           "results are written. Device positions: returns once the work is queued; the results are ready "
           "when the stream gets there, and a coordinate that is not finite or a type out of range is raised "
           "by the next synchronize() (the results since the last one are then not to be used). Returns a "
           "Result.")
      .def("synchronize", &ForceKernel::synchronize,
           "Waits for the device calls queued so far; raises ValueError for the first problem they found (a "
           "coordinate that is not finite, a type out of range, a pair whose force is not finite), naming the "
           "particle")
      .def("statistics", &ForceKernel::statistics,
           "The library's statistics as a dict (Context::statistics_json, docs/library.md): 'call' describes the "
           "last compute (its stages' seconds, transfer_seconds between host and device, builds, buffer bytes); "
           "after device calls, as of the last synchronize()")
      .def_prop_ro("dim", &ForceKernel::dim, "2 or 3: the box's axes, the positions' columns")
      .def_prop_ro("device", &ForceKernel::device, "the CUDA device's ordinal (backend 'cuda')")
      .def_prop_ro("type_names", &ForceKernel::type_names, "the types in index order")
      .def_prop_ro("backend", &ForceKernel::backend, "'cpu' or 'cuda': the backend in use")
      .def_prop_ro("description", &ForceKernel::description);
}

}  // namespace cellforce::python
