// `pair_style lj/cut` computed by cellforce, for cellforce-lammps (main.cpp registers it under
// LAMMPS's own name, so that a script written for LAMMPS runs unchanged). LAMMPS keeps what is its
// own: the domain decomposition, ghost exchange, integration, thermo, the pair's energy and virial
// tallies and `pair_modify shift`; each rank's compute() hands its owned atoms and their ghosts to
// cellforce::Context::compute_local (a pair of an owned atom and a ghost counted half on each of
// the two ranks that hold it), whose forces, energy and virial the pair adds to LAMMPS's.
#pragma once

#include <cellforce/cellforce.hpp>

#include <chrono>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "lammps_headers.h"

namespace cellforce::lammps {

// The engine options for every rank's context (set_option keys and values: backend, precision,
// skin, device), from the program's flags and CELLFORCE_* variables.
struct EngineSettings {
  std::vector<std::pair<std::string, std::string>> options;
};
EngineSettings& engine_settings();

class PairCellforce : public LAMMPS_NS::Pair {
 public:
  explicit PairCellforce(LAMMPS_NS::LAMMPS* instance);
  ~PairCellforce() override;

  void compute(int eflag, int vflag) override;
  void settings(int narg, char** arg) override;
  void coeff(int narg, char** arg) override;
  void init_style() override;
  double init_one(int i, int j) override;

  static LAMMPS_NS::Pair* create(LAMMPS_NS::LAMMPS* instance) { return new PairCellforce(instance); }

 private:
  void allocate();
  void make_context();  // the context for the physics now (types, pairs, cutoff, shift)
  std::vector<double> physics() const;  // what make_context reads, to compare
  void report_times();   // rank 0 prints where the time of the calls went (a collective call)
  using Clock = std::chrono::steady_clock;

  double cut_global_ = 0;
  double** epsilon_ = nullptr;  // [type][type], 1-based as LAMMPS's
  double** sigma_ = nullptr;
  bool stale_ = true;  // set by pair_style, pair_coeff and every init (each run's setup): compare again
  std::vector<double> made_for_;  // physics() of the context made last
  bool described_ = false;  // rank 0 has printed its engine
  int device_ = -1;         // the CUDA device this rank computes on (-1: the CPU)
  std::unique_ptr<cellforce::Context> ctx_;
  std::vector<double> positions_;  // 2D scripts: the rows packed to 2 columns
  std::vector<double> forces_, energies_, virials_;
  std::vector<uint32_t> types_;
  struct Times {  // seconds over the calls so far: those that made the context apart from the rest
    long long calls = 0, making_calls = 0;
    double cellforce = 0, stages = 0, pair = 0, making = 0;
  } times_;
};

}  // namespace cellforce::lammps
