// cellforce-lammps: LAMMPS (its library) runs an input script written for LAMMPS, with
// `pair_style lj/cut` computed by cellforce on every rank (pair_cellforce.h); every other pair
// style is refused. LAMMPS's own flags pass through (-in, -var, -log, -echo, ...); cellforce's
// engine options come from --cellforce-backend, --cellforce-precision, --cellforce-skin and
// --cellforce-device, or the variables CELLFORCE_BACKEND, CELLFORCE_PRECISION, CELLFORCE_SKIN and
// CELLFORCE_DEVICE (a flag wins); the defaults are backend auto (a GPU where the rank finds one,
// else the CPU) and precision double. Without a device given, rank r of a node uses that node's GPU
// r mod (its GPUs); the CPU backend's threads are the node's cores over its ranks (or
// CELLFORCE_THREADS).
//   mpirun -np 4 cellforce-lammps -in in.lj --cellforce-backend cpu
#include <mpi.h>

#ifdef CELLFORCE_HAVE_CUDA
#include <cuda_runtime.h>
#endif

#include <cellforce/cellforce.hpp>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <string>
#include <thread>
#include <vector>

#include "lammps_headers.h"
#include "pair_cellforce.h"

namespace {

// A pair style other than lj/cut: refused by LAMMPS's error, which names the script's line.
class RefusedPair : public LAMMPS_NS::Pair {
 public:
  explicit RefusedPair(LAMMPS_NS::LAMMPS* instance) : Pair(instance) {
    error->all(FLERR, std::string("cellforce-lammps computes pair_style lj/cut only (with cellforce): this pair style is "
                      "refused"));
  }
  void compute(int, int) override {}
  void settings(int, char**) override {}
  void coeff(int, char**) override {}
  static LAMMPS_NS::Pair* create(LAMMPS_NS::LAMMPS* instance) { return new RefusedPair(instance); }
};

// The pair styles cellforce computes: lj/cut, also under LAMMPS's accelerator suffixes (-sf opt,
// omp, ...: lj/cut/SUFFIX is lj/cut computed by another engine).
bool ours(const std::string& name) {
  if (name == "lj/cut") return true;
  for (const char* suffix : {"opt", "omp", "gpu", "intel", "kk", "kk/host", "kk/device"})
    if (name == "lj/cut/" + std::string(suffix)) return true;
  return false;
}

// The CUDA devices this process can use (0 without CUDA, or where the runtime finds none).
int cuda_devices() {
#ifdef CELLFORCE_HAVE_CUDA
  int count = 0;
  if (cudaGetDeviceCount(&count) != cudaSuccess) {
    (void)cudaGetLastError();
    return 0;
  }
  return count;
#else
  return 0;
#endif
}

// Makes `device` (when it is one of this process's `gpus`) the current CUDA device; a device that
// cannot be made current is left to the engine to report.
void select_device(int device, int gpus) {
#ifdef CELLFORCE_HAVE_CUDA
  if (device >= 0 && device < gpus && cudaSetDevice(device) != cudaSuccess) (void)cudaGetLastError();
#else
  (void)device;
  (void)gpus;
#endif
}

}  // namespace

