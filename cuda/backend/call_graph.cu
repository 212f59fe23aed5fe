// The kernels of the decided calls (backend/call_graph.cuh): the input pass with the displacement's
// reduction (its last block deciding where it is the graph's first node), and the kernels that set
// the graph's conditions.
#include "backend/call_graph.cuh"
#include <type_traits>

#include "search/cells.cuh"
#include "search/stages.cuh"

namespace cellforce::cuda {
namespace {

constexpr int kBlock = 256;

struct Axes {
  double length[kMaxDim] = {0, 0, 0};
  double inv_length[kMaxDim] = {0, 0, 0};
};

// The call's decision, as ReusePolicy::decide with the check on: rebuild where the largest squared
// displacement exceeds (skin / 2)^2 (a NaN does not: the input check names the coordinate). The
// route (call_graph.cuh): 1 a rebuild, else 2 where the structure's list fits (no body: the list's
// kernels beside the switch run, not_listed 0), 0 where the cells serve it. One thread.
__device__ void decide_call(CallState* state, double limit2, cudaGraphConditionalHandle route) {
  const unsigned long long bits = *static_cast<volatile unsigned long long*>(&state->d2);
  const bool again = __longlong_as_double(static_cast<long long>(bits)) > limit2 || state->force != 0;
  state->force = 0;
  state->last_d2 = bits;
  state->d2 = 0;
  ++state->calls;
  state->rebuilt = again;
  if (again) {
    ++state->builds;
    state->served = 1;
  } else {
    ++state->served;
  }
  const unsigned r = again ? 1u : state->overflow ? 0u : 2u;
  state->not_listed = r != 2u;
  cudaGraphSetConditional(route, r);
}

// One thread a particle: the row converted and stored, checked, and its squared displacement; then
// the block's largest (its bits: non-negative doubles order as their bits do; a NaN counts as the
// largest and compares false with the limit, as the host's check) by one atomicMax. Decide: the
// block that finishes last then decides (decide_call), the others' maxima visible to it by their
// fences before they count themselves done.
template <int D, class T, bool Decide>
__global__ void take_input_kernel(const T* __restrict__ in, std::size_t stride, const uint32_t* __restrict__ in_types,
                                  std::size_t n, Axes axes, uint32_t num_types, double* __restrict__ positions,
                                  uint32_t* __restrict__ types, const double* __restrict__ then,
                                  DeviceFlags* flags, CallState* state, double limit2,
                                  cudaGraphConditionalHandle route) {
  const std::size_t i = std::size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  double d2 = 0;
  if (i < n) {
    bool flagged = false;
    for (int a = 0; a < D; ++a) {
      const double x = double(in[i * stride + a]);
      positions[i * D + a] = x;
      if (!isfinite(x) && !flagged) {
        atomicMin(&flags->bad_coordinate, static_cast<unsigned long long>(i) << 32 | unsigned(a));
        flagged = true;
      }
      d2 += displacement_term(x, then[i * D + a], axes.length[a], axes.inv_length[a]);
    }
    if (in_types) {
      const uint32_t t = in_types[i];
      types[i] = t;
      if (t >= num_types) atomicMin(&flags->bad_type, static_cast<unsigned long long>(i) << 32 | t);
    }
    if (!(d2 >= 0)) d2 = __longlong_as_double(0x7ff8000000000000ll);
  }
  for (int offset = 16; offset > 0; offset >>= 1) {
    const double other = __shfl_xor_sync(0xffffffffu, d2, offset);
    d2 = __double_as_longlong(other) > __double_as_longlong(d2) ? other : d2;
  }
  __shared__ double warps[kBlock / 32];
  if (threadIdx.x % 32 == 0) warps[threadIdx.x / 32] = d2;
  __syncthreads();
  if (threadIdx.x == 0) {
    for (int w = 1; w < kBlock / 32; ++w)
      if (__double_as_longlong(warps[w]) > __double_as_longlong(d2)) d2 = warps[w];
    if (d2 > 0 || d2 != d2) atomicMax(&state->d2, static_cast<unsigned long long>(__double_as_longlong(d2)));
    if constexpr (Decide) {
      __threadfence();
      if (atomicAdd(&state->blocks_done, 1ull) == gridDim.x - 1) {
        __threadfence();
        state->blocks_done = 0;
        decide_call(state, limit2, route);
      }
    }
  }
}

__global__ void decide_kernel(CallState* state, double limit2, cudaGraphConditionalHandle route) {
  if (threadIdx.x == 0) decide_call(state, limit2, route);
}

__global__ void select_kernel(const CallState* state, cudaGraphConditionalHandle lists) {
  if (threadIdx.x == 0) cudaGraphSetConditional(lists, state->overflow ? 0u : 1u);
}

__global__ void reset_kernel(CallState* state, unsigned long long served, unsigned long long overflow) {
  if (threadIdx.x != 0) return;
  state->d2 = 0;
  state->served = served;
  state->overflow = overflow;
  state->blocks_done = 0;
}

template <bool Decide>
void queue_input(const void* in, Scalar scalar, std::size_t stride, const uint32_t* in_types, std::size_t n,
                 const Box& box, uint32_t num_types, double* positions, uint32_t* types, const double* then,
                 DeviceFlags* flags, CallState* state, double limit2, cudaGraphConditionalHandle route,
                 cudaStream_t stream) {
  Axes axes;
  for (int a = 0; a < box.dim; ++a) {
    axes.length[a] = box.length[a];
    axes.inv_length[a] = box.periodic[a] ? 1.0 / box.length[a] : 0.0;
  }
  const unsigned blocks = unsigned((n + kBlock - 1) / kBlock);
  auto go = [&](auto d, auto real) {
    using T = decltype(real);
    take_input_kernel<decltype(d)::value, T, Decide><<<blocks, kBlock, 0, stream>>>(
        static_cast<const T*>(in), stride, in_types, n, axes, num_types, positions, types, then, flags, state, limit2,
        route);
  };
  const bool single = scalar == Scalar::kFloat32;
  if (box.dim == 2) {
    if (single) go(std::integral_constant<int, 2>{}, float{});
    else go(std::integral_constant<int, 2>{}, double{});
  } else {
    if (single) go(std::integral_constant<int, 3>{}, float{});
    else go(std::integral_constant<int, 3>{}, double{});
  }
  CF_CUDA_CHECK_LAUNCH();
}

}  // namespace

void take_call_input(const void* in, Scalar scalar, std::size_t stride, const uint32_t* in_types, std::size_t n,
                     const Box& box, uint32_t num_types, double* positions, uint32_t* types, const double* then,
                     DeviceFlags* flags, CallState* state, cudaStream_t stream) {
  if (n == 0) return;
  queue_input<false>(in, scalar, stride, in_types, n, box, num_types, positions, types, then, flags, state, 0.0, 0,
                     stream);
}

void take_call_input_and_decide(const void* in, Scalar scalar, std::size_t stride, const uint32_t* in_types,
                                std::size_t n, const Box& box, uint32_t num_types, double* positions, uint32_t* types,
                                const double* then, DeviceFlags* flags, CallState* state, double limit2,
                                cudaGraphConditionalHandle route, cudaStream_t stream) {
  if (n == 0) throw Error("internal error: a decided call's input pass without particles");
  queue_input<true>(in, scalar, stride, in_types, n, box, num_types, positions, types, then, flags, state, limit2,
                    route, stream);
}

void reset_call_state(CallState* state, int64_t served, bool overflow, cudaStream_t stream) {
  reset_kernel<<<1, 32, 0, stream>>>(state, static_cast<unsigned long long>(served), overflow ? 1ull : 0ull);
  CF_CUDA_CHECK_LAUNCH();
}

__global__ void request_kernel(CallState* state) {
  if (threadIdx.x == 0) state->force = 1;
}

void request_build(CallState* state, cudaStream_t stream) {
  request_kernel<<<1, 32, 0, stream>>>(state);
  CF_CUDA_CHECK_LAUNCH();
}

void queue_decide(CallState* state, double limit2, cudaGraphConditionalHandle route, cudaStream_t stream) {
  decide_kernel<<<1, 32, 0, stream>>>(state, limit2, route);
  CF_CUDA_CHECK_LAUNCH();
}

void queue_select(const CallState* state, cudaGraphConditionalHandle lists, cudaStream_t stream) {
  select_kernel<<<1, 32, 0, stream>>>(state, lists);
  CF_CUDA_CHECK_LAUNCH();
}

}  // namespace cellforce::cuda
