// The C++ API from a program built with -D_GLIBCXX_USE_CXX11_ABI=0 (CMakeLists.txt): forces of
// three particles against the analytic pair sum, an option set by name (cutoff-mode), a type added
// by a std::string name, an error caught with its message, the text calls (backend_name, neighbor,
// statistics_json) and the run statistics after a few steps. Each check exits non-zero when it
// fails; the printed lines are required by tests/consumer/run_old_abi.cmake.
#include <cellforce/cellforce.hpp>

#include <cmath>
#include <cstdio>
#include <string>

#include "system.h"

// The old ABI, in force here: std::string is libstdc++'s reference-counted string.
static_assert(_GLIBCXX_USE_CXX11_ABI == 0, "old_abi.cpp must be built with -D_GLIBCXX_USE_CXX11_ABI=0");

namespace {

constexpr int kParticles = 3;
const double kPositions[3 * kParticles] = {1.0, 1.0, 1.0, 2.3, 1.0, 1.0, 1.0, 2.2, 1.0};

int fail(const std::string& what) {
  std::fprintf(stderr, "old_abi: %s\n", what.c_str());
  return 1;
}

// The shifted pair sum of kPositions (sigma = epsilon = 1, rc = kCutoff): each particle's force and
// the total energy.
void analytic(double* forces, double* energy) {
  double e_rc, unused;
  lj_pair(kCutoff, 1.0, 1.0, &e_rc, &unused);
  *energy = 0;
  for (int k = 0; k < 3 * kParticles; ++k) forces[k] = 0;
  for (int i = 0; i < kParticles; ++i)
    for (int j = i + 1; j < kParticles; ++j) {
      double d[3], r2 = 0;
      for (int a = 0; a < 3; ++a) {
        d[a] = kPositions[3 * i + a] - kPositions[3 * j + a];
        r2 += d[a] * d[a];
      }
      double e, f_over_r;
      lj_pair(std::sqrt(r2), 1.0, 1.0, &e, &f_over_r);
      *energy += e - e_rc;
      for (int a = 0; a < 3; ++a) {
        forces[3 * i + a] += f_over_r * d[a];
        forces[3 * j + a] -= f_over_r * d[a];
      }
    }
}

}  // namespace

int main() {
  try {
    cellforce::Context ctx(3);
    const double box[3] = {10.0, 10.0, 10.0};
    const bool periodic[3] = {true, true, true};
    ctx.set_box(box, periodic);
    ctx.set_option("cutoff-mode", "shift");
    ctx.set_cutoff(kCutoff);  // keeps the mode set by name
    const std::string name = "A";
    if (ctx.add_type(name, 1.0, 1.0) != 0) return fail("the first type's index is not 0");

    double forces[3 * kParticles], energy = 0, expected_forces[3 * kParticles], expected_energy = 0;
    ctx.compute(kParticles, kPositions, nullptr, {forces, nullptr, &energy, nullptr});
    analytic(expected_forces, &expected_energy);
    if (std::abs(energy - expected_energy) > 1e-13 * std::abs(expected_energy))
      return fail("energy " + std::to_string(energy) + ", expected " + std::to_string(expected_energy));
    for (int k = 0; k < 3 * kParticles; ++k)
      if (std::abs(forces[k] - expected_forces[k]) > 1e-12 * (1.0 + std::abs(expected_forces[k])))
        return fail("force " + std::to_string(k) + " is " + std::to_string(forces[k]) + ", expected " +
                    std::to_string(expected_forces[k]));
    std::printf("energy %.17g (analytic %.17g)\n", energy, expected_energy);
    for (int i = 0; i < kParticles; ++i)
      std::printf("force %d %.17g %.17g %.17g\n", i, forces[3 * i], forces[3 * i + 1], forces[3 * i + 2]);

    try {
      ctx.set_cutoff(-1.0);
      return fail("a negative cutoff was accepted");
    } catch (const cellforce::Error& e) {
      const std::string message = e.message();
      if (message.find("cutoff") == std::string::npos) return fail(std::string("unexpected message: ") + e.what());
      if (std::string(e.what()) != "cellforce: " + message) return fail(std::string("what() is ") + e.what());
      std::printf("error: %s\n", message.c_str());
    }

    const std::string backend = ctx.backend_name(), neighbor = ctx.neighbor();
    std::printf("backend: %s\nneighbor: %s\n", backend.c_str(), neighbor.c_str());

    const double masses[kParticles] = {1.0, 1.0, 1.0};
    ctx.set_integrator(cellforce::IntegratorOptions{});
    ctx.set_state(kParticles, kPositions, nullptr, nullptr, masses);
    ctx.step(10);
    const cellforce::RunStatistics run = ctx.run_statistics();
    if (run.steps != 10 || run.evaluations < 10) return fail("run statistics: " + std::to_string(run.steps) + " steps");
    std::printf("run: %lld steps, %lld evaluations\n", (long long)run.steps, (long long)run.evaluations);
    const std::string json = ctx.statistics_json();
    if (json.find("\"steps\":10") == std::string::npos) return fail("statistics_json without the steps: " + json);
    std::printf("statistics_json: %s\n", json.c_str());
    return 0;
  } catch (const cellforce::Error& e) {
    return fail(e.what());
  }
}
