// The CPU backend's integration job: the host integrators of md/md.h and FIRE (md/minimize.h) on
// host arrays, the forces from the CPU force engine.
#include <algorithm>
#include <chrono>
#include <cmath>

#include "backends/md_engine.h"
#include "core/error.h"
#include "core/text.h"

namespace cellforce {

void validate_masses(const std::vector<double>& masses, std::size_t n) {
  if (masses.size() != n)
    throw Error(std::to_string(masses.size()) + " masses for " + std::to_string(n) + " particles");
  for (std::size_t i = 0; i < n; ++i)
    if (!std::isfinite(masses[i]) || masses[i] <= 0)
      throw Error("particle " + std::to_string(i) + " has mass " + format_number(masses[i]) +
                  "; masses must be finite and > 0");
}

void add_stage_sample(MdCounters& c, const PipelineStats& s) {
  PipelineStats& sum = c.stages;
  sum.t_check += s.t_check;
  sum.t_cell_ids += s.t_cell_ids;
  sum.t_count += s.t_count;
  sum.t_sort += s.t_sort;
  sum.t_collision_cells += s.t_collision_cells;
  sum.t_traversal += s.t_traversal;
  sum.t_accumulate += s.t_accumulate;
  sum.t_transfer += s.t_transfer;
  sum.t_total += s.t_total;
  ++c.stage_samples;
}

void add_reuse(MdCounters& c, const PipelineStats& s, int64_t evaluations) {
  c.list_evaluations += s.listed ? evaluations : 0;
  c.builds += s.rebuilt ? 1 : 0;
  c.graph_builds += s.rebuilt && s.graph_build ? 1 : 0;
  c.dangerous_builds += s.dangerous_build ? 1 : 0;
  if (!s.rebuilt) c.served = std::max(c.served, s.max_displacement);
  c.missed_pairs += s.missed_pairs;
  c.repeated_pairs += s.repeated_pairs;
}

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

class CpuMdEngine final : public MdEngine {
 public:
  explicit CpuMdEngine(std::unique_ptr<ForceEngine> forces) : forces_(std::move(forces)) {}

  void set_state(const MdState& state, const std::vector<double>& masses, const ForceField& ff) override {
    validate_system(state.config.view(), ff);
    validate_masses(masses, state.config.size());
    state_ = state;
    masses_ = masses;
    ff_ = ff;
    evaluate(true);
  }

  void set_positions(const std::vector<double>& positions) override {
    Configuration trial = state_.config;
    trial.positions = positions;
    validate_system(trial.view(), ff_);
    // Into the state's own array (a state view's pointer holds), the positions before kept aside.
    const std::vector<double> before = state_.config.positions;
    std::copy(positions.begin(), positions.end(), state_.config.positions.begin());
    try {
      evaluate(true);
    } catch (const Error& e) {
      std::copy(before.begin(), before.end(), state_.config.positions.begin());
      try {
        evaluate(true);
      } catch (const Error& again) {
        throw Error(e.message() + "; the positions before could not be evaluated again either (" + again.message() +
                    "): set the state again");
      }
      throw;
    }
  }

  void set_velocities(const std::vector<double>& velocities) override {
    if (state_.velocities.size() == velocities.size())  // in place: a state view's pointer holds
      std::copy(velocities.begin(), velocities.end(), state_.velocities.begin());
    else
      state_.velocities = velocities;
  }

  void advance(int64_t steps, const IntegratorSettings& settings, bool observe) override {
    const auto t0 = Clock::now();
    double force_seconds = 0;
    for (int64_t k = 0; k < steps; ++k) {
      const bool last = k + 1 == steps;
      const int64_t next = state_.step + 1;
      try {
        cellforce::advance(state_, masses_, settings, [&](MdState&) {
          const auto tf = Clock::now();
          evaluate(observe && last);
          force_seconds += seconds_since(tf);
        }, ff_.cutoff);
      } catch (const Error& e) {  // the step that failed (built only then)
        rethrow_with("step " + std::to_string(next) + ": ", e);
      }
    }
    const double total = seconds_since(t0);
    counters_.steps += steps;
    counters_.force_seconds += force_seconds;
    counters_.integration_seconds += total - force_seconds;
    counters_.host_wait_seconds += total;
  }

