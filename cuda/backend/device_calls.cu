// compute_device calls whose rebuild the device decides (backend/call_graph.cuh): when a call may be
// one, the graph's capture from the engine's ordinary build and evaluation code, its launch, and
// what the host reads back (the posted sizes of the device's builds without waiting; the device's
// state when it synchronises or serves a call by its own path).
#include <cmath>
#include <cstring>

#include "backend/engine_state.cuh"
#include "core/error.h"

namespace cellforce {

bool GpuEngine::device_decides(const SystemView& system, const ForceField& ff) const {
  const Impl& s = *impl_;
  const ReuseOptions& r = options_.reuse;
  if (!options_.test.device_decides.value_or(true) || system.n == 0) return false;
  if (!(r.skin > 0) || !r.check || r.audit || r.every > 0) return false;
  if (options_.accumulation != Accumulation::kJacobi || options_.sort != SortMethod::kCub) return false;
  if (!Impl::lists(options_, system.box, ff.cutoff) || options_.test.list_count_masked.value_or(false)) return false;
  for (int a = 0; a < system.box.dim; ++a)
    if (!system.box.periodic[a]) return false;  // an open axis's grid comes from the particles' bounds
  if (s.lean || s.list_built_for != s.builds || s.list.neighbors.capacity() == 0) return false;
  return !reuse_.must_rebuild(system, ff.cutoff);
}

namespace {

// The list's array grown to `slots`, its entries kept (copied in stream order: the calls queued
// before read the old array, those after the new one, which holds the same list).
void grow_list_array(cuda::PairList& list, std::size_t slots, cudaStream_t stream) {
  DeviceBuffer<uint32_t> grown;
  grown.bind(stream);
  grown.reserve(slots);
  if (list.neighbors.capacity() > 0)
    CF_CUDA_CHECK(cudaMemcpyAsync(grown.data(), list.neighbors.data(), list.neighbors.bytes(),
                                  cudaMemcpyDeviceToDevice, stream));
  std::swap(list.neighbors, grown);
  grown.release();
}

}  // namespace

void GpuEngine::wait_decided_calls() {
  Impl& s = *impl_;
  if (s.decided_pending) CF_CUDA_CHECK(cudaStreamWaitEvent(s.stream, s.finished, 0));
}

bool GpuEngine::ready_device_call(const DeviceInput& input, const SystemView& system, const ForceField& ff,
                                  const Request& request,
                                  const DeviceOutputs& out, bool typed) {
  Impl& s = *impl_;
  settle_device_calls(false);  // the sizes the device's builds posted (the engine's stream already
                               // waits for the decided calls: evaluate_device)
  // Room for lists 1/8 longer than the last one (a liquid's lists grow as it leaves its lattice,
  // and a device build that finds no room for its list leaves the call to the cells): below it,
  // the array grows to 1/4 more, where the device's memory has it, and a list that did not fit is
  // built again at the next call; a list crowded enough for the host to decline it takes no more.
  const std::size_t n = system.n, dim = std::size_t(system.box.dim);
  if (s.call_state.capacity() == 0) {  // counters from zero
    s.call_state.reserve(1);
    CF_CUDA_CHECK(cudaMemsetAsync(s.call_state.data(), 0, sizeof(cuda::CallState), s.stream));
    s.engine_dirty = true;
  }
  cuda::PairList& list = s.list;
  const bool crowded = list.slots > 2 * list.pairs + 64 * n;
  if (!crowded && list.neighbors.capacity() < list.slots + list.slots / 8) {
    std::size_t free_bytes = 0, total_bytes = 0;
    CF_CUDA_CHECK(cudaMemGetInfo(&free_bytes, &total_bytes));
    const std::size_t want = list.slots + list.slots / 4;
    if (want * sizeof(uint32_t) + std::max<std::size_t>(free_bytes / 16, std::size_t(512) << 20) < free_bytes) {
      const bool overflowed = list.slots > list.neighbors.capacity();
      grow_list_array(list, want, s.stream);
      if (overflowed) cuda::request_build(s.call_state.data(), s.stream);
      s.engine_dirty = true;
    }
  }
  s.positions.reserve(std::max<std::size_t>(n * dim, 1));
  s.types.reserve(std::max<std::size_t>(n, 1));
  s.borrow(s.positions.data(), typed ? s.types.data() : nullptr);  // what the call's input pass writes
  const Grid& g = stats_.grid;
  auto ready = [&](auto real, auto accum) {
    using Real = decltype(real);
    using Accum = decltype(accum);
    s.upload_table<Real>(ff);
    s.reserve_cells<Real, Accum>(options_, g, n, request);  // the graph's ELSE body
    DeviceOutputs into = s.direct_outputs ? out : DeviceOutputs{};
    const DeviceInput* inside = s.input_in_graph ? &input : nullptr;
    cuda::CallGraph::Key key = s.call_key(options_, g, ff, n, request, into, inside);
    if (key != s.last_call_key) {  // room may have been taken for it, on the engine's stream
      s.engine_dirty = true;
      s.last_call_key = key;
    }
    s.call_input_inside = inside != nullptr;
    s.call_exec = s.call_graph.find(key);
    if (s.call_exec) {  // arrays the caller keeps, or takes by turns among a few: no change counted
      s.output_changes = s.input_changes = 0;
      return true;
    }
    // A kept graph for other arrays (outputs, input or both): a caller that changes them every call
    // would get a graph each call, so after a few changes the engine's own arrays serve instead.
    constexpr std::size_t kIn = Impl::kCallKeyInput, kInEnd = Impl::kCallKeyInputEnd;
    const bool outputs_only = s.call_graph.kept_differing_in(key, 0, kIn);
    const bool input_only = s.call_graph.kept_differing_in(key, kIn, kInEnd);
    const bool either = s.call_graph.kept_differing_in(key, 0, kInEnd);
    bool changed = false;
    if (s.direct_outputs && (outputs_only || (either && !input_only)) && ++s.output_changes > 2) {
      s.direct_outputs = false;  // from now on the engine's arrays, copied out
      into = DeviceOutputs{};
      changed = true;
    }
    if (s.input_in_graph && (input_only || (either && !outputs_only)) && ++s.input_changes > 2) {
      s.input_in_graph = false;  // from now on the input pass before the graph
      inside = nullptr;
      s.call_input_inside = false;
      changed = true;
    }
    if (changed) {
      key = s.call_key(options_, g, ff, n, request, into, inside);
      s.call_exec = s.call_graph.find(key);
      if (s.call_exec) return true;
    }
    if (s.call_graph.refused(key)) return false;
    try {
      s.call_exec = s.make_call_graph<Real, Accum>(options_, stats_, system, ff, request, reuse_.limit2(), into, inside,
                                                    std::move(key));
    } catch (const Error&) {  // a buffer would have grown: the host's path serves until the key changes
      return false;
    }
    return true;
  };
  switch (options_.precision) {
    case Precision::kSingle: return ready(float{}, float{});
    case Precision::kMixed: return ready(float{}, double{});
    case Precision::kDouble: break;
  }
  return ready(double{}, double{});
}

void GpuEngine::queue_device_call(const DeviceInput& input, const ForceField& ff, const DeviceOutputs& out,
                                  void* stream) {
  Impl& s = *impl_;
  const auto caller = static_cast<cudaStream_t>(stream);
  const std::size_t n = input.n, dim = std::size_t(input.box.dim);
  struct Stale {  // a throw below may leave this call's displacement in the state: set it afresh next time
    Impl& s;
    bool done = false;
    ~Stale() {
      if (!done) s.call_state_stale = true;
    }
  } stale{s};
  // The call runs on the caller's stream, after what the engine's stream queued (its flags, any
  // room taken) and after the last decided call where that ran on another stream.
  if (s.engine_dirty) {
    CF_CUDA_CHECK(cudaEventRecord(s.joined, s.stream));
    CF_CUDA_CHECK(cudaStreamWaitEvent(caller, s.joined, 0));
    s.engine_dirty = false;
  }
  if (s.decided_pending && s.decided_on != caller) CF_CUDA_CHECK(cudaStreamWaitEvent(caller, s.finished, 0));
  if (s.call_state_stale) {  // the host's path served the last call: the device's state from it
    cuda::reset_call_state(s.call_state.data(), reuse_.served(), !s.list_usable, caller);
    s.call_state_stale = false;
  }
  if (!s.call_input_inside)  // else the graph's first node
    cuda::take_call_input(input.positions, input.scalar, input.stride == 0 ? dim : input.stride, input.types, n,
                          input.box, uint32_t(ff.num_types()), s.positions.data(),
                          input.types ? s.types.data() : nullptr, s.build_positions.data(), s.flags.data(),
                          s.call_state.data(), caller);
  const Request request{out.energies || out.energy, out.virial != nullptr};
  if (!s.call_exec) throw Error("internal error: a decided call without its graph");
  s.call_graph.launch(s.call_exec, caller);
  s.call_exec = nullptr;
  if (!s.direct_outputs && n) {
    CF_CUDA_CHECK(cudaMemcpyAsync(out.forces, s.forces.data(), n * dim * sizeof(double), cudaMemcpyDeviceToDevice,
                                  caller));
    if (out.energies)
      CF_CUDA_CHECK(cudaMemcpyAsync(out.energies, s.energies.data(), n * sizeof(double), cudaMemcpyDeviceToDevice,
                                    caller));
  }
  if (request.energy || request.virial)
    cuda::write_totals(s.totals.data(), int(dim), out.energy, out.virial, caller);
  CF_CUDA_CHECK(cudaEventRecord(s.finished, caller));
  s.decided_on = caller;
  s.decided_pending = true;
  ++s.calls_unsettled;
  stale.done = true;
}

void GpuEngine::settle_device_calls(bool wait) {
  Impl& s = *impl_;
  if (s.calls_unsettled == 0) return;
  if (wait) {
    if (s.decided_pending) CF_CUDA_CHECK(cudaEventSynchronize(s.finished));
    s.decided_pending = false;
    CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  }
  // The sizes the device's last build posted: the list's figures, and a list that did not fit gets
  // an array for the next build (the cells serve until then).
  unsigned long long tag = 0;
  cuda::SizesReadback::Sizes sizes{};
  if (s.list.readback.peek(tag, sizes) && (tag & cuda::SizesReadback::kDeviceTag) && tag != s.settled_tag) {
    s.settled_tag = tag;
    cuda::PairList& list = s.list;
    const std::size_t width = std::size_t(sizes.value[0]), pairs = std::size_t(sizes.value[1]);
    const std::size_t mask_words = std::size_t(sizes.value[2]);
    const std::size_t entries_total = std::size_t(sizes.value[3]) * cuda::kGroup * cuda::kChunk;
    list.width = width;
    list.pairs = pairs;
    list.slots = entries_total;
    list.mask_words = width ? mask_words : 0;
    list.mask_words_held = width ? std::min(mask_words, list.masks.capacity()) : 0;
  }
  if (!wait) return;
  cuda::CallState state{};
  CF_CUDA_CHECK(cudaMemcpyAsync(&state, s.call_state.data(), sizeof(state), cudaMemcpyDeviceToHost, s.stream));
  CF_CUDA_CHECK(cudaStreamSynchronize(s.stream));
  reuse_.adopt(std::size_t(state.builds - s.device_builds), int64_t(state.served));
  s.device_builds = state.builds;
  s.list_overflows = std::size_t(state.overflows);
  s.list_usable = state.overflow == 0;
  s.calls_settled += s.calls_unsettled;
  s.calls_unsettled = 0;
  double d2 = 0;
  std::memcpy(&d2, &state.last_d2, sizeof d2);
  stats_.rebuilt = state.rebuilt != 0;
  stats_.max_displacement = std::sqrt(d2);
  stats_.dangerous_build = false;
  stats_.missed_pairs = stats_.repeated_pairs = 0;
  stats_.builds = reuse_.builds();
  stats_.listed = s.list_usable;
  stats_.graph_build = false;
}

std::size_t GpuEngine::device_calls() const { return impl_->calls_settled; }
std::size_t GpuEngine::call_captures() const { return impl_->call_graph.captures(); }
std::size_t GpuEngine::device_builds() const { return std::size_t(impl_->device_builds); }
std::size_t GpuEngine::list_overflows() const { return impl_->list_overflows; }

cuda::CallGraph::Key GpuEngine::Impl::call_key(const GpuOptions& o, const Grid& g, const ForceField& ff, std::size_t n,
                                               const Request& req, const DeviceOutputs& out, const DeviceInput* input) {
  cuda::CallGraph::Key key;
  cuda::add_to_key(key, out.forces);  // the evaluations write the caller's arrays
  cuda::add_to_key(key, out.energies);
  // Words kCallKeyInput .. kCallKeyInputEnd - 1: the input pass reads the caller's arrays (or none).
  cuda::add_to_key(key, input ? input->positions : nullptr);
  cuda::add_to_key(key, input ? input->types : nullptr);
  cuda::add_to_key(key, input ? input->stride : std::size_t(0));
  cuda::add_to_key(key, input ? int(input->scalar) + 1 : 0);
  for_each_buffer([&](const char*, auto& buffer) {
    cuda::add_to_key(key, buffer.data());
    cuda::add_to_key(key, buffer.capacity());
  });
  cuda::add_to_key(key, pos);
  cuda::add_to_key(key, typ);
  cuda::add_to_key(key, n);
  cuda::add_to_key(key, g.dim);
  for (int a = 0; a < kMaxDim; ++a) {
    cuda::add_to_key(key, g.n[a]);
    cuda::add_to_key(key, g.length[a]);
  }
  cuda::add_to_key(key, ff.cutoff);
  cuda::add_to_key(key, int(ff.mode));
  cuda::add_to_key(key, ff.num_types());
  cuda::add_to_key(key, int(req.energy) | int(req.virial) << 1);
  cuda::add_to_key(key, int(o.precision));
  cuda::add_to_key(key, o.reuse.skin);
  cuda::add_to_key(key, int(form));
  cuda::add_to_key(key, list.splits);
  cuda::add_to_key(key, list.threads_per_particle);
  cuda::add_to_key(key, int(list.use_masks));
  for (std::size_t i = 0; i < host_table.size(); i += sizeof(uint64_t)) {  // the pair table's values
    uint64_t word = 0;                                                      // (kernel arguments too)
    std::memcpy(&word, host_table.data() + i, std::min(sizeof word, host_table.size() - i));
    key.push_back(word);
  }
  return key;
}

template <class Real, class Accum>
cudaGraphExec_t GpuEngine::Impl::make_call_graph(const GpuOptions& o, const PipelineStats& st, const SystemView& sys,
                                      const ForceField& ff, const Request& req, double limit2,
                                      const DeviceOutputs& out, const DeviceInput* input, cuda::CallGraph::Key key) {
  // The capture queues nothing that runs now: what the captured code writes on the host is put back.
  struct Restore {
    Impl& s;
    std::size_t builds, list_built_for, width, pairs, slots;
    bool list_usable, timing;
    ~Restore() {
      s.builds = builds;
      s.list_built_for = list_built_for;
      s.list.width = width;
      s.list.pairs = pairs;
      s.list.slots = slots;
      s.list_usable = list_usable;
      s.timing = timing;
      s.plain_build = false;
      s.list.device_tag = nullptr;
      s.list.overflow = nullptr;
      s.forces_out = s.energies_out = nullptr;
      s.list_skip = nullptr;
    }
  } restore{*this, builds, list_built_for, list.width, list.pairs, list.slots, list_usable, timing};
  timing = false;      // no event nodes in a conditional body
  plain_build = true;  // the build's fixed part queued as it is, inside this capture
  cuda::CallState* state = call_state.data();
  list.device_tag = &state->builds;
  list.overflow = &state->overflow;
  forces_out = out.forces;  // the evaluations write the caller's arrays (the build writes neither)
  energies_out = out.energies;
  PipelineStats scratch = st;
  const Grid g = st.grid;
  auto decide = [&](cudaGraphConditionalHandle h) {
    if (!input) return cuda::queue_decide(state, limit2, h, stream);
    const std::size_t dim = std::size_t(sys.box.dim);
    cuda::take_call_input_and_decide(input->positions, input->scalar, input->stride == 0 ? dim : input->stride,
                                     input->types, sys.n, sys.box, uint32_t(ff.num_types()), positions.data(),
                                     input->types ? types.data() : nullptr, build_positions.data(), flags.data(), state,
                                     limit2, h, stream);
  };
  return call_graph.make(
      std::move(key), stream, decide,
      [&] {
        build(o, scratch, sys, ff, true);
        build_list<Real, Accum>(o, scratch.grid, sys, ff);
      },
      [&](cudaGraphConditionalHandle h) { cuda::queue_select(state, h, stream); },
      [&](bool kept) {
        list_usable = true;
        list_built_for = builds;
        list_skip = kept ? &state->not_listed : nullptr;
        evaluate_lists<Real, Accum>(g, sys, ff, req);
        list_skip = nullptr;
      },
      [&] { evaluate_cells<Real, Accum>(o, g, sys, ff, req); });
}

#define CF_CALL_GRAPH(Real, Accum)                                                                              \
  template cudaGraphExec_t GpuEngine::Impl::make_call_graph<Real, Accum>(const GpuOptions&, const PipelineStats&,          \
                                                              const SystemView&, const ForceField&, const Request&, \
                                                              double, const DeviceOutputs&, const DeviceInput*, \
                                                              cuda::CallGraph::Key);
CF_CALL_GRAPH(float, float)
CF_CALL_GRAPH(float, double)
CF_CALL_GRAPH(double, double)
#undef CF_CALL_GRAPH

}  // namespace cellforce