int main(int argc, char** argv) {
  MPI_Init(&argc, &argv);
  int rank = 0;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  // cellforce's options out of the arguments, the rest LAMMPS's
  auto& options = cellforce::lammps::engine_settings().options;
  const char* names[] = {"backend", "precision", "skin", "device"};
  std::vector<std::string> given(4);
  for (int k = 0; k < 4; ++k) {
    std::string variable = "CELLFORCE_" + std::string(names[k]);
    for (char& c : variable) c = char(std::toupper(c));
    if (const char* v = std::getenv(variable.c_str())) given[k] = v;
  }
  std::vector<char*> rest{argv[0]};
  for (int i = 1; i < argc; ++i) {
    bool ours = false;
    for (int k = 0; k < 4; ++k)
      if (std::string(argv[i]) == "--cellforce-" + std::string(names[k])) {
        if (i + 1 >= argc) {
          if (rank == 0) std::fprintf(stderr, "cellforce-lammps: %s needs a value\n", argv[i]);
          MPI_Finalize();
          return 2;
        }
        given[k] = argv[++i];
        ours = true;
      }
    if (!ours) rest.push_back(argv[i]);
  }
  if (given[0].empty()) given[0] = "auto";  // a GPU where this rank finds one, else the CPU
  for (int k = 0; k < 4; ++k)
    if (!given[k].empty()) options.emplace_back(names[k], given[k]);
  // The node's ranks (a collective call: every rank makes it). Without a device given, rank r of a
  // node computes on that node's GPU r mod (its GPUs); without threads given, the node's cores are
  // shared among its ranks.
  MPI_Comm node;
  MPI_Comm_split_type(MPI_COMM_WORLD, MPI_COMM_TYPE_SHARED, rank, MPI_INFO_NULL, &node);
  int local = 0, local_ranks = 1;
  MPI_Comm_rank(node, &local);
  MPI_Comm_size(node, &local_ranks);
  MPI_Comm_free(&node);
  std::string device = given[3], device_rule;
  const int gpus = cuda_devices();
  if (device.empty() && gpus > 0) {
    device = std::to_string(local % gpus);
    options.emplace_back("device", device);
    device_rule = ", device: the node's rank mod " + std::to_string(gpus);
  }
  // The rank's GPU made this process's current device (unless it runs on the CPU), so that no call
  // leaves a context of its own on device 0 (every rank of a node would hold one there, beside its
  // own GPU's).
  std::string backend = given[0];
  for (char& c : backend) c = char(std::tolower(static_cast<unsigned char>(c)));
  if (backend != "cpu" && !device.empty()) select_device(std::atoi(device.c_str()), gpus);
  if (!std::getenv("CELLFORCE_THREADS")) {
    const unsigned cores = std::thread::hardware_concurrency();
    options.emplace_back("threads", std::to_string(std::max(1u, cores / unsigned(std::max(1, local_ranks)))));
  } else {
    options.emplace_back("threads", std::getenv("CELLFORCE_THREADS"));
  }
  // The options checked on every rank before LAMMPS starts (the engine made: a backend or device
  // one rank cannot use fails there alone): when any rank fails, every rank stops, and the first
  // failing rank says why (a rank that stopped alone would leave the others waiting in LAMMPS).
  std::string failure;
  try {
    cellforce::Context check(3);
    for (const auto& [key, value] : options) check.set_option(key, value);
    (void)check.backend_name();
  } catch (const std::exception& e) {
    failure = e.what();
  }
  int ranks = 1;
  MPI_Comm_size(MPI_COMM_WORLD, &ranks);
  const int mine[2] = {failure.empty() ? 0 : 1, failure.empty() ? ranks : rank};
  int failed = 0, first = ranks;
  MPI_Allreduce(&mine[0], &failed, 1, MPI_INT, MPI_SUM, MPI_COMM_WORLD);
  MPI_Allreduce(&mine[1], &first, 1, MPI_INT, MPI_MIN, MPI_COMM_WORLD);
  if (failed > 0) {
    if (rank == first)
      std::fprintf(stderr, "cellforce-lammps: %s%s\n",
                   ranks > 1 ? ("rank " + std::to_string(rank) + " (" + std::to_string(failed) + " of " +
                                std::to_string(ranks) + " ranks failed this check): ")
                                   .c_str()
                             : "",
                   failure.c_str());
    MPI_Finalize();
    return 2;
  }
  rest.push_back(nullptr);

  auto* lmp = new LAMMPS_NS::LAMMPS(int(rest.size()) - 1, rest.data(), MPI_COMM_WORLD);
  // lj/cut is cellforce's, also under an accelerator's suffix (-sf opt, omp, ...: the script's
  // lj/cut whatever LAMMPS would have run it with); every other pair style is refused
  for (auto& [name, creator] : *lmp->force->pair_map)
    creator = ours(name) ? &cellforce::lammps::PairCellforce::create : &RefusedPair::create;
  if (rank == 0) {  // the settings, the defaults named
    auto value = [&](const char* key, const char* otherwise) {
      for (const auto& [k, v] : options)
        if (k == key) return v;
      return std::string(otherwise);
    };
    std::string line = "cellforce-lammps: pair_style lj/cut computed by cellforce " +
                       std::string(cellforce::version()) + " on " + std::to_string(ranks) +
                       (ranks == 1 ? " rank" : " ranks") + ": backend " + value("backend", "auto") + ", precision " +
                       value("precision", "double") + ", skin " + value("skin", "auto");
    if (backend != "cpu" && (gpus > 0 || !given[3].empty()))
      line += device_rule.empty() ? ", device " + value("device", "0") : device_rule;
    else
      line += ", CPU threads a rank: " + value("threads", "?");
    if (lmp->screen) std::fprintf(lmp->screen, "%s\n", line.c_str());
    if (lmp->logfile) std::fprintf(lmp->logfile, "%s\n", line.c_str());
  }
  lmp->input->file();
  delete lmp;
  MPI_Finalize();
  return 0;
}
