// cellforce's C++ API: Lennard-Jones forces, energies and virial of a particle system by the
// spatial-subdivision cutoff search of GPU Gems 3, chapter 32, on the CPU or a CUDA device.
//
//   cellforce::Context ctx(3);
//   const double box[3] = {10, 10, 10};
//   const bool periodic[3] = {true, true, true};
//   ctx.set_box(box, periodic);
//   ctx.set_cutoff(2.5, cellforce::CutoffMode::kTruncate);
//   ctx.add_type("A", 1.0, 1.0);
//   std::vector<double> forces(3 * n);
//   double energy;
//   ctx.compute(n, positions.data(), nullptr, {forces.data(), nullptr, &energy, nullptr});
//
// Units are the caller's: lengths as the positions, energies as epsilon, forces energy/length.
// Arrays are in the caller's particle order, row-major: particle i's coordinate a is
// positions[i * dim + a]. Every failing call throws cellforce::Error, whose message names the
// parameter, particle or option at fault; a failed call leaves the outputs unwritten and the
// context as it was. A Context is not thread-safe: one thread at a time.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include <cellforce/error.hpp>
#include <cellforce/export.hpp>
#include <cellforce/options.hpp>

namespace cellforce {

// The library's version, "MAJOR.MINOR.PATCH".
CELLFORCE_API const char* version();

// Where a compute call writes. Host pointers for compute(), device pointers (on the context's
// device) for compute_device(). Only forces is required; the others are computed only when given
// (energy and virial cost arithmetic, and are left out of the kernels when nobody reads them).
struct Outputs {
  double* forces = nullptr;    // n x dim: the force on each particle (energy / length)
  double* energies = nullptr;  // n: each particle's share of the potential energy (half of each
                               // of its pairs' energies); they sum to *energy
  double* energy = nullptr;    // 1: the total potential energy
  double* virial = nullptr;    // dim x dim, row-major: sum over pairs of r_ij (x) f_ij, with
                               // r_ij = x_i - x_j by minimum image and f_ij the force on i from j
};

// Pair counts of a configuration (count_pairs()).
struct PairCounts {
  std::size_t tested = 0;         // candidate pairs the traversal tested
  std::size_t within_cutoff = 0;  // pairs with r < rc (each once)
};

// Timings and sizes of the last compute call.
struct Statistics {
  double pipeline_seconds = 0;  // the engine's stages, without host <-> device copies (device
                                // stream time on CUDA)
  double transfer_seconds = 0;  // host <-> device copies (CUDA, compute() only)
  std::size_t builds = 0;       // neighbour structures built so far (stages 1-3)
  bool rebuilt = true;          // whether the last call built one (false: reused, skin > 0)
  std::size_t buffer_bytes = 0; // memory the engine holds for its stages (device memory on CUDA)
};

class CELLFORCE_API Context {
 public:
  // An empty context for 2 or 3 dimensions: no box, cutoff or types yet; CPU backend, double
  // precision, Lorentz-Berthelot mixing, no skin.
  explicit Context(int dim = 3);
  ~Context();
  Context(Context&&) noexcept;
  Context& operator=(Context&&) noexcept;
  Context(const Context&) = delete;
  Context& operator=(const Context&) = delete;

  // ---- the physics (may change between compute calls) ----
  // lengths[dim], periodic[dim]: edge lengths and which axes wrap. A periodic edge must be finite
  // and > 0 (and at least twice the cutoff, checked when computing); the length of an open axis
  // is ignored and may be 0 (particles may lie anywhere along it).
  void set_box(const double* lengths, const bool* periodic);
  // Pairs interact only when r < rc (strict); mode: what happens at rc (options.hpp).
  void set_cutoff(double rc, CutoffMode mode = CutoffMode::kTruncate);
  void set_mixing(Mixing mixing);
  // A particle type; returns its index (0, 1, ... in the order added). sigma and epsilon finite
  // and >= 0; names printable and unique.
  uint32_t add_type(const std::string& name, double sigma, double epsilon);
  // An explicit pair value that replaces the mixing rule for types a and b (either order).
  void set_pair(uint32_t a, uint32_t b, double sigma, double epsilon);

  // ---- the engine (a change takes effect at the next compute call) ----
  void set_backend(Backend backend, int device = 0);
  void set_precision(Precision precision);
  // Verlet skin of the neighbour structure (length): stages 1-3 are built for rc + skin and reused
  // while no particle has moved more than skin / 2; 0 (the default) rebuilds on every call.
  void set_skin(double skin);
  // Every choice by name, as the C API and scene files write them:
  //   backend       cpu | cuda | auto
  //   device        CUDA device ordinal, 0, 1, ...
  //   precision     single | mixed | double
  //   mixing        lorentz-berthelot | geometric
  //   cutoff-mode   truncate | shift | force-shift
  //   skin          a length >= 0
  //   accumulation  jacobi | gauss-seidel
  //   cell-rule     tight | chapter
  //   traversal     warp | thread            (CUDA)
  //   sort          cub | chapter            (CUDA)
  void set_option(std::string_view key, std::string_view value);

  // ---- computing ----
  // Host arrays. positions: n x dim (any periodic image; finite); types: n indices into the types
  // added, or null for all type 0. Returns when the results are written; on CUDA it copies the
  // arrays to the device and back. n = 0 is a valid, empty call (energy and virial 0).
  void compute(std::size_t n, const double* positions, const uint32_t* types, const Outputs& out);
  // Device arrays on the context's CUDA device (positions, types and every output pointer).
  // The work is ordered after what `stream` (a cudaStream_t; null: the legacy default stream)
  // already holds, and the results are ready when the stream reaches this call's point: work the
  // caller queues on `stream` afterwards sees them. Needs the cuda backend (or auto with a
  // device). This version synchronises the host: it reads the positions back to validate them
  // and plan the grid, and reads the counts that size the engine's buffers (a sync-free pipeline
  // is in progress). Results are bitwise those of compute() on the same input and backend.
  void compute_device(std::size_t n, const double* positions, const uint32_t* types, const Outputs& out,
                      void* stream = nullptr);
  // Pairs tested and within the cutoff for host arrays (an extra pass on CUDA; it counts as one
  // more use of a reused structure).
  PairCounts count_pairs(std::size_t n, const double* positions, const uint32_t* types);
  Statistics statistics() const;

  // ---- what the context is ----
  int dim() const;
  std::size_t num_types() const;
  // The backend in use, "cpu" or "cuda" (auto resolved; this creates the engine when needed), a
  // description (device or threads, algorithm), and the CUDA traversal and sort ("-" on the CPU).
  std::string backend_name();
  std::string description();
  std::string traversal();
  std::string sort();

  struct Impl;  // the engine and the physics it is given

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace cellforce
