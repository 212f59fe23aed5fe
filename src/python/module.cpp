// The Python module `cellforce` (its compiled part, `cellforce._cellforce`): the public C++ API
// (include/cellforce/cellforce.hpp) as ForceKernel, with NumPy arrays in and out. No physics of its
// own: every number comes from Context::compute or Context::compute_local. Bad input is a
// TypeError (an array's type or layout) or a ValueError (its shape, or what the library refuses,
// with the library's message naming the particle or parameter), never a crash.
#include <nanobind/nanobind.h>
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

namespace nb = nanobind;
namespace cf = cellforce;

namespace {

// What one compute() returns: host arrays (NumPy), each owned by its Python object.
struct Result {
  nb::object forces = nb::none();    // (n_local, dim) float64
  nb::object energies = nb::none();  // (n_local,) float64, with energy=True
  nb::object energy = nb::none();    // float, with energy=True
  nb::object virial = nb::none();    // (dim, dim) float64, with virial=True
  nb::object virials = nb::none();   // (n_local, dim, dim) float64, with virial=True and n_ghost > 0
};

// A float64 NumPy array of `shape` owning `values` (moved into a capsule).
nb::object numpy_array(std::vector<double> values, std::vector<std::size_t> shape) {
  auto* owned = new std::vector<double>(std::move(values));
  nb::capsule owner(owned, [](void* p) noexcept { delete static_cast<std::vector<double>*>(p); });
  return nb::cast(nb::ndarray<nb::numpy, double>(owned->data(), shape.size(), shape.data(), owner));
}

using HostArray = nb::ndarray<nb::ro, nb::c_contig, nb::device::cpu>;

class ForceKernel {
 public:
  ForceKernel(const std::vector<double>& box, nb::object periodic, double cutoff, nb::object types, nb::object pairs,
              const std::string& mixing, const std::string& mode, const std::string& precision,
              const std::string& backend)
      : ctx_(check_dim(box)) {
    const std::size_t dim = box.size();
    bool p[3] = {true, true, true};
    if (!periodic.is_none()) {  // any sequence of truth values (a list, NumPy's bools, ASE's atoms.pbc)
      std::size_t count = 0;
      try {
        for (nb::handle axis : nb::iter(periodic)) {
          if (count < 3) p[count] = PyObject_IsTrue(axis.ptr()) == 1;
          ++count;
        }
      } catch (const nb::python_error&) {
        throw nb::type_error("periodic: expected a sequence of truth values, one per axis");
      }
      if (count != dim)
        throw nb::value_error(("periodic: " + std::to_string(count) + " values for a box of " + std::to_string(dim) +
                               " axes").c_str());
    }
    ctx_.set_box(box.data(), p);
    ctx_.set_option("cutoff-mode", mode);
    ctx_.set_cutoff(cutoff);
    ctx_.set_option("mixing", mixing);
    ctx_.set_option("precision", precision);
    ctx_.set_option("backend", backend);
    // Types in the order given (a dict keeps it): a type's index is its place in that order.
    if (types.is_none()) {
      names_.push_back("A");
      ctx_.add_type("A", 1.0, 1.0);
    } else {
      if (!nb::isinstance<nb::dict>(types)) throw nb::type_error("types: expected {name: (sigma, epsilon)}");
      const nb::dict given = nb::borrow<nb::dict>(types);
      if (given.size() == 0) throw nb::value_error("types: no particle type given");
      for (const auto& [key, value] : given) {
        std::string name;
        std::pair<double, double> se;
        if (!nb::try_cast(key, name) || !nb::try_cast(value, se))
          throw nb::type_error("types: expected {name: (sigma, epsilon)}");
        ctx_.add_type(name, se.first, se.second);
        names_.push_back(std::move(name));
      }
    }
    if (!pairs.is_none() && !nb::isinstance<nb::dict>(pairs))
      throw nb::type_error("pairs: expected {(name, name): (sigma, epsilon)}");
    if (!pairs.is_none())
      for (const auto& [key, value] : nb::borrow<nb::dict>(pairs)) {
        std::pair<std::string, std::string> ab;
        std::pair<double, double> se;
        if (!nb::try_cast(key, ab) || !nb::try_cast(value, se))
          throw nb::type_error("pairs: expected {(name, name): (sigma, epsilon)}");
        ctx_.set_pair(index_of(ab.first, "pairs"), index_of(ab.second, "pairs"), se.first, se.second);
      }
  }

  int dim() const { return ctx_.dim(); }
  const std::vector<std::string>& type_names() const { return names_; }
  std::string backend() {
    const std::lock_guard<std::mutex> lock(mutex_);
    return ctx_.backend_name();
  }
  std::string description() {
    const std::lock_guard<std::mutex> lock(mutex_);
    return ctx_.description();
  }

