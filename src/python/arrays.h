// The Python module's arrays: a caller's array read where it lives (a NumPy array or any object
// with the buffer protocol on the host; on a CUDA device, any object with __cuda_array_interface__
// or DLPack: CuPy, PyTorch, JAX, Numba), and new result arrays made where the inputs live (NumPy on
// the host; on the device, memory of the module's own stream-ordered pool, handed out as the input's
// framework hands out arrays, or as a DLPack-capable nanobind array).
//
// Streams are integers as __cuda_array_interface__ and DLPack give them: 1 the legacy default
// stream, 2 the per-thread default stream, anything else a cudaStream_t (0 is read as 1).
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <vector>

namespace cellforce::python {

namespace nb = nanobind;

enum class Dtype : uint8_t { kFloat64, kFloat32, kInt32, kUInt32, kOther };
// Whose array an input was: results on the device are handed out as the same framework's.
enum class Framework : uint8_t { kOther, kCupy, kTorch, kJax };

// A caller's array as the module uses it: the memory in place, never a copy.
struct ArrayRef {
  void* data = nullptr;
  Dtype dtype = Dtype::kOther;
  std::vector<std::size_t> shape;
  int device = -1;  // the CUDA device that holds it; -1: the host
  bool writable = false;
  std::optional<uintptr_t> stream;  // the stream its __cuda_array_interface__ names, if any
  Framework framework = Framework::kOther;
  nb::object keep;               // the caller's object
  nb::ndarray<nb::ro> imported;  // its export (DLPack or the buffer protocol), which the pointer is into
};

// Reads `obj` (the argument `name`) where it lives. A device array exported through DLPack is asked
// for in the order of `stream` (its producer's pending work is ordered before it). A C-contiguous
// layout is required; `writable` also refuses a read-only array. TypeError names the argument.
ArrayRef take_array(nb::handle obj, const char* name, bool writable, uintptr_t stream);
// Whether `obj` is an array on a CUDA device (by __cuda_array_interface__ or __dlpack_device__).
bool on_device(nb::handle obj);
// The stream argument: None (nullopt), an integer as above, or a stream object (CuPy's .ptr,
// PyTorch's .cuda_stream, or the CUDA Python protocol's __cuda_stream__).
std::optional<uintptr_t> stream_argument(nb::handle obj);
// As the CUDA runtime takes it (a cudaStream_t): null for the legacy default stream.
void* runtime_stream(uintptr_t stream);

std::string shape_text(const std::vector<std::size_t>& shape);
const char* dtype_name(Dtype dtype);

// A float64 NumPy array of `shape` owning `values`.
nb::object numpy_array(std::vector<double> values, const std::vector<std::size_t>& shape);

// New float64 arrays on a CUDA device for one call's results, from the module's pool on that
// device, allocated in the order of `stream`. Their memory goes back to the pool when the last
// Python reference to an array goes, ordered after the call's work on `stream` (an event recorded
// there by finish()), wherever the array was used since then on other streams: those uses must be
// complete by then, as with any framework's stream-ordered memory.
class DeviceResults {
 public:
  DeviceResults(int device, uintptr_t stream, Framework framework);
  ~DeviceResults();
  DeviceResults(const DeviceResults&) = delete;
  DeviceResults& operator=(const DeviceResults&) = delete;
  // Memory for `count` doubles (at least one is allocated).
  double* allocate(std::size_t count);
  // After the call is queued: records its end on the stream and hands each allocation out, in the
  // order allocated, as an array of the shape given (an empty shape: a 0-d array).
  std::vector<nb::object> finish(const std::vector<std::vector<std::size_t>>& shapes);

 public:
  struct Block;  // one allocation (arrays.cpp)

 private:
  int device_;
  void* stream_;
  Framework framework_;
  std::vector<Block*> blocks_;
};

// The order of one kernel's device calls against the caller's streams, on one device: a call's
// stream waits for the work on the streams its arrays name (an event recorded there), and the
// arrays a call reads or writes are held until the device has run it (an event recorded on the
// call's stream), so that a caller may drop them at once, as with any framework's own calls.
class CallOrder {
 public:
  explicit CallOrder(int device) : device_(device) {}
  ~CallOrder();  // waits for the calls still holding arrays, then releases them
  CallOrder(const CallOrder&) = delete;
  CallOrder& operator=(const CallOrder&) = delete;
  // `call` waits for the work queued on `producer` so far, where they are not the same stream.
  void after(uintptr_t producer, uintptr_t call);
  // Holds `arrays` until the work queued on `call` so far has run.
  void hold(uintptr_t call, std::vector<ArrayRef> arrays);
  // Releases the arrays of the calls the device has run (all of them after a synchronisation).
  void release_done();

 private:
  void* event();  // an event of the pool (a cudaEvent_t)
  struct Held {
    void* event = nullptr;
    std::vector<ArrayRef> arrays;
  };
  int device_;
  std::deque<Held> held_;  // in the order held
  std::vector<void*> free_;
};

// Whether the module was built with the CUDA runtime (device arrays need it).
bool built_with_cuda();

}  // namespace cellforce::python
