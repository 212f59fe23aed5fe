// The CUDA engine's calls (backend/engine.h): host arrays in and out, the caller's device arrays on
// the caller's stream, and the MD engine's resident and gated evaluations. Each call plans or
// reuses the neighbour structure (core/reuse.h), runs the evaluation in the engine's precision on
// the engine's stream (backend/engine_state.cuh), and reads the kernels' flags when the host
// synchronises: a non-finite pair force becomes a close-pair error naming both particles, as on the
// CPU. The stages keep their counts in device memory (search/stages.cuh) and the buffers are sized
// by bounds the host knows from n and the grid, so that no stage waits for the host.
#include "backend/engine.h"

#include <cuda_runtime.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>
#include <utility>
#include <vector>

#include "backend/caller_arrays.cuh"
#include "backend/engine_state.cuh"
#include "core/error.h"

namespace cellforce {
namespace {

// Makes the engine's device current for a scope and restores the caller's afterwards.
class DeviceScope {
 public:
  explicit DeviceScope(int device) {
    CF_CUDA_CHECK(cudaGetDevice(&previous_));
    if (previous_ != device) CF_CUDA_CHECK(cudaSetDevice(device));
  }
  ~DeviceScope() { cudaSetDevice(previous_); }  // cannot throw; a failure shows at the next call
  DeviceScope(const DeviceScope&) = delete;
  DeviceScope& operator=(const DeviceScope&) = delete;

