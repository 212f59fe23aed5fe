// The CUDA backend's MdEngine: the MD state lives in device memory for the whole run, and the
// integrators run as kernels on the force engine's stream with the forces of its resident
// evaluations. This file is the schedule and the host's side: which kernels a call queues, when the
// host waits, what it reads back and how it reports a failure. The kernels are integrate/'s: the
// ungated steps (step_kernels.cuh), the steps a pair list serves behind the step gate
// (gated_steps.cuh, search/step_gate.h) and FIRE's (fire_kernels.cuh); their per-coordinate
// arithmetic is md/verlet_step.h's and md/fire_step.h's, the host's.
//
// The host queues a call's steps without waiting (the search keeps its counts on the device),
// except with an open axis (the particles' bounds, on steps that build the structure) and with a
// skin (the largest displacement: per step, or with pair lists per chunk of steps queued behind the
// step gate); the flags (a drift that diverged, a force that is not finite) are read once per
// advance() call. Nothing of the particles crosses PCIe except in set_state, get_state and the
// error path; observables() reads 8 numbers. FIRE's scalar decisions (dt, alpha, the downhill
// count, convergence) are the host's FireSchedule (md/minimize.h run_fire): each step the host
// reads back FireScalars (56 bytes) and the force engine's flags, one synchronisation per step.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <optional>

#include "backend/force_engine.h"
#include "backends/md_engine.h"
#include "check.cuh"
#include "core/box.h"
#include "core/error.h"
#include "core/text.h"
#include "device_buffer.cuh"
#include "forces/traversal.cuh"  // kCellSums
#include "integrate/fire_kernels.cuh"
#include "integrate/gate_readback.cuh"
#include "integrate/gated_steps.cuh"
#include "integrate/step_kernels.cuh"
#include "md/verlet_step.h"
#include "search/pair_list.cuh"  // unrank

namespace cellforce {
namespace {

using cuda::DeviceBuffer;
using cuda::FireScalars;
using cuda::ForceSums;
using cuda::WrapBox;

template <class T>
void upload(DeviceBuffer<T>& d, const std::vector<T>& h, cudaStream_t stream) {
  d.reserve(std::max<std::size_t>(h.size(), 1));
  if (!h.empty())
    CF_CUDA_CHECK(cudaMemcpyAsync(d.data(), h.data(), h.size() * sizeof(T), cudaMemcpyHostToDevice, stream));
}

template <class T>
void download(std::vector<T>& h, const T* d, std::size_t count, cudaStream_t stream) {
  h.resize(count);
  if (count) CF_CUDA_CHECK(cudaMemcpyAsync(h.data(), d, count * sizeof(T), cudaMemcpyDeviceToHost, stream));
}

using Clock = std::chrono::steady_clock;

// The engine's device current for a call, the caller's restored after it.
class OnDevice {
 public:
  explicit OnDevice(int device) {
    CF_CUDA_CHECK(cudaGetDevice(&previous_));
    if (previous_ != device) CF_CUDA_CHECK(cudaSetDevice(device));
  }
  ~OnDevice() { cudaSetDevice(previous_); }
  OnDevice(const OnDevice&) = delete;
  OnDevice& operator=(const OnDevice&) = delete;

 private:
  int previous_ = 0;
};

class CudaMdEngine final : public MdEngine {
 public:
  // The force engine of `choice` (CUDA), made here: the MD engine reaches it only through
  // cuda::ResidentForces, and queues its step kernels on the force engine's stream (the choice's
  // stream, or the one the force engine made).
  explicit CudaMdEngine(const EngineChoice& choice)
      : owner_(std::make_unique<CudaForceEngine>(choice)), resident_(owner_->resident()), hooks_(choice.test) {
    const OnDevice on(resident_.device());
    stream_ = static_cast<cudaStream_t>(resident_.stream());
    try {
      CF_CUDA_CHECK(cudaEventCreate(&chunk_start_));
      CF_CUDA_CHECK(cudaEventCreate(&chunk_end_));
    } catch (...) {
      release();
      throw;
    }
  }
  ~CudaMdEngine() override {
    try {
      const OnDevice on(resident_.device());  // the buffers are freed on their own device
      // Queued kernels may still post into the gate's mapped memory (a run left by an exception
      // before its synchronisation): wait for them before it goes (errors ignored).
      if (stream_) cudaStreamSynchronize(stream_);
      release();
    } catch (...) {
      release();  // a destructor cannot throw
    }
  }

