// Shared test helpers: deterministic random configurations, and the comparisons every test uses
// against the double-precision brute force (the oracle, src/reference/brute_force.h).
//
// Tolerances are always passed in and stated at the call site. Comparisons return
// ::testing::AssertionResult so that a failure names the worst particle and the numbers.
#pragma once

#include <gtest/gtest.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/box.h"
#include "core/force_field.h"
#include "core/system.h"
#include "scene/lattice.h"

namespace cftest {

using Pair = std::pair<uint32_t, uint32_t>;

// ---- deterministic random numbers (same sequence on every platform and standard library) -----
class Rng {
 public:
  explicit Rng(uint64_t seed) : state_(seed * 0x9E3779B97F4A7C15ull + 0x632BE59BD9B4E019ull) {}
  uint64_t next();                         // splitmix64
  double uniform();                        // [0, 1), 53 random bits
  double uniform(double lo, double hi);    // [lo, hi)
  std::size_t below(std::size_t n);        // [0, n)

 private:
  uint64_t state_;
};

// ---- sort oracle -------------------------------------------------------------------------------
// (key, value) with value = input position, stably sorted on the key's low `key_bits` bits by
// std::stable_sort: what every radix sort of the project must reproduce exactly.
std::vector<std::pair<uint32_t, uint32_t>> stable_sorted_with_positions(
    const std::vector<uint32_t>& keys, int key_bits);

// ---- boxes -------------------------------------------------------------------------------------
cellforce::Box make_box(int dim, std::array<double, 3> lengths, std::array<bool, 3> periodic);
// A cube (square in 2D) of edge l, periodic or open on every axis.
cellforce::Box cube(int dim, double l, bool periodic = true);

// ---- configurations ------------------------------------------------------------------------------
struct RandomSpec {
  // No two particles closer than this (minimum image on periodic axes); 0 = no constraint.
  double min_distance = 0.0;
  uint32_t num_types = 1;  // types drawn uniformly from [0, num_types)
  // Region the positions are drawn from, per axis; default [0, L_a).
  std::optional<std::array<double, 3>> lo, hi;
};

// n particles uniformly at random (random sequential addition when min_distance > 0). Throws
// std::runtime_error when n particles cannot be placed (the spec is too dense).
cellforce::Configuration random_configuration(const cellforce::Box& box, std::size_t n,
                                              uint64_t seed, const RandomSpec& spec = {});

// One particle type "A" (sigma, epsilon 1) with this cutoff and mode.
cellforce::ForceField lj_field(double cutoff, double sigma = 1.0,
                               cellforce::CutoffMode mode = cellforce::CutoffMode::kTruncate);

// `c` with each particle moved by a random vector (uniform direction) shorter than max_step; no
// wrap (periodic images are left as they fall).
cellforce::Configuration moved(const cellforce::Configuration& c, double max_step, uint64_t seed);

// Squared minimum-image distance of particles i and j of a configuration (exactly as a reader of
// brute_force.h would compute it).
double distance2(const cellforce::Configuration& c, std::size_t i, std::size_t j);

// A configuration whose particle i is the input's particle perm[i].
cellforce::Configuration permuted(const cellforce::Configuration& c,
                                  const std::vector<std::size_t>& perm);
std::vector<std::size_t> random_permutation(std::size_t n, uint64_t seed);

// ---- results ------------------------------------------------------------------------------------
double force_norm(const cellforce::ForceResult& r, std::size_t i);
double force_rms(const cellforce::ForceResult& r);

// Per particle: |F_got_i - F_ref_i| <= tol * max(|F_ref_i|, F_rms_ref).
::testing::AssertionResult forces_match(const cellforce::ForceResult& ref,
                                        const cellforce::ForceResult& got, double tol);
// Per particle: |e_got_i - e_ref_i| <= tol * max(|e_ref_i|, e_rms_ref).
::testing::AssertionResult energies_match(const cellforce::ForceResult& ref,
                                          const cellforce::ForceResult& got, double tol);
// |E_got - E_ref| <= tol * max(|E_ref|, sum_i |e_ref_i|) (the second term guards a total that
// cancels to near zero).
::testing::AssertionResult total_energy_matches(const cellforce::ForceResult& ref,
                                                const cellforce::ForceResult& got, double tol);
// Per component of the dim x dim block: |W_got_ab - W_ref_ab| <= tol * max_ab |W_ref_ab|.
::testing::AssertionResult virial_matches(const cellforce::ForceResult& ref,
                                          const cellforce::ForceResult& got, double tol);
// Bitwise equality of forces, energies, total energy and virial (memcmp, so -0.0 != 0.0).
::testing::AssertionResult bitwise_equal(const cellforce::ForceResult& a,
                                         const cellforce::ForceResult& b);
// Median over particles with F_ref_i != 0 of |F_got_i - F_ref_i| / |F_ref_i|.
double median_relative_force_error(const cellforce::ForceResult& ref,
                                   const cellforce::ForceResult& got);
// The engines' agreement with a reference evaluation in their precision (EXPECTs): double to 1e-12
// (forces, per-particle energies, total energy, virial); float pairs (single, mixed) a median
// relative force error below 1e-6 and total energy and virial to 1e-5.
void expect_results_match(const cellforce::ForceResult& ref, const cellforce::ForceResult& got,
                          cellforce::Precision precision);

// ---- pair sets ----------------------------------------------------------------------------------
// Each pair as (min, max), sorted; duplicates kept.
std::vector<Pair> normalized(std::vector<Pair> pairs);
// Pairs that appear more than once (each listed once per extra occurrence).
std::vector<Pair> duplicates(std::vector<Pair> pairs);
// Pairs of `expected` that `got` lacks (both taken as sets).
std::vector<Pair> missing(std::vector<Pair> expected, std::vector<Pair> got);
// got, as a multiset, equals expected exactly: no missing pair, no extra pair, no duplicate.
::testing::AssertionResult pair_sets_equal(std::vector<Pair> expected, std::vector<Pair> got);
std::string to_string(const std::vector<Pair>& pairs, std::size_t max_items = 10);

// ---- errors -------------------------------------------------------------------------------------
// true when `text` contains the decimal number `value` as a whole number (not inside another
// number: "particle 7" contains 7, "17" and "0.7" do not).
bool contains_number(const std::string& text, uint64_t value);
std::string lowercase(std::string s);

}  // namespace cftest