 private:
  int previous_ = 0;
};

}  // namespace

namespace {

// What the CUDA pipeline can hold, checked before anything runs (host and resident paths).
void check_capacity(const SystemView& system, const ForceField& ff) {
  if (ff.num_types() > cuda::kMaxStagedTypes)
    throw Error("the CUDA engine supports at most " + std::to_string(cuda::kMaxStagedTypes) +
                " particle types; the force field has " + std::to_string(ff.num_types()));
  const std::size_t entries = system.n << system.box.dim;
  if (entries > std::size_t(INT32_MAX))
    throw Error("the CUDA engine takes at most 2^31 - 1 cell-ID entries (N x 2^d): " +
                std::to_string(system.n) + " particles in " + std::to_string(system.box.dim) +
                "D make " + std::to_string(entries));
}


// Throws cellforce::DeviceError when no CUDA device can be used or `device` does not exist.
void check_device(int device) {
  const std::string why = GpuEngine::unavailable();
  if (!why.empty()) throw DeviceError("CUDA engine: " + why);
  int count = 0;
  CF_CUDA_CHECK(cudaGetDeviceCount(&count));
  if (device < 0 || device >= count)
    throw DeviceError("CUDA engine: device " + std::to_string(device) + " does not exist (" + std::to_string(count) +
                      " device(s))");
}

}  // namespace

std::shared_ptr<void> GpuEngine::make_stream(int device) {
  check_device(device);
  const DeviceScope scope(device);
  cudaStream_t stream = nullptr;
  CF_CUDA_CHECK(cudaStreamCreateWithFlags(&stream, cudaStreamNonBlocking));
  return std::shared_ptr<void>(stream, [device](void* s) {  // destroyed on its own device
    int previous = 0;
    cudaGetDevice(&previous);
    cudaSetDevice(device);
    cudaStreamDestroy(static_cast<cudaStream_t>(s));
    cudaSetDevice(previous);
  });
}

GpuEngine::GpuEngine(GpuOptions options)
    : options_(std::move(options)), reuse_(options_.reuse), impl_(std::make_unique<Impl>()) {
  validate_reuse(options_.reuse);
  if (const std::optional<int> t = options_.test.list_threads; t && *t != 1 && *t != 2 && *t != 4 && *t != 8)
    throw Error("CUDA engine: list_threads must be 1, 2, 4 or 8 threads per particle, not " + std::to_string(*t));
  if (const std::optional<int> b = options_.test.list_block; b && *b != 128 && *b != 256)
    throw Error("CUDA engine: list_block must be 128 or 256 threads a block, not " + std::to_string(*b));
  check_device(options_.device);
  const DeviceScope scope(options_.device);
  if (options_.stream) {  // the caller's: every evaluation is queued on it, and it outlives the engine
    impl_->stream = static_cast<cudaStream_t>(options_.stream);
    impl_->owns_stream = false;
  } else {
    CF_CUDA_CHECK(cudaStreamCreateWithFlags(&impl_->stream, cudaStreamNonBlocking));
  }
  CF_CUDA_CHECK(cudaDeviceGetAttribute(&impl_->multiprocessors, cudaDevAttrMultiProcessorCount,
                                       options_.device));
  int major = 0;
  CF_CUDA_CHECK(cudaDeviceGetAttribute(&major, cudaDevAttrComputeCapabilityMajor, options_.device));
  impl_->list.dependent_launch = major >= 9;
  for (cudaEvent_t& e : impl_->events) CF_CUDA_CHECK(cudaEventCreate(&e));
  CF_CUDA_CHECK(cudaEventCreateWithFlags(&impl_->joined, cudaEventDisableTiming));
  CF_CUDA_CHECK(cudaEventCreateWithFlags(&impl_->finished, cudaEventDisableTiming));
  CF_CUDA_CHECK(cudaEventCreateWithFlags(&impl_->table_copied, cudaEventDisableTiming));
  impl_->for_each_buffer([&](const char*, auto& buffer) { buffer.bind(impl_->stream); });
}

GpuEngine::~GpuEngine() {
  try {
    const DeviceScope scope(options_.device);  // the buffers are freed on their own device
    impl_.reset();
  } catch (...) {
    impl_.reset();  // a destructor cannot throw
  }
}

// Traversal and accumulation in the engine's precision, then the kernels' flags (read after a
// synchronisation): on an error the caller's result is left as it was (as the CPU engine does).
void GpuEngine::traverse(const SystemView& system, const ForceField& ff, const Request& request, bool read_flags) {
  Impl& s = *impl_;
  const Grid& g = stats_.grid;
  switch (options_.precision) {
    case Precision::kSingle: stats_.listed = s.traverse_and_sum<float, float>(options_, g, system, ff, request); break;
    case Precision::kMixed: stats_.listed = s.traverse_and_sum<float, double>(options_, g, system, ff, request); break;
    case Precision::kDouble:
      stats_.listed = s.traverse_and_sum<double, double>(options_, g, system, ff, request);
      break;
  }
  if (!read_flags) return;
  cuda::DeviceFlags flags{};
  CF_CUDA_CHECK(cudaMemcpyAsync(&flags, s.flags.data(), sizeof(flags), cudaMemcpyDeviceToHost, s.stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  s.throw_flags(flags, system, ff, options_.precision);
}

void GpuEngine::evaluate(const SystemView& system, const ForceField& ff, const Request& request,
                         ForceResult& result) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  s.per_call_flags();
  prepare(system, ff);
  traverse(system, ff, request);
  const Grid& g = stats_.grid;

  const std::size_t n = system.n, dim = std::size_t(g.dim);
  result.dim = g.dim;
  double totals[cuda::kCellSums] = {};
  if (request.energy || request.virial)
    CF_CUDA_CHECK(cudaMemcpyAsync(totals, s.totals.data(), sizeof(totals), cudaMemcpyDeviceToHost, s.stream));
  result.forces.resize(n * dim);
  result.energies.resize(request.energy ? n : 0);
  s.staging.download(result.forces.data(), s.forces.data(), n * dim, s.stream);
  s.staging.download(result.energies.data(), s.energies.data(), result.energies.size(), s.stream);
  s.record(Impl::kDownloaded);
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));

  result.energy = request.energy ? totals[0] : 0.0;
  const double no_virial[6] = {};
  set_virial(result, g.dim, request.virial ? totals + 1 : no_virial);

  finish_timing();
  s.read_counts(stats_);
  audit(system, ff);  // after the total: its host search is no part of the engine's time
}

