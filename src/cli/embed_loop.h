// `cellforce bench --embed`: the loop a code that embeds cellforce as its force kernel runs. Its own
// velocity Verlet, two small kernels of its own on a stream of its own, around
// Context::compute_device on device arrays it holds:
//   kick and drift (v += dt/2 F/m; x += dt v), compute_device(x -> F), kick (v += dt/2 F/m).
// Only the public API is used, as an embedding code would use it; the kernels are the user's, not
// the engine's (cellforce's own integrator is Context::step). Built with CUDA only.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>

#include <cellforce/cellforce.hpp>

namespace cellforce {

class EmbeddedVerlet {
 public:
  // Uploads the state (positions and velocities n x dim, types n or null, masses n) to the current
  // CUDA device (the context's must be the same: bench runs device 0), makes a stream, and queues
  // the forces at the positions. The context holds the physics and the engine options; it must
  // run on CUDA.
  EmbeddedVerlet(Context& ctx, std::size_t n, const double* positions, const double* velocities,
                 const uint32_t* types, const double* masses, double dt);
  ~EmbeddedVerlet();
  EmbeddedVerlet(const EmbeddedVerlet&) = delete;
  EmbeddedVerlet& operator=(const EmbeddedVerlet&) = delete;

  // Queues `count` steps and returns (the host waits only where compute_device does). With
  // `observe`, the last step's compute_device also writes the potential energy.
  void step(int64_t count, bool observe);
  // Waits for the queued steps; the potential energy of the last observed step plus the kinetic
  // energy now (a reduction on the device), per the whole system.
  double total_energy();
  // Waits, then the positions (as integrated: not wrapped) and forces into host arrays (n x dim).
  void download(double* positions, double* forces);
  // The host's time inside one compute_device call, averaged over the calls so far (seconds): what
  // a caller's thread spends queueing a force evaluation.
  double call_host_seconds() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace cellforce
