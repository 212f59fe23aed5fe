// Particle configurations built from lattices, for scenes, tests and benchmarks.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "core/box.h"
#include "core/names.h"
#include "state/configuration.h"

namespace cellforce {

enum class Lattice : uint8_t { kSimpleCubic, kBcc, kFcc, kSquare, kHexagonal };
inline constexpr Named<Lattice> kLatticeNames[] = {{"sc", Lattice::kSimpleCubic},
                                                   {"bcc", Lattice::kBcc},
                                                   {"fcc", Lattice::kFcc},
                                                   {"square", Lattice::kSquare},
                                                   {"hexagonal", Lattice::kHexagonal}};

// cells[0] x cells[1] (x cells[2] in 3D) unit cells of lattice constant a, periodic box of the
// lattice's extent, all particles type 0. fcc: 4 per cell, bcc: 2, sc and square: 1; hexagonal
// (2D, triangular): a rectangular cell a x a*sqrt(3) holding 2.
Configuration make_lattice_cells(Lattice lattice, std::array<int, 3> cells, double a);
// The particles make_lattice_cells places, as a double (the product of three counts may exceed
// any integer): checked against the memory before anything is allocated.
double lattice_site_count(Lattice lattice, std::array<int, 3> cells);
// The lattice constant that gives the number density (particles per volume, or per area in 2D).
double lattice_constant_for(Lattice lattice, double density);
// Lattice dimension: 2 for square and hexagonal, else 3.
int lattice_dimension(Lattice lattice);

// A periodic cubic (square in 2D) box of cells^dim unit cells at the given number density;
// all particles type 0. fcc: 4 per cell, bcc: 2, sc and square: 1.
Configuration make_lattice(Lattice lattice, int cells, double density);

// Moves every particle by an independent uniform displacement in [-amplitude, amplitude) per
// axis (deterministic for a seed).
void jitter(Configuration& config, double amplitude, uint64_t seed);

// n particles uniformly at random in the box (no minimum distance), all type 0.
Configuration make_random(const Box& box, std::size_t n, uint64_t seed);

// n particles placed one by one uniformly at random, each at least min_distance from all
// placed before (minimum image on periodic axes), all type 0; deterministic for a seed. Throws
// cellforce::Error when a particle finds no place in 10,000 tries (the packing is too dense).
Configuration make_random_spaced(const Box& box, std::size_t n, double min_distance, uint64_t seed);

}  // namespace cellforce