void GpuEngine::evaluate_local(const SystemView& system, std::size_t n_local, const ForceField& ff,
                               const Request& request, ForceResult& result) {
  if (n_local > system.n)
    throw Error("internal error: " + std::to_string(n_local) + " locals of " + std::to_string(system.n) + " particles");
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  s.per_call_flags();
  prepare(system, ff, nullptr, false);
  const Grid& g = stats_.grid;
  switch (options_.precision) {
    case Precision::kSingle: s.evaluate_local<float, float>(options_, g, system, n_local, ff, request); break;
    case Precision::kMixed: s.evaluate_local<float, double>(options_, g, system, n_local, ff, request); break;
    case Precision::kDouble: s.evaluate_local<double, double>(options_, g, system, n_local, ff, request); break;
  }
  stats_.listed = false;
  const std::size_t dim = std::size_t(g.dim);
  const bool observables = request.energy || request.virial;
  cuda::DeviceFlags flags{};
  CF_CUDA_CHECK(cudaMemcpyAsync(&flags, s.flags.data(), sizeof(flags), cudaMemcpyDeviceToHost, s.stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  s.throw_flags(flags, system, ff, options_.precision);  // before the result is touched

  result.dim = g.dim;
  result.forces.resize(n_local * dim);
  result.energies.resize(request.energy ? n_local : 0);
  std::vector<double>& w6 = s.local_virials;
  w6.resize(observables ? n_local * kVirialComponents : 0);
  s.staging.download(result.forces.data(), s.forces.data(), result.forces.size(), s.stream);
  s.staging.download(result.energies.data(), s.energies.data(), result.energies.size(), s.stream);
  s.staging.download(w6.data(), s.virials.data(), w6.size(), s.stream);
  s.record(Impl::kDownloaded);
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));  // the event, for the stage times
  // The totals: the locals' shares in index order (a pair of two locals whole, with a ghost half).
  result.energy = 0;
  for (const double e : result.energies) result.energy += e;
  double w[kVirialComponents] = {};
  result.virials.assign(request.virial ? n_local * dim * dim : 0, 0.0);
  if (request.virial)
    for (std::size_t i = 0; i < n_local; ++i)
      for (int k = 0; k < kVirialComponents; ++k) {
        const double v = w6[i * kVirialComponents + std::size_t(k)];
        w[k] += v;
        const std::size_t r = std::size_t(virial_row(k)), c = std::size_t(virial_col(k));
        if (r >= dim || c >= dim) continue;
        result.virials[i * dim * dim + r * dim + c] = result.virials[i * dim * dim + c * dim + r] = v;
      }
  set_virial(result, g.dim, w);

  finish_timing();
  s.read_counts(stats_);
  stats_.candidate_pairs = std::size_t(flags.candidates);  // counted by the ghosts' traversal
  stats_.interacting_pairs = std::size_t(flags.interacting);
}

void GpuEngine::evaluate_device(const DeviceInput& input, const ForceField& ff, const DeviceOutputs& out,
                                void* stream) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  if (input.n > 0 && (!input.positions || !out.forces))
    throw Error(std::string(input.positions ? "forces" : "positions") + " is a null pointer (" +
                std::to_string(input.n) + " particles)");
  if (input.stride != 0 && input.stride < std::size_t(input.box.dim))
    throw Error("positions: a row stride of " + std::to_string(input.stride) + " elements is less than the " +
                std::to_string(input.box.dim) + " coordinates of a row");
  // Every pointer must be one the device can use: a host pointer here would fault the context.
  const std::pair<const void*, const char*> pointers[] = {{input.positions, "positions"}, {input.types, "types"},
                                                          {out.forces, "forces"}, {out.energies, "energies"},
                                                          {out.energy, "energy"}, {out.virial, "virial"}};
  for (const auto& [p, what] : pointers) {
    if (!p || (input.n == 0 && (p == input.positions || p == input.types || p == out.forces || p == out.energies)))
      continue;
    if (!device_pointer(p))
      throw Error(std::string(what) + " is not a device pointer (compute_device takes device arrays; use "
                  "compute for host arrays)");
  }
  // What can be checked without the arrays: the box, the force field, the capacity.
  const std::size_t n = input.n, dim = std::size_t(input.box.dim);
  const SystemView system{input.box, n, nullptr, nullptr};  // no host arrays: nothing reads them
  validate_physics(input.box, ff, n);
  check_capacity(system, ff);

  const Request request{out.energies || out.energy, out.virial != nullptr};
  const bool decided = device_decides(system, ff);
  if (!decided) settle_device_calls(true);  // before the host's path, and before it waits for the caller
  wait_decided_calls();  // what the engine's stream queues comes after the decided calls still queued
  if (!s.accumulate_flags) {  // flags accumulate until synchronize()
    s.reset_flags();
    s.accumulate_flags = true;
    s.engine_dirty = true;
  }
  s.plan_from_corners = true;
  s.corner_count = 0;
  // A call the device decides runs on the caller's stream (backend/device_calls.cu): its input
  // pass copies and checks the arrays and measures the displacement, its graph writes the caller's
  // outputs.
  if (decided && ready_device_call(input, system, ff, request, out, input.types != nullptr)) {
    queue_device_call(input, ff, out, stream);
    return;
  }
  settle_device_calls(true);
  s.engine_dirty = true;
  const auto caller = static_cast<cudaStream_t>(stream);
  CF_CUDA_CHECK(cudaEventRecord(s.joined, caller));  // the engine starts after the caller's work
  CF_CUDA_CHECK(cudaStreamWaitEvent(s.stream, s.joined, 0));
  // The arrays are checked on the device; what it finds is raised by synchronize(). Positions not
  // held as packed float64 rows are converted into the engine's array and read from there.
  DeviceSystemView dsys{input.box, n, static_cast<const double*>(input.positions), input.types};
  if (!input.packed()) {
    s.positions.reserve(std::max<std::size_t>(n * dim, 1));
    cuda::pack_positions(input.positions, input.scalar, input.stride == 0 ? dim : input.stride, n, int(dim),
                         s.positions.data(), s.stream);
    dsys.positions = s.positions.data();
  }
  cuda::check_input(dsys.positions, dsys.types, n, int(dim), uint32_t(ff.num_types()), s.flags.data(), s.stream);
  prepare_resident(system, ff, dsys);
  traverse(system, ff, request, false);
  if (n) {
    CF_CUDA_CHECK(cudaMemcpyAsync(out.forces, s.forces.data(), n * dim * sizeof(double),
                                  cudaMemcpyDeviceToDevice, s.stream));
    if (out.energies)
      CF_CUDA_CHECK(cudaMemcpyAsync(out.energies, s.energies.data(), n * sizeof(double),
                                    cudaMemcpyDeviceToDevice, s.stream));
  }
  if (request.energy || request.virial)  // sum_cells wrote the totals (zeros for no cells)
    cuda::write_totals(s.totals.data(), int(dim), out.energy, out.virial, s.stream);
  s.record(Impl::kDownloaded);
  CF_CUDA_CHECK(cudaEventRecord(s.finished, s.stream));
  CF_CUDA_CHECK(cudaStreamWaitEvent(caller, s.finished, 0));
  if (options_.reuse.audit && !stats_.rebuilt) {  // diagnostics: the positions come to the host
    std::vector<double> host_positions;
    std::vector<uint32_t> host_types;
    download(host_positions, dsys.positions, n * dim, s.stream);
    if (dsys.types) download(host_types, dsys.types, n, s.stream);
    CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
    audit(SystemView{dsys.box, n, host_positions.data(), dsys.types ? host_types.data() : nullptr}, ff);
  }
}

