// The device's ungated velocity Verlet and Langevin BAOAB steps (md/md.h's advance(), step for
// step), as kernels a thread per coordinate: the kicks, the drifts with their check, the kick and
// drift of a Verlet step in one pass, BAOAB's thermostat, and the kinetic energy's reduction. The
// per-coordinate arithmetic is md/verlet_step.h's, the host loop's, bit for bit. The MD engine
// (backend/md_engine.cu) orders them; the steps a pair list serves behind the step gate have their
// own kernels (integrate/gated_steps.cuh).
#pragma once

#include <cuda_runtime.h>

#include <cstddef>
#include <cstdint>

#include "device_buffer.cuh"
#include "md/verlet_step.h"

namespace cellforce::cuda {

// f += add, `count` coordinates (an external force: backend/md_engine.cu).
void queue_add(double* f, const double* add, std::size_t count, cudaStream_t stream);

// `kicks` half kicks v += (h / m) F of every coordinate (n x dim; mass n).
void queue_kick(double* v, const double* f, const double* mass, double h, int kicks, std::size_t n, int dim,
                cudaStream_t stream);

// A drift x += h v of every coordinate, checked against box.most (a failure raises the particle in
// flags); with `wrap` (a step's last drift) wrapped into the box on periodic axes.
void queue_drift(double* x, const double* v, double h, const DriftBox& box, bool wrap, std::size_t n,
                 MdFlags* flags, cudaStream_t stream);

// A Verlet step's kicks and drift in one pass: `kicks` half kicks (h = dt / 2), then the drift
// x += dt v with the check and the wrap: one read and write of the state instead of three.
void queue_kick_drift(double* x, double* v, const double* f, const double* mass, double h, int kicks, double dt,
                      const DriftBox& box, std::size_t n, MdFlags* flags, cudaStream_t stream);

// BAOAB's O step: v = c1 v + c2 sqrt(kT / m) xi, xi from counter_normal(seed, step + 1, coordinate),
// keyed by the particle's stable index (the caller's order), as the host draws it.
void queue_thermostat(double* v, const double* mass, double c1, double c2, double kT, uint64_t seed,
                      uint64_t noise_stream, std::size_t n, int dim, cudaStream_t stream);

// The kinetic energy sum_i m_i v_i^2 / 2 into *result (device); scratch grows as CUB asks.
void sum_kinetic_energy(const double* v, const double* mass, std::size_t n, int dim, double* result,
                        DeviceBuffer<std::byte>& scratch, cudaStream_t stream);

}  // namespace cellforce::cuda
