// The CUDA backend's MdEngine: the MD state lives in device memory for the whole run, and the
// integrators run as kernels on the force engine's stream with the forces of its resident
// evaluations. The class (its methods in backend/md_engine.cu and, for FIRE, backend/md_minimize.cu)
// is the schedule and the host's side: which kernels a call queues, when the
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
#pragma once

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
#include "transfer.cuh"

namespace cellforce {

class CudaMdEngine final : public MdEngine {
  // Host helpers of the engine's calls.
  template <class T>
  using DeviceBuffer = cuda::DeviceBuffer<T>;
  using FireScalars = cuda::FireScalars;
  using ForceSums = cuda::ForceSums;
  using WrapBox = cuda::WrapBox;
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


 public:
  // The force engine of `choice` (CUDA), made here: the MD engine reaches it only through
  // cuda::ResidentForces, and queues its step kernels on the force engine's stream (the choice's
  // stream, or the one the force engine made).
  explicit CudaMdEngine(const EngineChoice& choice);
  ~CudaMdEngine() override;

  void set_state(const MdState& state, const std::vector<double>& masses, const ForceField& ff) override;

  void advance(int64_t steps, const IntegratorSettings& settings, bool observe) override;

  void set_positions(const std::vector<double>& positions) override;
  void set_velocities(const std::vector<double>& velocities) override;
  void get_state(MdState& state) override;
  StateArrays state_arrays() override;

  int64_t step() const override { return step_; }
  std::vector<std::pair<const char*, std::size_t>> state_buffers() const override;

  Observables observables() override;

  void reevaluate() override;
  // An external array is added after each evaluation, a gated one's too (behind the gate, into the
  // chunk's rank order; such chunks are not fused); with a callback the steps are not gated (the
  // host's function runs after each step's evaluation: gate_chunk() gives none).
  void set_external_force(const ExternalForce& external) override;
  FireResult minimize(const FireSettings& settings) override;

  ForceEngine& forces() override { return *owner_; }
  const MdCounters& counters() const override { return counters_; }
  void reset_counters() override { counters_ = MdCounters{}; }

 private:
  static constexpr int64_t kRun = 256;
  static constexpr int64_t kMaxGated = 64;  // steps queued behind the gate between two reads of it

  void release();

  // `steps` steps queued back to back, then the flags read (one synchronisation). An error thrown
  // while queueing (an evaluation of positions that diverged) gives way to the flags' diagnosis.
  // Steps before the last go behind the step gate in chunks wherever the force engine can serve
  // them from its pair list (run_gated): one host wait per chunk instead of one per step. A step's
  // closing half kick is deferred into the next step's first kernel, but for the last step's.
  // `sampled`: the last run of an advance() call, whose last evaluation's stage times it samples.
  void run(int64_t steps, const IntegratorSettings& settings, bool observe, bool sampled);

  // A gated chunk's end: the device idles from here (the gate's read) until the host queues more
  // work, which first records the matching resume(). The gap is booked to no stage.
  void pause();
  void resume();

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
  // rebuild, whose kick-drift reads the gate first; at least 2. A chunk that ends before the gate
  // closes costs one more read of the gate. `overshoot`: the chunk's length is the expected one (not cut short by the run's end, `every` or the gate's own
  // bound), so its last step is the one past the expected rebuild.
  struct GateChunk {
    int64_t count = 0;
    bool overshoot = false;
  };
  GateChunk gate_chunk(int64_t most) const;

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

  Chunk begin_chunk(const IntegratorSettings& settings);

  // The chunk's `count` steps, queued: each step's kernels (integrate/gated_steps.cuh; in a fused
  // chunk the first step's only) and its gated evaluation. `gathered`: the first kernel has copied
  // the state into rank order (for the diagnosis when a later launch throws).
  void queue_chunk(Chunk& c, const GateChunk& chunk, int first_kicks, const IntegratorSettings& settings,
                   std::size_t& timed, bool& gathered);

  // `count` steps behind the step gate (search/step_gate.h), then one read of the gate. Steps the
  // structure served are done; at the step where the gate closed (its drifts done, its evaluation
  // not run), the ordinary evaluation rebuilds and that step is done too. Returns the steps done.
  int64_t run_gated(const GateChunk& chunk, int first_kicks, const IntegratorSettings& settings,
                    std::size_t& timed);

  // The chunk's end: the gate read (its notice, or its copy), the steps served settled and counted,
  // and where the gate closed, the closed step's ordinary (rebuilding) evaluation.
  int64_t read_chunk(const Chunk& c, int64_t count, double dt, std::size_t& timed);

  // A rank-order chunk's positions and velocities back into the caller's order.
  void unrank_state(const cuda::GatedState& state, const uint32_t* rank) {
    cuda::unrank(rank, state.x_ranked, n_, box_.dim, state.x, stream_);
    cuda::unrank(rank, state.v_ranked, n_, box_.dim, state.v, stream_);
  }

  void kick(double h, int kicks) {
    cuda::queue_kick(velocities_.data(), resident_.device_forces(), masses_.data(), h, kicks, n_, box_.dim, stream_);
  }

  void kick_drift(double h, int kicks, double dt);

  DriftBox drift_box(double limit) const;

  void drift(double h, double limit, bool wrap) {
    at_build_ = false;
    cuda::queue_drift(positions_.data(), velocities_.data(), h, drift_box(limit), wrap, n_, flags_.data(), stream_);
  }

  // known_d2: the step gate's displacement at these positions, where it closed (the reuse check's
  // value). The external force is added to the evaluation's forces.
  void evaluate(bool observe, std::optional<double> known_d2 = {}, bool time_stages = true);

  // FIRE on the state (minimize() restores the start when this throws): md/minimize.h's run_fire,
  // its per-particle arithmetic in kernels, its decisions on the host.
  FireResult fire(const FireSettings& settings);

  // One FIRE evaluation at the positions now (energy and virial), its ForceSums with the
  // velocities now, its energy, and the drift's flag (FireScalars): the numbers the host reads per
  // step, with
  // the force engine's flags (one synchronisation). Throws for a pair whose force is not finite
  // and for a position that is not finite (that diagnosis first: an evaluation of such positions
  // may fail on its own).
  FireEvaluation fire_evaluate();

  static LargestForce largest_of(const ForceSums& s) {
    return LargestForce{s.largest2 < 0 ? 0.0 : std::sqrt(s.largest2), std::size_t(s.particle)};
  }

  // The error path of FIRE's drift flag: the flag, then the coordinate it names, to the host.
  void throw_if_position_not_finite();
  [[noreturn]] void throw_position_not_finite(unsigned long long key);

  void reset_flags() { CF_CUDA_CHECK(cudaMemsetAsync(flags_.data(), 0xff, sizeof(MdFlags), stream_)); }

  // gate_notice_check (tests): a chunk's notice (the first and only one posted) must be there exactly
  // where its gate closed (`closed`, from the copy), with the copy's values: the closed step, its
  // displacement and the largest one served.
  static void check_gate_notice(uint64_t closed, const cuda::StepGate& copy,
                                const std::optional<cuda::StepGate>& notice);

  // Reads the integration's and the force engine's flags (synchronises) and throws for the first
  // that is raised, naming the steps first..last of the call.
  void check(int64_t first, int64_t last);

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
  ExternalForce external_;            // its host array (values) is held on the device, below
  DeviceBuffer<double> external_values_;
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

}  // namespace cellforce