  void set_state(const MdState& state, const std::vector<double>& masses, const ForceField& ff) override {
    const OnDevice on(resident_.device());
    validate_system(state.config.view(), ff);
    validate_masses(masses, state.config.size());
    if (ff.num_types() > 1 && state.config.types.size() != state.config.size())
      throw Error("the state has " + std::to_string(state.config.types.size()) + " types for " +
                  std::to_string(state.config.size()) + " particles");
    at_build_ = false;  // the positions change
    box_ = state.config.box;
    n_ = state.config.size();
    ff_ = ff;
    step_ = state.step;
    time_ = state.time;
    host_types_ = state.config.types;
    upload(positions_, state.config.positions, stream_);
    upload(velocities_, state.velocities.empty() ? std::vector<double>(n_ * box_.dim, 0.0) : state.velocities,
           stream_);
    upload(masses_, masses, stream_);
    uniform_mass_.reset();  // one mass for all, bit for bit, is passed as a number (no load per coordinate)
    if (!masses.empty() && std::all_of(masses.begin(), masses.end(), [&](double m) {
          return std::memcmp(&m, &masses[0], sizeof m) == 0;
        }))
      uniform_mass_ = masses[0];
    upload(types_, state.config.types, stream_);
    counters_.bytes_to_device += (2 * n_ * box_.dim + n_) * sizeof(double) + n_ * sizeof(uint32_t);
    flags_.reserve(1);
    reset_flags();
    evaluate(true);
    check(step_, step_);
  }

  void advance(int64_t steps, const IntegratorSettings& settings, bool observe) override {
    const OnDevice on(resident_.device());
    const auto t0 = Clock::now();
    // At most kRun steps are queued between two reads of the flags (and of the timing events).
    for (int64_t done = 0; done < steps;) {
      const int64_t k = std::min<int64_t>(steps - done, kRun);
      const bool final_run = done + k == steps;  // its last evaluation is the call's: observed, sampled
      run(k, settings, observe && final_run, final_run);
      done += k;
    }
    counters_.host_wait_seconds += std::chrono::duration<double>(Clock::now() - t0).count();
    resident_.collect_timing();  // the stage times of the call's last evaluation
    add_stage_sample(counters_, resident_.stats());
  }

  void get_state(MdState& state) override {
    const OnDevice on(resident_.device());
    const std::size_t nd = n_ * std::size_t(box_.dim);
    state.config.box = box_;
    state.config.types = host_types_;
    download(state.config.positions, positions_.data(), nd, stream_);
    download(state.velocities, velocities_.data(), nd, stream_);
    download(state.forces, resident_.device_forces(), nd, stream_);
    CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
    counters_.bytes_to_host += 3 * nd * sizeof(double);
    state.step = step_;
    state.time = time_;
  }

  int64_t step() const override { return step_; }
  std::vector<std::pair<const char*, std::size_t>> state_buffers() const override {
    return {{"md: positions", positions_.bytes()},
            {"md: velocities", velocities_.bytes()},
            {"md: masses", masses_.bytes()},
            {"md: types", types_.bytes()},
            {"md: flags", flags_.bytes()},
            {"md: reduction result", scratch_result_.bytes()},
            {"md: FIRE scalars", fire_scalars_.bytes()},
            {"md: FIRE start", fire_start_.bytes()},
            {"md: reduction scratch", reduce_scratch_.bytes()},
            {"md: step gate", gate_.bytes()},
            {"md: chunk state in rank order", ranked_state_.bytes()}};
  }

  Observables observables() override {
    const OnDevice on(resident_.device());
    if (!observed_) {
      evaluate(true);
      check(step_, step_);
    }
    // One reduction and one copy of 8 numbers: kinetic energy, then the engine's totals.
    scratch_result_.reserve(1 + cuda::kCellSums);
    double* result = scratch_result_.data();
    cuda::sum_kinetic_energy(velocities_.data(), masses_.data(), n_, box_.dim, result, reduce_scratch_, stream_);
    CF_CUDA_CHECK(cudaMemcpyAsync(result + 1, resident_.device_totals(), cuda::kCellSums * sizeof(double),
                                  cudaMemcpyDeviceToDevice, stream_));
    double host[1 + cuda::kCellSums] = {};
    CF_CUDA_CHECK(cudaMemcpyAsync(host, result, sizeof(host), cudaMemcpyDeviceToHost, stream_));
    CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
    counters_.bytes_to_host += sizeof(host);
    Observables o;
    o.kinetic = host[0];
    o.potential = host[1];
    for (int k = 0; k < kVirialComponents; ++k) {
      const int r = virial_row(k), c = virial_col(k);
      if (r >= box_.dim || c >= box_.dim) continue;
      o.virial[r][c] = o.virial[c][r] = host[2 + k];
    }
    return o;
  }

  void reevaluate() override {
    const OnDevice on(resident_.device());
    at_build_ = false;  // the structure may have been restored from other positions (restore_reuse)
    evaluate(true);
    check(step_, step_);
  }
  FireResult minimize(const FireSettings& settings) override {
    const OnDevice on(resident_.device());
    check_fire_settings(settings);
    const std::size_t nd = n_ * std::size_t(box_.dim);
    // The state to come back to when FIRE throws: a copy on the device.
    fire_start_.reserve(std::max<std::size_t>(2 * nd, 1));
    if (nd) {
      CF_CUDA_CHECK(cudaMemcpyAsync(fire_start_.data(), positions_.data(), nd * sizeof(double),
                                    cudaMemcpyDeviceToDevice, stream_));
      CF_CUDA_CHECK(cudaMemcpyAsync(fire_start_.data() + nd, velocities_.data(), nd * sizeof(double),
                                    cudaMemcpyDeviceToDevice, stream_));
    }
    try {
      return fire(settings);
    } catch (...) {
      try {
        try {
          resident_.check_flags(box_, n_, positions_.data(), ff_);  // clears what the failed evaluation raised
        } catch (const Error&) {
        }
        at_build_ = false;  // the positions change
        if (nd) {
          CF_CUDA_CHECK(cudaMemcpyAsync(positions_.data(), fire_start_.data(), nd * sizeof(double),
                                        cudaMemcpyDeviceToDevice, stream_));
          CF_CUDA_CHECK(cudaMemcpyAsync(velocities_.data(), fire_start_.data() + nd, nd * sizeof(double),
                                        cudaMemcpyDeviceToDevice, stream_));
        }
        evaluate(true);  // the start's forces again, and its energy and virial
        check(step_, step_);
      } catch (...) {  // the start was evaluated before: FIRE's error is the one to report
      }
      throw;
    }
  }

