// Particle configurations built from lattices, for scenes, tests and benchmarks.
#pragma once

#include <cstdint>
#include <vector>

#include "core/box.h"
#include "core/system.h"

namespace cellforce {

// Owns what a SystemView points to.
struct Configuration {
  Box box;
  std::vector<double> positions;  // n x box.dim
  std::vector<uint32_t> types;    // n

  std::size_t size() const { return types.size(); }
  SystemView view() const { return SystemView{box, types.size(), positions.data(), types.data()}; }
};

enum class Lattice : uint8_t { kSimpleCubic, kBcc, kFcc, kSquare };

// A periodic cubic (square in 2D) box of cells^dim unit cells at the given number density;
// all particles type 0. fcc: 4 per cell, bcc: 2, sc and square: 1.
Configuration make_lattice(Lattice lattice, int cells, double density);

// Moves every particle by an independent uniform displacement in [-amplitude, amplitude) per
// axis (deterministic for a seed).
void jitter(Configuration& config, double amplitude, uint64_t seed);

// n particles uniformly at random in the box (no minimum distance), all type 0.
Configuration make_random(const Box& box, std::size_t n, uint64_t seed);

}  // namespace cellforce
