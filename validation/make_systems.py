"""Generate the validation configurations (extended XYZ) in systems/validation/.

The files are committed; this script documents how they were made. It writes only missing
files unless --force is given; every file is written under a temporary name and renamed when
complete (lj.write_extxyz), so an interrupted run leaves no truncated file to be kept later. Equilibration runs OpenMM's CPU platform (truncated LJ, rc 2.5,
velocity Verlet with velocity rescaling every 50 steps, deterministic forces, numpy seeds), so
a rerun with the same OpenMM build and thread count reproduces the files.

    python validation/make_systems.py [--force] [NAME ...]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import lj  # noqa: E402

OUT = lj.REPO_ROOT / "systems" / "validation"
LIQUID_DENSITY = 0.8442
LIQUID_KT = 1.44
CUTOFF = 2.5
DT = 0.004  # ps, i.e. 0.004 tau in these units
RESCALE_EVERY = 50
MAX_BYTES = 2_500_000
MIN_DISTANCE = 0.8  # in units of the pair's sigma
SPECIES_PARAMS = {"A": (1.0, 1.0), "B": (0.88, 0.5)}  # sigma, epsilon (Lorentz-Berthelot)


def fcc(cells: int, a: float) -> np.ndarray:
    """fcc lattice of cells^3 cubic cells of edge a (4 sites per cell)."""
    basis = np.array([[0, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5], [0, 0.5, 0.5]])
    grid = np.stack(np.meshgrid(*[np.arange(cells)] * 3, indexing="ij"), -1).reshape(-1, 1, 3)
    return ((grid + basis) * a).reshape(-1, 3) + a / 4


def wrap(positions, lengths, pbc) -> np.ndarray:
    """Positions folded into [0, L) on periodic axes."""
    x = np.array(positions, dtype=float)
    for k in range(3):
        if pbc[k]:
            x[:, k] -= lengths[k] * np.floor(x[:, k] / lengths[k])
            x[x[:, k] >= lengths[k], k] = 0.0
    return x


def min_distance_ratio(positions, species, lengths, pbc, dim=3) -> float:
    """Smallest r_ij / sigma_ij over all pairs (minimum image, Lorentz-Berthelot sigma)."""
    x = np.asarray(positions, dtype=float)[:, :dim]
    sig = np.array([SPECIES_PARAMS[s][0] for s in species])
    best = np.inf
    for start in range(0, len(x) - 1, 256):
        d = x[start:start + 256, None, :] - x[None, :, :]
        for k in range(dim):
            if pbc[k]:
                d[..., k] -= lengths[k] * np.round(d[..., k] / lengths[k])
        r = np.sqrt(np.einsum("ijk,ijk->ij", d, d))
        r /= 0.5 * (sig[start:start + 256, None] + sig[None, :])
        rows = np.arange(r.shape[0])
        r[rows, start + rows] = np.inf
        best = min(best, r.min())
    return float(best)


def equilibrate(positions, species, lengths, kts_and_steps, seed, dim=3):
    """Run MD at each (kT, steps) in turn; return final unwrapped positions and the mean squared
    displacement from the start (sigma^2), which shows whether the start has melted."""
    import openmm as mm
    from openmm import unit

    n = len(positions)
    box = list(lengths)
    if dim == 2:
        box[2] = max(box[2], 2 * CUTOFF + 1)
    system = mm.System()
    force = mm.NonbondedForce()
    force.setNonbondedMethod(mm.NonbondedForce.CutoffPeriodic)
    force.setCutoffDistance(CUTOFF)
    force.setUseDispersionCorrection(False)
    for s in species:
        system.addParticle(1.0)
        force.addParticle(0.0, *SPECIES_PARAMS[s])
    system.addForce(force)
    system.setDefaultPeriodicBoxVectors(mm.Vec3(box[0], 0, 0), mm.Vec3(0, box[1], 0),
                                        mm.Vec3(0, 0, box[2]))
    integrator = mm.VerletIntegrator(DT)
    platform = mm.Platform.getPlatformByName("CPU")
    context = mm.Context(system, integrator, platform, {"DeterministicForces": "true"})
    context.setPositions(positions)
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v[:, dim:] = 0.0
    v -= v.mean(axis=0)
    dof = dim * (n - 1)
    for kt, steps in kts_and_steps:
        for _ in range(steps // RESCALE_EVERY):
            v *= np.sqrt(dof * kt / np.sum(v * v))
            context.setVelocities(v)
            integrator.step(RESCALE_EVERY)
            state = context.getState(getVelocities=True)
            v = state.getVelocities(asNumpy=True).value_in_unit(unit.nanometer / unit.picosecond)
    x = context.getState(getPositions=True).getPositions(asNumpy=True).value_in_unit(unit.nanometer)
    msd = float(np.mean(np.sum((x - positions) ** 2, axis=1)))
    return np.array(x), msd


def check_and_write(name, positions, species, lengths, pbc, dim=3, check=True):
    """Assert no overlaps (r > 0.8 sigma_ij), write the file (10 digits if 17 is too large)."""
    if check:
        ratio = min_distance_ratio(positions, species, lengths, pbc, dim)
        assert ratio > MIN_DISTANCE, f"{name}: minimum r/sigma = {ratio:.3f}"
    else:
        ratio = float("nan")
    path = OUT / name
    lj.write_extxyz(path, positions, species, lengths, pbc)
    if os.path.getsize(path) > MAX_BYTES:
        lj.write_extxyz(path, positions, species, lengths, pbc, digits=10)
    print(f"{name}: N = {len(positions)}, box {' x '.join(f'{v:.4f}' for v in lengths)}, "
          f"pbc {pbc}, min r/sigma {ratio:.3f}, {os.path.getsize(path) / 1e6:.2f} MB")


def melted(name, msd):
    assert msd > 1.0, f"{name}: mean squared displacement {msd:.2f} sigma^2, still a solid?"
    print(f"{name}: mean squared displacement from the lattice {msd:.1f} sigma^2")


def lattice_liquid(name, cells, seed):
    """fcc at density 0.8442, equilibrated at kT = 1.44."""
    edge = (4 * cells**3 / LIQUID_DENSITY) ** (1 / 3)
    start = fcc(cells, edge / cells)
    species = ["A"] * len(start)
    x, msd = equilibrate(start, species, [edge] * 3, [(LIQUID_KT, 6000)], seed)
    melted(name, msd)
    pbc = (True, True, True)
    check_and_write(name, wrap(x, [edge] * 3, pbc), species, [edge] * 3, pbc)


def make_lj_liquid():
    lattice_liquid("lj_liquid.xyz", 10, seed=11)


def make_lj_small_half_box():
    lattice_liquid("lj_small_half_box.xyz", 4, seed=12)


def make_lj_gas():
    """1000 particles at density 0.02: random with r > 1, then a short run at kT = 1.5."""
    n, edge = 1000, (1000 / 0.02) ** (1 / 3)
    rng = np.random.default_rng(13)
    placed = np.empty((0, 3))
    while len(placed) < n:
        trial = rng.uniform(0, edge, 3)
        d = placed - trial
        d -= edge * np.round(d / edge)
        if not len(d) or np.min(np.einsum("ij,ij->i", d, d)) > 1.0:
            placed = np.vstack([placed, trial])
    species = ["A"] * n
    x, _ = equilibrate(placed, species, [edge] * 3, [(1.5, 2000)], seed=14)
    pbc = (True, True, True)
    check_and_write("lj_gas.xyz", wrap(x, [edge] * 3, pbc), species, [edge] * 3, pbc)


def make_binary_lb():
    """80:20 A/B at density 1.0: fcc 8^3 (2048 sites) less 48, melted at kT = 3, then 1.5."""
    rng = np.random.default_rng(15)
    edge = 2000 ** (1 / 3)
    sites = fcc(8, edge / 8)
    start = sites[np.sort(rng.permutation(len(sites))[:2000])]
    species = np.array(["A"] * 2000)
    species[rng.permutation(2000)[:400]] = "B"
    species = species.tolist()
    x, msd = equilibrate(start, species, [edge] * 3, [(3.0, 2000), (1.5, 6000)], seed=16)
    melted("binary_lb.xyz", msd)
    pbc = (True, True, True)
    check_and_write("binary_lb.xyz", wrap(x, [edge] * 3, pbc), species, [edge] * 3, pbc)


def make_lj_2d():
    """32 x 32 square lattice at area density 0.7, equilibrated in 2D at kT = 1.0 (z = 0)."""
    n_side, edge = 32, np.sqrt(1024 / 0.7)
    grid = np.stack(np.meshgrid(np.arange(n_side), np.arange(n_side), indexing="ij"), -1)
    start = np.zeros((1024, 3))
    start[:, :2] = (grid.reshape(-1, 2) + 0.5) * (edge / n_side)
    species = ["A"] * 1024
    x, msd = equilibrate(start, species, [edge, edge, 1.0], [(1.0, 6000)], seed=17, dim=2)
    melted("lj_2d.xyz", msd)
    assert np.all(x[:, 2] == 0.0), "2D run left the plane"
    pbc = (True, True, False)
    check_and_write("lj_2d.xyz", wrap(x, [edge, edge, 1.0], pbc), species, [edge, edge, 1.0],
                    pbc, dim=2)


def _liquid():
    """The committed liquid, and each particle's displacement from the box centre."""
    x, species, lengths, pbc = lj.read_extxyz(OUT / "lj_liquid.xyz")
    d = x - 0.5 * lengths
    d -= lengths * np.round(d / lengths)
    return x, species, lengths, d