void GpuEngine::synchronize(const ForceField& ff) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  settle_device_calls(true);
  if (!s.accumulate_flags) return;
  cuda::DeviceFlags flags{};
  CF_CUDA_CHECK(cudaMemcpyAsync(&flags, s.flags.data(), sizeof(flags), cudaMemcpyDeviceToHost, s.stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  s.accumulate_flags = false;
  s.plan_from_corners = false;
  finish_timing();
  s.read_counts(stats_);
  s.throw_flags(flags, SystemView{}, ff, options_.precision);
}

void GpuEngine::evaluate_resident(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                                  const ForceField& ff, const Request& request, std::optional<double> known_d2,
                                  bool time_stages) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  s.timing = time_stages;
  struct TimedAgain {  // every other evaluation records its stage events, whatever this one throws
    Impl& s;
    ~TimedAgain() { s.timing = true; }
  } timed_again{s};
  if (!s.accumulate_flags) {  // the first resident evaluation: flags from here on accumulate
    s.reset_flags();
    s.accumulate_flags = true;
  }
  const SystemView system{box, n, nullptr, nullptr};  // no host arrays: nothing reads them
  const DeviceSystemView on_device{box, n, positions, types};
  s.plan_from_corners = true;
  s.corner_count = 0;
  prepare_resident(system, ff, on_device, known_d2);
  traverse(system, ff, request, false);
  s.record(Impl::kDownloaded);
  if (options_.reuse.audit && !stats_.rebuilt) {  // diagnostics: the positions come to the host
    std::vector<double> host_positions;
    std::vector<uint32_t> host_types;
    download(host_positions, positions, n * std::size_t(box.dim), s.stream);
    if (types) download(host_types, types, n, s.stream);
    CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
    audit(SystemView{box, n, host_positions.data(), types ? host_types.data() : nullptr}, ff);
  }
}

