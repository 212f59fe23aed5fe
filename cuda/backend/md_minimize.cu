// The CUDA MdEngine's minimize(): FIRE (md/minimize.h's run_fire, its decisions on the host) on
// the state in device memory, its per-particle arithmetic in integrate/fire_kernels.cuh; one
// synchronisation per step, for FireScalars (56 bytes) and the force engine's flags.
#include "backend/md_engine.cuh"

namespace cellforce {

FireResult CudaMdEngine::minimize(const FireSettings& settings) {
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

FireResult CudaMdEngine::fire(const FireSettings& settings) {
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

FireEvaluation CudaMdEngine::fire_evaluate() {
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

void CudaMdEngine::throw_if_position_not_finite() {
  unsigned long long key = ~0ull;
  CF_CUDA_CHECK(cudaMemcpyAsync(&key, &fire_scalars_.data()->bad_position, sizeof key, cudaMemcpyDeviceToHost,
                                stream_));
  CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
  if (key != ~0ull) throw_position_not_finite(key);
}

[[noreturn]] void CudaMdEngine::throw_position_not_finite(unsigned long long key) {
  const std::size_t i = std::size_t(key % n_);
  const int axis = int(key / n_);
  double value = 0;
  CF_CUDA_CHECK(cudaMemcpyAsync(&value, positions_.data() + i * std::size_t(box_.dim) + std::size_t(axis),
                                sizeof value, cudaMemcpyDeviceToHost, stream_));
  CF_CUDA_CHECK(cudaStreamSynchronize(stream_));
  counters_.bytes_to_host += sizeof key + sizeof value;
  throw_fire_position_not_finite(i, axis, value);
}

}  // namespace cellforce