  ForceEngine& forces() override { return *owner_; }
  const MdCounters& counters() const override { return counters_; }
  void reset_counters() override { counters_ = MdCounters{}; }

 private:
  static constexpr int64_t kRun = 256;
  static constexpr int64_t kMaxGated = 64;  // steps queued behind the gate between two reads of it

  void release() {
    for (cudaEvent_t e : force_events_) cudaEventDestroy(e);
    force_events_.clear();
    for (cudaEvent_t e : wait_events_) cudaEventDestroy(e);
    wait_events_.clear();
    if (chunk_start_) cudaEventDestroy(chunk_start_);
    if (chunk_end_) cudaEventDestroy(chunk_end_);
    chunk_start_ = chunk_end_ = nullptr;
  }

  // `steps` steps queued back to back, then the flags read (one synchronisation). An error thrown
  // while queueing (an evaluation of positions that diverged) gives way to the flags' diagnosis.
  // Steps before the last go behind the step gate in chunks wherever the force engine can serve
  // them from its pair list (run_gated): one host wait per chunk instead of one per step. A step's
  // closing half kick is deferred into the next step's first kernel, but for the last step's.
  // `sampled`: the last run of an advance() call, whose last evaluation's stage times it samples.
  void run(int64_t steps, const IntegratorSettings& settings, bool observe, bool sampled) {
    const int dim = box_.dim;
    const double dt = settings.dt;
    const int64_t first = step_ + 1;
    drift_share_ = settings.langevin ? 0.5 : 1.0;  // as drift_box's limits below
    CF_CUDA_CHECK(cudaEventRecord(chunk_start_, stream_));
    std::size_t timed = 0;
    waits_ = 0;
    paused_ = false;
    shut_ms_ = 0;
    try {
      for (int64_t k = 0; k < steps;) {
        const bool last = k + 1 == steps;
        if (!last) {
          const GateChunk chunk = gate_chunk(steps - 1 - k);
          if (chunk.count > 0) {
            k += run_gated(chunk, k == 0 ? 1 : 2, settings, timed);
            continue;
          }
        }
        resume();
        if (!settings.langevin) {
          // The previous step's closing half kick (deferred) with this step's opening one, and the drift.
          kick_drift(0.5 * dt, k == 0 ? 1 : 2, dt);
        } else {
          kick(0.5 * dt, k == 0 ? 1 : 2);  // the previous step's closing half kick (deferred) and this one's
          drift(0.5 * dt, 0.5, false);  // two half drifts of at most L / 2: a step of at most L
          const double c1 = std::exp(-settings.friction * dt);
          const double c2 = std::sqrt(1.0 - c1 * c1);
          cuda::queue_thermostat(velocities_.data(), masses_.data(), c1, c2, settings.kT, settings.seed,
                                 uint64_t(step_) + 1, n_, dim, stream_);
          drift(0.5 * dt, 0.5, true);
        }
        step_ += 1;
        time_ = double(step_) * dt;  // not summed: the same after a restart
        // Only the sampled run's last evaluation records its stage events: its stage
        // times are advance()'s sample (collect_timing), and a build between (`every`) is then keyed
        // as the gated chunks' closing ones, so that their graph serves it.
        timed_evaluation(timed, [&] { evaluate(observe && last, std::nullopt, last && sampled); });
        if (last) kick(0.5 * dt, 1);  // before the last: deferred into the next step's first kernel
        ++k;
      }
    } catch (const Error& e) {
      check(first, step_);  // throws the divergence or the bad pair when one is flagged
      rethrow_with((first == step_ ? "step " + std::to_string(first)
                                   : "steps " + std::to_string(first) + "-" + std::to_string(step_)) + ": ",
                   e);
    }
    resume();
    CF_CUDA_CHECK(cudaEventRecord(chunk_end_, stream_));
    check(first, step_);  // synchronises: the one host wait beyond the search's counts
    float ms = 0;
    double forces_ms = shut_ms_;  // a chunk's timed first evaluation when the gate shut it
    for (std::size_t t = 0; t < timed; ++t) {
      CF_CUDA_CHECK(cudaEventElapsedTime(&ms, force_events_[2 * t], force_events_[2 * t + 1]));
      forces_ms += ms * double(force_weights_[t]);
    }
    double wait_ms = 0;  // the device idle while the host read a gate and queued on: no stage's time
    for (std::size_t w = 0; w < waits_; ++w) {
      CF_CUDA_CHECK(cudaEventElapsedTime(&ms, wait_events_[2 * w], wait_events_[2 * w + 1]));
      wait_ms += ms;
    }
    CF_CUDA_CHECK(cudaEventElapsedTime(&ms, chunk_start_, chunk_end_));
    counters_.steps += steps;
    counters_.force_seconds += 1e-3 * forces_ms;
    counters_.integration_seconds += 1e-3 * std::max(double(ms) - forces_ms - wait_ms, 0.0);
  }