void GpuEngine::check_flags(const Box& box, std::size_t n, const double* positions, const ForceField& ff) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  if (!s.accumulate_flags) return;
  cuda::DeviceFlags flags{};
  CF_CUDA_CHECK(cudaMemcpyAsync(&flags, s.flags.data(), sizeof(flags), cudaMemcpyDeviceToHost, s.stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  s.reset_flags();
  if (!flags.impossible && flags.bad_pair == ~0ull) return;
  // The error path only: the positions come to the host for the message.
  std::vector<double> host;
  download(host, positions, n * std::size_t(box.dim), s.stream);
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  s.throw_flags(flags, SystemView{box, n, host.data(), nullptr}, ff, options_.precision);
}

int64_t GpuEngine::gate_steps(const Box& box, std::size_t n, const ForceField& ff) const {
  const Impl& s = *impl_;
  const ReuseOptions& r = options_.reuse;
  if (n == 0 || !r.check || r.audit || !Impl::lists(options_, box, ff.cutoff)) return 0;
  if (!s.list_usable || s.list_built_for != s.builds || !s.accumulate_flags) return 0;
  if (reuse_.must_rebuild(SystemView{box, n, nullptr, nullptr}, ff.cutoff)) return 0;
  return reuse_.remaining();
}

unsigned long long GpuEngine::gate_limit() const {
  const double limit = reuse_.limit2();
  unsigned long long bits = 0;
  std::memcpy(&bits, &limit, sizeof bits);
  return bits;
}

const double* GpuEngine::device_build_positions() const { return impl_->build_positions.data(); }

cuda::RankOrder GpuEngine::rank_order(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                                      const ForceField& ff, bool fused) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  settle_device_calls(true);  // the list in use may be one the device built
  if (!s.list_usable || s.list_built_for != s.builds)
    throw Error("internal error: rank_order() without the pair list of the structure in use");
  s.borrow(positions, types);
  const SystemView system{box, n, nullptr, nullptr};
  const Grid& g = stats_.grid;
  switch (options_.precision) {
    case Precision::kSingle: return s.rank_order<float, float>(g, system, ff, fused);
    case Precision::kMixed: return s.rank_order<float, double>(g, system, ff, fused);
    case Precision::kDouble: break;
  }
  return s.rank_order<double, double>(g, system, ff, fused);
}

void GpuEngine::unrank_forces(std::size_t n) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  if (s.lean) return;  // lean gated evaluations stored in the caller's order (rank_order)
  cuda::unrank_forces(s.list, n, stats_.grid.dim, s.forces.data(), s.stream);
}

void GpuEngine::evaluate_gated(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                               const ForceField& ff, const cuda::GateView& gate, const cuda::NextKickDrift* then) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  const SystemView system{box, n, nullptr, nullptr};
  s.borrow(positions, types);  // no timing events: the gated evaluations are not timed by stage
  const Grid& g = stats_.grid;
  const Request forces_only{false, false};
  switch (options_.precision) {
    case Precision::kSingle: s.list_forces<float, float>(g, system, ff, forces_only, gate, then); break;
    case Precision::kMixed: s.list_forces<float, double>(g, system, ff, forces_only, gate, then); break;
    case Precision::kDouble: s.list_forces<double, double>(g, system, ff, forces_only, gate, then); break;
  }
}

void GpuEngine::settle_gate(int64_t served, double served_d2) {
  if (served <= 0) return;
  reuse_.reused(served);
  stats_.rebuilt = false;
  stats_.listed = true;  // the gated evaluations walk the lists
  stats_.dangerous_build = false;
  stats_.max_displacement = std::sqrt(served_d2);
  stats_.missed_pairs = stats_.repeated_pairs = 0;
  stats_.builds = reuse_.builds();
  stats_.list_block = impl_->list.fused_block;  // 0: the chunk ran no such kernel
}

const double* GpuEngine::device_forces() const { return impl_->forces.data(); }
double* GpuEngine::device_forces_to_add() { return impl_->forces.data(); }
std::size_t GpuEngine::listed_pairs() const {
  const Impl& s = *impl_;
  return s.list_usable && s.list_built_for == s.builds ? s.list.pairs : 0;
}
std::vector<std::pair<const char*, std::size_t>> GpuEngine::buffers() const { return impl_->buffers(); }
std::size_t GpuEngine::list_masked_fills() const { return impl_->list.masked_fills; }
std::size_t GpuEngine::list_partly_masked_fills() const { return impl_->list.partly_masked_fills; }
std::size_t GpuEngine::list_masked_units() const { return impl_->list.masked_units; }
std::size_t GpuEngine::list_staged_counts() const { return impl_->list.staged_counts; }
std::size_t GpuEngine::build_replays() const { return impl_->graph.replays(); }
std::size_t GpuEngine::build_captures() const { return impl_->graph.captures(); }
const double* GpuEngine::device_totals() const { return impl_->totals.data(); }
void* GpuEngine::stream() const { return impl_->stream; }
void GpuEngine::collect_timing() {
  const DeviceScope scope(options_.device);
  if (impl_->timed_events) CF_CUDA_CHECK(cudaEventSynchronize(impl_->events[Impl::kDownloaded]));
  else CF_CUDA_CHECK(cudaStreamSynchronize(impl_->stream));
  finish_timing();
  impl_->read_counts(stats_);
}

