// The backends' force job: one interface, implemented by the CPU engine (src/cpu, adapted in
// src/backends/cpu_force_engine.cpp) and the CUDA engine (cuda/, adapted in
// cuda/backend/force_engine.cpp). Layers above (the public API in src/api) hold a ForceEngine and
// never name an engine class or test for CUDA themselves.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <utility>
#include <vector>
#include <string>

#include <cellforce/options.hpp>

#include "core/engine_options.h"
#include "core/force_field.h"
#include "core/grid.h"
#include "core/reuse.h"
#include "core/system.h"
#include "backends/test_hooks.h"

namespace cellforce {

// Everything that chooses and configures an engine, typed and validated where it enters (the API,
// the scene file, the CLI); names in core/names.h.
struct EngineChoice {
  Backend backend = Backend::kAuto;
  Precision precision = Precision::kDouble;
  Accumulation accumulation = Accumulation::kJacobi;
  CellRule rule = CellRule::kTight;
  TraversalForm traversal = TraversalForm::kAuto;         // CUDA only
  SortMethod sort = SortMethod::kCub;                     // CUDA only
  ReuseOptions reuse;                                     // skin (or automatic), check, every, audit, list
  int device = 0;                                         // CUDA device ordinal
  ListMemory memory = ListMemory::kAuto;                  // CUDA pair lists' memory mode (option `memory`)
  int threads = 0;                                        // CPU: OpenMP threads of the engine's parallel
                                                          // regions (option `threads`); 0: OpenMP's default
  // CUDA: the stream (a cudaStream_t) the engine runs on, the caller's; null: the engine makes and
  // owns one. Every evaluation and, for an MD engine, every step kernel is queued on it.
  void* stream = nullptr;
  EngineTestHooks test;                                   // tests only (backends/test_hooks.h)
};

class ForceEngine {
 public:
  virtual ~ForceEngine() = default;

  // Host arrays in, host results out; throws cellforce::Error on bad input, naming the particle
  // or parameter (as CpuEngine::evaluate).
  virtual void evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                        ForceResult& result) = 0;

  // Local and ghost particles (Context::compute_local): particles 0 .. n_local - 1 of `system` are
  // the caller's own, n_local .. n - 1 its ghosts. `result` holds the locals only: forces n_local x
  // dim, energies n_local (request.energy), virials n_local x dim x dim (request.virial), each a
  // local's share (half of each of its pairs); energy and virial are the sums of those shares, so
  // a pair of two locals counts whole and a pair of a local and a ghost half (LAMMPS's newton off).
  // A pair of two ghosts is never evaluated (nor counted in stats()' pair counts). The caller has
  // checked n_local <= n.
  virtual void evaluate_local(const SystemView& system, std::size_t n_local, const ForceField& ff,
                              const Request& request, ForceResult& result) = 0;

  // Device arrays in and out, work ordered after what `stream` (a cudaStream_t; null: the legacy
  // default stream) already holds, results ready when the stream reaches the point of the call.
  // Throws cellforce::Error on a backend without a device. The host need not wait for the device:
  // problems the device finds in the arrays are raised by synchronize().
  // The positions as the caller holds them (DeviceInput): packed float64 rows are read in place,
  // others converted on the device first.
  virtual void evaluate_device(const DeviceInput& input, const ForceField& ff, const DeviceOutputs& out,
                               void* stream) = 0;
  // Waits for the work of evaluate_device() calls and throws cellforce::Error for what their
  // kernels flagged (naming the particle or pair); also makes stats() theirs. A no-op on the CPU.
  virtual void synchronize(const ForceField& ff) = 0;

  // The last evaluation's stage times; with `counts`, also the candidate and interacting pair
  // counts (the CUDA engine counts them in an extra pass over the same system, which with a skin
  // counts as one more evaluation of the structure: it may rebuild, and it uses up one of
  // `every`; the build counts it reports are the extra pass's).
  virtual PipelineStats stats(const SystemView& system, const ForceField& ff, bool counts) = 0;

  // The statistics of the last call as the engine holds them (stage times of evaluate(); pair
  // counts after visited_pairs(), and on the CPU after every evaluation).
  virtual const PipelineStats& stats() const = 0;

  // The bytes each stage buffer holds now (those that hold any; names are string literals): what
  // stats().buffer_bytes sums, asked for only when a caller wants the breakdown.
  virtual std::vector<std::pair<const char*, std::size_t>> buffers() const = 0;

  // Every pair the traversal evaluates with r < rc, once per evaluation (a pair evaluated twice
  // appears twice), as (min index, max index), in no particular order: what the coverage tests
  // compare with the brute force's pair set. With a skin the structure is rebuilt or reused as for
  // evaluate().
  virtual std::vector<std::pair<uint32_t, uint32_t>> visited_pairs(const SystemView& system,
                                                                   const ForceField& ff) = 0;

  // Reuse across a restart (the engines' reuse_state / restore_reuse).
  virtual ReuseState reuse_state() const = 0;
  virtual void restore_reuse(const SystemView& built_from, const ForceField& ff, int64_t served) = 0;

  virtual Backend backend() const = 0;             // kCpu or kCuda, never kAuto
  virtual std::string description() const = 0;    // device or threads, and the algorithm
  virtual std::string traversal() const = 0;       // CUDA: the traversal form; CPU: "-"
  virtual std::string sort() const = 0;            // CUDA: the sort; CPU: "-"
};

// The engine that `choice` names (kAuto: CUDA when a device can be used, else the CPU). Throws
// cellforce::Error when the backend cannot be used (no CUDA device, a CPU-only build) or an
// option is out of range (the skin).
// choice.reuse must be resolved (resolve_reuse: not automatic).
std::unique_ptr<ForceEngine> make_force_engine(const EngineChoice& choice);

// The backend kAuto stands for here (CUDA when a device can be used, else the CPU); others as given.
Backend resolve_backend(Backend backend);

// The lists' memory mode an MD state of n particles runs in under `choice`, for its automatic skin
// (resolve_reuse): where that skin is automatic and the backend CUDA, the CUDA engine's rule on the
// device's memory (cuda_lists_memory); else choice.memory as given.
ListMemory md_list_memory(const EngineChoice& choice, std::size_t n);

// A device stream for the engines of one owner (the Context gives it to every engine it makes,
// EngineChoice::stream, so that its force calls and MD steps share one ordered queue): made on
// choice.device for the CUDA backend, destroyed with the last copy of the handle; null for the CPU.
std::shared_ptr<void> make_engine_stream(const EngineChoice& choice);

// The backends themselves (make_force_engine picks one).
std::unique_ptr<ForceEngine> make_cpu_force_engine(const EngineChoice& choice);
#ifdef CELLFORCE_HAVE_CUDA
std::unique_ptr<ForceEngine> make_cuda_force_engine(const EngineChoice& choice);
std::string cuda_unavailable();  // empty when a CUDA device can be used; otherwise why not
bool cuda_device_pointer(const void* p);  // whether the device can use p (GpuEngine::device_pointer)
// The lists' memory mode for n particles on `device` (cuda/backend/memory_plan.h lists_memory on
// its total memory; `asked` where the device cannot be used).
ListMemory cuda_lists_memory(ListMemory asked, std::size_t n, int device);
std::shared_ptr<void> cuda_make_stream(int device);
#endif

}  // namespace cellforce
