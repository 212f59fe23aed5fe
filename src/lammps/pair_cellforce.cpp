#include "pair_cellforce.h"

#include <algorithm>
#include <cstdio>
#include <exception>
#include <string>

namespace cellforce::lammps {


namespace {
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
  stale_ = false;
}

void PairCellforce::compute(int eflag, int vflag) {
  ev_init(eflag, vflag);
  if (stale_ || !ctx_) {
    try {
      make_context();
    } catch (const std::exception& e) {
      error->one(FLERR, std::string("cellforce: ") + e.what());
    }
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
  forces_.resize(std::size_t(nlocal) * std::size_t(dim));
  energies_.resize(eflag_atom ? std::size_t(nlocal) : 0);
  virials_.resize(vflag_atom ? std::size_t(nlocal) * dim * dim : 0);
  double energy = 0, w[9] = {};
  cellforce::LocalOutputs out;
  out.forces = forces_.data();
  out.energy = eflag_global ? &energy : nullptr;
  out.virial = vflag_global ? w : nullptr;
  out.energies = eflag_atom ? energies_.data() : nullptr;
  out.virials = vflag_atom ? virials_.data() : nullptr;
  try {
    ctx_->compute_local(std::size_t(nlocal), std::size_t(nghost), rows, types_.data(), out);
  } catch (const std::exception& e) {
    error->one(FLERR, std::string("cellforce: ") + e.what());
  }
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
}

}  // namespace cellforce::lammps