  // A gated chunk's end: the device idles from here (the gate's read) until the host queues more
  // work, which first records the matching resume(). The gap is booked to no stage.
  void pause() {
    while (wait_events_.size() < 2 * (waits_ + 1)) {
      cudaEvent_t ev;
      CF_CUDA_CHECK(cudaEventCreate(&ev));
      wait_events_.push_back(ev);
    }
    CF_CUDA_CHECK(cudaEventRecord(wait_events_[2 * waits_], stream_));
    ++waits_;
    paused_ = true;
  }
  void resume() {
    if (!paused_) return;
    CF_CUDA_CHECK(cudaEventRecord(wait_events_[2 * waits_ - 1], stream_));
    paused_ = false;
  }

  // Runs `queue` between the timing events of evaluation number `timed` (then counted).
  template <class Queue>
  void timed_evaluation(std::size_t& timed, Queue&& queue) {
    while (force_events_.size() < 2 * (timed + 1)) {
      cudaEvent_t ev;
      CF_CUDA_CHECK(cudaEventCreate(&ev));
      force_events_.push_back(ev);
    }
    force_weights_.resize(timed + 1);
    force_weights_[timed] = 1;  // evaluations it stands for (run_gated: a chunk's served ones)
    CF_CUDA_CHECK(cudaEventRecord(force_events_[2 * timed], stream_));
    queue();
    CF_CUDA_CHECK(cudaEventRecord(force_events_[2 * timed + 1], stream_));
    ++timed;
  }

  // How many of the next `most` steps to queue behind the gate: 0 when the force engine cannot
  // serve them from its list, else enough to reach the next rebuild if it comes as far after this
  // build as the last one did (interval_), and one more, so that few queued steps find the gate
  // shut: a shut step still costs its kernels' loads, except the last, the one past the expected
  // rebuild, whose kick-drift reads the gate first; at least 2. A chunk that ends before the gate closes costs one more read of the gate. `overshoot`: the
  // chunk's length is the expected one (not cut short by the run's end, `every` or the gate's own
  // bound), so its last step is the one past the expected rebuild.
  struct GateChunk {
    int64_t count = 0;
    bool overshoot = false;
  };
  GateChunk gate_chunk(int64_t most) const {
    const int64_t allowed = std::min(most, resident_.gate_steps(box_, n_, ff_));
    if (allowed <= 0) return {};
    const int64_t expected = std::clamp<int64_t>(interval_ + 1 - since_build_, 2, kMaxGated);
    return {std::min(allowed, expected), expected <= allowed};
  }

  // A gated chunk's set-up: the gate, where the drifts place the positions, and the state the
  // kernels run on (fast memory: a copy in the list's rank order, written back at the chunk's end).
  struct Chunk {
    cuda::GateView view;
    cuda::RankOrder to;
    cuda::GatedState state{};
    cuda::NextKickDrift then;  // fused: what the force kernels need for the next step's kick-drift
    DriftBox box{};
    bool ranked = false;       // the state in rank order (fast memory)
    bool fused = false;        // a Verlet chunk in rank order: the force kernels run the kick-drifts
    bool check_notice = false, notice_first = true;
    const uint32_t* types = nullptr;
  };

