// The seam between the CUDA MD engine (backend/md_engine.cu) and the force engine under it: what an
// MD run whose state stays in device memory asks of the force side. GpuEngine (backend/engine.h)
// implements it; the MD engine holds this interface and nothing else of the force engine, so that
// the integration never reaches past it. Plain C++: no CUDA headers.
//
// Two parts: resident evaluations of the MD state (every step's forces, and energy and virial when
// asked), and the gated evaluations a pair list serves behind the step gate (search/step_gate.h),
// queued in chunks with no host wait per step.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>

#include "core/box.h"
#include "core/engine_options.h"  // PipelineStats
#include "core/force_field.h"
#include "core/system.h"          // Request
#include "forces/fused_step.h"    // NextKickDrift
#include "search/rank_order.h"
#include "search/step_gate.h"

namespace cellforce::cuda {

class ResidentForces {
 public:
  virtual ~ResidentForces() = default;

  // The CUDA device and the stream (a cudaStream_t) every evaluation runs on; the MD engine queues
  // its step kernels on the same stream, so that they and the evaluations are ordered without a
  // host wait.
  virtual int device() const = 0;
  virtual void* stream() const = 0;

  // ---- resident evaluations ----

  // The forces at `positions` (n x dim, device, wrapped on periodic axes) with `types` (n, device,
  // or null for all type 0), validated by the caller before its run. Queued on stream(); the host
  // does not wait, except with an open axis when the structure is built (the particles' bounds,
  // 2 x dim numbers), with a skin and the displacement check (the largest displacement), and with
  // pair lists when the structure is built (the list's size). Forces stay on the device
  // (device_forces(), n x dim); with `request`, so do the energy and virial totals
  // (device_totals(): energy, then w_xx, w_yy, w_zz, w_xy, w_xz, w_yz). The kernels' flags
  // accumulate until check_flags(). `known_d2`: where the step gate closed at these positions, the
  // largest squared displacement its kick-drift measured (+inf where not finite): the reuse check
  // takes it instead of reducing it again on the device and waiting for it. `time_stages` false:
  // the evaluation records no stage events (collect_timing() and stats()' stage times are not for
  // it): for an evaluation whose stage times nothing reads.
  virtual void evaluate_resident(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                                 const ForceField& ff, const Request& request,
                                 std::optional<double> known_d2 = {}, bool time_stages = true) = 0;
  // Reads the flags raised since the last check (synchronises the stream) and clears them; throws
  // cellforce::Error naming both particles of a pair whose force was not finite (the positions
  // come to the host only then, for the message).
  virtual void check_flags(const Box& box, std::size_t n, const double* positions, const ForceField& ff) = 0;
  virtual const double* device_forces() const = 0;
  // The same array, for the MD engine to add its external force into after an evaluation (before
  // anything reads it).
  virtual double* device_forces_to_add() = 0;
  virtual const double* device_totals() const = 0;
  // stats() gets the counts of the last evaluation and the stage times of the last timed one
  // (zeros where none was timed); synchronises.
  virtual void collect_timing() = 0;
  virtual const PipelineStats& stats() const = 0;

  // ---- gated evaluations (pair lists, behind the step gate) ----

  // How many of the next evaluations may be queued behind the gate (0: none may). Positive only
  // while the structure in use has its pair list, the displacement check is on, the audit is off,
  // flags accumulate (resident evaluations) and nothing but the displacement could ask for a
  // rebuild before then (same box, count and cutoff; `every` bounds the count).
  virtual int64_t gate_steps(const Box& box, std::size_t n, const ForceField& ff) const = 0;
  // What the steps' drift kernels need: the bits of (skin / 2)^2 and the positions the structure in
  // use was built from (n x dim, device).
  virtual unsigned long long gate_limit() const = 0;
  virtual const double* device_build_positions() const = 0;
  // Where the gated steps' last drift kernels place the positions in the list's rank order (the
  // gather's values), for gated evaluations that then leave their gather out, and where those
  // leave the forces. Valid until the structure is rebuilt. With `fused` (a Verlet chunk in fast
  // memory), the list's second rank-ordered array is reserved too, for gated evaluations that run
  // the next step's kick-drift (evaluate_gated's `then`).
  virtual RankOrder rank_order(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                               const ForceField& ff, bool fused = false) = 0;
  // After a chunk whose last gated evaluation ran: its forces, left in rank order (the RankOrder's
  // `forces`, when not null), into device_forces() in the caller's order.
  virtual void unrank_forces(std::size_t n) = 0;
  // One gated evaluation (forces only, from the pair list), queued; the host does not wait and
  // nothing is counted until settle_gate(). The step's drift placed the positions (rank_order()),
  // and the forces go where the RankOrder says. With `then` (rank_order()'s `fused`), the
  // evaluation runs the next gated step's Verlet kick-drift on the chunk's rank-order state
  // instead of storing its forces; the gate's test is then the next step's.
  virtual void evaluate_gated(const Box& box, std::size_t n, const double* positions, const uint32_t* types,
                              const ForceField& ff, const GateView& gate, const NextKickDrift* then = nullptr) = 0;
  // After the host read the gate: `served` gated evaluations ran (the structure served them, the
  // largest squared displacement among them `served_d2`). stats() then reads as after a reused
  // evaluation.
  virtual void settle_gate(int64_t served, double served_d2) = 0;
};

}  // namespace cellforce::cuda
