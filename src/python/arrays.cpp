#include "arrays.h"

#include <nanobind/ndarray.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#ifdef CELLFORCE_HAVE_CUDA
#include <cuda_runtime.h>
#endif

#include <cstring>
#include <limits>
#include <mutex>
#include <utility>

namespace cellforce::python {
namespace {

constexpr int kDLCpu = 1, kDLCuda = 2, kDLCudaManaged = 13;  // DLPack's device types

Framework framework_of(nb::handle obj) {
  const nb::handle type = reinterpret_cast<PyObject*>(Py_TYPE(obj.ptr()));
  std::string module;
  if (!nb::try_cast(nb::getattr(type, "__module__", nb::none()), module)) return Framework::kOther;
  auto starts = [&](const char* prefix) { return module.rfind(prefix, 0) == 0; };
  if (starts("cupy")) return Framework::kCupy;
  if (starts("torch")) return Framework::kTorch;
  if (starts("jax")) return Framework::kJax;
  return Framework::kOther;
}

Dtype dtype_of(const nb::dlpack::dtype& t) {
  if (t == nb::dtype<double>()) return Dtype::kFloat64;
  if (t == nb::dtype<float>()) return Dtype::kFloat32;
  if (t == nb::dtype<int32_t>()) return Dtype::kInt32;
  if (t == nb::dtype<uint32_t>()) return Dtype::kUInt32;
  return Dtype::kOther;
}

[[noreturn]] void type_error(const char* name, const std::string& what) {
  throw nb::type_error((std::string(name) + ": " + what).c_str());
}

#ifdef CELLFORCE_HAVE_CUDA
[[noreturn]] void cuda_failed(const char* call, cudaError_t err) {
  (void)cudaGetLastError();
  throw nb::builtin_exception(nb::exception_type::runtime_error,
                              (std::string(call) + " failed: " + cudaGetErrorName(err) + " (" +
                               cudaGetErrorString(err) + ")").c_str());
}
void check(cudaError_t err, const char* call) {
  if (err != cudaSuccess) cuda_failed(call, err);
}

// Calls on `device`, the caller's current device restored afterwards.
class OnDevice {
 public:
  explicit OnDevice(int device) {
    check(cudaGetDevice(&previous_), "cudaGetDevice");
    if (previous_ != device) check(cudaSetDevice(device), "cudaSetDevice");
  }
  ~OnDevice() { (void)cudaSetDevice(previous_); }
  OnDevice(const OnDevice&) = delete;
  OnDevice& operator=(const OnDevice&) = delete;

 private:
  int previous_ = 0;
};

// The same without throwing, for destructors and deleters: errors are cleared and ignored.
class OnDeviceQuietly {
 public:
  explicit OnDeviceQuietly(int device) {
    if (cudaGetDevice(&previous_) != cudaSuccess) previous_ = -1;
    if (previous_ != device) (void)cudaSetDevice(device);
  }
  ~OnDeviceQuietly() {
    if (previous_ >= 0) (void)cudaSetDevice(previous_);
    (void)cudaGetLastError();
  }
  OnDeviceQuietly(const OnDeviceQuietly&) = delete;
  OnDeviceQuietly& operator=(const OnDeviceQuietly&) = delete;