// The stage times of the evaluation whose events were recorded last (synchronised).
void GpuEngine::finish_timing() {
  Impl& s = *impl_;
  // Pair counts come from count_pairs()/visited_pairs(), not from the force kernels.
  stats_.candidate_pairs = stats_.interacting_pairs = stats_.max_occupancy = 0;
  // The last timed evaluation's (none: zeros, its events never recorded).
  auto seconds = [&](Impl::Event from, Impl::Event to) { return s.timed_events ? s.seconds(from, to) : 0.0; };
  stats_.t_transfer = seconds(Impl::kStart, Impl::kUploaded) + seconds(Impl::kAccumulated, Impl::kDownloaded);
  stats_.t_check = seconds(Impl::kUploaded, Impl::kChecked);
  stats_.t_cell_ids = seconds(Impl::kChecked, Impl::kCellIds);
  stats_.t_count = seconds(Impl::kCellIds, Impl::kCounted);
  stats_.t_sort = seconds(Impl::kCounted, Impl::kSorted);
  stats_.t_collision_cells = seconds(Impl::kSorted, Impl::kCellsFound);
  stats_.t_traversal = seconds(Impl::kCellsFound, Impl::kTraversed);
  stats_.t_accumulate = seconds(Impl::kTraversed, Impl::kAccumulated);
  stats_.t_total = seconds(Impl::kStart, Impl::kDownloaded);
  stats_.buffer_bytes = s.bytes();
  stats_.list_pairs = listed_pairs();
  stats_.list_slots = stats_.list_pairs ? s.list.slots : 0;
  stats_.list_mask_words = stats_.list_pairs ? s.list.mask_words : 0;
  stats_.list_mask_words_held = stats_.list_pairs ? s.list.mask_words_held : 0;
}


// Validates the input, uploads it, then rebuilds the structure (stages 1-3) or keeps the last
// one: shared by evaluate() and the pair recorder.
void GpuEngine::prepare(const SystemView& system, const ForceField& ff, const DeviceSystemView* on_device,
                        bool lists) {
  Impl& s = *impl_;
  // The arrays' values are checked as they are copied to the device (upload_system), the rest here.
  validate_physics(system.box, ff, system.n);
  if (system.n > 0 && system.positions == nullptr) throw Error("positions array is null");
  check_capacity(system, ff);
  settle_device_calls(true);  // what the device decided, before the host decides
  s.call_state_stale = true;
  s.engine_dirty = true;
  s.upload_system(system, on_device, &ff);
  const bool rebuild = reuse_.decide(system, ff.cutoff, [&] {
    return cuda::max_displacement2(system.box, s.pos, s.build_positions.data(), system.n, s.cub,
                                   s.stream);
  }, stats_);
  s.record(Impl::kChecked);
  if (rebuild) {
    build(system, ff, lists);
  } else {
    s.skip_build();
    reuse_.reused();
  }
  stats_.builds = reuse_.builds();
}

// prepare() for resident evaluations: the caller validated the arrays (at the start of its run;
// drifts are checked on the device), so nothing here reads them on the host.
void GpuEngine::prepare_resident(const SystemView& system, const ForceField& ff, const DeviceSystemView& on_device,
                                 std::optional<double> known_d2) {
  Impl& s = *impl_;
  check_capacity(system, ff);
  settle_device_calls(true);  // what the device decided, before the host decides
  s.call_state_stale = true;
  s.engine_dirty = true;
  s.upload_system(system, &on_device);
  const bool rebuild = reuse_.decide(system, ff.cutoff, [&] {
    return known_d2 ? *known_d2
                    : cuda::max_displacement2(system.box, s.pos, s.build_positions.data(), system.n, s.cub, s.stream);
  }, stats_);
  s.record(Impl::kChecked);
  if (rebuild) {
    plan_corners(system.box, system.n, on_device.positions);
    build(system, ff);
  } else {
    s.skip_build();
    reuse_.reused();
  }
  stats_.builds = reuse_.builds();
}