  // positions: (n, dim) float64 or float32, C order, on the host; types: None (all the first
  // type), (n,) int32 or uint32 indices, or a sequence of type names.
  Result compute(nb::handle positions, nb::handle types, bool energy, bool virial, int64_t ghosts) {
    const std::size_t dim = std::size_t(ctx_.dim());
    const Host pos = host_positions(positions, dim);
    const std::size_t n = pos.n;
    if (ghosts < 0 || std::size_t(ghosts) > n)
      throw nb::value_error(("n_ghost: " + std::to_string(ghosts) + " ghosts of " + std::to_string(n) +
                             " particles").c_str());
    const std::size_t n_ghost = std::size_t(ghosts);
    const HostTypes typ = host_types(types, n);
    const std::size_t n_local = n - n_ghost;
    std::vector<double> f(n_local * dim), e(energy ? n_local : 0), w(virial ? dim * dim : 0);
    double u = 0;
    Result r;
    if (n_ghost == 0) {
      cf::Outputs out;
      out.forces = f.data();
      out.energies = energy ? e.data() : nullptr;
      out.energy = energy ? &u : nullptr;
      out.virial = virial ? w.data() : nullptr;
      cf::Types t;
      t.data = typ.data;
      t.index = typ.index;
      cf::Positions p;
      p.data = pos.data;
      p.scalar = pos.scalar;
      {
        nb::gil_scoped_release release;  // the arrays are held (pos, typ); one thread at a time in the context
        const std::lock_guard<std::mutex> lock(mutex_);
        ctx_.compute(n, p, t, out);
      }
    } else {
      // compute_local takes float64 rows and uint32 types: the others are converted here.
      std::vector<double> x;
      const double* xs = static_cast<const double*>(pos.data);
      if (pos.scalar == cf::Scalar::kFloat32) {
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
            throw nb::value_error(("types: particle " + std::to_string(i) + " has type index " +
                                   std::to_string(signed_ids[i])).c_str());
          ids[i] = uint32_t(signed_ids[i]);
        }
        ts = ids.data();
      }
      std::vector<double> shares(virial ? n_local * dim * dim : 0);
      cf::LocalOutputs out;
      out.forces = f.data();
      out.energies = energy ? e.data() : nullptr;
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
    r.forces = numpy_array(std::move(f), {n_local, dim});
    if (energy) {
      r.energies = numpy_array(std::move(e), {n_local});
      r.energy = nb::float_(u);
    }
    if (virial) r.virial = numpy_array(std::move(w), {dim, dim});
    return r;
  }

 private:
  static int check_dim(const std::vector<double>& box) {
    if (box.size() != 2 && box.size() != 3)
      throw nb::value_error(("box: " + std::to_string(box.size()) + " edge lengths; expected 2 or 3").c_str());
    return int(box.size());
  }

  uint32_t index_of(const std::string& name, const char* what) const {
    const auto it = std::find(names_.begin(), names_.end(), name);
    if (it == names_.end()) throw nb::value_error((std::string(what) + ": unknown type '" + name + "'").c_str());
    return uint32_t(it - names_.begin());
  }

  struct Host {
    const void* data = nullptr;
    cf::Scalar scalar = cf::Scalar::kFloat64;
    std::size_t n = 0;
    HostArray keep;  // the caller's array as exported, which the pointer is into
  };
  struct HostTypes {
    const void* data = nullptr;
    cf::Index index = cf::Index::kUInt32;
    std::vector<uint32_t> from_names;
    HostArray keep;
  };

  // positions as an (n, dim) C-contiguous float64 or float32 array on the host, used in place (no
  // conversion: another dtype or layout is refused, never copied behind the caller's back).
  Host host_positions(nb::handle obj, std::size_t dim) const {
    HostArray a;
    if (!nb::try_cast(obj, a, false))
      throw nb::type_error("positions: expected a C-contiguous NumPy array (n, dim) of float64 or float32 on the host");
    Host h;
    h.keep = a;
    if (a.ndim() != 2 || a.shape(1) != dim)
      throw nb::value_error(("positions: shape " + shape_text(a) + "; expected (n, " + std::to_string(dim) + ")").c_str());
    if (a.dtype() == nb::dtype<double>()) h.scalar = cf::Scalar::kFloat64;
    else if (a.dtype() == nb::dtype<float>()) h.scalar = cf::Scalar::kFloat32;
    else throw nb::type_error("positions: expected float64 or float32 values");
    h.data = a.data();
    h.n = a.shape(0);
    return h;
  }

  HostTypes host_types(nb::handle obj, std::size_t n) const {
    HostTypes t;
    if (obj.is_none()) return t;
    HostArray a;
    if (nb::try_cast(obj, a, false) && a.dtype() != nb::dtype<double>() && a.dtype() != nb::dtype<float>()) {
      if (a.ndim() != 1 || a.shape(0) != n)
        throw nb::value_error(("types: shape " + shape_text(a) + "; expected (" + std::to_string(n) + ",)").c_str());
      if (a.dtype() == nb::dtype<int32_t>()) t.index = cf::Index::kInt32;
      else if (a.dtype() == nb::dtype<uint32_t>()) t.index = cf::Index::kUInt32;
      else throw nb::type_error("types: expected int32 or uint32 indices (or a sequence of type names)");
      t.data = a.data();
      t.keep = a;
      return t;
    }
    std::vector<std::string> names;
    if (!nb::try_cast(obj, names))
      throw nb::type_error("types: expected None, an int32 or uint32 array of indices, or a sequence of type names");
    if (names.size() != n)
      throw nb::value_error(("types: " + std::to_string(names.size()) + " names for " + std::to_string(n) +
                             " particles").c_str());
    t.from_names.reserve(n);
    for (std::size_t i = 0; i < n; ++i) {
      const auto it = std::find(names_.begin(), names_.end(), names[i]);
      if (it == names_.end())
        throw nb::value_error(("types: particle " + std::to_string(i) + " has the unknown type '" + names[i] +
                               "'").c_str());
      t.from_names.push_back(uint32_t(it - names_.begin()));
    }
    t.data = t.from_names.data();
    t.index = cf::Index::kUInt32;
    return t;
  }

