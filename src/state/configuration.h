// A configuration the host owns: what a SystemView points to. The state layer's host form, used
// by the integrators, the file readers and the scene builders alike.
#pragma once

#include <cstdint>
#include <vector>

#include "core/box.h"
#include "core/system.h"

namespace cellforce {

struct Configuration {
  Box box;
  std::vector<double> positions;  // n x box.dim, row-major
  std::vector<uint32_t> types;    // n

  std::size_t size() const { return types.size(); }
  SystemView view() const { return SystemView{box, types.size(), positions.data(), types.data()}; }
};

}  // namespace cellforce