// The grid of an open axis spans the particles: their bounds, read back (2 x dim numbers) only for
// a build; periodic axes need none.
void GpuEngine::plan_corners(const Box& box, std::size_t n, const double* positions) {
  Impl& s = *impl_;
  s.corner_count = 0;
  bool open = false;
  for (int a = 0; a < box.dim; ++a) open = open || !box.periodic[a];
  if (!open) return;
  double lo[kMaxDim], hi[kMaxDim];
  cuda::bounding_box(positions, n, box.dim, lo, hi, s.cub, s.stream);
  bool finite = true;
  for (int a = 0; a < box.dim; ++a) {
    s.corners[a] = lo[a];
    s.corners[box.dim + a] = hi[a];
    finite = finite && std::isfinite(lo[a]) && std::isfinite(hi[a]);
  }
  // A drift that diverged this step: plan one cell (the kernels clamp what they bin) and let the
  // caller's flag check name the particle.
  s.corner_count = n && finite ? 2 : 0;
}

// Stages 1-3 on the uploaded positions, the policy invalid until they complete.
void GpuEngine::build(const SystemView& system, const ForceField& ff, bool with_lists) {
  reuse_.invalidate();
  Impl& s = *impl_;
  const bool lists = with_lists && Impl::lists(options_, system.box, ff.cutoff);
  const std::size_t replays = s.graph.replays();
  stats_.graph_build = false;
  // Stages 1-3, then the list in the engine's precision; the pair table first, before the build's
  // fixed part, whose graph holds no copy of it.
  auto stages = [&](auto real, auto accum) {
    using Real = decltype(real);
    using Accum = decltype(accum);
    if (lists) s.upload_table<Real>(ff);
    s.build(options_, stats_, system, ff, lists);
    if (lists) s.build_list<Real, Accum>(options_, stats_.grid, system, ff);
  };
  try {
    switch (options_.precision) {
      case Precision::kSingle: stages(float{}, float{}); break;
      case Precision::kMixed: stages(float{}, double{}); break;
      case Precision::kDouble: stages(double{}, double{}); break;
    }
    if (s.graph.open()) throw Error("internal error: the build's fixed part did not end");
    if (!lists) {  // none built: the cells serve this structure's evaluations
      s.list_usable = false;
      s.list_built_for = s.builds;
      s.list.pairs = s.list.slots = 0;  // no figures of an older list for the decided calls' room
    }
    stats_.graph_build = s.graph.replays() > replays;
  } catch (...) {
    s.graph.abandon(s.stream);
    throw;
  }
  reuse_.built(system, ff.cutoff);
}

ReuseState GpuEngine::reuse_state() const {
  if (reuse_.served() == 0) return {};
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  ReuseState state;
  state.served = reuse_.served();
  download(state.build_positions, s.build_positions.data(), reuse_.particles() * std::size_t(stats_.grid.dim),
           s.stream);
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  return state;
}

void GpuEngine::restore_reuse(const SystemView& built_from, const ForceField& ff, int64_t served) {
  if (!reuse_.enabled()) return;
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  settle_device_calls(true);
  s.engine_dirty = true;
  s.plan_from_corners = false;  // the grid from these host positions
  validate_system(built_from, ff);
  s.upload_system(built_from);
  s.record(Impl::kChecked);
  build(built_from, ff);
  reuse_.set_served(served);
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
}

// The audit of a reused structure: pairs closer than rc now that it misses or repeats: the pair
// lists when they served this evaluation, else the cells.
void GpuEngine::audit(const SystemView& system, const ForceField& ff) {
  if (!options_.reuse.audit || stats_.rebuilt) return;
  const auto pairs = pairs_within(system, ff.cutoff);
  const ReuseAudit a = stats_.listed ? audit_lists(impl_->list_partners(system.n), pairs)
                                     : audit_reuse(stats_.grid, impl_->build_keys.data(),
                                                   impl_->build_control.data(), system, ff.cutoff, pairs);
  stats_.missed_pairs = a.missed;
  stats_.repeated_pairs = a.repeated;
}

