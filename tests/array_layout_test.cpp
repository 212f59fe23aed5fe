// Arrays as callers hold them (cellforce.hpp Positions and Types, C cf_compute_layout): float32 or
// float64 coordinates in rows of any stride >= dim, int32 or uint32 types, on host and device. The
// oracle is the same call on packed float64 and uint32 arrays of the same values: a float32
// coordinate converts to float64 exactly, so every result must be bitwise equal. The padding of a
// row holds NaN, so a result that read it would not be finite. Device instances skip without a GPU.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cellforce/cellforce.h>
#include <cellforce/cellforce.hpp>

#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#ifdef CELLFORCE_HAVE_CUDA
#include <cuda_runtime.h>

#include "backend/engine.h"  // GpuEngine::unavailable
#endif
#include "oracle.h"

namespace {

namespace cf = cellforce;
using ::testing::HasSubstr;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// A binary liquid whose coordinates are floats (so that float32 arrays hold them exactly).
struct Liquid {
  cf::Configuration config;
  int dim = 3;
  std::size_t n() const { return config.size(); }
};

Liquid float_liquid(int dim, std::size_t n, uint64_t seed) {
  Liquid l;
  l.dim = dim;
  const double edge = dim == 3 ? std::cbrt(double(n) / 0.8) : std::sqrt(double(n) / 0.7);
  cftest::RandomSpec spec;
  spec.min_distance = 0.8;
  spec.num_types = 2;
  l.config = cftest::random_configuration(cftest::cube(dim, edge), n, seed, spec);
  for (double& x : l.config.positions) x = double(float(x));
  return l;
}

cf::Context context_for(const Liquid& l, cf::Backend backend, cf::Precision precision) {
  cf::Context ctx(l.dim);
  const bool periodic[3] = {true, true, true};
  ctx.set_box(l.config.box.length, periodic);
  ctx.set_cutoff(2.5, cf::CutoffMode::kForceShift);
  ctx.add_type("A", 1.0, 1.0);
  ctx.add_type("B", 0.88, 0.5);
  ctx.set_backend(backend);
  ctx.set_precision(precision);
  return ctx;
}

// The rows padded to `stride` with NaN, as T.
template <class T>
std::vector<T> padded_rows(const Liquid& l, std::size_t stride) {
  std::vector<T> rows(l.n() * stride, T(kNaN));
  for (std::size_t i = 0; i < l.n(); ++i)
    for (int a = 0; a < l.dim; ++a) rows[i * stride + std::size_t(a)] = T(l.config.positions[i * std::size_t(l.dim) + std::size_t(a)]);
  return rows;
}

std::vector<int32_t> int32_types(const Liquid& l) { return {l.config.types.begin(), l.config.types.end()}; }

struct Results {
  std::vector<double> forces, energies;
  double energy = kNaN;
  double virial[9] = {kNaN, kNaN, kNaN, kNaN, kNaN, kNaN, kNaN, kNaN, kNaN};
  explicit Results(const Liquid& l) : forces(l.n() * std::size_t(l.dim), kNaN), energies(l.n(), kNaN) {}
  cf::Outputs outputs() { return {forces.data(), energies.data(), &energy, virial}; }
};

void expect_bitwise(const Results& a, const Results& b, int dim) {
  ASSERT_EQ(a.forces.size(), b.forces.size());
  EXPECT_EQ(std::memcmp(a.forces.data(), b.forces.data(), a.forces.size() * sizeof(double)), 0);
  EXPECT_EQ(std::memcmp(a.energies.data(), b.energies.data(), a.energies.size() * sizeof(double)), 0);
  EXPECT_EQ(std::memcmp(&a.energy, &b.energy, sizeof(double)), 0) << a.energy << " " << b.energy;
  EXPECT_EQ(std::memcmp(a.virial, b.virial, std::size_t(dim * dim) * sizeof(double)), 0);
  EXPECT_TRUE(std::isfinite(a.energy));
}

std::vector<cf::Backend> backends_here() {
  std::vector<cf::Backend> out = {cf::Backend::kCpu};
#ifdef CELLFORCE_HAVE_CUDA
  if (cf::GpuEngine::unavailable().empty()) out.push_back(cf::Backend::kCuda);
#endif
  return out;
}

const cf::Precision kPrecisions[] = {cf::Precision::kDouble, cf::Precision::kMixed, cf::Precision::kSingle};

}  // namespace