  Chunk begin_chunk(const IntegratorSettings& settings) {
    const double dt = settings.dt;
    // The gate zeroed, its closed step kGateOpen: by the last chunk's end (its gate copy resets
    // it), else here.
    if (!gate_reset_) {
      gate_.reserve(1);
      CF_CUDA_CHECK(cudaMemsetAsync(gate_.data(), 0, sizeof(cuda::StepGate), stream_));
      CF_CUDA_CHECK(cudaMemsetAsync(&gate_.data()->closed, 0xff, sizeof(unsigned long long), stream_));
    }
    gate_reset_ = false;  // until this chunk's end queues the copy that resets it
    Chunk c;
    c.view = cuda::GateView{gate_.data(), uint64_t(step_) + 1, resident_.gate_limit()};
    // The host reads the gate's notice or its copy, whichever comes first (tests may ask for the
    // copy alone, or for both, checked against each other).
    c.check_notice = hooks_.gate_notice_check.value_or(false);
    c.notice_first = hooks_.gate_notice.value_or(true) && !c.check_notice;
    gate_read_.begin(c.view, hooks_.gate_notice.value_or(true) || c.check_notice);
    c.box = drift_box(settings.langevin ? 0.5 : 1.0);  // as the ungated steps' drifts
    c.types = ff_.num_types() > 1 ? types_.data() : nullptr;
    // The drifts place the positions; a Verlet chunk's evaluations may run the next step's kick-drift.
    c.to = resident_.rank_order(box_, n_, positions_.data(), c.types, ff_, !settings.langevin);
    // With the forces in rank order (fast mode), the chunk runs on a rank-order copy of the state.
    c.ranked = c.to.forces != nullptr;
    c.state = cuda::GatedState{positions_.data(), velocities_.data(), resident_.device_forces(),
                               uniform_mass_ ? nullptr : masses_.data(), resident_.device_build_positions(),
                               nullptr, nullptr, nullptr, nullptr, c.to.forces, uniform_mass_.value_or(0.0), at_build_};
    at_build_ = false;  // the chunk's drifts move the positions
    if (c.ranked) {
      const std::size_t nd = n_ * std::size_t(box_.dim);
      ranked_state_.reserve(std::max<std::size_t>(3 * nd + (uniform_mass_ ? 0 : n_), 1));
      c.state.x_ranked = ranked_state_.data();
      c.state.v_ranked = c.state.x_ranked + nd;
      c.state.built_ranked = c.state.v_ranked + nd;
      if (!uniform_mass_) c.state.mass_ranked = c.state.built_ranked + nd;
    } else {
      ranked_state_.release();  // lean: none (a fast-mode system before may have left it)
    }
    // Verlet on the rank-order copy: every gated evaluation but the chunk's last runs the next
    // step's kick-drift in its force kernel, so only the chunk's first step has a kick-drift kernel.
    c.fused = c.ranked && !settings.langevin;
    c.then = cuda::NextKickDrift{c.state.x_ranked, c.state.v_ranked, c.state.mass_ranked, c.state.built_ranked,
                                 c.to.order, 0.5 * dt, dt, c.box, flags_.data(), c.state.mass_value};
    return c;
  }

  // The chunk's `count` steps, queued: each step's kernels (integrate/gated_steps.cuh; in a fused
  // chunk the first step's only) and its gated evaluation. `gathered`: the first kernel has copied
  // the state into rank order (for the diagnosis when a later launch throws).
  void queue_chunk(Chunk& c, const GateChunk& chunk, int first_kicks, const IntegratorSettings& settings,
                   std::size_t& timed, bool& gathered) {
    const int64_t count = chunk.count;
    const uint64_t first = c.view.step;
    cuda::GatedStep step;
    step.state = c.state;
    step.langevin = settings.langevin;
    step.dt = settings.dt;
    step.box = c.box;
    step.n = n_;
    step.flags = flags_.data();
    step.to = c.to;
    step.c1 = std::exp(-settings.friction * settings.dt);  // as run()
    step.c2 = std::sqrt(1.0 - step.c1 * step.c1);
    step.kT = settings.kT;
    step.seed = settings.seed;
    for (int64_t j = 0; j < count; ++j) {
      c.view.step = first + uint64_t(j);
      if (!(c.fused && j > 0)) {  // fused: the previous evaluation ran this step's kick-drift
        step.kicks = j == 0 ? first_kicks : 2;
        step.gate_first = chunk.overshoot && j == count - 1;  // the step past the expected rebuild
        step.order = !c.ranked ? cuda::StateOrder::kCaller : j == 0 ? cuda::StateOrder::kGather : cuda::StateOrder::kRank;
        step.gate = c.view;
        cuda::queue_gated_step(step, stream_);
      }
      gathered = c.ranked;
      // Only the chunk's first evaluation is timed: the events around each gated evaluation would
      // hold the device between the step's kernels. The chunk's served evaluations are booked at
      // that one's time (they run the same kernels on the same list); the untimed ones the gate shut
      // (kernels that return at once) fall in the integration's time.
      const cuda::NextKickDrift* next = c.fused && j + 1 < count ? &c.then : nullptr;
      if (j == 0) {
        std::size_t slot = timed;  // counted by read_chunk, for every step served
        timed_evaluation(slot, [&] { resident_.evaluate_gated(box_, n_, positions_.data(), c.types, ff_, c.view, next); });
      } else {
        resident_.evaluate_gated(box_, n_, positions_.data(), c.types, ff_, c.view, next);
      }
    }
    c.view.step = first;
  }

  // `count` steps behind the step gate (search/step_gate.h), then one read of the gate. Steps the
  // structure served are done; at the step where the gate closed (its drifts done, its evaluation
  // not run), the ordinary evaluation rebuilds and that step is done too. Returns the steps done.
  int64_t run_gated(const GateChunk& chunk, int first_kicks, const IntegratorSettings& settings,
                    std::size_t& timed) {
    resume();
    observed_ = false;  // the state moves on: thermo() must evaluate again unless a later step observes
    Chunk c = begin_chunk(settings);
    bool gathered = false;
    try {
      queue_chunk(c, chunk, first_kicks, settings, timed, gathered);
    } catch (...) {
      try {
        if (gathered) unrank_state(c.state, c.to.rank);  // the state as the queued kernels left it, for the diagnosis
      } catch (...) {
      }
      throw;
    }
    if (c.ranked) unrank_state(c.state, c.to.rank);
    pause();
    gate_read_.queue_copy(gate_.data(), stream_);  // control data, like the displacement: not counted
    gate_reset_ = true;
    return read_chunk(c, chunk.count, settings.dt, timed);
  }