// Runs the pair recorder; with `keep` the pairs are stored (the buffer grows to the count the
// kernel reports and the kernel reruns), without it only counted.
std::vector<std::pair<uint32_t, uint32_t>> GpuEngine::record(const SystemView& system,
                                                             const ForceField& ff, bool keep) {
  const DeviceScope scope(options_.device);
  Impl& s = *impl_;
  s.per_call_flags();
  prepare(system, ff);
  const Grid& g = stats_.grid;
  cuda::TraversalArgs<double, double> args =
      s.prepare<double, double>(g, system, ff, CutoffMode::kTruncate);
  s.read_counts(stats_);
  cuda::DeviceFlags flags{};
  for (;;) {
    if (keep) {
      s.pairs.reserve(std::max<std::size_t>(stats_.valid_entries * 8, 1024));
      args.pairs = s.pairs.data();
      args.pair_capacity = s.pairs.capacity();
    }
    cuda::record_pairs(s.form, g.dim, g.any_wrap_inside_cell(), args, s.stream);
    CF_CUDA_CHECK(cudaMemcpyAsync(&flags, s.flags.data(), sizeof(flags), cudaMemcpyDeviceToHost, s.stream));
    CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
    if (flags.impossible)
      throw Error("CUDA engine: the pair recorder met a particle index out of range (an internal error)");
    if (!keep || flags.recorded <= s.pairs.capacity()) break;
    s.pairs.reserve(std::size_t(flags.recorded));
    s.reset_flags();
  }
  std::vector<uint2> raw;
  if (keep) download(raw, s.pairs.data(), std::size_t(flags.recorded), s.stream);
  std::vector<CollisionCell> cells;
  download(cells, s.cells.data(), stats_.collision_cells, s.stream);
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  stats_.candidate_pairs = std::size_t(flags.candidates);
  stats_.interacting_pairs = std::size_t(flags.interacting);
  stats_.max_occupancy = 0;
  for (const CollisionCell& c : cells)
    stats_.max_occupancy = std::max<std::size_t>(stats_.max_occupancy, std::size_t(c.h) + c.p);
  // Stage times belong to evaluate().
  stats_.t_cell_ids = stats_.t_count = stats_.t_sort = stats_.t_collision_cells = 0;
  stats_.t_traversal = stats_.t_accumulate = stats_.t_transfer = stats_.t_total = stats_.t_check = 0;
  audit(system, ff);
  std::vector<std::pair<uint32_t, uint32_t>> pairs(raw.size());
  for (std::size_t k = 0; k < raw.size(); ++k) pairs[k] = {raw[k].x, raw[k].y};
  return pairs;
}

std::vector<std::pair<uint32_t, uint32_t>> GpuEngine::visited_pairs(const SystemView& system,
                                                                    const ForceField& ff) {
  return record(system, ff, true);
}

void GpuEngine::count_pairs(const SystemView& system, const ForceField& ff) {
  (void)record(system, ff, false);
}

TraversalForm GpuEngine::traversal() const {
  if (options_.traversal != TraversalForm::kAuto) return options_.traversal;
  return impl_->entries > 0 || stats_.builds > 0 ? impl_->form : TraversalForm::kAuto;  // auto: chosen at a build
}

std::string GpuEngine::device_name() const {
  cudaDeviceProp prop{};
  CF_CUDA_CHECK(cudaGetDeviceProperties(&prop, options_.device));
  return prop.name;
}

std::size_t GpuEngine::memory_bytes(int device) {
  // Never throws: a device that cannot be used is the engine's to report, when it is made. An
  // error one of these calls returns is cleared (a sticky one stays, for the engine to meet).
  auto ok = [](cudaError_t e) {
    if (e != cudaSuccess) (void)cudaGetLastError();
    return e == cudaSuccess;
  };
  int count = 0, previous = 0;
  if (!ok(cudaGetDeviceCount(&count)) || device < 0 || device >= count || !ok(cudaGetDevice(&previous))) return 0;
  std::size_t free_bytes = 0, total_bytes = 0;
  if (!ok(cudaSetDevice(device)) || !ok(cudaMemGetInfo(&free_bytes, &total_bytes))) total_bytes = 0;
  (void)ok(cudaSetDevice(previous));
  return total_bytes;
}

bool GpuEngine::device_pointer(const void* p) {
  cudaPointerAttributes attributes{};
  const cudaError_t err = cudaPointerGetAttributes(&attributes, p);
  if (err != cudaSuccess) (void)cudaGetLastError();
  return err == cudaSuccess && attributes.type != cudaMemoryTypeUnregistered &&
         !(attributes.type == cudaMemoryTypeHost && attributes.devicePointer == nullptr);
}

std::string GpuEngine::unavailable() {
  int count = 0;
  const cudaError_t err = cudaGetDeviceCount(&count);
  if (err != cudaSuccess) {
    (void)cudaGetLastError();  // clear the error this call left
    return std::string("no CUDA device: cudaGetDeviceCount failed with ") + cudaGetErrorName(err) +
           " (" + cudaGetErrorString(err) + ")";
  }
  if (count == 0) return "no CUDA device: cudaGetDeviceCount returned 0";
  return {};
}

}  // namespace cellforce
