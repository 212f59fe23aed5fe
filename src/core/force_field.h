// Lennard-Jones parameters of a scene: particle types, mixing rule, explicit pair values, cutoff
// and cutoff mode, and the per-pair table that the pair evaluator reads.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include <cellforce/options.hpp>  // Mixing, CutoffMode, Precision

#include "core/lj.h"

namespace cellforce {

struct ParticleType {
  std::string name;
  double sigma = 1.0;    // length units
  double epsilon = 1.0;  // energy units
};

// An explicit pair value that replaces the mixing rule (e.g. Kob-Andersen's A-B pair).
struct PairOverride {
  std::size_t a = 0, b = 0;  // type indices
  double sigma = 1.0;
  double epsilon = 1.0;
};

struct ForceField {
  double cutoff = 2.5;
  CutoffMode mode = CutoffMode::kTruncate;
  Mixing mixing = Mixing::kLorentzBerthelot;
  std::vector<ParticleType> types = {ParticleType{"A", 1.0, 1.0}};
  std::vector<PairOverride> overrides;

  std::size_t num_types() const { return types.size(); }
  double pair_sigma(std::size_t a, std::size_t b) const;
  double pair_epsilon(std::size_t a, std::size_t b) const;
  // Throws cellforce::Error naming the offending parameter (cutoff, type name, override).
  void validate() const;
};

// Throws cellforce::Error when a float evaluation (Precision::kSingle or kMixed) of this force
// field would leave float's range: a pair constant of make_lj_params (core/lj.h) outside
// [kFloatRangeLow, kFloatRangeHigh] (float's normal range with 2^24 to spare on either side, for
// the powers of q and the sums they enter), or the cutoff's square. The message names the pair's
// types, the parameter (sigma, epsilon or the cutoff) and the precision. Double is not limited.
void check_precision_range(const ForceField& ff, Precision precision);
inline constexpr double kFloatRangeLow = 0x1p-102;   // FLT_MIN * 2^24
inline constexpr double kFloatRangeHigh = 0x1p+104;  // ~FLT_MAX * 2^-24

// num_types x num_types table, row-major, symmetric.
template <class Real>
std::vector<LJParams<Real>> make_pair_table(const ForceField& ff);

const char* to_string(CutoffMode mode);
const char* to_string(Mixing mixing);

}  // namespace cellforce