  // The chunk's end: the gate read (its notice, or its copy), the steps served settled and counted,
  // and where the gate closed, the closed step's ordinary (rebuilding) evaluation.
  int64_t read_chunk(const Chunk& c, int64_t count, double dt, std::size_t& timed) {
    const cuda::GateReadback::Outcome read = gate_read_.wait(c.notice_first);
    const uint64_t first = c.view.step;
    const uint64_t last = first + uint64_t(count) - 1;
    // The step the gate closed at: the copy's, or where no later kernel closed it, the last step's
    // own displacement past the limit (its shut evaluation posted the notice).
    auto closed_at = [&](const cuda::StepGate& g) {
      return g.closed == cuda::kGateOpen && g.d2[last % 3] > c.view.limit ? last : g.closed;
    };
    if (read.copy && c.check_notice) check_gate_notice(closed_at(*read.copy), *read.copy, read.notice);
    // Where the gate closed, the notice's values (the same as the copy's); else the copy's.
    const cuda::StepGate g = read.notice ? *read.notice : *read.copy;
    const bool early = !read.copy;  // the chunk's tail (shut steps, write-back, copy) may still run
    const uint64_t closed = closed_at(g);
    const int64_t served = closed == cuda::kGateOpen ? count : int64_t(closed - first);
    if (closed != cuda::kGateOpen) {
      ++counters_.gate_closings;
      if (early) ++counters_.gate_closings_early;
    }
    // Every step served: the last gated evaluation's forces are the state's, in the caller's order
    // for whatever comes next. (Where the gate closed, the closed step's kick-drift has read them and
    // its evaluation writes new ones.)
    if (served == count && c.to.forces) {
      resume();  // integration's time, as the kicks
      resident_.unrank_forces(n_);
    }
    if (served == 0) {  // the timed evaluation was shut: its slot is reused below, so read it now
      // (after its end event: the host may have read the notice or the gate's mapped copy first)
      CF_CUDA_CHECK(cudaEventSynchronize(force_events_[2 * timed + 1]));
      float ms = 0;
      CF_CUDA_CHECK(cudaEventElapsedTime(&ms, force_events_[2 * timed], force_events_[2 * timed + 1]));
      shut_ms_ += ms;
    }
    double served_d2 = 0;
    std::memcpy(&served_d2, &g.served, sizeof served_d2);
    resident_.settle_gate(served, served_d2);
    if (served > 0) {
      counters_.evaluations += served;
      add_reuse(counters_, resident_.stats(), served);
      if (resident_.stats().list_block) counters_.list_block = resident_.stats().list_block;
    }
    since_build_ += served;
    counters_.gated_steps += served;
    if (served > 0) force_weights_[timed++] = served;  // the chunk's one timed evaluation, for all it served
    step_ += served;
    time_ = double(step_) * dt;
    if (served == count) return count;
    step_ += 1;  // the closed step: drifted, to be evaluated
    time_ = double(step_) * dt;
    resume();
    double closed_d2 = 0;  // its displacement, as the gated kick-drift measured it: the check's value
    std::memcpy(&closed_d2, &g.d2[closed % 3], sizeof closed_d2);
    // Its stage events are left out: advance() samples its last evaluation's stage times (run():
    // the last step is never gated).
    timed_evaluation(timed, [&] { evaluate(false, closed_d2, false); });
    return served + 1;
  }

  // A rank-order chunk's positions and velocities back into the caller's order.
  void unrank_state(const cuda::GatedState& state, const uint32_t* rank) {
    cuda::unrank(rank, state.x_ranked, n_, box_.dim, state.x, stream_);
    cuda::unrank(rank, state.v_ranked, n_, box_.dim, state.v, stream_);
  }

  void kick(double h, int kicks) {
    cuda::queue_kick(velocities_.data(), resident_.device_forces(), masses_.data(), h, kicks, n_, box_.dim, stream_);
  }

  void kick_drift(double h, int kicks, double dt) {
    at_build_ = false;
    cuda::queue_kick_drift(positions_.data(), velocities_.data(), resident_.device_forces(), masses_.data(), h, kicks, dt,
                           drift_box(1.0), n_, flags_.data(), stream_);
  }

  DriftBox drift_box(double limit) const {
    DriftBox b{};
    b.dim = box_.dim;
    for (int a = 0; a < box_.dim; ++a) {
      b.length[a] = box_.length[a];
      b.periodic[a] = box_.periodic[a];
      b.most[a] = drift_limit(box_, a, ff_.cutoff, limit);
      b.inv_length[a] = box_.periodic[a] ? 1.0 / box_.length[a] : 0.0;  // as cuda/reuse.cu
    }
    return b;
  }

  void drift(double h, double limit, bool wrap) {
    at_build_ = false;
    cuda::queue_drift(positions_.data(), velocities_.data(), h, drift_box(limit), wrap, n_, flags_.data(), stream_);
  }

