#include "pair_cellforce.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <map>
#include <string>
#include <vector>

namespace cellforce::lammps {


namespace {
double seconds(std::chrono::steady_clock::duration d) { return std::chrono::duration<double>(d).count(); }

// cellforce's message, prefixed once
std::string said(const std::exception& e) {
  const std::string what = e.what();
  return what.rfind("cellforce", 0) == 0 ? what : "cellforce: " + what;
}

std::string number(double v) {  // as %g writes it
  char text[32];
  std::snprintf(text, sizeof text, "%g", v);
  return text;
}
}  // namespace

EngineSettings& engine_settings() {
  static EngineSettings settings;
  return settings;
}

PairCellforce::PairCellforce(LAMMPS_NS::LAMMPS* instance) : Pair(instance) {
  single_enable = 0;
  restartinfo = 0;
  no_virial_fdotr_compute = 1;  // the virial comes from cellforce
}

PairCellforce::~PairCellforce() {
  report_times();
  if (allocated) {
    memory->destroy(setflag);
    memory->destroy(cutsq);
    memory->destroy(epsilon_);
    memory->destroy(sigma_);
  }
}

void PairCellforce::allocate() {
  allocated = 1;
  const int n = atom->ntypes;
  memory->create(setflag, n + 1, n + 1, "pair:setflag");
  memory->create(cutsq, n + 1, n + 1, "pair:cutsq");
  memory->create(epsilon_, n + 1, n + 1, "pair:epsilon");
  memory->create(sigma_, n + 1, n + 1, "pair:sigma");
  for (int i = 0; i <= n; ++i)
    for (int j = 0; j <= n; ++j) setflag[i][j] = 0;
}

// pair_style lj/cut RC: one global cutoff (cellforce takes one for every pair).
void PairCellforce::settings(int narg, char** arg) {
  if (narg != 1) error->all(FLERR, std::string("pair_style lj/cut (cellforce): expected one argument, the global cutoff"));
  cut_global_ = LAMMPS_NS::utils::numeric(FLERR, arg[0], false, lmp);
  if (!(cut_global_ > 0)) error->all(FLERR, std::string("pair_style lj/cut (cellforce): the cutoff must be > 0"));
  stale_ = true;
}

// pair_coeff I J EPSILON SIGMA [RC]: a cutoff of its own is refused unless it is the global one.
void PairCellforce::coeff(int narg, char** arg) {
  if (narg < 4 || narg > 5)
    error->all(FLERR, std::string("pair_coeff (cellforce lj/cut): expected I J epsilon sigma [cutoff]"));
  if (!allocated) allocate();
  int ilo = 0, ihi = 0, jlo = 0, jhi = 0;
  LAMMPS_NS::utils::bounds(FLERR, arg[0], 1, atom->ntypes, ilo, ihi, error);
  LAMMPS_NS::utils::bounds(FLERR, arg[1], 1, atom->ntypes, jlo, jhi, error);
  const double epsilon = LAMMPS_NS::utils::numeric(FLERR, arg[2], false, lmp);
  const double sigma = LAMMPS_NS::utils::numeric(FLERR, arg[3], false, lmp);
  if (!(epsilon >= 0) || !(sigma > 0))  // as cellforce takes them (checked here on every rank)
    error->all(FLERR, "pair_coeff (cellforce lj/cut): epsilon " + std::string(arg[2]) + " and sigma " +
                          std::string(arg[3]) + ": expected epsilon >= 0 and sigma > 0");
  if (narg == 5) {
    const double cut = LAMMPS_NS::utils::numeric(FLERR, arg[4], false, lmp);
    if (cut != cut_global_)
      error->all(FLERR, "pair_coeff (cellforce lj/cut): a cutoff of " + std::string(arg[4]) +
                            " for these types differs from pair_style's " + number(cut_global_) +
                            ": cellforce computes every pair with one cutoff");
  }
  int count = 0;
  for (int i = ilo; i <= ihi; ++i)
    for (int j = std::max(jlo, i); j <= jhi; ++j) {
      epsilon_[i][j] = epsilon;
      sigma_[i][j] = sigma;
      setflag[i][j] = 1;
      ++count;
    }
  if (count == 0) error->all(FLERR, std::string("pair_coeff (cellforce lj/cut): no types in the ranges given"));
  stale_ = true;
}

// No neighbour list of LAMMPS's: cellforce searches the owned atoms and ghosts itself. LAMMPS still
// sends the ghosts within the cutoff and the skin (its communication cutoff).
void PairCellforce::init_style() {
  // What LAMMPS's lj/cut would honour and cellforce cannot: refused, not ignored.
  if (atom->molecular &&
      (force->special_lj[1] != 1.0 || force->special_lj[2] != 1.0 || force->special_lj[3] != 1.0))
    error->all(FLERR, std::string("pair_style lj/cut (cellforce): special_bonds lj factors other than 1 are not "
                                  "computed by cellforce (every pair within the cutoff counts whole)"));
  if (neighbor->exclude)
    error->all(FLERR, std::string("pair_style lj/cut (cellforce): neigh_modify exclude is not honoured by cellforce "
                                  "(it searches every pair itself)"));
  if (tail_flag)
    error->all(FLERR, std::string("pair_style lj/cut (cellforce): pair_modify tail yes (the long-range tail "
                                  "correction) is not computed by cellforce"));
  stale_ = true;
}

double PairCellforce::init_one(int i, int j) {
  if (setflag[i][j] == 0) {  // LAMMPS's mixing rule (pair_modify mix; geometric by default)
    if (setflag[i][i] == 0 || setflag[j][j] == 0)
      error->all(FLERR, "pair_coeff (cellforce lj/cut): no coefficients for types " + std::to_string(i) + " and " +
                            std::to_string(j) + " (nor for each type alone, to mix)");
    epsilon_[i][j] = mix_energy(epsilon_[i][i], epsilon_[j][j], sigma_[i][i], sigma_[j][j]);
    sigma_[i][j] = mix_distance(sigma_[i][i], sigma_[j][j]);
  }
  epsilon_[j][i] = epsilon_[i][j];
  sigma_[j][i] = sigma_[i][j];
  stale_ = true;
  return cut_global_;
}

// The dimension, cutoff, shift and every type pair's coefficients: a context made for them serves
// until one of them changes (LAMMPS's init before every run marks the pair stale whether or not).
std::vector<double> PairCellforce::physics() const {
  const int n = atom->ntypes;
  std::vector<double> key = {double(domain->dimension), cut_global_, double(offset_flag), double(n)};
  for (int i = 1; i <= n; ++i)
    for (int j = i; j <= n; ++j) key.insert(key.end(), {epsilon_[i][j], sigma_[i][j]});
  return key;
}

void PairCellforce::make_context() {
  const int dim = domain->dimension;
  ctx_ = std::make_unique<cellforce::Context>(dim);
  // Every axis open: the ghosts stand in for the periodic images and the neighbouring ranks.
  const double lengths[3] = {0, 0, 0};
  const bool periodic[3] = {false, false, false};
  ctx_->set_box(lengths, periodic);
  for (const auto& [key, value] : engine_settings().options) ctx_->set_option(key, value);
  ctx_->set_cutoff(cut_global_, offset_flag ? cellforce::CutoffMode::kShift : cellforce::CutoffMode::kTruncate);
  const int n = atom->ntypes;
  for (int t = 1; t <= n; ++t) ctx_->add_type(std::to_string(t), sigma_[t][t], epsilon_[t][t]);
  for (int i = 1; i <= n; ++i)
    for (int j = i + 1; j <= n; ++j) ctx_->set_pair(uint32_t(i - 1), uint32_t(j - 1), sigma_[i][j], epsilon_[i][j]);
  device_ = -1;
  if (ctx_->backend_name() == "cuda") {
    device_ = 0;
    for (const auto& [key, value] : engine_settings().options)
      if (key == "device") device_ = std::atoi(value.c_str());
  }
  if (comm->me == 0 && !described_) {  // once: what rank 0's engine is (the others' alike)
    const std::string line = "cellforce-lammps: rank 0 computes on " + ctx_->backend_name() + " (" +
                             ctx_->description() + "); neighbour structure: " + ctx_->neighbor();
    if (screen) std::fprintf(screen, "%s\n", line.c_str());
    if (logfile) std::fprintf(logfile, "%s\n", line.c_str());
    described_ = true;
  }
}

void PairCellforce::compute(int eflag, int vflag) {
  const auto started = Clock::now();
  ev_init(eflag, vflag);
  // A context made again only for new physics (a run's setup call then; timed apart from the rest).
  bool making = false;
  if (stale_ || !ctx_) {
    std::vector<double> now = physics();
    making = !ctx_ || now != made_for_;
    if (making) {
      try {
        make_context();
      } catch (const std::exception& e) {
        error->one(FLERR, said(e));
      }
      made_for_ = std::move(now);
    }
    stale_ = false;
  }
  const int dim = domain->dimension;
  const int nlocal = atom->nlocal, nghost = atom->nghost, n = nlocal + nghost;
  double** x = atom->x;
  double** f = atom->f;
  const int* type = atom->type;
  // LAMMPS holds x as n rows of 3 in one block: in 3D that is cellforce's layout, read in place; in
  // 2D the rows are packed to 2 columns here.
  const double* rows = n > 0 ? x[0] : nullptr;
  if (dim != 3) {
    positions_.resize(std::size_t(n) * std::size_t(dim));
    for (int i = 0; i < n; ++i)
      for (int a = 0; a < dim; ++a) positions_[std::size_t(i) * dim + a] = x[i][a];
    rows = positions_.data();
  }
  types_.resize(std::size_t(n));
  for (int i = 0; i < n; ++i) types_[std::size_t(i)] = uint32_t(type[i] - 1);  // LAMMPS's types count from 1
  // In 3D LAMMPS's f (n rows of 3 in one block) takes cellforce's forces in place, added to what is
  // there; in 2D they come in 2 columns (to zeros) and are added here.
  if (dim != 3) forces_.assign(std::size_t(nlocal) * std::size_t(dim), 0.0);
  // The outputs accumulate (out.accumulate): the per-atom ones start from zeros on every call.
  energies_.assign(eflag_atom ? std::size_t(nlocal) : 0, 0.0);
  virials_.assign(vflag_atom ? std::size_t(nlocal) * dim * dim : 0, 0.0);
  double energy = 0, w[9] = {};
  cellforce::LocalOutputs out;
  out.forces = dim == 3 ? (nlocal > 0 ? f[0] : nullptr) : forces_.data();
  out.accumulate = true;
  out.energy = eflag_global ? &energy : nullptr;
  out.virial = vflag_global ? w : nullptr;
  out.energies = eflag_atom ? energies_.data() : nullptr;
  out.virials = vflag_atom ? virials_.data() : nullptr;
  const auto called = Clock::now();
  try {
    ctx_->compute_local(std::size_t(nlocal), std::size_t(nghost), rows, types_.data(), out);
  } catch (const std::exception& e) {
    error->one(FLERR, said(e));
  }
  const auto returned = Clock::now();
  if (dim != 3)
    for (int i = 0; i < nlocal; ++i)
      for (int a = 0; a < dim; ++a) f[i][a] += forces_[std::size_t(i) * dim + a];
  if (eflag_global) eng_vdwl += energy;
  // LAMMPS's virial order: xx, yy, zz, xy, xz, yz (cellforce's: dim x dim, row-major)
  auto at = [&](const double* m, int r, int c) { return (r < dim && c < dim) ? m[r * dim + c] : 0.0; };
  if (vflag_global) {
    virial[0] += at(w, 0, 0);
    virial[1] += at(w, 1, 1);
    virial[2] += at(w, 2, 2);
    virial[3] += at(w, 0, 1);
    virial[4] += at(w, 0, 2);
    virial[5] += at(w, 1, 2);
  }
  if (eflag_atom)
    for (int i = 0; i < nlocal; ++i) eatom[i] += energies_[std::size_t(i)];
  if (vflag_atom)
    for (int i = 0; i < nlocal; ++i) {
      const double* m = &virials_[std::size_t(i) * dim * dim];
      vatom[i][0] += at(m, 0, 0);
      vatom[i][1] += at(m, 1, 1);
      vatom[i][2] += at(m, 2, 2);
      vatom[i][3] += at(m, 0, 1);
      vatom[i][4] += at(m, 0, 2);
      vatom[i][5] += at(m, 1, 2);
    }
  if (making) {
    times_.making_calls += 1;
    times_.making += seconds(Clock::now() - started);
    return;
  }
  const cellforce::Statistics engine = ctx_->statistics();
  times_.calls += 1;
  times_.cellforce += seconds(returned - called);
  times_.stages += engine.pipeline_seconds;
  times_.pair += seconds(Clock::now() - started) - seconds(returned - called);
}

// Rank 0 says where the pair's time went over the script, averaged over the ranks (and the most
// any rank took): the whole compute_local call, the engine's stages in it (device time on CUDA),
// and the pair's own packing and adding around it; the calls that made the context (the script's
// first, and a run's setup call after the physics changed) apart, whole.
void PairCellforce::report_times() {
  if (times_.calls == 0 && times_.making_calls == 0) return;
  double mine[4] = {times_.cellforce, times_.stages, times_.pair, times_.making}, sum[4] = {}, most[4] = {};
  MPI_Reduce(mine, sum, 4, MPI_DOUBLE, MPI_SUM, 0, world);
  MPI_Reduce(mine, most, 4, MPI_DOUBLE, MPI_MAX, 0, world);
  // Which device each rank computed on (the rank rule, seen): ranks by CUDA device, or "the CPU".
  std::vector<int> devices(comm->me == 0 ? std::size_t(comm->nprocs) : 1);
  MPI_Gather(&device_, 1, MPI_INT, devices.data(), 1, MPI_INT, 0, world);
  if (comm->me != 0) return;
  std::map<int, int> ranks_on;
  for (const int d : devices) ++ranks_on[d];
  std::string where;
  for (const auto& [d, count] : ranks_on)
    where += (where.empty() ? "" : ", ") + std::to_string(count) + (d < 0 ? " on the CPU" : " on GPU " + std::to_string(d));
  char line[512] = "";
  int at = 0;
  if (times_.calls > 0) {
    const double per = 1e3 / (double(times_.calls) * comm->nprocs), top = 1e3 / double(times_.calls);
    at = std::snprintf(line, sizeof line,
                       "cellforce-lammps: %lld force calls; ms a call, averaged over ranks (the slowest rank): "
                       "compute_local %.3f (%.3f), of it the engine's stages %.3f (%.3f); the pair's packing and "
                       "adding %.3f (%.3f)",
                       times_.calls, sum[0] * per, most[0] * top, sum[1] * per,
                       most[1] * top, sum[2] * per, most[2] * top);
  } else {
    at = std::snprintf(line, sizeof line, "cellforce-lammps: ");
  }
  const long long making = times_.making_calls;
  if (making > 0 && at >= 0 && std::size_t(at) < sizeof line) {
    const double each = 1e3 * sum[3] / (double(making) * comm->nprocs), slowest = 1e3 * most[3] / double(making);
    std::snprintf(line + at, sizeof line - std::size_t(at), "%s%lld call%s that made the engine: %.3f ms each (%.3f)",
                  times_.calls > 0 ? "; " : "", making, making == 1 ? "" : "s", each, slowest);
  }
  for (FILE* f : {screen, logfile})
    if (f) std::fprintf(f, "%s\ncellforce-lammps: ranks: %s\n", line, where.c_str());
}

}  // namespace cellforce::lammps
