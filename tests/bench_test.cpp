// `cellforce bench` (src/cli/bench.h) on the CPU backend: its JSON rows carry what the performance
// report reads, with values checked against what they must be (step counts, a force error against
// double precision of the float rounding's size, memory per particle of the state at least), and a
// size that cannot run becomes a row with its error while the other sizes still run.
#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>

#include "cli/bench.h"
#include "temp_folder.h"

namespace cftest {
namespace {

using Bench = TempFolder;

cellforce::BenchArgs small_bench(const std::string& json) {
  cellforce::BenchArgs a;
  a.engine.set(cellforce::OptionId::kBackend, "cpu");
  a.engine.set(cellforce::OptionId::kPrecision, "mixed");
  a.steps = 20;
  a.warmup = 5;
  a.samples = 4;
  a.json = json;
  return a;
}

TEST_F(Bench, RowsCarryTheReportsNumbers) {
  cellforce::BenchArgs a = small_bench(path("bench.json"));
  a.cells = {3, 4};
  ASSERT_EQ(cellforce::run_bench(a), 0);
  const nlohmann::json doc = nlohmann::json::parse(read(path("bench.json")));
  ASSERT_EQ(doc["rows"].size(), 2u);
  const std::size_t expected_n[] = {108, 256};
  for (std::size_t k = 0; k < 2; ++k) {
    const nlohmann::json& r = doc["rows"][k];
    EXPECT_EQ(r["n"].get<std::size_t>(), expected_n[k]);
    EXPECT_EQ(r["engine"], "cellforce");
    EXPECT_EQ(r["configuration"], "default");
    EXPECT_EQ(r["precision"], "mixed");
    EXPECT_EQ(r["steps"].get<int64_t>(), 20);  // 4 samples of 5 steps
    EXPECT_EQ(r["builds"].get<int64_t>(), r["evaluations"].get<int64_t>()) << "no skin: a build per evaluation";
    EXPECT_EQ(r["skin_requested"], "auto");  // BenchArgs' default, as a scene without [neighbor]
    EXPECT_EQ(r["skin"].get<double>(), 0.0);  // what auto chose on the CPU
    EXPECT_EQ(r["neighbor"], "none, stages 1-3 every evaluation (auto: no skin on the cpu)");
    EXPECT_EQ(r["list_evaluations"].get<int64_t>(), 0);
    EXPECT_FALSE(r["neighbor_list"].get<bool>());
    const double rate = r["steps_per_second"].get<double>();
    EXPECT_GT(rate, 0.0);
    EXPECT_NEAR(r["particle_steps_per_second"].get<double>(), rate * double(expected_n[k]), 1e-9 * rate * 256);
    EXPECT_NEAR(r["ms_per_step"].get<double>(), 1e3 / rate, 1e-9 * 1e3 / rate);
    // Mixed against double on the same configuration: float pairs, ~1e-6.
    EXPECT_GT(r["force_error_median"].get<double>(), 0.0);
    EXPECT_LT(r["force_error_median"].get<double>(), 1e-5);
    // At least positions, velocities, forces and masses in double.
    EXPECT_GE(r["bytes_per_particle"].get<double>(), 80.0);
    EXPECT_TRUE(std::isfinite(r["nve_drift"].get<double>()));
    EXPECT_NEAR(r["nve_time_span"].get<double>(), 20 * 0.005, 1e-12);
  }
}

// --langevin: the same fluid under BAOAB at kT 1.44 (friction 1): the lattice start gives half its
// kinetic energy to the potential (NVE settles near T 0.7), and the thermostat brings it back
// within 1/friction = 200 steps; the row says so and carries no NVE drift.
TEST_F(Bench, LangevinRowsHoldTheirTemperature) {
  cellforce::BenchArgs a = small_bench(path("bench.json"));
  a.cells = {4};
  a.langevin = true;
  a.reference = false;
  a.steps = 800;
  a.warmup = 200;
  ASSERT_EQ(cellforce::run_bench(a), 0);
  const nlohmann::json r = nlohmann::json::parse(read(path("bench.json")))["rows"][0];
  EXPECT_EQ(r["integrator"], "langevin");
  EXPECT_TRUE(r["nve_drift"].is_null());
  EXPECT_GT(r["temperature_end"].get<double>(), 1.0);
  EXPECT_LT(r["temperature_end"].get<double>(), 2.0);
  a.langevin = false;
  ASSERT_EQ(cellforce::run_bench(a), 0);
  const nlohmann::json nve = nlohmann::json::parse(read(path("bench.json")))["rows"][0];
  EXPECT_EQ(nve["integrator"], "nve");
  EXPECT_LT(nve["temperature_end"].get<double>(), 1.0) << "NVE from the lattice settles near T 0.7";
}

TEST_F(Bench, ASizeThatCannotRunIsAnErrorRowAndTheOthersRun) {
  cellforce::BenchArgs a = small_bench(path("bench.json"));
  a.cells = {1, 3};  // one fcc cell: a box of 1.68, less than twice the cutoff 2.5
  a.reference = false;
  EXPECT_EQ(cellforce::run_bench(a), 1);
  const nlohmann::json doc = nlohmann::json::parse(read(path("bench.json")));
  ASSERT_EQ(doc["rows"].size(), 2u);
  ASSERT_TRUE(doc["rows"][0].contains("error"));
  EXPECT_NE(doc["rows"][0]["error"].get<std::string>().find("cutoff"), std::string::npos)
      << doc["rows"][0]["error"];
  EXPECT_FALSE(doc["rows"][1].contains("error"));
  EXPECT_EQ(doc["rows"][1]["n"].get<std::size_t>(), 108u);
  EXPECT_FALSE(doc["rows"][1].contains("force_error_median")) << "--no-reference";
}

}  // namespace
}  // namespace cftest
