// The shared __host__ __device__ core on a GPU, compiled as the kernels are (nvcc's default FMA
// contraction on): bin_particle (periodic, open and slab grids, 2D and 3D, points on faces, box
// edges, -0.0, -1e-8 and random) must equal the host BITWISE (style.md: "the CPU and GPU bin a
// particle identically"; the geometry helpers use mul_rn for that), and lj_pair (every cutoff
// mode, with and without energy, double and float) must give the same hit flags bitwise and the
// same force and energy to a few ulps (FMA changes last bits there).
//
// Skips with a clear message where no CUDA device is present. Every CUDA call is checked.
#include <cuda_runtime.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "core/box.h"
#include "cuda_device.h"
#include "core/grid.h"
#include "core/lj.h"

namespace {

using cellforce::Control;
using cellforce::CutoffMode;
using cellforce::Grid;
using cellforce::kMaxCellTypes;
using cellforce::LJParams;

using cellforce::cuda::DeviceBuffer;
using cftest::download;
using cftest::upload;

class CoreOnDevice : public cftest::NeedsCudaDevice {};

// ---- lj_pair ------------------------------------------------------------------------------------
// Per input: for each of the 3 modes x {energy, no energy}: hit, force_over_r, energy (outputs
// start from sentinels so that "left alone" is compared too).
constexpr int kLjOutputs = 3 * 2 * 3;

template <class Real, CutoffMode Mode, bool Energy>
CF_HD void lj_one(Real r2, Real rc2, const LJParams<Real>& p, Real* out) {
  Real f = Real(-777), u = Real(-555);
  const bool hit = cellforce::lj_pair<Mode, Energy>(r2, rc2, p, f, u);
  out[0] = hit ? Real(1) : Real(0);
  out[1] = f;
  out[2] = u;
}

template <class Real>
CF_HD void lj_all(Real r2, Real rc2, const LJParams<Real>* p, Real* out) {
  lj_one<Real, CutoffMode::kTruncate, true>(r2, rc2, p[0], out + 0);
  lj_one<Real, CutoffMode::kTruncate, false>(r2, rc2, p[0], out + 3);
  lj_one<Real, CutoffMode::kShift, true>(r2, rc2, p[1], out + 6);
  lj_one<Real, CutoffMode::kShift, false>(r2, rc2, p[1], out + 9);
  lj_one<Real, CutoffMode::kForceShift, true>(r2, rc2, p[2], out + 12);
  lj_one<Real, CutoffMode::kForceShift, false>(r2, rc2, p[2], out + 15);
}

struct LjCase {
  double sigma, epsilon, cutoff;
};

template <class Real>
__global__ void lj_kernel(const Real* r2, int n, Real rc2, const LJParams<Real>* params,
                          Real* out) {
  const int i = int(blockIdx.x * blockDim.x + threadIdx.x);
  if (i < n) lj_all<Real>(r2[i], rc2, params, out + std::size_t(i) * kLjOutputs);
}

template <class Real>
void compare_lj(const LjCase& c) {
  const LJParams<Real> params[3] = {
      cellforce::make_lj_params<Real>(c.sigma, c.epsilon, c.cutoff, CutoffMode::kTruncate),
      cellforce::make_lj_params<Real>(c.sigma, c.epsilon, c.cutoff, CutoffMode::kShift),
      cellforce::make_lj_params<Real>(c.sigma, c.epsilon, c.cutoff, CutoffMode::kForceShift)};
  const Real rc2 = Real(c.cutoff) * Real(c.cutoff);
  std::vector<Real> r2;
  for (double x = 0.2; x < 1.3; x += 0.00137) r2.push_back(Real(x * c.cutoff) * Real(x * c.cutoff));
  for (Real v : {rc2, std::nextafter(rc2, Real(0)), std::nextafter(rc2, Real(1e30)), Real(0.25),
                 Real(1e-6), Real(1e30)})
    r2.push_back(v);
  const int n = int(r2.size());

  std::vector<Real> host(r2.size() * kLjOutputs);
  for (int i = 0; i < n; ++i) lj_all<Real>(r2[std::size_t(i)], rc2, params, &host[std::size_t(i) * kLjOutputs]);

  DeviceBuffer<Real> d_r2, d_out(host.size());
  DeviceBuffer<LJParams<Real>> d_params;
  upload(d_r2, r2);
  upload(d_params, std::vector<LJParams<Real>>(params, params + 3));
  lj_kernel<Real><<<(n + 127) / 128, 128>>>(d_r2.data(), n, rc2, d_params.data(), d_out.data());
  CF_CUDA_CHECK_LAUNCH();
  CF_CUDA_CHECK(cudaDeviceSynchronize());
  std::vector<Real> device;
  device = download(d_out, host.size());

  // The hit flag and every output left alone must match bitwise (the cutoff contract has no
  // arithmetic in it). Force and energy may differ in their last bits: nvcc contracts a * b + c
  // into an FMA (the GPU kernels keep that for speed), the host compiler does not. They must agree
  // to 32 ulps of the largest term that enters them (computed here in double).
  const double eps = double(std::numeric_limits<Real>::epsilon());
  std::size_t mismatches = 0;
  for (std::size_t k = 0; k < host.size(); ++k) {
    if (std::memcmp(&host[k], &device[k], sizeof(Real)) == 0) continue;
    const std::size_t base = k - k % 3;  // this variant's (hit, force_over_r, energy)
    const int component = int(k % 3);
    const LJParams<Real>& p = params[(k % kLjOutputs) / 6];
    const double x = double(r2[k / kLjOutputs]);
    bool ok = false;
    if (component != 0 && host[base] == Real(1) && device[base] == Real(1) &&
        std::isfinite(double(host[k])) && std::isfinite(double(device[k]))) {
      // q = lambda^2 / r^2 in the pair's unit (core/lj.h): F / r = f12 q^7 - f6 q^4, U = e12 q^6 - e6 q^3.
      const double q = 1.0 / (x * double(p.inv_s2)), q3 = q * q * q, r = std::sqrt(x);
      const double f12 = std::abs(double(p.f12)) * q3 * q3 * q, f6 = std::abs(double(p.f6)) * q3 * q;
      const double e12 = std::abs(double(p.e12)) * q3 * q3, e6 = std::abs(double(p.e6)) * q3;
      const double fshift = std::abs(double(p.f_rc));
      const double scale = component == 1 ? f12 + f6 + fshift / r
                                          : e12 + e6 + std::abs(double(p.u_rc)) + fshift * (r + double(p.rc));
      ok = std::abs(double(device[k]) - double(host[k])) <= 32 * eps * scale;
    }
    if (!ok && ++mismatches <= 5)
      ADD_FAILURE() << "sigma " << c.sigma << " r2 " << r2[k / kLjOutputs] << " output "
                    << k % kLjOutputs << ": host " << host[k] << ", device " << device[k]
                    << " (diff " << double(device[k]) - double(host[k]) << ")";
  }
  EXPECT_EQ(mismatches, 0u) << "of " << host.size() << " outputs";
}

const LjCase kLjCases[] = {{1.0, 1.0, 2.5},           {0.88, 0.5, 2.2},        {1.3, 2.7, 3.25},
                           {3.4, 0.0104, 8.5},        {3.4e-10, 1.65e-21, 8.5e-10}, {1e-4, 1e-4, 2.5e-4},
                           {1e10, 1e10, 2.5e10}};

// Double: hit flags bitwise, force and energy within 32 ulps of the largest term (see compare_lj).
TEST_F(CoreOnDevice, LjPairDoubleMatchesHost) {
  for (const LjCase& c : kLjCases) compare_lj<double>(c);
}

// Float: hit flags bitwise, force and energy within 32 ulps of the largest term (see compare_lj).
TEST_F(CoreOnDevice, LjPairFloatMatchesHost) {
  for (const LjCase& c : kLjCases) compare_lj<float>(c);
}

// ---- reciprocal ----------------------------------------------------------------------------------
template <class Real>
__global__ void reciprocal_kernel(const Real* x, int n, Real* out) {
  const int i = int(blockIdx.x * blockDim.x + threadIdx.x);
  if (i < n) out[i] = cellforce::reciprocal(x[i]);
}

template <class Real>
std::vector<Real> device_reciprocals(const std::vector<Real>& x) {
  DeviceBuffer<Real> d_x, d_out(x.size());
  upload(d_x, x);
  const int n = int(x.size());
  reciprocal_kernel<Real><<<(n + 255) / 256, 256>>>(d_x.data(), n, d_out.data());
  CF_CUDA_CHECK_LAUNCH();
  CF_CUDA_CHECK(cudaDeviceSynchronize());
  return download(d_out, x.size());
}

// Every float x with 2^-126 <= |x| <= 2^126 (bit patterns 0x00800000 to 0x7e800000, both signs):
// counts the x whose cellforce::reciprocal differs in any bit from __frcp_rn (the device's IEEE
// round-to-nearest reciprocal, with its slow path), and keeps the smallest such pattern.
__global__ void reciprocal_sweep(unsigned long long* mismatches, unsigned* first) {
  constexpr uint32_t kLo = 0x00800000u, kHi = 0x7e800000u;
  const uint64_t stride = uint64_t(gridDim.x) * blockDim.x;
  for (uint64_t u = kLo + uint64_t(blockIdx.x) * blockDim.x + threadIdx.x; u <= kHi; u += stride) {
    for (int negative = 0; negative < 2; ++negative) {
      const uint32_t sign = negative ? 0x80000000u : 0u;
      const float x = __uint_as_float(uint32_t(u) | sign);
      if (__float_as_uint(cellforce::reciprocal(x)) != __float_as_uint(__frcp_rn(x))) {
        atomicAdd(mismatches, 1ull);
        atomicMin(first, uint32_t(u) | sign);
      }
    }
  }
}

// The device's float reciprocal (the estimate and one Newton step, no range test) is the correctly
// rounded 1 / x BITWISE for every normal x up to 2^126: against __frcp_rn for every such float
// (both signs, ~4.2e9), and against the host's division for 2^12 significands of [1, 2) (a
// stride of 2^11 in the mantissa) scaled by every power of two from 2^-126 to 2^125, both signs,
// 2^126 itself, and the float r^2 of 10^5 random LJ separations (0.5 to 3 sigma). Beyond that
// range it is documented as not 1 / x: NaN for 0, subnormals and inf (the pair is flagged as not
// finite either way), 0 above 2^126.
TEST_F(CoreOnDevice, FloatReciprocalIsTheCorrectlyRoundedQuotient) {
  std::vector<float> x;
  for (uint32_t m = 0; m < (1u << 23); m += 1u << 11) {
    const float significand = 1.0f + float(m) / float(1u << 23);
    for (int e = -126; e <= 125; ++e) {
      const float v = std::ldexp(significand, e);
      x.push_back(v);
      x.push_back(-v);
    }
  }
  uint64_t state = 0x9e3779b97f4a7c15ull;
  for (int k = 0; k < 100000; ++k) {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    const float r = 0.5f + 2.5f * float(state >> 40) / float(1u << 24);
    x.push_back(r * r);
  }
  x.push_back(std::ldexp(1.0f, 126));
  x.push_back(-std::ldexp(1.0f, 126));
  const std::vector<float> device = device_reciprocals(x);
  std::size_t mismatches = 0;
  for (std::size_t k = 0; k < x.size(); ++k) {
    const float host = 1.0f / x[k];
    if (std::memcmp(&host, &device[k], sizeof(float)) != 0 && ++mismatches <= 5)
      ADD_FAILURE() << "x " << x[k] << ": host " << host << ", device " << device[k];
  }
  EXPECT_EQ(mismatches, 0u) << "of " << x.size();

  DeviceBuffer<unsigned long long> d_count(1);
  DeviceBuffer<unsigned> d_first(1);
  upload(d_count, std::vector<unsigned long long>{0});
  upload(d_first, std::vector<unsigned>{~0u});
  reciprocal_sweep<<<4096, 256>>>(d_count.data(), d_first.data());
  CF_CUDA_CHECK_LAUNCH();
  CF_CUDA_CHECK(cudaDeviceSynchronize());
  const unsigned long long swept = download(d_count, 1)[0];
  const unsigned first = download(d_first, 1)[0];
  EXPECT_EQ(swept, 0ull) << "floats whose reciprocal is not __frcp_rn's, the first 0x" << std::hex << first;

  const float sub = std::numeric_limits<float>::denorm_min(), inf = std::numeric_limits<float>::infinity();
  const std::vector<float> off = device_reciprocals(std::vector<float>{0.0f, -0.0f, sub, 1e-39f, inf});
  for (const float r : off) EXPECT_TRUE(std::isnan(r)) << r;
  EXPECT_EQ(device_reciprocals(std::vector<float>{std::ldexp(1.5f, 126)})[0], 0.0f);
  // Double divides on the device too: bitwise the host's.
  const std::vector<double> xd = {1e-300, 0.37, 2.5 * 2.5, 6.25000001, 1e300};
  const std::vector<double> dd = device_reciprocals(xd);
  for (std::size_t k = 0; k < xd.size(); ++k) EXPECT_EQ(dd[k], 1.0 / xd[k]) << xd[k];
}

// ---- bin_particle --------------------------------------------------------------------------------
__global__ void bin_kernel(Grid g, const double* x, int n, uint32_t* ids, Control* control, uint32_t* slab) {
  const int i = int(blockIdx.x * blockDim.x + threadIdx.x);
  if (i < n) {
    uint32_t local[kMaxCellTypes];
    for (int t = 0; t < kMaxCellTypes; ++t) local[t] = 0xdeadbeefu;
    control[i] = cellforce::bin_particle(g, x + std::size_t(i) * 3, local, slab + i);
    for (int t = 0; t < kMaxCellTypes; ++t) ids[std::size_t(i) * kMaxCellTypes + t] = local[t];
  }
}

struct AxisSpec {
  bool periodic;
  double length;  // box edge (periodic) or extent of the particles (open)
  double origin;  // 0 on periodic axes
  uint32_t cells;
};

// A grid built by hand the way core/grid.h documents its fields (this binary does not link the
// library's plan_grid), with the most slab bits.
Grid make_grid(int dim, const AxisSpec (&axes)[3], double cutoff) {
  Grid g;
  g.dim = dim;
  g.half_width = 0.70710678118654752440 * (1.0 + 1e-6) * cutoff;
  uint32_t total = 1;
  for (int a = 0; a < 3; ++a) {
    const AxisSpec s = a < dim ? axes[a] : AxisSpec{false, 1.0, 0.0, 1};
    g.n[a] = s.cells;
    g.origin[a] = s.periodic ? 0.0 : s.origin;
    g.cell[a] = s.length / s.cells;
    g.inv_cell[a] = 1.0 / g.cell[a];
    g.length[a] = s.periodic ? s.length : 0.0;
    g.inv_length[a] = s.periodic ? 1.0 / s.length : 0.0;
    g.half_width_cells[a] = a < dim ? g.half_width * g.inv_cell[a] : 0.0;
    total *= s.cells;
  }
  g.num_cells = total;
  g.slab_bits = cellforce::kMaxSlabBits;
  return g;
}

std::vector<double> special_values(const Grid& g, int a) {
  const bool periodic = g.inv_length[a] != 0.0;
  const double l = g.n[a] * g.cell[a];
  std::vector<double> v = {g.origin[a], g.origin[a] + l, std::nextafter(g.origin[a] + l, -1e300)};
  if (periodic) v.insert(v.end(), {-0.0, -1e-8, -1e-300, -l, 1e3 * l + 0.5, 3 * l - 1e-9});
  for (uint32_t k = 0; k <= g.n[a]; ++k) {
    const double f = g.origin[a] + k * g.cell[a];
    for (double x : {f, std::nextafter(f, -1e300), std::nextafter(f, 1e300), f + 1e-12, f - 1e-12,
                     f + g.half_width, f - g.half_width, f + g.half_width * (1 + 1e-12),
                     f + 0.5 * g.cell[a]})
      if (periodic || (x >= g.origin[a] && x <= g.origin[a] + l)) v.push_back(x);
    // The slab's layer boundaries along the last axis (an fcc start puts particles on them).
    if (a == g.dim - 1 && k < g.n[a])
      for (uint32_t q = 1; q < (1u << g.slab_bits); ++q) {
        const double b = f + g.cell[a] * q / double(1u << g.slab_bits);
        for (double x : {b, std::nextafter(b, -1e300), std::nextafter(b, 1e300)}) v.push_back(x);
      }
  }
  return v;
}

void compare_binning(const char* name, const Grid& g) {
  std::vector<std::vector<double>> values;
  for (int a = 0; a < g.dim; ++a) values.push_back(special_values(g, a));
  std::vector<double> x;
  std::size_t total = 1;
  for (const auto& v : values) total *= v.size();
  for (std::size_t idx = 0; idx < total; ++idx) {
    std::size_t r = idx;
    for (int a = 0; a < 3; ++a) {
      if (a < g.dim) {
        x.push_back(values[std::size_t(a)][r % values[std::size_t(a)].size()]);
        r /= values[std::size_t(a)].size();
      } else {
        x.push_back(0.0);
      }
    }
  }
  uint64_t state = 12345;  // plus random points (splitmix64)
  auto uniform = [&state] {
    uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return double((z ^ (z >> 31)) >> 11) * 0x1.0p-53;
  };
  for (int i = 0; i < 5000; ++i)
    for (int a = 0; a < 3; ++a)
      x.push_back(a < g.dim ? g.origin[a] + (uniform() * 1.2 - 0.1) * g.n[a] * g.cell[a] : 0.0);
  const int n = int(x.size() / 3);

  std::vector<uint32_t> host_ids(std::size_t(n) * kMaxCellTypes, 0xdeadbeefu);
  std::vector<Control> host_control(static_cast<std::size_t>(n));
  std::vector<uint32_t> host_slab(static_cast<std::size_t>(n), 0xdeadbeefu);
  for (int i = 0; i < n; ++i)
    host_control[std::size_t(i)] = cellforce::bin_particle(g, &x[std::size_t(i) * 3],
                                                           &host_ids[std::size_t(i) * kMaxCellTypes], &host_slab[std::size_t(i)]);

  DeviceBuffer<double> d_x;
  DeviceBuffer<uint32_t> d_ids(std::max<std::size_t>(host_ids.size(), 1));
  DeviceBuffer<Control> d_control(std::max<std::size_t>(host_control.size(), 1));
  DeviceBuffer<uint32_t> d_slab(std::max<std::size_t>(host_slab.size(), 1));
  upload(d_x, x);
  bin_kernel<<<(n + 127) / 128, 128>>>(g, d_x.data(), n, d_ids.data(), d_control.data(), d_slab.data());
  CF_CUDA_CHECK_LAUNCH();
  CF_CUDA_CHECK(cudaDeviceSynchronize());
  std::vector<uint32_t> dev_ids;
  std::vector<Control> dev_control;
  dev_ids = download(d_ids, host_ids.size());
  dev_control = download(d_control, host_control.size());
  const std::vector<uint32_t> dev_slab = download(d_slab, host_slab.size());

  std::size_t mismatches = 0;
  for (int i = 0; i < n; ++i) {
    bool same = host_control[std::size_t(i)] == dev_control[std::size_t(i)] &&
                host_slab[std::size_t(i)] == dev_slab[std::size_t(i)] && host_slab[std::size_t(i)] < (1u << g.slab_bits);
    for (int t = 0; t < kMaxCellTypes; ++t)
      same = same && host_ids[std::size_t(i) * kMaxCellTypes + std::size_t(t)] ==
                         dev_ids[std::size_t(i) * kMaxCellTypes + std::size_t(t)];
    if (!same && ++mismatches <= 5)
      ADD_FAILURE() << name << ": point (" << x[std::size_t(i) * 3] << ", "
                    << x[std::size_t(i) * 3 + 1] << ", " << x[std::size_t(i) * 3 + 2]
                    << "): host home " << host_ids[std::size_t(i) * kMaxCellTypes] << " control "
                    << host_control[std::size_t(i)] << ", device home "
                    << dev_ids[std::size_t(i) * kMaxCellTypes] << " control "
                    << dev_control[std::size_t(i)] << "; slab host " << host_slab[std::size_t(i)] << " device "
                    << dev_slab[std::size_t(i)];
  }
  EXPECT_EQ(mismatches, 0u) << name << ": of " << n << " points";
}

// Cell IDs (all 8 slots), control bits and slabs equal exactly, host vs device, on every grid.
TEST_F(CoreOnDevice, BinParticleEqualsHost) {
  const double rc = 2.5;
  compare_binning("periodic3d_L20", make_grid(3, {{true, 20, 0, 4}, {true, 20, 0, 4}, {true, 20, 0, 4}}, rc));
  compare_binning("periodic3d_uneven", make_grid(3, {{true, 9, 0, 2}, {true, 13, 0, 2}, {true, 21.3, 0, 4}}, rc));
  compare_binning("periodic3d_one_cell", make_grid(3, {{true, 5, 0, 1}, {true, 5, 0, 1}, {true, 5, 0, 1}}, rc));
  compare_binning("periodic2d", make_grid(2, {{true, 20, 0, 4}, {true, 17.7, 0, 4}, {false, 1, 0, 1}}, rc));
  compare_binning("open3d", make_grid(3, {{false, 20, -3.1, 4}, {false, 17, 1.7, 3}, {false, 40, -20, 9}}, rc));
  compare_binning("slab3d", make_grid(3, {{true, 20, 0, 4}, {true, 20, 0, 4}, {false, 13, 2.2, 3}}, rc));
  compare_binning("slab2d", make_grid(2, {{true, 30.7, 0, 6}, {false, 20, -10, 4}, {false, 1, 0, 1}}, rc));
}

}  // namespace