  // known_d2: the step gate's displacement at these positions, where it closed (the reuse check's value).
  void evaluate(bool observe, std::optional<double> known_d2 = {}, bool time_stages = true) {
    resident_.evaluate_resident(box_, n_, positions_.data(), ff_.num_types() > 1 ? types_.data() : nullptr, ff_,
                           Request{observe, observe}, known_d2, time_stages);
    observed_ = observe;
    at_build_ = resident_.stats().rebuilt;  // the build's positions are the positions now
    ++counters_.evaluations;
    add_reuse(counters_, resident_.stats());
    if (resident_.stats().rebuilt) {
      if (since_build_ > 0) interval_ = since_build_ + 1;
      since_build_ = 0;
    } else {
      ++since_build_;
    }
  }

  // FIRE on the state (minimize() restores the start when this throws): md/minimize.h's run_fire,
  // its per-particle arithmetic in kernels, its decisions on the host.
  FireResult fire(const FireSettings& settings) {
    const int dim = box_.dim;
    const std::size_t nd = n_ * std::size_t(dim);
    fire_scalars_.reserve(1);
    CF_CUDA_CHECK(cudaMemsetAsync(fire_scalars_.data(), 0xff, sizeof(FireScalars), stream_));  // no bad position
    if (nd) CF_CUDA_CHECK(cudaMemsetAsync(velocities_.data(), 0, nd * sizeof(double), stream_));
    WrapBox wrap{};
    wrap.dim = dim;
    for (int a = 0; a < dim; ++a) {
      wrap.length[a] = box_.length[a];
      wrap.periodic[a] = box_.periodic[a];
    }

    const FireResult result = run_fire(settings, fire_evaluate(), [&](bool uphill, double dt, double alpha) {
      at_build_ = false;  // the step's drift moves the positions
      // n_ > 0 here: without particles the largest force is 0, converged.
      cuda::queue_fire_kick(positions_.data(), velocities_.data(), resident_.device_forces(), masses_.data(), dt,
                            0.5 * dt, uphill, n_, dim, stream_);
      cuda::sum_fire_speeds(velocities_.data(), n_, dim, &fire_scalars_.data()->v2, reduce_scratch_, stream_);
      cuda::queue_fire_drift(positions_.data(), velocities_.data(), resident_.device_forces(), fire_scalars_.data(), alpha,
                             dt, settings.max_displacement, wrap, n_, stream_);
      return fire_evaluate();
    });
    if (nd) CF_CUDA_CHECK(cudaMemsetAsync(velocities_.data(), 0, nd * sizeof(double), stream_));
    CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
    return result;
  }

  // One FIRE evaluation at the positions now (energy and virial), its ForceSums with the
  // velocities now, its energy, and the drift's flag (FireScalars): the numbers the host reads per
  // step, with
  // the force engine's flags (one synchronisation). Throws for a pair whose force is not finite
  // and for a position that is not finite (that diagnosis first: an evaluation of such positions
  // may fail on its own).
  FireEvaluation fire_evaluate() {
    FireScalars* d = fire_scalars_.data();
    try {
      evaluate(true);
    } catch (const Error&) {
      throw_if_position_not_finite();
      throw;
    }
    const ForceSums none{0, 0, -1, 0};  // largest_force's answer without particles
    cuda::sum_fire_forces(resident_.device_forces(), velocities_.data(), n_, box_.dim, &d->forces, reduce_scratch_, stream_);
    CF_CUDA_CHECK(
        cudaMemcpyAsync(&d->energy, resident_.device_totals(), sizeof(double), cudaMemcpyDeviceToDevice, stream_));
    FireScalars host{};
    CF_CUDA_CHECK(cudaMemcpyAsync(&host, d, sizeof host, cudaMemcpyDeviceToHost, stream_));
    try {
      resident_.check_flags(box_, n_, positions_.data(), ff_);  // synchronises the stream
    } catch (const Error&) {
      throw_if_position_not_finite();
      throw;
    }
    counters_.bytes_to_host += sizeof host;
    if (!n_) host.forces = none;
    if (host.bad_position != ~0ull) throw_position_not_finite(host.bad_position);
    return FireEvaluation{host.energy, largest_of(host.forces), host.forces.power};
  }

  static LargestForce largest_of(const ForceSums& s) {
    return LargestForce{s.largest2 < 0 ? 0.0 : std::sqrt(s.largest2), std::size_t(s.particle)};
  }

  // The error path of FIRE's drift flag: the flag, then the coordinate it names, to the host.
  void throw_if_position_not_finite() {
    unsigned long long key = ~0ull;
    CF_CUDA_CHECK(cudaMemcpyAsync(&key, &fire_scalars_.data()->bad_position, sizeof key, cudaMemcpyDeviceToHost,
                                  stream_));
    CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
    if (key != ~0ull) throw_position_not_finite(key);
  }
  [[noreturn]] void throw_position_not_finite(unsigned long long key) {
    const std::size_t i = std::size_t(key % n_);
    const int axis = int(key / n_);
    double value = 0;
    CF_CUDA_CHECK(cudaMemcpyAsync(&value, positions_.data() + i * std::size_t(box_.dim) + std::size_t(axis),
                                  sizeof value, cudaMemcpyDeviceToHost, stream_));
    CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
    counters_.bytes_to_host += sizeof key + sizeof value;
    throw_fire_position_not_finite(i, axis, value);
  }

  void reset_flags() { CF_CUDA_CHECK(cudaMemsetAsync(flags_.data(), 0xff, sizeof(MdFlags), stream_)); }