// Host arrays: float32 rows padded to four, float64 rows padded to five, int32 types: bitwise the
// packed float64 / uint32 call, on every backend here and in every precision, in 3D and 2D.
TEST(ArrayLayout, HostRowsOfAnyLayoutAreThePackedResults) {
  for (int dim : {3, 2})
    for (cf::Backend backend : backends_here())
      for (cf::Precision p : kPrecisions) {
        SCOPED_TRACE(std::to_string(dim) + "D backend " + std::to_string(int(backend)) + " precision " +
                     std::to_string(int(p)));
        const Liquid l = float_liquid(dim, 1500, 70 + uint64_t(dim));
        cf::Context ctx = context_for(l, backend, p);
        Results packed(l), f32(l), f64(l);
        ctx.compute(l.n(), l.config.positions.data(), l.config.types.data(), packed.outputs());
        const std::vector<float> rows32 = padded_rows<float>(l, 4);
        const std::vector<double> rows64 = padded_rows<double>(l, 5);
        const std::vector<int32_t> types32 = int32_types(l);
        ctx.compute(l.n(), cf::Positions{rows32.data(), cf::Scalar::kFloat32, 4},
                    cf::Types{types32.data(), cf::Index::kInt32}, f32.outputs());
        ctx.compute(l.n(), cf::Positions{rows64.data(), cf::Scalar::kFloat64, 5},
                    cf::Types{l.config.types.data(), cf::Index::kUInt32}, f64.outputs());
        expect_bitwise(f32, packed, dim);
        expect_bitwise(f64, packed, dim);
      }
}

