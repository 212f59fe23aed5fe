// FIRE's kernels (md/minimize.h's algorithm; the MD engine's minimize(), backend/md_engine.cu):
// per step one kernel steps back (on an uphill step) and kicks, a reduction sums v^2, one kernel
// mixes, caps, drifts and wraps (md/fire_step.h's per-particle arithmetic, the host's bits), and
// after the force engine's evaluation one reduction gives P = F.v, sum F^2 and the largest |F_i|
// with its particle. The scalar decisions (dt, alpha, the downhill count, convergence) stay on the
// host, which reads FireScalars back once a step.
#pragma once

#include <cuda_runtime.h>

#include <cstddef>

#include "core/box.h"  // kMaxDim
#include "device_buffer.cuh"

namespace cellforce::cuda {

// What one FIRE reduction gives over the particles after an evaluation: P = F.v and sum F^2 over
// every coordinate, and the largest |F_i|^2 with its particle (largest_force's choice: a NaN is
// the largest of all, ties go to the smallest index).
struct ForceSums {
  double power;
  double f2;
  double largest2;
  unsigned long long particle;
};

// The numbers the host reads back per FIRE step.
struct FireScalars {
  ForceSums forces;                 // of the last evaluation, with the velocities now
  double v2;                        // sum v^2 after the kick (the mixing's |v|)
  double energy;                    // the last evaluation's potential energy (its totals[0])
  unsigned long long bad_position;  // min over non-finite coordinates of axis x n + particle; ~0 if none
};

struct WrapBox {
  int dim;
  double length[kMaxDim];
  bool periodic[kMaxDim];
};

// An uphill step's step back by half a step (x -= half_dt v, v = 0) when `uphill`, then the kick
// v += (dt / m) F; per particle.
void queue_fire_kick(double* x, double* v, const double* f, const double* mass, double dt, double half_dt,
                     bool uphill, std::size_t n, int dim, cudaStream_t stream);

// sum v^2 over every coordinate into *v2 (device).
void sum_fire_speeds(const double* v, std::size_t n, int dim, double* v2, DeviceBuffer<std::byte>& scratch,
                     cudaStream_t stream);

// The velocity mixing (with sums->v2 and sums->forces.f2 from the device), the displacement cap and
// the drift, then the wrap on periodic axes; a coordinate that is not finite raises
// sums->bad_position (axis x n + particle, the smallest: the host's wrap names the same one).
void queue_fire_drift(double* x, double* v, const double* f, FireScalars* sums, double alpha, double dt,
                      double max_displacement, const WrapBox& box, std::size_t n, cudaStream_t stream);

// The ForceSums of forces f and velocities v into *out (device): for n = 0, {0, 0, -1, 0}.
void sum_fire_forces(const double* f, const double* v, std::size_t n, int dim, ForceSums* out,
                     DeviceBuffer<std::byte>& scratch, cudaStream_t stream);

}  // namespace cellforce::cuda
