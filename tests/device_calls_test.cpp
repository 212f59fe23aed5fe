// compute_device calls whose rebuild the device decides (cuda/backend/call_graph.cuh): queued back
// to back with no host wait between them, they give bitwise the results of the host-decided path
// (EngineTestHooks::device_decides false: the host reads the displacement and the list's sizes at
// every call) on the same positions, call by call, rebuilding on the same calls; a list that
// outgrows its array is served by the cells, and every call after it is exact (the double brute
// force's forces) but no longer bitwise the host-decided path's. Skips with a message where no
// CUDA device exists; compiled only with CUDA.
#ifdef CELLFORCE_HAVE_CUDA

#include <cuda_runtime.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "backend/engine.h"  // cuda/backend/engine.h
#include "reference/brute_force.h"
#include "scene/scene.h"

namespace cftest {
namespace {

using cellforce::GpuEngine;
using cellforce::GpuOptions;
using cellforce::Precision;

#define CF_SKIP_WITHOUT_DEVICE()                       \
  do {                                                 \
    const std::string why_ = GpuEngine::unavailable(); \
    if (!why_.empty()) GTEST_SKIP() << why_;           \
  } while (0)

template <class T>
T* device_array(std::size_t count) {
  T* p = nullptr;
  EXPECT_EQ(cudaMalloc(reinterpret_cast<void**>(&p), std::max<std::size_t>(count, 1) * sizeof(T)), cudaSuccess);
  return p;
}

template <class T>
std::vector<T> to_host(const T* p, std::size_t count) {
  std::vector<T> h(count);
  EXPECT_EQ(cudaMemcpy(h.data(), p, count * sizeof(T), cudaMemcpyDeviceToHost), cudaSuccess);
  return h;
}

// The in.lj fluid (4,000 particles, edge 16.8, each moved off its lattice site by up to 0.15 a
// component) and a trajectory of positions for the calls:
// call k moves every particle by k times its own random step (components within +-0.03), so that
// the largest displacement passes skin / 2 = 0.3 every few calls; `squeeze` replaces the calls in
// [from, to) by the start pulled 30% towards the box's centre (2.9 times the density: a list
// several times longer than the array the start's builds gave it).
struct Trajectory {
  cellforce::Scene scene = cellforce::default_scene();
  cellforce::Configuration start;
  std::vector<double> step;
  Trajectory() {
    scene.particles.cells = {10, 10, 10};
    start = cellforce::build_configuration(scene);
    std::mt19937_64 rng(2026);
    std::uniform_real_distribution<double> u(-0.03, 0.03), shake(-0.15, 0.15);
    for (std::size_t i = 0; i < start.positions.size(); ++i) {  // off the lattice, as a liquid
      const double length = start.box.length[i % 3];
      double x = start.positions[i] + shake(rng);
      x -= length * std::floor(x / length);
      start.positions[i] = x < length ? x : 0.0;
    }
    step.resize(start.positions.size());
    for (double& s : step) s = u(rng);
  }
  std::size_t n() const { return start.size(); }
  std::vector<double> at(int k, int squeeze_from = -1, int squeeze_to = -1) const {
    const cellforce::Box& box = start.box;
    std::vector<double> p = start.positions;
    const bool squeezed = k >= squeeze_from && k < squeeze_to;
    for (std::size_t i = 0; i < p.size(); ++i) {
      const double length = box.length[i % 3];
      double x = squeezed ? 0.5 * length + 0.7 * (p[i] - 0.5 * length) : p[i] + k * step[i];
      x -= length * std::floor(x / length);
      p[i] = x < length ? x : 0.0;
    }
    return p;
  }
};

GpuOptions call_options(Precision p, bool device_decides) {
  GpuOptions o;
  o.precision = p;
  o.reuse.skin = 0.6;
  o.reuse.list = true;
  o.test.device_decides = device_decides;
  return o;
}

// One engine's calls over the trajectory, queued back to back (each call's positions and outputs
// in arrays of their own), then one synchronize(). Calls from `observe` on ask for per-particle
// energies, the energy and the virial. `arrays`: kFixed, every call reads one positions array and
// writes one set of outputs, as an embedding code's loop does (each call's positions copied in
// before it and its outputs copied out after it, on the calls' stream); kInputsByTurns, four
// positions arrays by turns and one set of outputs; kOutputsByTurns, one positions array and four
// sets of outputs by turns.
enum class Arrays { kFresh, kFixed, kInputsByTurns, kOutputsByTurns };
struct Calls {
  std::vector<std::vector<double>> forces, energies, energy, virial;
};
Calls run_calls(GpuEngine& engine, const Trajectory& t, int calls, int observe, int squeeze_from = -1,
                int squeeze_to = -1, Arrays arrays = Arrays::kFresh) {
  const std::size_t n = t.n(), nd = 3 * n;
  uint32_t* types = device_array<uint32_t>(n);
  EXPECT_EQ(cudaMemcpy(types, t.start.types.data(), n * sizeof(uint32_t), cudaMemcpyHostToDevice), cudaSuccess);
  std::vector<double*> pos(calls), f(calls), e(calls), u(calls), w(calls);
  for (int k = 0; k < calls; ++k) {
    pos[k] = device_array<double>(nd);
    f[k] = device_array<double>(nd);
    e[k] = device_array<double>(n);
    u[k] = device_array<double>(1);
    w[k] = device_array<double>(9);
    const std::vector<double> p = t.at(k, squeeze_from, squeeze_to);
    EXPECT_EQ(cudaMemcpy(pos[k], p.data(), nd * sizeof(double), cudaMemcpyHostToDevice), cudaSuccess);
  }
  constexpr int kTurns = 4;
  std::vector<double*> turn_pos(kTurns), turn_f(kTurns), turn_e(kTurns), turn_u(kTurns), turn_w(kTurns);
  for (int j = 0; j < kTurns; ++j) {
    turn_pos[j] = device_array<double>(nd);
    turn_f[j] = device_array<double>(nd);
    turn_e[j] = device_array<double>(n);
    turn_u[j] = device_array<double>(1);
    turn_w[j] = device_array<double>(9);
  }
  EXPECT_EQ(cudaDeviceSynchronize(), cudaSuccess);
  for (int k = 0; k < calls; ++k) {
    const bool obs = k >= observe;
    const int in = arrays == Arrays::kInputsByTurns ? k % kTurns : 0;
    const int to = arrays == Arrays::kOutputsByTurns ? k % kTurns : 0;
    double *one_pos = turn_pos[in], *one_f = turn_f[to], *one_e = turn_e[to], *one_u = turn_u[to],
           *one_w = turn_w[to];
    if (arrays == Arrays::kFresh) {
      engine.evaluate_device(cellforce::DeviceInput{t.start.box, n, pos[k], cellforce::Scalar::kFloat64, 0, types},
                             t.scene.force_field,
                             cellforce::DeviceOutputs{f[k], obs ? e[k] : nullptr, obs ? u[k] : nullptr,
                                                      obs ? w[k] : nullptr},
                             nullptr);
      continue;
    }
    EXPECT_EQ(cudaMemcpyAsync(one_pos, pos[k], nd * sizeof(double), cudaMemcpyDeviceToDevice, nullptr), cudaSuccess);
    engine.evaluate_device(cellforce::DeviceInput{t.start.box, n, one_pos, cellforce::Scalar::kFloat64, 0, types},
                           t.scene.force_field,
                           cellforce::DeviceOutputs{one_f, obs ? one_e : nullptr, obs ? one_u : nullptr,
                                                    obs ? one_w : nullptr},
                           nullptr);
    const std::pair<double*, double*> out[] = {{f[k], one_f}, {e[k], one_e}, {u[k], one_u}, {w[k], one_w}};
    const std::size_t sizes[] = {nd, n, 1, 9};
    for (int a = 0; a < (obs ? 4 : 1); ++a)
      EXPECT_EQ(cudaMemcpyAsync(out[a].first, out[a].second, sizes[a] * sizeof(double), cudaMemcpyDeviceToDevice,
                                nullptr),
                cudaSuccess);
  }
  engine.synchronize(t.scene.force_field);
  Calls out;
  for (int k = 0; k < calls; ++k) {
    const bool obs = k >= observe;
    out.forces.push_back(to_host(f[k], nd));
    out.energies.push_back(obs ? to_host(e[k], n) : std::vector<double>{});
    out.energy.push_back(obs ? to_host(u[k], 1) : std::vector<double>{});
    out.virial.push_back(obs ? to_host(w[k], 9) : std::vector<double>{});
    for (double* p : {pos[k], f[k], e[k], u[k], w[k]}) cudaFree(p);
  }
  for (int j = 0; j < kTurns; ++j)
    for (double* p : {turn_pos[j], turn_f[j], turn_e[j], turn_u[j], turn_w[j]}) cudaFree(p);
  cudaFree(types);
  return out;
}

// Every output of every call bitwise the same in x and y.
void expect_bitwise(const Calls& x, const Calls& y, int calls) {
  for (int k = 0; k < calls; ++k) {
    SCOPED_TRACE("call " + std::to_string(k));
    EXPECT_TRUE(x.forces[k] == y.forces[k]);
    EXPECT_TRUE(x.energies[k] == y.energies[k]);
    EXPECT_TRUE(x.energy[k] == y.energy[k]);
    EXPECT_TRUE(x.virial[k] == y.virial[k]);
  }
}

class DeviceCalls : public ::testing::TestWithParam<Precision> {
 protected:
  void SetUp() override { CF_SKIP_WITHOUT_DEVICE(); }
};

// 48 calls (forces only, then from call 24 energies, energy and virial too), each into output
// arrays of its own: bitwise the host-decided calls, the same builds, most calls served by the
// device's graph, no list outgrown, and a few graphs made, not one a call.
TEST_P(DeviceCalls, DecidedCallsAreTheHostDecidedCalls) {
  const Trajectory t;
  const int calls = 48, observe = 24;
  GpuEngine device(call_options(GetParam(), true)), host(call_options(GetParam(), false));
  const Calls x = run_calls(device, t, calls, observe), y = run_calls(host, t, calls, observe);
  expect_bitwise(x, y, calls);
  EXPECT_EQ(device.stats().builds, host.stats().builds);
  EXPECT_GE(host.stats().builds, 6u) << "too few rebuilds to test the device's decision";
  EXPECT_GE(device.device_builds(), 3u) << "the device decided too few of the builds";
  EXPECT_GE(device.device_calls(), std::size_t(calls) - 12) << "the device's graph served too few calls";
  EXPECT_EQ(device.list_overflows(), 0u);
  EXPECT_EQ(host.device_calls(), 0u);
  // Each call writes arrays of its own: after a few graphs for new arrays the engine's are copied
  // out (else a graph would be made for every call).
  EXPECT_LE(device.call_captures(), 8u);
  std::printf("device-decided calls (%s): %zu of %d, builds %zu (%zu decided by the device), graphs %zu\n",
              cellforce::to_string(GetParam()), device.device_calls(), calls, device.stats().builds,
              device.device_builds(), device.call_captures());
}

// The same calls as an embedding code's loop makes them, one positions array and one set of outputs
// for all (the graph then holds the input pass, its last block deciding, and writes the outputs),
// and with the positions or the outputs in four arrays by turns (after three changes the input pass
// is queued before the graph, or the engine's outputs are copied out): bitwise the host-decided
// calls, and a few graphs (forces, then observables; a list array that grew; the arrays of the
// first turns), not one a call.
TEST_P(DeviceCalls, DecidedCallsOnFixedArraysAreTheHostDecidedCalls) {
  const Trajectory t;
  const int calls = 48, observe = 24;
  GpuEngine host(call_options(GetParam(), false));
  const Calls y = run_calls(host, t, calls, observe);
  for (const Arrays arrays : {Arrays::kFixed, Arrays::kInputsByTurns, Arrays::kOutputsByTurns}) {
    SCOPED_TRACE("arrays " + std::to_string(int(arrays)));
    GpuEngine device(call_options(GetParam(), true));
    const Calls x = run_calls(device, t, calls, observe, -1, -1, arrays);
    expect_bitwise(x, y, calls);
    EXPECT_EQ(device.stats().builds, host.stats().builds);
    EXPECT_GE(device.device_builds(), 3u) << "the device decided too few of the builds";
    EXPECT_GE(device.device_calls(), std::size_t(calls) - 12) << "the device's graph served too few calls";
    EXPECT_LE(device.call_captures(), arrays == Arrays::kFixed ? 4u : 8u);  // a grown list array: another key
  }
}

// The fluid squeezed at calls 16 to 21 (a list ~3x longer than its array): the device's build at
// call 16 finds that the list does not fit, and the cells serve. From there on each call is exact
// (the double brute force's forces and energy, to the precision's bound), but no longer bitwise
// the host-decided path's: which calls the cells serve and where the device builds again depend
// on when the host gives the list a larger array. Before call 16, bitwise.
TEST_P(DeviceCalls, ListThatOutgrowsItsArrayIsServedByTheCells) {
  const Trajectory t;
  const int calls = 30, from = 16, to = 22;
  GpuEngine device(call_options(GetParam(), true)), host(call_options(GetParam(), false));
  const Calls x = run_calls(device, t, calls, 0, from, to), y = run_calls(host, t, calls, 0, from, to);
  EXPECT_GE(device.list_overflows(), 1u) << "the squeezed list fitted its array: nothing tested";
  const double bound = GetParam() == Precision::kDouble ? 1e-11 : 1e-4;
  for (int k = 0; k < calls; ++k) {
    SCOPED_TRACE("call " + std::to_string(k));
    if (k < from) {
      EXPECT_TRUE(x.forces[k] == y.forces[k]);
      EXPECT_TRUE(x.energy[k] == y.energy[k]);
      continue;
    }
    cellforce::Configuration c = t.start;
    c.positions = t.at(k, from, to);
    cellforce::ForceResult ref;
    cellforce::brute_force(c.view(), t.scene.force_field, cellforce::Request{true, false}, ref);
    double largest = 0, worst = 0;
    for (double v : ref.forces) largest = std::max(largest, std::abs(v));
    for (std::size_t i = 0; i < ref.forces.size(); ++i) worst = std::max(worst, std::abs(x.forces[k][i] - ref.forces[i]));
    EXPECT_LT(worst, bound * largest) << "forces against the double brute force";
    EXPECT_NEAR(x.energy[k][0], ref.energy, bound * std::abs(ref.energy));
  }
}

// Calls as an embedding code may make them: float32 rows padded to four (x, y, z, w), int32 types,
// the calls alternating between two streams of the caller's, queued back to back: bitwise the
// host-decided calls on float64 rows of the same values (a float32 converts exactly), with the
// same builds.
TEST_P(DeviceCalls, CallersArraysAndStreamsAreTheHostDecidedCalls) {
  const Trajectory t;
  const std::size_t n = t.n(), nd = 3 * n;
  const int calls = 24;
  GpuEngine device(call_options(GetParam(), true)), host(call_options(GetParam(), false));
  cudaStream_t streams[2] = {};
  for (cudaStream_t& st : streams) ASSERT_EQ(cudaStreamCreateWithFlags(&st, cudaStreamNonBlocking), cudaSuccess);
  int32_t* types = device_array<int32_t>(n);
  std::vector<int32_t> types32(t.start.types.begin(), t.start.types.end());
  ASSERT_EQ(cudaMemcpy(types, types32.data(), n * sizeof(int32_t), cudaMemcpyHostToDevice), cudaSuccess);
  std::vector<float*> rows(calls);
  std::vector<double*> packed(calls), fx(calls), fy(calls);
  for (int k = 0; k < calls; ++k) {
    const std::vector<double> p = t.at(k);
    std::vector<float> padded(4 * n, 0.0f);
    std::vector<double> same(nd);
    for (std::size_t i = 0; i < n; ++i)
      for (int a = 0; a < 3; ++a) {
        padded[4 * i + a] = float(p[3 * i + a]);
        same[3 * i + a] = double(padded[4 * i + a]);
      }
    rows[k] = device_array<float>(4 * n);
    packed[k] = device_array<double>(nd);
    fx[k] = device_array<double>(nd);
    fy[k] = device_array<double>(nd);
    ASSERT_EQ(cudaMemcpy(rows[k], padded.data(), 4 * n * sizeof(float), cudaMemcpyHostToDevice), cudaSuccess);
    ASSERT_EQ(cudaMemcpy(packed[k], same.data(), nd * sizeof(double), cudaMemcpyHostToDevice), cudaSuccess);
  }
  ASSERT_EQ(cudaDeviceSynchronize(), cudaSuccess);
  const auto* typed = reinterpret_cast<const uint32_t*>(types);  // int32 passes as uint32 (DeviceInput)
  for (int k = 0; k < calls; ++k) {
    device.evaluate_device(cellforce::DeviceInput{t.start.box, n, rows[k], cellforce::Scalar::kFloat32, 4, typed},
                           t.scene.force_field, cellforce::DeviceOutputs{fx[k], nullptr, nullptr, nullptr},
                           streams[k % 2]);
    host.evaluate_device(cellforce::DeviceInput{t.start.box, n, packed[k], cellforce::Scalar::kFloat64, 0, typed},
                         t.scene.force_field, cellforce::DeviceOutputs{fy[k], nullptr, nullptr, nullptr}, nullptr);
  }
  device.synchronize(t.scene.force_field);
  host.synchronize(t.scene.force_field);
  for (cudaStream_t st : streams) ASSERT_EQ(cudaStreamSynchronize(st), cudaSuccess);
  for (int k = 0; k < calls; ++k) {
    SCOPED_TRACE("call " + std::to_string(k));
    EXPECT_TRUE(to_host(fx[k], nd) == to_host(fy[k], nd));
  }
  EXPECT_EQ(device.stats().builds, host.stats().builds);
  EXPECT_GE(device.device_builds(), 2u) << "the device decided too few of the builds";
  EXPECT_GE(device.device_calls(), std::size_t(calls) - 6);
  for (int k = 0; k < calls; ++k)
    for (void* p : {static_cast<void*>(rows[k]), static_cast<void*>(packed[k]), static_cast<void*>(fx[k]),
                    static_cast<void*>(fy[k])})
      cudaFree(p);
  cudaFree(types);
  for (cudaStream_t st : streams) cudaStreamDestroy(st);
}

INSTANTIATE_TEST_SUITE_P(Precisions, DeviceCalls,
                         ::testing::Values(Precision::kSingle, Precision::kMixed, Precision::kDouble),
                         [](const ::testing::TestParamInfo<Precision>& p) { return cellforce::to_string(p.param); });

}  // namespace
}  // namespace cftest

#endif  // CELLFORCE_HAVE_CUDA
