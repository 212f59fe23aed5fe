// The CUDA MdEngine's state and steps (backend/md_engine.cuh): set_state, get_state and the
// observables, and advance(): the schedule of a call's steps, ungated or in chunks behind the step
// gate, and the report of a divergence or a bad pair.
#include "backend/md_engine.cuh"

namespace cellforce {

CudaMdEngine::CudaMdEngine(const EngineChoice& choice)
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

CudaMdEngine::~CudaMdEngine() {
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

void CudaMdEngine::set_state(const MdState& state, const std::vector<double>& masses, const ForceField& ff) {
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
  cuda::upload(positions_, state.config.positions, stream_);
  cuda::upload(velocities_, state.velocities.empty() ? std::vector<double>(n_ * box_.dim, 0.0) : state.velocities,
         stream_);
  cuda::upload(masses_, masses, stream_);
  uniform_mass_.reset();  // one mass for all, bit for bit, is passed as a number (no load per coordinate)
  if (!masses.empty() && std::all_of(masses.begin(), masses.end(), [&](double m) {
        return std::memcmp(&m, &masses[0], sizeof m) == 0;
      }))
    uniform_mass_ = masses[0];
  cuda::upload(types_, state.config.types, stream_);
  counters_.bytes_to_device += (2 * n_ * box_.dim + n_) * sizeof(double) + n_ * sizeof(uint32_t);
  flags_.reserve(1);
  reset_flags();
  evaluate(true);
  check(step_, step_);
}

void CudaMdEngine::advance(int64_t steps, const IntegratorSettings& settings, bool observe) {
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

// The positions alone are uploaded; the ones before stay on the device (a copy beside them) until
// the forces at the new ones are known to be finite.
void CudaMdEngine::set_positions(const std::vector<double>& positions) {
  const OnDevice on(resident_.device());
  validate_system(SystemView{box_, n_, positions.data(), host_types_.empty() ? nullptr : host_types_.data()}, ff_);
  const std::size_t nd = n_ * std::size_t(box_.dim);
  DeviceBuffer<double> before;
  before.bind(stream_);
  before.reserve(std::max<std::size_t>(nd, 1));
  CF_CUDA_CHECK(cudaMemcpyAsync(before.data(), positions_.data(), nd * sizeof(double), cudaMemcpyDeviceToDevice,
                                stream_));
  cuda::upload(positions_, positions, stream_);
  counters_.bytes_to_device += nd * sizeof(double);
  at_build_ = false;  // the positions change
  try {
    evaluate(true);
    check(step_, step_);
  } catch (const Error& e) {
    try {
      CF_CUDA_CHECK(cudaMemcpyAsync(positions_.data(), before.data(), nd * sizeof(double), cudaMemcpyDeviceToDevice,
                                    stream_));
      reset_flags();
      evaluate(true);
      check(step_, step_);
    } catch (const Error& again) {
      throw Error(e.message() + "; the positions before could not be evaluated again either (" + again.message() +
                  "): set the state again");
    }
    throw;
  }
}

void CudaMdEngine::set_velocities(const std::vector<double>& velocities) {
  const OnDevice on(resident_.device());
  cuda::upload(velocities_, velocities, stream_);
  counters_.bytes_to_device += velocities.size() * sizeof(double);
}

void CudaMdEngine::get_state(MdState& state) {
  const OnDevice on(resident_.device());
  const std::size_t nd = n_ * std::size_t(box_.dim);
  state.config.box = box_;
  state.config.types = host_types_;
  cuda::download(state.config.positions, positions_.data(), nd, stream_);
  cuda::download(state.velocities, velocities_.data(), nd, stream_);
  cuda::download(state.forces, resident_.device_forces(), nd, stream_);
  CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
  counters_.bytes_to_host += 3 * nd * sizeof(double);
  state.step = step_;
  state.time = time_;
}

MdEngine::StateArrays CudaMdEngine::state_arrays() {
  const OnDevice on(resident_.device());
  CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
  return {positions_.data(), velocities_.data(), resident_.device_forces(), resident_.device()};
}

std::vector<std::pair<const char*, std::size_t>> CudaMdEngine::state_buffers() const {
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
          {"md: chunk state in rank order", ranked_state_.bytes()},
          {"md: external forces", external_values_.bytes()}};
}

Observables CudaMdEngine::observables() {
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

void CudaMdEngine::set_external_force(const ExternalForce& external) {
  const OnDevice on(resident_.device());
  external_ = external;
  if (!external.values.empty()) {
    cuda::upload(external_values_, external.values, stream_);
    counters_.bytes_to_device += external.values.size() * sizeof(double);
  } else {
    external_values_.release();
  }
  external_.values.clear();  // the device copy serves
  external_.device = external.values.empty() ? external.device : external_values_.data();
}

void CudaMdEngine::reevaluate() {
  const OnDevice on(resident_.device());
  at_build_ = false;  // the structure may have been restored from other positions (restore_reuse)
  evaluate(true);
  check(step_, step_);
}

void CudaMdEngine::release() {
  for (cudaEvent_t e : force_events_) cudaEventDestroy(e);
  force_events_.clear();
  for (cudaEvent_t e : wait_events_) cudaEventDestroy(e);
  wait_events_.clear();
  if (chunk_start_) cudaEventDestroy(chunk_start_);
  if (chunk_end_) cudaEventDestroy(chunk_end_);
  chunk_start_ = chunk_end_ = nullptr;
}

void CudaMdEngine::run(int64_t steps, const IntegratorSettings& settings, bool observe, bool sampled) {
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

void CudaMdEngine::pause() {
  while (wait_events_.size() < 2 * (waits_ + 1)) {
    cudaEvent_t ev;
    CF_CUDA_CHECK(cudaEventCreate(&ev));
    wait_events_.push_back(ev);
  }
  CF_CUDA_CHECK(cudaEventRecord(wait_events_[2 * waits_], stream_));
  ++waits_;
  paused_ = true;
}

void CudaMdEngine::resume() {
  if (!paused_) return;
  CF_CUDA_CHECK(cudaEventRecord(wait_events_[2 * waits_ - 1], stream_));
  paused_ = false;
}

CudaMdEngine::GateChunk CudaMdEngine::gate_chunk(int64_t most) const {
  if (external_.callback) return {};  // the host's function runs after each step's evaluation
  const int64_t allowed = std::min(most, resident_.gate_steps(box_, n_, ff_));
  if (allowed <= 0) return {};
  const int64_t expected = std::clamp<int64_t>(interval_ + 1 - since_build_, 2, kMaxGated);
  return {std::min(allowed, expected), expected <= allowed};
}

CudaMdEngine::Chunk CudaMdEngine::begin_chunk(const IntegratorSettings& settings) {
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
  // An external array is added after each evaluation (no fused kick-drift).
  const bool fusible = !settings.langevin && !external_.device;
  c.to = resident_.rank_order(box_, n_, positions_.data(), c.types, ff_, fusible);
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
  c.fused = c.ranked && fusible;
  c.then = cuda::NextKickDrift{c.state.x_ranked, c.state.v_ranked, c.state.mass_ranked, c.state.built_ranked,
                               c.to.order, 0.5 * dt, dt, c.box, flags_.data(), c.state.mass_value};
  return c;
}

void CudaMdEngine::queue_chunk(Chunk& c, const GateChunk& chunk, int first_kicks, const IntegratorSettings& settings,
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
    auto evaluate_step = [&] {
      resident_.evaluate_gated(box_, n_, positions_.data(), c.types, ff_, c.view, next);
      if (external_.device)  // into the evaluation's forces: rank order (RankOrder::forces) or the caller's
        cuda::queue_gated_external(c.view, c.ranked ? c.to.forces : resident_.device_forces_to_add(),
                                   external_.device, c.ranked ? c.to.order : nullptr, n_, box_.dim, stream_);
    };
    if (j == 0) {
      std::size_t slot = timed;  // counted by read_chunk, for every step served
      timed_evaluation(slot, evaluate_step);
    } else {
      evaluate_step();
    }
  }
  c.view.step = first;
}

int64_t CudaMdEngine::run_gated(const GateChunk& chunk, int first_kicks, const IntegratorSettings& settings,
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

int64_t CudaMdEngine::read_chunk(const Chunk& c, int64_t count, double dt, std::size_t& timed) {
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

void CudaMdEngine::kick_drift(double h, int kicks, double dt) {
  at_build_ = false;
  cuda::queue_kick_drift(positions_.data(), velocities_.data(), resident_.device_forces(), masses_.data(), h, kicks, dt,
                         drift_box(1.0), n_, flags_.data(), stream_);
}

DriftBox CudaMdEngine::drift_box(double limit) const {
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

void CudaMdEngine::evaluate(bool observe, std::optional<double> known_d2, bool time_stages) {
  resident_.evaluate_resident(box_, n_, positions_.data(), ff_.num_types() > 1 ? types_.data() : nullptr, ff_,
                         Request{observe, observe}, known_d2, time_stages);
  if (external_.device) cuda::queue_add(resident_.device_forces_to_add(), external_.device, n_ * std::size_t(box_.dim), stream_);
  if (external_.callback)
    external_.callback(external_.user, step_, n_, box_.dim, positions_.data(), resident_.device_forces_to_add(), stream_);
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

void CudaMdEngine::check_gate_notice(uint64_t closed, const cuda::StepGate& copy,
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

void CudaMdEngine::check(int64_t first, int64_t last) {
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

std::unique_ptr<MdEngine> make_cuda_md_engine(const EngineChoice& choice) {
  return std::make_unique<CudaMdEngine>(choice);
}

}  // namespace cellforce