  FireResult minimize(const FireSettings& settings) override {
    check_fire_settings(settings);
    const MdState start = state_;  // the state to come back to when FIRE throws
    try {
      // Every evaluation through evaluate(): the state's forces and result_'s energy and virial
      // are always those of its positions, the last evaluation's at the end.
      return minimize_fire(state_, masses_, settings, [&](MdState&) {
        evaluate(true);
        return result_.energy;
      });
    } catch (...) {
      state_ = start;
      try {
        evaluate(true);  // the start's forces again, and its energy and virial
      } catch (...) {    // the start was evaluated before: FIRE's error is the one to report
      }
      throw;
    }
  }

  void get_state(MdState& state) override { state = state_; }
  StateArrays state_arrays() override {
    return {state_.config.positions.data(), state_.velocities.data(), state_.forces.data(), -1};
  }
  int64_t step() const override { return state_.step; }
  std::vector<std::pair<const char*, std::size_t>> state_buffers() const override {
    return {{"md: positions", sizeof(double) * state_.config.positions.size()},
            {"md: velocities", sizeof(double) * state_.velocities.size()},
            {"md: forces", sizeof(double) * state_.forces.size()},
            {"md: masses", sizeof(double) * masses_.size()},
            {"md: types", sizeof(uint32_t) * state_.config.types.size()}};
  }

  Observables observables() override {
    if (!observed_) evaluate(true);
    Observables o;
    o.kinetic = kinetic_energy(state_, masses_);
    o.potential = result_.energy;
    for (int a = 0; a < kMaxDim; ++a)
      for (int b = 0; b < kMaxDim; ++b) o.virial[a][b] = result_.virial[a][b];
    return o;
  }

  void reevaluate() override { evaluate(true); }
  void set_external_force(const ExternalForce& external) override {
    if (external.device) throw Error("internal error: a device array as the CPU engine's external force");
    external_ = external;
  }
  ForceEngine& forces() override { return *forces_; }
  const MdCounters& counters() const override { return counters_; }
  void reset_counters() override { counters_ = MdCounters{}; }

 private:
  void evaluate(bool observe) {
    const SystemView view = state_.config.view();
    forces_->evaluate(view, ff_, Request{observe, observe}, result_);
    state_.forces.swap(result_.forces);  // no copy: the engine overwrites the old buffer next time
    add_external();
    observed_ = observe;
    ++counters_.evaluations;
    const PipelineStats s = forces_->stats(view, ff_, false);
    add_stage_sample(counters_, s);
    add_reuse(counters_, s);
  }

  void add_external() {
    std::vector<double>& f = state_.forces;
    if (!external_.values.empty())
      for (std::size_t k = 0; k < f.size(); ++k) f[k] += external_.values[k];
    if (external_.callback)
      external_.callback(external_.user, state_.step, masses_.size(), state_.config.box.dim,
                         state_.config.positions.data(), f.data(), nullptr);
  }

  std::unique_ptr<ForceEngine> forces_;
  ExternalForce external_;
  MdState state_;
  std::vector<double> masses_;
  ForceField ff_;
  ForceResult result_;
  bool observed_ = false;
  MdCounters counters_;
};

}  // namespace

std::unique_ptr<MdEngine> make_cpu_md_engine(std::unique_ptr<ForceEngine> forces) {
  return std::make_unique<CpuMdEngine>(std::move(forces));
}

std::unique_ptr<MdEngine> make_md_engine(const EngineChoice& choice) {
#ifdef CELLFORCE_HAVE_CUDA
  if (choice.reuse.automatic)  // as make_force_engine: the caller resolves it for its system
    throw Error("internal error: an engine was asked for with an unresolved automatic skin");
  if (resolve_backend(choice.backend) == Backend::kCuda) return make_cuda_md_engine(choice);
#endif
  return make_cpu_md_engine(make_force_engine(choice));
}

}  // namespace cellforce
