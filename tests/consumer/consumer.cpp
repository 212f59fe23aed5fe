// The C++ API as a C++ program uses it: the same checks and output as consumer.c.
#include <cellforce/cellforce.hpp>

// The target asks for C++14 (tests/consumer/CMakeLists.txt); cellforce::cellforce raises it.
static_assert(__cplusplus >= 201703L, "the cellforce package should require C++17 of its users");

#include <cmath>
#include <cstdio>
#include <vector>

#include "system.h"

int main() {
  try {
    double box[3];
    std::vector<double> positions(3 * kN), forces(3 * kN);
    std::vector<uint32_t> types(kN);
    make_system(positions.data(), types.data(), box);
    cellforce::Context ctx(3);
    const bool periodic[3] = {true, true, true};
    ctx.set_box(box, periodic);
    ctx.set_cutoff(kCutoff, cellforce::CutoffMode::kTruncate);
    ctx.add_type("A", 1.0, 1.0);
    ctx.add_type("B", 0.9, 0.6);

    const double pair[6] = {1.0, 1.0, 1.0, 1.0, 2.3, 1.0};
    double f2[6], e2 = 0, w2[9];
    ctx.compute(2, pair, nullptr, {f2, nullptr, &e2, w2});
    double e_ref, fr_ref;
    lj_pair(1.3, 1.0, 1.0, &e_ref, &fr_ref);
    const double f_ref = -fr_ref * 1.3;
    if (std::abs(e2 - e_ref) > 1e-13 * std::abs(e_ref) || std::abs(f2[1] - f_ref) > 1e-13 * std::abs(f_ref)) {
      std::fprintf(stderr, "consumer_cpp: pair energy %.17g force %.17g; expected %.17g %.17g\n", e2, f2[1],
                   e_ref, f_ref);
      return 1;
    }

    double energy = 0, virial[9];
    ctx.compute(kN, positions.data(), types.data(), {forces.data(), nullptr, &energy, virial});
    std::printf("cellforce %s\nheaders %d.%d.%d\nenergy %.17g\n", cellforce::version(), CELLFORCE_VERSION_MAJOR,
                CELLFORCE_VERSION_MINOR, CELLFORCE_VERSION_PATCH, energy);
    for (int k = 0; k < 9; ++k) std::printf("virial %d %.17g\n", k, virial[k]);
    for (int i = 0; i < 3 * kN; ++i) std::printf("force %d %.17g\n", i, forces[std::size_t(i)]);

    // Molecular dynamics: kMdSteps Verlet steps from the lattice at rest, as consumer.c runs them.
    std::vector<double> masses(kN), x(3 * kN), v(3 * kN);
    for (int i = 0; i < kN; ++i) masses[std::size_t(i)] = kMass[types[std::size_t(i)]];
    cellforce::IntegratorOptions integrator;
    integrator.dt = kDt;
    ctx.set_integrator(integrator);
    ctx.set_state(kN, positions.data(), nullptr, types.data(), masses.data(), 0);
    ctx.step(kMdSteps);
    ctx.get_state(x.data(), v.data(), nullptr);
    const cellforce::Thermo t = ctx.thermo();
    std::printf("md kinetic %.17g potential %.17g temperature %.17g pressure %.17g\n", t.kinetic, t.potential,
                t.temperature, t.pressure);
    for (int i = 0; i < 3 * kN; ++i)
      std::printf("md %d %.17g %.17g\n", i, x[std::size_t(i)], v[std::size_t(i)]);
    // Errors arrive as cellforce::Error naming the parameter.
    try {
      ctx.set_cutoff(-1.0);
      std::fprintf(stderr, "consumer_cpp: a negative cutoff was accepted\n");
      return 1;
    } catch (const cellforce::Error& e) {
      if (e.message().find("cutoff") == std::string::npos) {
        std::fprintf(stderr, "consumer_cpp: unexpected message: %s\n", e.what());
        return 1;
      }
    }
    return 0;
  } catch (const cellforce::Error& e) {
    std::fprintf(stderr, "consumer_cpp: %s\n", e.what());
    return 1;
  }
}