def make_lj_cluster_open():
    """The 500 liquid particles nearest the box centre, open boundaries, 1-sigma margin."""
    _, species, _, d = _liquid()
    keep = np.sort(np.argsort(np.einsum("ij,ij->i", d, d), kind="stable")[:500])
    x = d[keep] - d[keep].min(axis=0) + 1.0
    lengths = d[keep].max(axis=0) - d[keep].min(axis=0) + 2.0
    check_and_write("lj_cluster_open.xyz", x, [species[i] for i in keep], lengths,
                    (False, False, False))


def make_lj_droplet():
    """The 2000 liquid particles nearest the box centre, centred in a periodic cube of ~1000x
    the droplet's volume."""
    _, species, _, d = _liquid()
    r2 = np.einsum("ij,ij->i", d, d)
    keep = np.sort(np.argsort(r2, kind="stable")[:2000])
    radius = np.sqrt(r2[keep].max())
    edge = (1000 * 4 / 3 * np.pi * radius**3) ** (1 / 3)
    x = d[keep] - d[keep].mean(axis=0) + 0.5 * edge
    check_and_write("lj_droplet.xyz", x, [species[i] for i in keep], [edge] * 3,
                    (True, True, True))


def make_lj_liquid_32k():
    """lj_liquid replicated 2 x 2 x 2 (32,000 particles, density 0.8442); no further MD."""
    x, species, lengths, pbc = lj.read_extxyz(OUT / "lj_liquid.xyz")
    shifts = np.stack(np.meshgrid(*[np.arange(2)] * 3, indexing="ij"), -1).reshape(-1, 1, 3)
    big = (x[None, :, :] + shifts * lengths).reshape(-1, 3)
    check_and_write("lj_liquid_32k.xyz", big, species * 8, 2 * lengths, pbc, check=False)


# Derived files follow lj_liquid.xyz, which they read.
MAKERS = {
    "lj_liquid.xyz": make_lj_liquid,
    "lj_gas.xyz": make_lj_gas,
    "binary_lb.xyz": make_binary_lb,
    "lj_small_half_box.xyz": make_lj_small_half_box,
    "lj_2d.xyz": make_lj_2d,
    "lj_cluster_open.xyz": make_lj_cluster_open,
    "lj_droplet.xyz": make_lj_droplet,
    "lj_liquid_32k.xyz": make_lj_liquid_32k,
}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help=f"files to make (default: all missing); of {', '.join(MAKERS)}")
    parser.add_argument("--force", action="store_true", help="overwrite existing files")
    args = parser.parse_args()
    unknown = set(args.names) - MAKERS.keys()
    if unknown:
        parser.error(f"unknown files {sorted(unknown)}")
    OUT.mkdir(parents=True, exist_ok=True)
    for name, make in MAKERS.items():
        if args.names and name not in args.names:
            continue
        if (OUT / name).exists() and not args.force:
            print(f"{name}: exists, kept (--force to remake)")
            continue
        make()


if __name__ == "__main__":
    main()
