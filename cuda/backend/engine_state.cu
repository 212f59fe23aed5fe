// GpuEngine::Impl's buffers and host bookkeeping (backend/engine_state.cuh).
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <string>

#include "backend/engine_state.cuh"
#include "core/error.h"

namespace cellforce {
namespace {

// r^2 of a pair by minimum image in double, for the close-pair error message.
double distance2(const SystemView& s, uint32_t i, uint32_t j) {
  double r2 = 0;
  for (int a = 0; a < s.box.dim; ++a) {
    const double inv_length = s.box.periodic[a] ? 1.0 / s.box.length[a] : 0.0;
    const double d = separation(s.positions[std::size_t(i) * s.box.dim + a],
                                s.positions[std::size_t(j) * s.box.dim + a], s.box.length[a], inv_length);
    r2 += d * d;
  }
  return r2;
}

}  // namespace

std::size_t GpuEngine::Impl::bytes() {
  std::size_t b = 0;
  for_each_buffer([&](const char*, const auto& buffer) { b += buffer.bytes(); });
  return b;
}

std::vector<std::pair<const char*, std::size_t>> GpuEngine::Impl::buffers() {
  std::vector<std::pair<const char*, std::size_t>> out;
  for_each_buffer([&](const char* name, const auto& buffer) {
    if (buffer.bytes()) out.emplace_back(name, buffer.bytes());
  });
  return out;
}

cuda::BuildGraph::Key GpuEngine::Impl::build_key(const GpuOptions& o, const Grid& g, const ForceField& ff, std::size_t n) {
  using cuda::add_to_key;
  cuda::BuildGraph::Key k;
  k.reserve(192);
  for (const auto v : {n, entries, max_cells, std::size_t(timing), std::size_t(form), std::size_t(multiprocessors), std::size_t(g.dim),
                       std::size_t(g.num_cells), std::size_t(g.key_bits), std::size_t(accumulate_flags),
                       std::size_t(o.precision), std::size_t(ff.num_types()), std::size_t(ff.mode),
                       std::size_t(o.test.list_splits.value_or(0)), std::size_t(o.test.list_masks.value_or(true)),
                       o.test.list_mask_words.value_or(0), std::size_t(o.test.list_threads.value_or(0))})
    add_to_key(k, v);
  for (const double v : {g.half_width, ff.cutoff, o.reuse.skin}) add_to_key(k, v);
  for (int a = 0; a < kMaxDim; ++a) {
    add_to_key(k, g.n[a]);
    for (const double v : {g.origin[a], g.cell[a], g.inv_cell[a], g.length[a], g.inv_length[a], g.half_width_cells[a]})
      add_to_key(k, v);
  }
  add_to_key(k, pos);
  add_to_key(k, typ);
  for_each_part_buffer([&](const auto& buffer) {
    add_to_key(k, static_cast<const void*>(buffer.data()));
    add_to_key(k, buffer.capacity());
  });
  return k;
}

void GpuEngine::Impl::stage_record(Event e) {
  if (!timing) return;
  if (graph.capturing()) CF_CUDA_CHECK(cudaEventRecordWithFlags(events[e], stream, cudaEventRecordExternal));
  else record(e);
}

GpuEngine::Impl::~Impl() {
  // Queued work may still use the buffers and the pinned table: stream-ordered memory is freed
  // without waiting for it, so wait here (a destructor cannot throw; errors are ignored).
  if (decided_pending) cudaEventSynchronize(finished);  // a decided call runs on the caller's stream
  if (stream) cudaStreamSynchronize(stream);
  for (cudaEvent_t e : events)
    if (e) cudaEventDestroy(e);
  if (joined) cudaEventDestroy(joined);
  if (finished) cudaEventDestroy(finished);
  if (table_copied) cudaEventDestroy(table_copied);
  if (pinned_table) cudaFreeHost(pinned_table);
  if (stream && owns_stream) cudaStreamDestroy(stream);
}

void GpuEngine::Impl::record(Event e) {
  if (!timing) return;
  CF_CUDA_CHECK(cudaEventRecord(events[e], stream));
  if (e == kDownloaded) timed_events = true;
}

double GpuEngine::Impl::seconds(Event from, Event to) const {
  float ms = 0;
  CF_CUDA_CHECK(cudaEventElapsedTime(&ms, events[from], events[to]));
  return 1e-3 * ms;
}

template <class Real>
void GpuEngine::Impl::upload_table(const ForceField& f) {
  const std::vector<LJParams<Real>> params = make_pair_table<Real>(f);
  const std::size_t bytes = params.size() * sizeof(LJParams<Real>);
  if (host_table.size() == bytes && std::memcmp(host_table.data(), params.data(), bytes) == 0) return;
  if (graph.capturing() || !graph.queuing())  // GpuEngine::build uploads it before the build's fixed
    throw Error("internal error: the pair table changed inside the build's graph");  // part: none in its graph
  CF_CUDA_CHECK(cudaEventSynchronize(table_copied));
  if (pinned_bytes < bytes) {
    if (pinned_table) CF_CUDA_CHECK(cudaFreeHost(pinned_table));
    pinned_table = nullptr;
    pinned_bytes = 0;
    CF_CUDA_CHECK(cudaMallocHost(&pinned_table, bytes));
    pinned_bytes = bytes;
  }
  host_table.resize(bytes);
  std::memcpy(host_table.data(), params.data(), bytes);
  std::memcpy(pinned_table, params.data(), bytes);
  table.reserve(bytes);
  CF_CUDA_CHECK(cudaMemcpyAsync(table.data(), pinned_table, bytes, cudaMemcpyHostToDevice, stream));
  CF_CUDA_CHECK(cudaEventRecord(table_copied, stream));
}

void GpuEngine::Impl::per_call_flags() {
  if (!accumulate_flags) return;
  accumulate_flags = false;
  plan_from_corners = false;
}

void GpuEngine::Impl::reset_flags() {
  flags.reserve(1);
  cuda::DeviceFlags* f = flags.data();
  static_assert(offsetof(cuda::DeviceFlags, bad_coordinate) == sizeof(f->bad_pair) &&
                offsetof(cuda::DeviceFlags, bad_type) == 2 * sizeof(f->bad_pair));
  CF_CUDA_CHECK(cudaMemsetAsync(f, 0, sizeof(cuda::DeviceFlags), stream));
  CF_CUDA_CHECK(cudaMemsetAsync(f, 0xff, 3 * sizeof(f->bad_pair), stream));  // "none" for the minima
}

void GpuEngine::Impl::upload_system(const SystemView& sys, const DeviceSystemView* on_device,
                                    const ForceField* check) {
  record(kStart);
  const std::size_t nd = sys.n * std::size_t(sys.box.dim);
  if (on_device) {  // borrowed: the caller keeps them unchanged until the work is done
    borrow(on_device->positions, on_device->types);
  } else {
    positions.reserve(std::max<std::size_t>(nd, 1));
    // A coordinate is finite when its exponent bits are not all ones: tested without a branch, so
    // that the check runs at the copy's pace.
    auto finite = [&](const double* chunk, std::size_t m) {
      if (!check) return true;
      uint64_t bad = 0;
      for (std::size_t k = 0; k < m; ++k) {
        uint64_t bits;
        std::memcpy(&bits, chunk + k, sizeof bits);
        bad |= uint64_t((bits & 0x7ff0000000000000ull) == 0x7ff0000000000000ull);
      }
      return bad == 0;
    };
    bool good = staging.upload(positions.data(), sys.positions, nd, stream, finite);
    if (good && sys.types) {
      types.reserve(std::max<std::size_t>(sys.n, 1));
      good = staging.upload(types.data(), sys.types, sys.n, stream, [&](const uint32_t* chunk, std::size_t m) {
        if (!check) return true;
        uint32_t most = 0;
        for (std::size_t k = 0; k < m; ++k) most = std::max(most, chunk[k]);
        return m == 0 || most < uint32_t(check->num_types());
      });
    }
    if (!good) {  // (only with a check) the error names the particle
      validate_system(sys, *check);
      throw Error("internal error: a host array failed its check on the way to the device, not on the host");
    }
    borrow(positions.data(), sys.types ? types.data() : nullptr);
  }
  record(kUploaded);
}

void GpuEngine::Impl::throw_flags(const cuda::DeviceFlags& f, const SystemView& system, const ForceField& ff,
                 Precision precision) const {
  static constexpr const char* kAxis[kMaxDim] = {"x", "y", "z"};
  if (f.impossible)
    throw Error("CUDA engine: a traversal kernel met a particle index out of range (an internal "
                "error, not bad input)");
  if (f.bad_coordinate != ~0ull)
    throw Error("particle " + std::to_string(f.bad_coordinate >> 32) + " has a non-finite " +
                kAxis[std::min<unsigned>(unsigned(f.bad_coordinate & 0xffffffffu), kMaxDim - 1)] + " coordinate");
  if (f.bad_type != ~0ull) {
    const uint32_t index = uint32_t(f.bad_type & 0xffffffffu);
    // An int32 array passes as uint32 (DeviceInput): a negative index is named as such too.
    const std::string as_int32 = index >= 0x80000000u ? " (" + std::to_string(int32_t(index)) + " as int32)" : "";
    throw Error("particle " + std::to_string(f.bad_type >> 32) + " has type index " + std::to_string(index) +
                as_int32 + " but there are " + std::to_string(ff.num_types()) + " types");
  }
  if (f.bad_pair != ~0ull) {
    const auto i = uint32_t(f.bad_pair >> 32), j = uint32_t(f.bad_pair & 0xffffffffu);
    if (system.positions) throw_close_pair(system, i, j, distance2(system, i, j), &ff, precision);
    throw Error("particles " + std::to_string(i) + " and " + std::to_string(j) +
                " are too close: the Lennard-Jones force is not finite in this precision");
  }
}

void GpuEngine::Impl::read_counts(PipelineStats& st) {
  cuda::PipelineCounts c{};
  if (entries > 0) {
    CF_CUDA_CHECK(cudaMemcpyAsync(&c, counts.data(), sizeof(c), cudaMemcpyDeviceToHost, stream));
    CF_CUDA_CHECK(cudaStreamSynchronize(stream));
  }
  st.valid_entries = std::size_t(c.valid);
  st.collision_cells = c.cell_range[1];
}

std::size_t GpuEngine::Impl::sort_scratch_bytes(std::size_t n_entries, int bits) {
  if (n_entries != sort_entries || bits != sort_bits) {
    sort_scratch = cuda::radix_sort_cub_bytes(n_entries, bits);
    sort_entries = n_entries;
    sort_bits = bits;
  }
  return sort_scratch;
}

std::vector<std::vector<uint32_t>> GpuEngine::Impl::list_partners(std::size_t n) {
  std::vector<uint32_t> rank_order, lengths, entries_of;
  std::vector<unsigned long long> rows;
  download(rank_order, list.order.data(), n, stream);
  download(lengths, list.length.data(), n, stream);
  download(rows, list.group_chunks.data(), (n + cuda::kGroup - 1) / cuda::kGroup + 1, stream);
  download(entries_of, list.neighbors.data(), list.slots, stream);
  CF_CUDA_CHECK(cudaStreamSynchronize(stream));
  std::vector<std::vector<uint32_t>> partners(n);
  for (std::size_t p = 0; p < n; ++p) {
    std::vector<uint32_t>& mine = partners[rank_order[p]];
    for (uint32_t k = 0; k < lengths[p]; ++k)
      mine.push_back(rank_order[entries_of[cuda::list_entry(rows[p / cuda::kGroup], p, k)]]);
  }
  return partners;
}

void GpuEngine::Impl::skip_build() {
  record(kCellIds);
  record(kCounted);
  record(kSorted);
  record(kCellsFound);
}

template void GpuEngine::Impl::upload_table<float>(const ForceField&);
template void GpuEngine::Impl::upload_table<double>(const ForceField&);

}  // namespace cellforce