  static std::string shape_text(const HostArray& a) {
    std::string s = "(";
    for (std::size_t k = 0; k < a.ndim(); ++k) s += (k ? ", " : "") + std::to_string(a.shape(k));
    return s + (a.ndim() == 1 ? ",)" : ")");
  }

  cf::Context ctx_;  // one thread at a time (mutex_): compute releases the GIL
  std::mutex mutex_;
  std::vector<std::string> names_;
};

}  // namespace

NB_MODULE(_cellforce, m) {
  m.doc() = "cellforce's compiled part: ForceKernel over the C++ API (include/cellforce/cellforce.hpp)";
  m.attr("__version__") = CELLFORCE_VERSION_STRING;
  // The library's errors name the particle or parameter at fault: bad input is a ValueError, a
  // device that cannot be used a RuntimeError.
  nb::register_exception_translator([](const std::exception_ptr& p, void*) {
    try {
      std::rethrow_exception(p);
    } catch (const cf::DeviceError& e) {
      PyErr_SetString(PyExc_RuntimeError, e.what());
    } catch (const cf::Error& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    }
  });

  nb::class_<Result>(m, "Result",
                     "What ForceKernel.compute returns: NumPy arrays on the host, in the caller's particle order "
                     "(the locals only where there are ghosts), in the caller's units.")
      .def_ro("forces", &Result::forces, "(n_local, dim) float64: the force on each particle (energy / length)")
      .def_ro("energies", &Result::energies,
              "(n_local,) float64 or None: each particle's share of the potential energy (half of each of its "
              "pairs); None unless energy=True")
      .def_ro("energy", &Result::energy,
              "float or None: the total potential energy (the locals' shares with ghosts); None unless energy=True")
      .def_ro("virial", &Result::virial,
              "(dim, dim) float64 or None: sum over pairs of r_ij (x) f_ij, energy units (with ghosts, the locals' "
              "shares); None unless virial=True")
      .def_ro("virials", &Result::virials,
              "(n_local, dim, dim) float64 or None: each local's share of the virial, with ghosts (n_ghost > 0) "
              "and virial=True");

  nb::class_<ForceKernel>(m, "ForceKernel",
                          "Lennard-Jones forces by cellforce's cell search (CPU or CUDA). The physics is fixed "
                          "at construction; compute() takes positions as NumPy arrays.")
      .def(nb::init<const std::vector<double>&, nb::object, double, nb::object, nb::object, const std::string&,
                    const std::string&, const std::string&, const std::string&>(),
           nb::arg("box"), nb::arg("periodic") = nb::none(), nb::arg("cutoff") = 2.5, nb::arg("types") = nb::none(),
           nb::arg("pairs") = nb::none(), nb::arg("mixing") = "lorentz-berthelot", nb::arg("mode") = "truncate",
           nb::arg("precision") = "double", nb::arg("backend") = "auto",
           "box: the edge lengths (2 or 3, length units); periodic: which axes wrap (default all); cutoff: "
           "pairs interact for r < cutoff; types: {name: (sigma, epsilon)} (default one type 'A': (1, 1)), "
           "indexed in the dict's order; pairs: {(a, b): (sigma, epsilon)} explicit pair values; mixing: "
           "'lorentz-berthelot' or 'geometric'; mode: 'truncate', 'shift' or 'force-shift'; precision: "
           "'single', 'mixed' or 'double'; backend: 'cpu', 'cuda' or 'auto'")
      .def("compute", &ForceKernel::compute, nb::arg("positions"), nb::arg("types") = nb::none(),
           nb::arg("energy") = false, nb::arg("virial") = false, nb::arg("n_ghost") = 0,
           "positions: (n, dim) float64 or float32, C order, host (length units, any periodic image); types: "
           "None (all the first type), (n,) int32 or uint32 indices, or n type names; energy, virial: also "
           "compute them; n_ghost: the last n_ghost rows are ghosts (an axis they stand in for must be open): "
           "results for the others only, a pair with a ghost counted half. Returns a Result.")
      .def_prop_ro("dim", &ForceKernel::dim, "2 or 3: the box's axes, the positions' columns")
      .def_prop_ro("type_names", &ForceKernel::type_names, "the types in index order")
      .def_prop_ro("backend", &ForceKernel::backend, "'cpu' or 'cuda': the backend in use")
      .def_prop_ro("description", &ForceKernel::description);
}