 private:
  int previous_ = -1;
};

// The module's pool on a device: stream-ordered allocations that stay with the pool when freed
// (no release threshold), so that a loop's results are served without reaching the driver.
cudaMemPool_t pool_on(int device) {
  static std::mutex mutex;
  static std::vector<cudaMemPool_t> pools;
  const std::lock_guard<std::mutex> lock(mutex);
  if (std::size_t(device) >= pools.size()) pools.resize(std::size_t(device) + 1, nullptr);
  if (!pools[std::size_t(device)]) {
    cudaMemPoolProps props{};
    props.allocType = cudaMemAllocationTypePinned;
    props.location.type = cudaMemLocationTypeDevice;
    props.location.id = device;
    cudaMemPool_t pool = nullptr;
    check(cudaMemPoolCreate(&pool, &props), "cudaMemPoolCreate");
    uint64_t keep = std::numeric_limits<uint64_t>::max();
    check(cudaMemPoolSetAttribute(pool, cudaMemPoolAttrReleaseThreshold, &keep), "cudaMemPoolSetAttribute");
    pools[std::size_t(device)] = pool;  // held for the process's life
  }
  return pools[std::size_t(device)];
}

int device_of_pointer(const void* p, const char* name) {
  cudaPointerAttributes attributes{};
  const cudaError_t err = cudaPointerGetAttributes(&attributes, p);
  if (err != cudaSuccess) {
    (void)cudaGetLastError();
    type_error(name, "__cuda_array_interface__ gives a pointer the CUDA runtime does not know (" +
                         std::string(cudaGetErrorName(err)) + ")");
  }
  if (attributes.type == cudaMemoryTypeUnregistered || attributes.type == cudaMemoryTypeHost)
    type_error(name, "__cuda_array_interface__ gives a pointer to host memory");
  return attributes.device;
}
#endif

// An array by __cuda_array_interface__ (versions 2 and 3): a C-contiguous layout, no mask.
ArrayRef from_cuda_array_interface(nb::handle obj, nb::handle cai, const char* name, bool writable) {
  ArrayRef a;
  if (!nb::isinstance<nb::dict>(cai)) type_error(name, "__cuda_array_interface__ is not a dict");
  const nb::dict d = nb::borrow<nb::dict>(cai);
  std::vector<int64_t> shape;
  std::string typestr;
  std::pair<uintptr_t, bool> data;
  if (!d.contains("shape") || !nb::try_cast(d["shape"], shape) || !d.contains("typestr") ||
      !nb::try_cast(d["typestr"], typestr) || !d.contains("data") || !nb::try_cast(d["data"], data))
    type_error(name, "__cuda_array_interface__ lacks shape, typestr or data");
  if (d.contains("mask") && !d["mask"].is_none()) type_error(name, "a masked array");
  std::size_t itemsize = 0;
  if (typestr.size() == 3 && (typestr[0] == '<' || typestr[0] == '=' || typestr[0] == '|')) {
    const std::string kind = typestr.substr(1);
    if (kind == "f8") a.dtype = Dtype::kFloat64, itemsize = 8;
    else if (kind == "f4") a.dtype = Dtype::kFloat32, itemsize = 4;
    else if (kind == "i4") a.dtype = Dtype::kInt32, itemsize = 4;
    else if (kind == "u4") a.dtype = Dtype::kUInt32, itemsize = 4;
  }
  std::size_t count = 1;
  for (const int64_t s : shape) {
    if (s < 0) type_error(name, "a negative extent in __cuda_array_interface__");
    a.shape.push_back(std::size_t(s));
    count *= std::size_t(s);
  }
  if (itemsize && d.contains("strides") && !d["strides"].is_none()) {  // (another dtype: the caller names it)
    std::vector<int64_t> strides;
    if (!nb::try_cast(d["strides"], strides) || strides.size() != shape.size())
      type_error(name, "__cuda_array_interface__'s strides are not one per axis");
    int64_t expected = int64_t(itemsize);
    for (std::size_t k = shape.size(); k-- > 0;) {
      if (shape[k] > 1 && strides[k] != expected)
        type_error(name, "expected a C-contiguous array (rows packed, in C order); copy it first, e.g. "
                         "cupy.ascontiguousarray");
      expected *= shape[k];
    }
  }
  if (d.contains("stream") && !d["stream"].is_none()) {
    uintptr_t s = 0;
    if (!nb::try_cast(d["stream"], s)) type_error(name, "__cuda_array_interface__'s stream is not an integer");
    a.stream = s;
  }
  if (writable && data.second) type_error(name, "a read-only array; the results need a writable one");
  a.data = reinterpret_cast<void*>(data.first);
  a.writable = !data.second;
  a.framework = framework_of(obj);
  a.keep = nb::borrow(obj);
#ifdef CELLFORCE_HAVE_CUDA
  a.device = (a.data == nullptr && count == 0) ? -2 : device_of_pointer(a.data, name);
#else
  (void)count;
  throw nb::builtin_exception(nb::exception_type::runtime_error,
                              (std::string(name) + ": a CUDA array, but this cellforce was built without CUDA")
                                  .c_str());
#endif
  return a;
}

// (device type, id) of a DLPack producer, or nullopt when it has no __dlpack_device__.
std::optional<std::pair<int, int>> dlpack_device(nb::handle obj) {
  if (!nb::hasattr(obj, "__dlpack_device__")) return std::nullopt;
  std::pair<int, int> where;
  try {
    if (nb::try_cast(obj.attr("__dlpack_device__")(), where)) return where;
  } catch (const nb::python_error&) {
  }
  return std::nullopt;
}

ArrayRef from_ndarray(nb::handle source, nb::handle obj, const char* name, bool writable, int device) {
  ArrayRef a;
  if (writable) {
    nb::ndarray<nb::c_contig> array;
    if (!nb::try_cast(source, array, false))
      type_error(name, "expected a writable C-contiguous array (rows packed, in C order)");
    if (device < 0 && array.device_type() != nb::device::cpu::value)
      type_error(name, "an array that is not in host memory; expected the host or a CUDA device");
    a.data = array.data();
    a.dtype = dtype_of(array.dtype());
    for (std::size_t k = 0; k < array.ndim(); ++k) a.shape.push_back(array.shape(k));
    a.imported = nb::ndarray<nb::ro>(array);
    a.writable = true;
  } else {
    nb::ndarray<nb::ro, nb::c_contig> array;
    if (!nb::try_cast(source, array, false))
      type_error(name, "expected a C-contiguous array (rows packed, in C order): NumPy on the host, or CuPy, "
                       "PyTorch, JAX or any __cuda_array_interface__ / DLPack array on a CUDA device");
    if (device < 0 && array.device_type() != nb::device::cpu::value)
      type_error(name, "an array that is not in host memory; expected the host or a CUDA device");
    a.data = const_cast<void*>(array.data());
    a.dtype = dtype_of(array.dtype());
    for (std::size_t k = 0; k < array.ndim(); ++k) a.shape.push_back(array.shape(k));
    a.imported = nb::ndarray<nb::ro>(array);
  }
  a.keep = nb::borrow(obj);
  a.device = device;
  a.framework = framework_of(obj);
  return a;
}

}  // namespace

bool built_with_cuda() {
#ifdef CELLFORCE_HAVE_CUDA
  return true;
#else
  return false;
#endif
}

void* runtime_stream(uintptr_t stream) {
  if (stream == 0 || stream == 1) return nullptr;  // the legacy default stream
  return reinterpret_cast<void*>(stream);           // 2: cudaStreamPerThread's handle, or a stream
}

std::optional<uintptr_t> stream_argument(nb::handle obj) {
  if (obj.is_none()) return std::nullopt;
  uintptr_t s = 0;
  if (nb::isinstance<nb::int_>(obj)) {
    if (!nb::try_cast(obj, s)) throw nb::value_error("stream: expected a cudaStream_t as a non-negative integer");
    return s == 0 ? uintptr_t(1) : s;
  }
  if (nb::hasattr(obj, "__cuda_stream__")) {  // the CUDA Python protocol: (version, handle)
    std::pair<int, uintptr_t> v;
    if (nb::try_cast(obj.attr("__cuda_stream__")(), v)) return v.second == 0 ? uintptr_t(1) : v.second;
  }
  for (const char* attribute : {"cuda_stream", "ptr"})  // PyTorch's, CuPy's
    if (nb::hasattr(obj, attribute) && nb::try_cast(obj.attr(attribute), s)) return s == 0 ? uintptr_t(1) : s;
  throw nb::type_error("stream: expected None, a cudaStream_t as an integer, or a CuPy, PyTorch or CUDA Python "
                       "stream");
}

bool on_device(nb::handle obj) {
  if (nb::hasattr(obj, "__cuda_array_interface__")) return true;  // false where the property raises
  const auto where = dlpack_device(obj);
  return where && (where->first == kDLCuda || where->first == kDLCudaManaged);
}

ArrayRef take_array(nb::handle obj, const char* name, bool writable, uintptr_t stream) {
  // A device array: its __cuda_array_interface__ where it has one (it may name the stream its
  // work is on), else DLPack, asked for in the order of the call's stream.
  // An interface that names no stream (PyTorch's, version 2) says nothing of the producer's
  // stream: DLPack, where the object has it, orders the producer's work before the call's stream.
  PyObject* cai = PyObject_GetAttrString(obj.ptr(), "__cuda_array_interface__");
  if (cai) {
    const nb::object interface = nb::steal(cai);
    const bool names_stream = nb::isinstance<nb::dict>(interface) && nb::borrow<nb::dict>(interface).contains("stream");
    if (names_stream || !nb::hasattr(obj, "__dlpack__")) return from_cuda_array_interface(obj, interface, name, writable);
  } else {
    PyErr_Clear();  // no such attribute, or a framework's refusal on a host array
  }
  const auto where = dlpack_device(obj);
  if (where && where->first != kDLCpu && where->first != kDLCuda && where->first != kDLCudaManaged)
    type_error(name, "an array on a DLPack device of type " + std::to_string(where->first) +
                         "; expected the host or a CUDA device");
  if (where && (where->first == kDLCuda || where->first == kDLCudaManaged)) {
#ifdef CELLFORCE_HAVE_CUDA
    nb::object capsule;
    try {
      capsule = obj.attr("__dlpack__")(nb::arg("stream") = stream);
    } catch (nb::python_error& e) {
      type_error(name, std::string("its __dlpack__ failed: ") + e.what());
    }
    return from_ndarray(capsule, obj, name, writable, where->second);
#else
    (void)stream;
    throw nb::builtin_exception(nb::exception_type::runtime_error,
                                (std::string(name) + ": a CUDA array, but this cellforce was built without CUDA")
                                    .c_str());
#endif
  }
  ArrayRef a = from_ndarray(obj, obj, name, writable, -1);
  return a;
}

std::string shape_text(const std::vector<std::size_t>& shape) {
  std::string s = "(";
  for (std::size_t k = 0; k < shape.size(); ++k) s += (k ? ", " : "") + std::to_string(shape[k]);
  return s + (shape.size() == 1 ? ",)" : ")");
}

const char* dtype_name(Dtype dtype) {
  switch (dtype) {
    case Dtype::kFloat64: return "float64";
    case Dtype::kFloat32: return "float32";
    case Dtype::kInt32: return "int32";
    case Dtype::kUInt32: return "uint32";
    default: return "another type";
  }
}

nb::object numpy_array(std::vector<double> values, const std::vector<std::size_t>& shape) {
  auto* owned = new std::vector<double>(std::move(values));
  nb::capsule owner(owned, [](void* p) noexcept { delete static_cast<std::vector<double>*>(p); });
  // rv_policy::reference: the array is handed out as it is, held by its owner (a moved ndarray
  // would be copied by the framework)
  return nb::cast(nb::ndarray<nb::numpy, double>(owned->data(), shape.size(), shape.data(), owner),
                  nb::rv_policy::reference);
}

// ---- results on the device ----

#ifdef CELLFORCE_HAVE_CUDA
namespace {
// The end of one call's work on its stream; the blocks of that call free their memory after it.
struct CallEnd {
  cudaEvent_t event = nullptr;
  int references = 0;
};
}  // namespace

struct DeviceResults::Block {
  double* data = nullptr;
  int device = 0;
  CallEnd* end = nullptr;  // null: the call ran on the legacy default stream, where the free is queued
};

namespace {
void release(void* p) noexcept {
  auto* block = static_cast<DeviceResults::Block*>(p);
  int previous = 0;
  if (cudaGetDevice(&previous) == cudaSuccess) {
    (void)cudaSetDevice(block->device);
    if (block->end) (void)cudaStreamWaitEvent(nullptr, block->end->event, 0);
    (void)cudaFreeAsync(block->data, nullptr);
    (void)cudaSetDevice(previous);
  }
  (void)cudaGetLastError();
  if (block->end && --block->end->references == 0) {
    (void)cudaEventDestroy(block->end->event);
    delete block->end;
  }
  delete block;
}

template <typename Framework>
nb::object device_array(double* data, const std::vector<std::size_t>& shape, nb::capsule owner, int device) {
  return nb::cast(nb::ndarray<Framework, double>(data, shape.size(), shape.data(), owner, nullptr,
                                                 nb::dtype<double>(), nb::device::cuda::value, device),
                  nb::rv_policy::reference);  // in place, held by the owner: never copied
}
}  // namespace

DeviceResults::DeviceResults(int device, uintptr_t stream, Framework framework)
    : device_(device), stream_(runtime_stream(stream)), framework_(framework) {}

DeviceResults::~DeviceResults() {
  for (Block* b : blocks_) {  // not handed out (the call failed before queueing its work)
    OnDeviceQuietly on(b->device);
    (void)cudaFreeAsync(b->data, static_cast<cudaStream_t>(stream_));
    delete b;
  }
}

double* DeviceResults::allocate(std::size_t count) {
  OnDevice on(device_);
  void* p = nullptr;
  check(cudaMallocFromPoolAsync(&p, (count ? count : 1) * sizeof(double), pool_on(device_),
                                static_cast<cudaStream_t>(stream_)),
        "cudaMallocFromPoolAsync");
  blocks_.push_back(new Block{static_cast<double*>(p), device_, nullptr});
  return static_cast<double*>(p);
}

std::vector<nb::object> DeviceResults::finish(const std::vector<std::vector<std::size_t>>& shapes) {
  CallEnd* end = nullptr;
  if (stream_ && !blocks_.empty()) {
    OnDevice on(device_);
    cudaEvent_t event = nullptr;
    check(cudaEventCreateWithFlags(&event, cudaEventDisableTiming), "cudaEventCreateWithFlags");
    const cudaError_t recorded = cudaEventRecord(event, static_cast<cudaStream_t>(stream_));
    if (recorded != cudaSuccess) {
      (void)cudaEventDestroy(event);
      cuda_failed("cudaEventRecord", recorded);
    }
    end = new CallEnd{event, int(blocks_.size())};  // each block holds it from here on
    for (Block* b : blocks_) b->end = end;
  }
  // Each block into its capsule first (nothing here throws), then the arrays over them: a throw
  // while exporting leaves every block with an owner that frees it.
  std::vector<nb::capsule> owners;
  owners.reserve(blocks_.size());
  for (Block* b : blocks_) owners.emplace_back(b, release);
  std::vector<Block*> blocks = std::move(blocks_);
  blocks_.clear();
  std::vector<nb::object> arrays;
  for (std::size_t k = 0; k < blocks.size(); ++k) {
    Block* b = blocks[k];
    const nb::capsule& owner = owners[k];
    switch (framework_) {
      case Framework::kCupy: arrays.push_back(device_array<nb::cupy>(b->data, shapes[k], owner, device_)); break;
      case Framework::kTorch: arrays.push_back(device_array<nb::pytorch>(b->data, shapes[k], owner, device_)); break;
      case Framework::kJax: arrays.push_back(device_array<nb::jax>(b->data, shapes[k], owner, device_)); break;
      default: arrays.push_back(device_array<nb::no_framework>(b->data, shapes[k], owner, device_)); break;
    }
  }
  return arrays;
}

// ---- the order of a kernel's calls ----

CallOrder::~CallOrder() {
  OnDeviceQuietly on(device_);
  for (Held& h : held_) {
    (void)cudaEventSynchronize(static_cast<cudaEvent_t>(h.event));
    free_.push_back(h.event);
  }
  held_.clear();  // the arrays go (the GIL is held: the kernel is destroyed from Python)
  for (void* e : free_) (void)cudaEventDestroy(static_cast<cudaEvent_t>(e));
}

void* CallOrder::event() {
  if (!free_.empty()) {
    void* e = free_.back();
    free_.pop_back();
    return e;
  }
  cudaEvent_t e = nullptr;
  check(cudaEventCreateWithFlags(&e, cudaEventDisableTiming), "cudaEventCreateWithFlags");
  return e;
}

void CallOrder::after(uintptr_t producer, uintptr_t call) {
  if (runtime_stream(producer) == runtime_stream(call)) return;
  OnDevice on(device_);
  void* e = event();
  const cudaError_t recorded = cudaEventRecord(static_cast<cudaEvent_t>(e), static_cast<cudaStream_t>(runtime_stream(producer)));
  const cudaError_t waited = recorded == cudaSuccess
                                 ? cudaStreamWaitEvent(static_cast<cudaStream_t>(runtime_stream(call)),
                                                       static_cast<cudaEvent_t>(e), 0)
                                 : recorded;
  free_.push_back(e);  // reusable at once: a wait takes the event's state when it is queued
  if (waited != cudaSuccess) cuda_failed("stream: ordering the call after the array's stream", waited);
}

void CallOrder::hold(uintptr_t call, std::vector<ArrayRef> arrays) {
  OnDevice on(device_);
  void* e = event();
  const cudaError_t recorded = cudaEventRecord(static_cast<cudaEvent_t>(e), static_cast<cudaStream_t>(runtime_stream(call)));
  if (recorded != cudaSuccess) {
    free_.push_back(e);
    cuda_failed("cudaEventRecord", recorded);
  }
  held_.push_back(Held{e, std::move(arrays)});
}

void CallOrder::release_done() {
  // In the order held: a call's event completes after the earlier calls' on one stream, so the
  // first one not done ends the look (a later one on another stream waits for the next look).
  OnDeviceQuietly on(device_);
  while (!held_.empty()) {
    const cudaError_t state = cudaEventQuery(static_cast<cudaEvent_t>(held_.front().event));
    if (state == cudaErrorNotReady) break;
    free_.push_back(held_.front().event);  // done (or failed: the call's error comes with synchronize())
    held_.pop_front();
  }
  (void)cudaGetLastError();
}

#else
struct DeviceResults::Block {};
DeviceResults::DeviceResults(int device, uintptr_t, Framework framework)
    : device_(device), stream_(nullptr), framework_(framework) {}
DeviceResults::~DeviceResults() = default;
double* DeviceResults::allocate(std::size_t) {
  throw nb::builtin_exception(nb::exception_type::runtime_error, "this cellforce was built without CUDA");
}
std::vector<nb::object> DeviceResults::finish(const std::vector<std::vector<std::size_t>>&) { return {}; }
CallOrder::~CallOrder() = default;
void* CallOrder::event() { return nullptr; }
void CallOrder::after(uintptr_t, uintptr_t) {}
void CallOrder::hold(uintptr_t, std::vector<ArrayRef>) {}
void CallOrder::release_done() {}
#endif

}  // namespace cellforce::python
