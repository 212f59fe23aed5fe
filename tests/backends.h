// The engines under test, behind the backends' ForceEngine interface, so that every pipeline
// property is one test body instantiated for each backend (style.md, tests): the CPU engine and,
// where CUDA is built, the CUDA engine in each traversal form, whose `unavailable` returns a
// reason ("no CUDA device: ...") so that its instances skip where there is no GPU.
#pragma once

#include <cstddef>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/grid.h"
#include "core/reuse.h"
#include "core/system.h"
#include "backends/force_engine.h"
#include "oracle.h"

namespace cftest {

// What a test may ask of any backend.
struct EngineSpec {
  cellforce::Precision precision = cellforce::Precision::kDouble;
  cellforce::Accumulation accumulation = cellforce::Accumulation::kJacobi;
  // Tests only: a grid used as given, unchecked (make_grid_unchecked), to break a condition.
  std::optional<cellforce::Grid> grid_override;
  cellforce::ReuseOptions reuse;  // skin, check, every, audit (core/reuse.h)
};

// The product's force-engine interface (src/backends/force_engine.h): the tests drive the engines
// exactly as the public API does.
using EngineUnderTest = cellforce::ForceEngine;

struct Backend {
  std::string name;  // [a-z0-9] only: it becomes part of test names
  // Empty when the backend can run here; otherwise why not (the test is skipped with it).
  std::function<std::string()> unavailable;
  std::function<std::unique_ptr<EngineUnderTest>(const EngineSpec&)> make;
};

const std::vector<Backend>& backends();
// 0 .. backends().size() - 1, for ::testing::ValuesIn.
std::vector<std::size_t> backend_ids();

}  // namespace cftest