  // gate_notice_check (tests): a chunk's notice (the first and only one posted) must be there exactly
  // where its gate closed (`closed`, from the copy), with the copy's values: the closed step, its
  // displacement and the largest one served.
  static void check_gate_notice(uint64_t closed, const cuda::StepGate& copy,
                                const std::optional<cuda::StepGate>& notice) {
    if (closed == cuda::kGateOpen) {
      if (notice) throw Error("internal error: a gated chunk posted a notice at step " +
                              std::to_string(notice->closed) + ", but its gate did not close");
      return;
    }
    if (!notice)
      throw Error("internal error: the step gate closed at step " + std::to_string(closed) +
                  ", but no kernel posted its notice");
    if (notice->closed != closed || notice->d2[closed % 3] != copy.d2[closed % 3] || notice->served != copy.served)
      throw Error("internal error: the step gate closed at step " + std::to_string(closed) +
                  ", but its notice says step " + std::to_string(notice->closed) + " or other values");
  }

  // Reads the integration's and the force engine's flags (synchronises) and throws for the first
  // that is raised, naming the steps first..last of the call.
  void check(int64_t first, int64_t last) {
    MdFlags f{};
    CF_CUDA_CHECK(cudaMemcpyAsync(&f, flags_.data(), sizeof(f), cudaMemcpyDeviceToHost, stream_));
    const std::string steps = first == last ? "step " + std::to_string(first)
                                            : "steps " + std::to_string(first) + "-" + std::to_string(last);
    try {
      resident_.check_flags(box_, n_, positions_.data(), ff_);  // synchronises the stream
    } catch (const Error& e) {
      if (f.diverged == ~0ull) rethrow_with(steps + ": ", e);
    }
    if (f.diverged != ~0ull) {
      reset_flags();
      if (drift_key_particle(f.drift) == f.diverged) {  // the particle's drift (below 2^32 particles)
        double dx;
        const unsigned long long bits = drift_key_displacement_bits(f.drift);
        std::memcpy(&dx, &bits, sizeof dx);
        char digits[32];  // the key keeps 6 digits: shown as such, not as the truncated double's
        std::snprintf(digits, sizeof digits, "%.6g", dx);
        if (std::isfinite(dx)) dx = std::strtod(digits, nullptr);
        throw Error(steps + ": " + diverged_message(std::size_t(f.diverged), drift_key_axis(f.drift), dx, NAN,
                                                    box_, ff_.cutoff, drift_share_));
      }
      throw Error(steps + ": particle " + std::to_string(f.diverged) +
                  " moved too far in one drift or left the finite numbers: the integration diverged; lower dt, "
                  "or remove overlaps first");
    }
  }

  std::unique_ptr<CudaForceEngine> owner_;
  cuda::ResidentForces& resident_;  // the force side: owner_'s resident evaluations
  EngineTestHooks hooks_;      // tests only: the gate's notice
  cudaStream_t stream_ = nullptr;
  Box box_;
  std::size_t n_ = 0;
  ForceField ff_;
  int64_t step_ = 0;
  double time_ = 0;
  double drift_share_ = 1.0;  // drift_limit's share in the steps last queued: 0.5 under Langevin
  std::vector<uint32_t> host_types_;
  DeviceBuffer<double> positions_, velocities_, masses_;
  DeviceBuffer<uint32_t> types_;
  DeviceBuffer<MdFlags> flags_;
  DeviceBuffer<double> scratch_result_;
  DeviceBuffer<FireScalars> fire_scalars_;
  DeviceBuffer<double> fire_start_;  // positions, then velocities, before minimize()
  DeviceBuffer<double> ranked_state_;  // a gated chunk's state in rank order: x, v, built, mass
  DeviceBuffer<std::byte> reduce_scratch_;
  bool observed_ = false;
  std::optional<double> uniform_mass_;  // every particle's mass, where they are all the same
  bool at_build_ = false;  // the positions are those the structure in use was built from
  DeviceBuffer<cuda::StepGate> gate_;
  cuda::GateReadback gate_read_;  // the gate's copy and notice on the host
  bool gate_reset_ = false;       // the last chunk's copy reset the gate
  int64_t interval_ = 16;    // steps between the last two builds (a guess before there were two)
  int64_t since_build_ = 0;  // evaluations served since the last build
  MdCounters counters_;
  std::vector<cudaEvent_t> force_events_;
  std::vector<int64_t> force_weights_;    // per timed evaluation: the evaluations its time stands for
  std::vector<cudaEvent_t> wait_events_;  // per host turnaround of a run() call's gated chunks: pause, resume
  std::size_t waits_ = 0;                 // turnarounds in the run() call
  bool paused_ = false;                   // a turnaround's resume is still to be recorded
  double shut_ms_ = 0;                    // force-kernel time of the timed evaluations the gate shut, this call
  cudaEvent_t chunk_start_ = nullptr, chunk_end_ = nullptr;
};

}  // namespace

std::unique_ptr<MdEngine> make_cuda_md_engine(const EngineChoice& choice) {
  return std::make_unique<CudaMdEngine>(choice);
}

}  // namespace cellforce