// What a layout gets wrong is named before anything is computed, and the outputs stay unwritten.
TEST(ArrayLayout, BadHostLayoutsAreNamed) {
  const Liquid l = float_liquid(3, 200, 75);
  cf::Context ctx = context_for(l, cf::Backend::kCpu, cf::Precision::kDouble);
  Results out(l);
  const std::vector<float> rows = padded_rows<float>(l, 4);
  auto message = [&](const cf::Positions& p, const cf::Types& t) {
    try {
      ctx.compute(l.n(), p, t, out.outputs());
    } catch (const cf::Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_THAT(message({rows.data(), cf::Scalar::kFloat32, 2}, {}), HasSubstr("a row stride of 2 elements is less than the 3"));
  EXPECT_THAT(message({rows.data(), static_cast<cf::Scalar>(7), 4}, {}), HasSubstr("scalar 7 is neither float64 nor float32"));
  EXPECT_THAT(message({rows.data(), cf::Scalar::kFloat32, 4}, {l.config.types.data(), static_cast<cf::Index>(9)}),
              HasSubstr("index 9 is neither uint32 nor int32"));
  EXPECT_THAT(message({nullptr, cf::Scalar::kFloat32, 4}, {}), HasSubstr("positions is a null pointer"));
  std::vector<int32_t> types = int32_types(l);
  types[3] = -1;
  EXPECT_THAT(message({rows.data(), cf::Scalar::kFloat32, 4}, {types.data(), cf::Index::kInt32}),
              HasSubstr("particle 3 has type index -1"));
  std::vector<float> bad = rows;
  bad[5 * 4 + 1] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THAT(message({bad.data(), cf::Scalar::kFloat32, 4}, {}), HasSubstr("particle 5 has a non-finite y coordinate"));
  for (double v : out.forces) EXPECT_TRUE(std::isnan(v));
  EXPECT_TRUE(std::isnan(out.energy));
}

// The C calls: float32 rows of stride 4 and int32 types give bitwise cf_compute_energies' results;
// an unknown scalar or index is CF_ERROR_INPUT naming it.
TEST(CApiLayout, LayoutCallsAreThePackedResults) {
  const Liquid l = float_liquid(3, 800, 76);
  cf_context* c = nullptr;
  ASSERT_EQ(cf_create(&c, 3), CF_OK);
  const int periodic[3] = {1, 1, 1};
  ASSERT_EQ(cf_set_box(c, l.config.box.length, periodic), CF_OK);
  ASSERT_EQ(cf_set_cutoff(c, 2.5, "force-shift"), CF_OK);
  ASSERT_EQ(cf_add_type(c, "A", 1.0, 1.0, nullptr), CF_OK);
  ASSERT_EQ(cf_add_type(c, "B", 0.88, 0.5, nullptr), CF_OK);
  Results packed(l), layout(l);
  ASSERT_EQ(cf_compute_energies(c, l.n(), l.config.positions.data(), l.config.types.data(), packed.forces.data(),
                                packed.energies.data(), &packed.energy, packed.virial),
            CF_OK);
  const std::vector<float> rows = padded_rows<float>(l, 4);
  const std::vector<int32_t> types = int32_types(l);
  ASSERT_EQ(cf_compute_layout(c, l.n(), rows.data(), CF_FLOAT32, 4, types.data(), CF_INT32, layout.forces.data(),
                              layout.energies.data(), &layout.energy, layout.virial),
            CF_OK)
      << cf_last_error(c);
  expect_bitwise(layout, packed, 3);
  EXPECT_EQ(cf_compute_layout(c, l.n(), rows.data(), static_cast<cf_scalar>(5), 4, nullptr, CF_UINT32,
                              layout.forces.data(), nullptr, nullptr, nullptr),
            CF_ERROR_INPUT);
  EXPECT_THAT(std::string(cf_last_error(c)), HasSubstr("scalar 5 is neither CF_FLOAT64 (0) nor CF_FLOAT32 (1)"));
  EXPECT_EQ(cf_compute_layout(c, l.n(), rows.data(), CF_FLOAT32, 4, types.data(), static_cast<cf_index>(4),
                              layout.forces.data(), nullptr, nullptr, nullptr),
            CF_ERROR_INPUT);
  EXPECT_THAT(std::string(cf_last_error(c)), HasSubstr("index 4 is neither CF_UINT32 (0) nor CF_INT32 (1)"));
  cf_destroy(c);
}

#ifdef CELLFORCE_HAVE_CUDA
namespace {

template <class T>
T* device_copy(const std::vector<T>& host) {
  T* d = nullptr;
  EXPECT_EQ(cudaMalloc(reinterpret_cast<void**>(&d), std::max<std::size_t>(host.size(), 1) * sizeof(T)), cudaSuccess);
  EXPECT_EQ(cudaMemcpy(d, host.data(), host.size() * sizeof(T), cudaMemcpyHostToDevice), cudaSuccess);
  return d;
}

// compute_device of `positions` and `types` (device) into host Results, on `stream`.
Results device_results(cf::Context& ctx, const Liquid& l, const cf::Positions& positions, const cf::Types& types,
                       cudaStream_t stream) {
  Results r(l);
  double* d_f = device_copy(r.forces);
  double* d_e = device_copy(r.energies);
  double* d_energy = device_copy(std::vector<double>(1, kNaN));
  double* d_w = device_copy(std::vector<double>(9, kNaN));
  ctx.compute_device(l.n(), positions, types, {d_f, d_e, d_energy, d_w}, stream);
  ctx.synchronize();
  EXPECT_EQ(cudaStreamSynchronize(stream), cudaSuccess);
  EXPECT_EQ(cudaMemcpy(r.forces.data(), d_f, r.forces.size() * sizeof(double), cudaMemcpyDeviceToHost), cudaSuccess);
  EXPECT_EQ(cudaMemcpy(r.energies.data(), d_e, r.energies.size() * sizeof(double), cudaMemcpyDeviceToHost),
            cudaSuccess);
  EXPECT_EQ(cudaMemcpy(&r.energy, d_energy, sizeof(double), cudaMemcpyDeviceToHost), cudaSuccess);
  EXPECT_EQ(cudaMemcpy(r.virial, d_w, std::size_t(l.dim * l.dim) * sizeof(double), cudaMemcpyDeviceToHost),
            cudaSuccess);
  for (void* p : {static_cast<void*>(d_f), static_cast<void*>(d_e), static_cast<void*>(d_energy),
                  static_cast<void*>(d_w)})
    cudaFree(p);
  return r;
}

}  // namespace

// Device arrays: float32 rows padded to four with int32 types, and float64 rows padded to five,
// converted on the caller's stream: bitwise the host call on packed arrays, in every precision,
// also with a skin (the converted array is the one the reuse check reads).
TEST(ArrayLayoutDevice, DeviceRowsOfAnyLayoutAreThePackedResults) {
  if (!cf::GpuEngine::unavailable().empty()) GTEST_SKIP() << cf::GpuEngine::unavailable();
  cudaStream_t stream = nullptr;
  ASSERT_EQ(cudaStreamCreateWithFlags(&stream, cudaStreamNonBlocking), cudaSuccess);
  for (int dim : {3, 2})
    for (cf::Precision p : kPrecisions)
      for (const char* skin : {"0", "0.3"}) {
        SCOPED_TRACE(std::to_string(dim) + "D precision " + std::to_string(int(p)) + " skin " + skin);
        const Liquid l = float_liquid(dim, 1500, 80 + uint64_t(dim));
        cf::Context ctx = context_for(l, cf::Backend::kCuda, p);
        ctx.set_option("skin", skin);
        Results packed(l);
        ctx.compute(l.n(), l.config.positions.data(), l.config.types.data(), packed.outputs());
        float* rows32 = device_copy(padded_rows<float>(l, 4));
        double* rows64 = device_copy(padded_rows<double>(l, 5));
        int32_t* types32 = device_copy(int32_types(l));
        uint32_t* types = device_copy(l.config.types);
        expect_bitwise(device_results(ctx, l, {rows32, cf::Scalar::kFloat32, 4}, {types32, cf::Index::kInt32}, stream),
                       packed, dim);
        expect_bitwise(device_results(ctx, l, {rows64, cf::Scalar::kFloat64, 5}, {types, cf::Index::kUInt32}, stream),
                       packed, dim);
        for (void* q : {static_cast<void*>(rows32), static_cast<void*>(rows64), static_cast<void*>(types32),
                        static_cast<void*>(types)})
          cudaFree(q);
      }
  cudaStreamDestroy(stream);
}

// On the device a negative int32 type and a float32 NaN are named by synchronize(); a stride below
// dim before anything is queued.
TEST(ArrayLayoutDevice, BadDeviceLayoutsAreNamed) {
  if (!cf::GpuEngine::unavailable().empty()) GTEST_SKIP() << cf::GpuEngine::unavailable();
  const Liquid l = float_liquid(3, 300, 85);
  cf::Context ctx = context_for(l, cf::Backend::kCuda, cf::Precision::kMixed);
  std::vector<float> rows = padded_rows<float>(l, 4);
  std::vector<int32_t> types = int32_types(l);
  types[7] = -2;
  float* d_rows = device_copy(rows);
  int32_t* d_types = device_copy(types);
  double* d_f = device_copy(std::vector<double>(l.n() * 3, 0.0));
  auto synchronize_message = [&] {
    try {
      ctx.synchronize();
    } catch (const cf::Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  ctx.compute_device(l.n(), {d_rows, cf::Scalar::kFloat32, 4}, {d_types, cf::Index::kInt32}, {d_f}, nullptr);
  EXPECT_THAT(synchronize_message(), HasSubstr("particle 7 has type index 4294967294 (-2 as int32)"));
  rows[11 * 4 + 2] = std::numeric_limits<float>::infinity();
  float* d_bad = device_copy(rows);
  ctx.compute_device(l.n(), {d_bad, cf::Scalar::kFloat32, 4}, {}, {d_f}, nullptr);
  EXPECT_THAT(synchronize_message(), HasSubstr("particle 11 has a non-finite z coordinate"));
  try {
    ctx.compute_device(l.n(), {d_rows, cf::Scalar::kFloat32, 1}, {}, {d_f}, nullptr);
    ADD_FAILURE() << "a stride of 1 was taken";
  } catch (const cf::Error& e) {
    EXPECT_THAT(std::string(e.what()), HasSubstr("a row stride of 1 elements is less than the 3"));
  }
  for (void* q : {static_cast<void*>(d_rows), static_cast<void*>(d_types), static_cast<void*>(d_f),
                  static_cast<void*>(d_bad)})
    cudaFree(q);
}
#endif
