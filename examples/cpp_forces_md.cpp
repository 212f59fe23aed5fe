// cellforce's C++ API, host arrays: the forces and energy of one configuration, then a short NVE run.
//
// The same system, calls and checks as c_forces_md.c, through cellforce::Context: LAMMPS's in.lj
// (4,000 particles, fcc at density 0.8442, periodic, Lennard-Jones cut at rc = 2.5, T = 1.44,
// velocity Verlet with dt = 0.005), with the potential shifted to zero at rc so that the total
// energy is conserved. It prints what c_forces_md prints, number for number, and exits 1 when a
// check fails or a call throws.
//
// Build against the installed package: examples/README.md.
#include <cellforce/cellforce.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <vector>

namespace {

constexpr int kCells = 10, kN = 4 * kCells * kCells * kCells, kSteps = 500, kEvery = 50;
constexpr double kDensity = 0.8442, kCutoff = 2.5, kTemperature = 1.44, kDt = 0.005;
constexpr double kDriftTolerance = 5e-4;  // largest change of the total energy per particle
constexpr double kBasis[4][3] = {{0, 0, 0}, {0.5, 0.5, 0}, {0.5, 0, 0.5}, {0, 0.5, 0.5}};

// The fcc lattice (cubic cell edge a) and, from a fixed random sequence, velocities with zero total
// momentum scaled to kTemperature = 2 KE / (3 (N - 1)): the numbers c_forces_md.c makes.
void make_system(double a, std::vector<double>& x, std::vector<double>& v) {
  uint64_t seed = 87287;
  double mean[3] = {0, 0, 0}, v2 = 0;
  std::size_t i = 0;
  for (int cx = 0; cx < kCells; ++cx)
    for (int cy = 0; cy < kCells; ++cy)
      for (int cz = 0; cz < kCells; ++cz)
        for (int b = 0; b < 4; ++b, ++i) {
          const int c[3] = {cx, cy, cz};
          for (int k = 0; k < 3; ++k) {
            x[3 * i + k] = (c[k] + kBasis[b][k]) * a;
            seed = seed * 6364136223846793005ull + 1442695040888963407ull;
            v[3 * i + k] = double(seed >> 11) / 9007199254740992.0 - 0.5;
            mean[k] += v[3 * i + k] / kN;
          }
        }
  for (i = 0; i < v.size(); ++i) v2 += (v[i] - mean[i % 3]) * (v[i] - mean[i % 3]);
  const double scale = std::sqrt(kTemperature * 3 * (kN - 1) / v2);  // unit masses: 2 KE = sum v^2
  for (i = 0; i < v.size(); ++i) v[i] = (v[i] - mean[i % 3]) * scale;
}

// The lattice's energy without cellforce: N/2 times one site's pair energies with the sites within rc.
double lattice_energy(double a) {
  double sum = 0;
  for (int i = -3; i <= 3; ++i)
    for (int j = -3; j <= 3; ++j)
      for (int k = -3; k <= 3; ++k)
        for (const auto& b : kBasis) {
          const double d[3] = {(i + b[0]) * a, (j + b[1]) * a, (k + b[2]) * a};
          const double r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
          if (r2 == 0 || r2 >= kCutoff * kCutoff) continue;
          const double s6 = 1 / (r2 * r2 * r2), c6 = 1 / std::pow(kCutoff, 6); // shifted: U(rc) = 0
          sum += 4 * (s6 * s6 - s6) - 4 * (c6 * c6 - c6);
        }
  return 0.5 * kN * sum;
}

int fail(const char* what) {
  std::fprintf(stderr, "cpp_forces_md: check failed: %s\n", what);
  return 1;
}

}  // namespace

int main() {
  try {
    std::vector<double> x(3 * kN), v(3 * kN), f(3 * kN), masses(kN, 1.0);
    const double a = std::cbrt(4 / kDensity);
    make_system(a, x, v);

    // The physics: box, cutoff and types (type 0 first; a null types array means all type 0).
    cellforce::Context ctx(3);
    const double box[3] = {kCells * a, kCells * a, kCells * a};
    const bool periodic[3] = {true, true, true};
    ctx.set_box(box, periodic);
    ctx.set_cutoff(kCutoff, cellforce::CutoffMode::kShift);  // U(r) - U(rc) for r < rc, else 0
    ctx.add_type("A", 1.0, 1.0);  // sigma, epsilon
    ctx.set_backend(cellforce::Backend::kAuto);  // a CUDA device when one can be used, else the CPU

    // 1. Forces, total energy and virial of one configuration: Outputs names where each result goes
    // (a null pointer: not computed).
    double energy = 0, virial[9];
    ctx.compute(kN, x.data(), nullptr, {f.data(), nullptr, &energy, virial});
    double largest_force = 0;
    for (double fk : f) largest_force = std::max(largest_force, std::abs(fk));
    const double expected = lattice_energy(a);
    std::printf("cellforce %s: %d particles, box %.6f, rc %.1f\n", cellforce::version(), kN, box[0], kCutoff);
    std::printf("lattice energy/particle %.12f (lattice sum %.12f), largest force component %.1e\n", energy / kN,
                expected / kN, largest_force);
    if (std::abs(energy - expected) > 1e-10 * std::abs(expected) || largest_force > 1e-9)
      return fail("the lattice's energy (1e-10 relative) or its zero forces (1e-9)");

    // 2. Molecular dynamics: the context keeps the state (on the GPU with cuda) and steps it; the
    // host reads it back only when asked (thermo, get_state).
    cellforce::IntegratorOptions verlet;  // kVerlet: NVE
    verlet.dt = kDt;
    ctx.set_integrator(verlet);
    ctx.set_state(kN, x.data(), v.data(), nullptr, masses.data(), 0);  // also evaluates the forces
    double e0 = 0, drift = 0;
    std::printf("%6s %10s %12s %12s %12s %10s\n", "step", "temp", "ke/atom", "pe/atom", "etot/atom", "press");
    for (int step = 0; step <= kSteps; step += kEvery) {
      if (step > 0) ctx.step(kEvery);  // the last step of each call computes the energy
      const cellforce::Thermo t = ctx.thermo();
      std::printf("%6d %10.6f %12.8f %12.8f %12.8f %10.6f\n", step, t.temperature, t.kinetic / kN,
                  t.potential / kN, (t.kinetic + t.potential) / kN, t.pressure);
      if (step == 0) e0 = t.kinetic + t.potential;
      drift = std::max(drift, std::abs(t.kinetic + t.potential - e0) / kN);
      if (step == 0 && std::abs(t.temperature - kTemperature) > 1e-12 * kTemperature)
        return fail("the state's temperature is not the velocities' (1e-12 relative)");
    }
    ctx.get_state(x.data(), v.data(), f.data());  // positions (wrapped into the box), velocities, forces
    double momentum[3] = {0, 0, 0};
    for (std::size_t i = 0; i < v.size(); ++i) momentum[i % 3] += v[i];  // unit masses
    const double p = std::max({std::abs(momentum[0]), std::abs(momentum[1]), std::abs(momentum[2])});
    std::printf("energy conserved: largest |etot - etot(0)| per particle %.1e (tolerance %.0e)\n", drift,
                kDriftTolerance);
    std::printf("momentum conserved: largest component of the total %.0e (tolerance 1e-9)\n", p);
    if (drift > kDriftTolerance || p > 1e-9) return fail("the total energy or momentum is not conserved");
    return 0;
  } catch (const cellforce::Error& e) {  // names the parameter, particle or option at fault
    std::fprintf(stderr, "cpp_forces_md: %s\n", e.what());
    return 1;
  }
}
