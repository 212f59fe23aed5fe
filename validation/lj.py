"""Shared pieces of cellforce's validation: cases, extended XYZ files, a numpy brute-force
oracle, the same system in OpenMM, the cellforce command line, and the error metrics.

Units: sigma = 1 nm, epsilon = 1 kJ/mol, mass = 1 amu, so forces are in kJ/mol/nm and the time
unit is 1 ps.
"""

from __future__ import annotations

import os
import shlex
import statistics
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
MODES = ("truncate", "shift", "force-shift")
MIXINGS = ("lorentz-berthelot", "geometric")
# Pair elements per brute-force chunk (rows x all particles); each element costs ~50 bytes.
_CHUNK_ELEMENTS = 2_000_000
# Lower-case pieces of cellforce's error message when a backend cannot run on this machine:
# such rows are skipped (or, where asked, failed), not counted as wrong results.
UNAVAILABLE = ("no cuda device", "built without cuda")


@dataclass
class Case:
    """One validation case: a configuration file and the force field evaluated on it."""

    name: str
    xyz: str  # path relative to the repository root
    dim: int
    cutoff: float
    mode: str
    types: list[tuple[str, float, float]]  # (name, sigma, epsilon)
    mixing: str = "lorentz-berthelot"
    pairs: list[tuple[str, str, float, float]] = field(default_factory=list)
    quick: bool = False
    description: str = ""

    def __post_init__(self):
        if self.dim not in (2, 3):
            raise ValueError(f"{self.name}: dim must be 2 or 3, not {self.dim}")
        if self.mode not in MODES:
            raise ValueError(f"{self.name}: mode must be one of {MODES}, not {self.mode!r}")
        if self.mixing not in MIXINGS:
            raise ValueError(f"{self.name}: mixing must be one of {MIXINGS}, not {self.mixing!r}")

    @property
    def path(self) -> Path:
        return REPO_ROOT / self.xyz


# ---------------------------------------------------------------------------------------------
# Extended XYZ


def _header_fields(line: str) -> dict[str, str]:
    """key=value pairs of an extended XYZ comment line (values may be double-quoted)."""
    fields = {}
    for token in shlex.split(line):
        key, sep, value = token.partition("=")
        if not sep:
            raise ValueError(f"extended XYZ header: {token!r} is not key=value")
        fields[key] = value
    return fields


def _columns(properties: str) -> dict[str, tuple[int, int]]:
    """Column range (start, count) of each name in a Properties=name:type:count:... string."""
    parts = properties.split(":")
    if len(parts) % 3:
        raise ValueError(f"extended XYZ Properties {properties!r}: not name:type:count triples")
    columns, start = {}, 0
    for name, _, count in zip(parts[0::3], parts[1::3], parts[2::3]):
        columns[name] = (start, int(count))
        start += int(count)
    return columns


def read_extxyz(path):
    """Read an extended XYZ file of exactly one frame with an orthorhombic Lattice.

    A file of several frames is refused (ValueError): cellforce is always run on frame 0 (see
    cellforce_command), and one frame per file keeps the oracle and cellforce on the same
    configuration beyond doubt. Blank lines after the frame are allowed.

    Returns positions (N x 3 float64), species (list of str), lengths (3,) and pbc (3 bools).
    """
    with open(path) as f:
        n = int(f.readline())
        header = _header_fields(f.readline())
        lines = [f.readline() for _ in range(n)]
        if any(line.strip() for line in f):
            raise ValueError(f"{path}: more than one frame (or text after the first frame's "
                             f"{n} particle lines); the validation reads one-frame files only")
    if "Lattice" not in header:
        raise ValueError(f"{path}: no Lattice in the header")
    lattice = np.array(header["Lattice"].split(), dtype=float).reshape(3, 3)
    if np.any(lattice[~np.eye(3, dtype=bool)] != 0):
        raise ValueError(f"{path}: Lattice is not orthorhombic (off-diagonal entries are not 0)")
    lengths = lattice.diagonal().copy()
    pbc_words = header.get("pbc", "T T T").split()
    if len(pbc_words) != 3 or any(w not in ("T", "F") for w in pbc_words):
        raise ValueError(f"{path}: pbc must be three of T/F, not {header['pbc']!r}")
    pbc = tuple(w == "T" for w in pbc_words)
    columns = _columns(header.get("Properties", "species:S:1:pos:R:3"))
    if columns.get("species", (0, 0))[1] != 1 or columns.get("pos", (0, 0))[1] != 3:
        raise ValueError(f"{path}: Properties must hold species:S:1 and pos:R:3")
    s0, p0 = columns["species"][0], columns["pos"][0]
    rows = [line.split() for line in lines]
    if any(len(row) < p0 + 3 for row in rows):
        raise ValueError(f"{path}: fewer than {n} complete particle lines")
    species = [row[s0] for row in rows]
    positions = np.array([row[p0:p0 + 3] for row in rows], dtype=float).reshape(n, 3)
    return positions, species, lengths, pbc


def write_extxyz(path, positions, species, lengths, pbc, digits=17):
    """Write one extended XYZ frame; 17 significant digits read back to the same doubles.

    The frame goes to a temporary file in the same folder, renamed over path when complete, so
    an interrupted run leaves either the old file or none, never a truncated one.
    """
    path = Path(path)
    positions = np.asarray(positions, dtype=float)
    lx, ly, lz = (f"{v:.17g}" for v in lengths)
    header = (f'Lattice="{lx} 0 0 0 {ly} 0 0 0 {lz}" Properties=species:S:1:pos:R:3 '
              f'pbc="{" ".join("T" if p else "F" for p in pbc)}"')
    fmt = f"%.{digits}g"
    partial = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        with open(partial, "w") as f:
            f.write(f"{len(positions)}\n{header}\n")
            for name, (x, y, z) in zip(species, positions):
                f.write(f"{name} {fmt % x} {fmt % y} {fmt % z}\n")
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def write_h5md(path, positions, type_index, lengths, pbc, dim):
    """Write one frame as H5MD 1.1 (h5py): /particles/all/position/value (1 x N x dim) with step
    and time, box (dimension, boundary as fixed-length strings, edges) and integer species."""
    positions = np.asarray(positions, dtype=float)[:, :dim]
    with h5py.File(path, "w") as f:
        h5md = f.create_group("h5md")
        h5md.attrs["version"] = np.array([1, 1], dtype=np.int32)
        h5md.create_group("author").attrs["name"] = "cellforce validation"
        creator = h5md.create_group("creator")
        creator.attrs["name"], creator.attrs["version"] = "validation/lj.py", "1"
        group = f.create_group("particles/all")
        box = group.create_group("box")
        box.attrs["dimension"] = np.int32(dim)
        box.attrs["boundary"] = np.array([b"periodic" if p else b"none" for p in pbc[:dim]],
                                         dtype="S8")
        box.create_dataset("edges", data=np.asarray(lengths, dtype=float)[:dim])
        position = group.create_group("position")
        position.create_dataset("value", data=positions[None, :, :])
        position.create_dataset("step", data=np.array([0], dtype=np.int64))
        position.create_dataset("time", data=np.array([0.0]))
        group.create_dataset("species", data=np.asarray(type_index, dtype=np.int32))


# ---------------------------------------------------------------------------------------------
# Force field


def pair_table(case: Case):
    """sigma_ij and epsilon_ij matrices over case.types, after mixing and explicit overrides."""
    sig = np.array([t[1] for t in case.types], dtype=float)
    eps = np.array([t[2] for t in case.types], dtype=float)
    if case.mixing == "lorentz-berthelot":
        sigma = 0.5 * (sig[:, None] + sig[None, :])
    else:
        sigma = np.sqrt(sig[:, None] * sig[None, :])
    epsilon = np.sqrt(eps[:, None] * eps[None, :])
    index = {t[0]: k for k, t in enumerate(case.types)}
    for a, b, s, e in case.pairs:
        i, j = index[a], index[b]
        sigma[i, j] = sigma[j, i] = s
        epsilon[i, j] = epsilon[j, i] = e
    return sigma, epsilon


def type_indices(case: Case, species) -> np.ndarray:
    """Index into case.types of every particle's species."""
    index = {t[0]: k for k, t in enumerate(case.types)}
    unknown = sorted(set(species) - index.keys())
    if unknown:
        raise ValueError(f"{case.name}: species {unknown} have no --type entry")
    return np.array([index[s] for s in species], dtype=np.int64)


def _lj_pair(r2, s, e, cutoff, mode):
    """Pair energy u and F(r)/r (so that the force on i is (F/r) * (x_i - x_j))."""
    sr6 = (s * s / r2) ** 3
    u = 4.0 * e * (sr6 * sr6 - sr6)
    f_over_r = 24.0 * e * (2.0 * sr6 * sr6 - sr6) / r2
    if mode == "truncate":
        return u, f_over_r
    sc6 = (s / cutoff) ** 6
    u = u - 4.0 * e * (sc6 * sc6 - sc6)
    if mode == "shift":
        return u, f_over_r
    fc = 24.0 * e * (2.0 * sc6 * sc6 - sc6) / cutoff
    r = np.sqrt(r2)
    return u + (r - cutoff) * fc, f_over_r - fc / r


def brute_force(positions, type_index, lengths, pbc, dim, sigma, eps, cutoff, mode):
    """O(N^2) double-precision LJ over all pairs with r^2 < rc^2 (minimum image on periodic axes).

    Returns forces (N x dim), per-particle energies (half of each pair's energy to each
    particle), the total energy and the virial sum_pairs r_ij (x) f_ij (dim x dim).
    """
    x = np.asarray(positions, dtype=float)[:, :dim]
    types = np.asarray(type_index)
    n = len(x)
    edges = np.asarray(lengths, dtype=float)
    periodic = [k for k in range(dim) if pbc[k]]
    rc2 = cutoff * cutoff
    forces = np.zeros((n, dim))
    energies = np.zeros(n)
    virial = np.zeros((dim, dim))
    chunk = max(1, _CHUNK_ELEMENTS // n)
    for start in range(0, n, chunk):
        stop = min(n, start + chunk)
        d = x[start:stop, None, :] - x[None, :, :]
        for k in periodic:
            d[..., k] -= edges[k] * np.round(d[..., k] / edges[k])
        r2 = np.einsum("ijk,ijk->ij", d, d)
        r2[np.arange(stop - start), np.arange(start, stop)] = np.inf  # no self pair
        i, j = np.nonzero(r2 < rc2)
        dij = d[i, j]
        ti, tj = types[start + i], types[j]
        u, f_over_r = _lj_pair(r2[i, j], sigma[ti, tj], eps[ti, tj], cutoff, mode)
        fij = f_over_r[:, None] * dij
        for k in range(dim):
            forces[start:stop, k] += np.bincount(i, weights=fij[:, k], minlength=stop - start)
        energies[start:stop] += 0.5 * np.bincount(i, weights=u, minlength=stop - start)
        virial += 0.5 * dij.T @ fij  # every pair is met from both ends
    return forces, energies, energies.sum(), virial


# ---------------------------------------------------------------------------------------------
# OpenMM

# Energy expressions of CustomNonbondedForce: U(r) = 4 eps [(s/r)^12 - (s/r)^6], F = -dU/dr,
# shift: U - U(rc); force-shift: U - U(rc) + (r - rc) F(rc).
_TABLES = "sr6 = (sig/r)^6; sig = sigma_t(type1, type2); eps = epsilon_t(type1, type2)"
_CUSTOM_ENERGY = {
    "truncate": f"4*eps*(sr6*sr6 - sr6); {_TABLES}",
    "shift": f"4*eps*((sr6*sr6 - sr6) - (sc6*sc6 - sc6)); sc6 = (sig/rc)^6; {_TABLES}",
    "force-shift": ("4*eps*((sr6*sr6 - sr6) - (sc6*sc6 - sc6))"
                    " + (r - rc)*24*eps*(2*sc6*sc6 - sc6)/rc;"
                    f" sc6 = (sig/rc)^6; {_TABLES}"),
}


def _all_periodic(dim, pbc) -> bool:
    """True if the first dim axes are periodic, False if all open; mixed is refused."""
    flags = [bool(p) for p in pbc[:dim]]
    if all(flags) != any(flags):
        raise ValueError(f"OpenMM cannot represent mixed periodicity {flags}: "
                         "every axis in use must be periodic, or none")
    return flags[0]


def openmm_system(case: Case, positions, species, lengths, pbc):
    """The case as an openmm.System (mass 1, no long-range or dispersion correction).

    Truncated Lorentz-Berthelot LJ without explicit pairs uses NonbondedForce; every other case
    uses CustomNonbondedForce with per-pair sigma/epsilon tables. In 2D the box's z edge is
    at least 2 rc + 1 so that no z image is within the cutoff.
    """
    import openmm as mm

    positions = np.asarray(positions, dtype=float)
    if case.dim == 2 and np.any(positions[:, 2] != 0):
        raise ValueError(f"{case.name}: a 2D configuration needs z = 0 for every particle")
    periodic = _all_periodic(case.dim, pbc)
    box = [float(v) for v in lengths]
    if case.dim == 2:
        box[2] = max(box[2], 2 * case.cutoff + 1)
    system = mm.System()
    for _ in species:
        system.addParticle(1.0)
    if periodic:
        system.setDefaultPeriodicBoxVectors(mm.Vec3(box[0], 0, 0), mm.Vec3(0, box[1], 0),
                                            mm.Vec3(0, 0, box[2]))
    types = type_indices(case, species)
    if case.mode == "truncate" and case.mixing == "lorentz-berthelot" and not case.pairs:
        force = mm.NonbondedForce()
        force.setNonbondedMethod(mm.NonbondedForce.CutoffPeriodic if periodic
                                 else mm.NonbondedForce.CutoffNonPeriodic)
        force.setUseDispersionCorrection(False)
        for t in types:
            _, sigma, epsilon = case.types[t]
            force.addParticle(0.0, sigma, epsilon)
    else:
        sigma, epsilon = pair_table(case)
        k = len(case.types)
        force = mm.CustomNonbondedForce(_CUSTOM_ENERGY[case.mode])
        force.addGlobalParameter("rc", case.cutoff)
        force.addPerParticleParameter("type")
        # Discrete2DFunction reads values[i + k*j] as f(i, j): column-major order.
        for name, table in (("sigma_t", sigma), ("epsilon_t", epsilon)):
            force.addTabulatedFunction(name, mm.Discrete2DFunction(k, k, table.ravel("F").tolist()))
        force.setNonbondedMethod(mm.CustomNonbondedForce.CutoffPeriodic if periodic
                                 else mm.CustomNonbondedForce.CutoffNonPeriodic)
        force.setUseLongRangeCorrection(False)
        for t in types:
            force.addParticle([float(t)])
    force.setCutoffDistance(case.cutoff)
    force.setUseSwitchingFunction(False)
    system.addForce(force)
    return system


def _context(system, platform, precision):
    """An openmm.Context of system on the named platform ('Precision' set where given)."""
    import openmm as mm

    chosen = mm.Platform.getPlatformByName(platform)
    properties = {}
    if precision is not None:
        if "Precision" not in chosen.getPropertyNames():
            raise ValueError(f"OpenMM platform {platform} has no Precision property")
        properties["Precision"] = precision
    return mm.Context(system, mm.VerletIntegrator(0.001), chosen, properties)


def openmm_forces(system, positions, platform="Reference", precision=None, repeats=1,
                  rebuild=False, shift=0.0):
    """Forces (N x 3, kJ/mol/nm), potential energy (kJ/mol) and median seconds per evaluation.

    One evaluation = setPositions + getState(forces, energy) + conversion to numpy; one untimed
    warm-up comes first, and its forces and energy are returned. precision sets the platform's
    'Precision' property where it has one.

    OpenMM keeps its neighbour list while no particle has moved beyond its padding, so timing the
    same positions again leaves most of the list build out. With rebuild, the timed evaluations
    alternate between the positions and the positions translated by `shift` along x and y
    (a translation leaves the forces unchanged; shift must exceed the padding, e.g. the cutoff),
    so that every evaluation rebuilds the list, as every cellforce evaluation runs its search.
    """
    from openmm import unit

    context = _context(system, platform, precision)
    positions = np.asarray(positions, dtype=float)
    moved = positions.copy()
    if rebuild:
        if not shift > 0:
            raise ValueError("openmm_forces: rebuild needs a shift > 0")
        moved[:, :2] += shift

    def evaluate(x):
        context.setPositions(x)
        state = context.getState(getForces=True, getEnergy=True)
        f = state.getForces(asNumpy=True).value_in_unit(unit.kilojoule_per_mole / unit.nanometer)
        return np.asarray(f, dtype=float), state.getPotentialEnergy().value_in_unit(
            unit.kilojoule_per_mole)

    forces, energy = evaluate(positions)
    times = []
    for k in range(repeats):
        t0 = time.perf_counter()
        evaluate(moved if rebuild and k % 2 == 0 else positions)
        times.append(time.perf_counter() - t0)
    return forces, energy, statistics.median(times)


def openmm_round_trip(system, positions, platform, precision=None, repeats=1) -> float:
    """Median seconds of OpenMM's round trip alone, no forces: setPositions +
    getState(getPositions=True) + conversion to numpy, after one untimed warm-up, as in
    openmm_forces. It is the part of an OpenMM evaluation's time that is not force work."""
    from openmm import unit

    context = _context(system, platform, precision)
    positions = np.asarray(positions, dtype=float)

    def round_trip():
        context.setPositions(positions)
        state = context.getState(getPositions=True)
        return np.asarray(state.getPositions(asNumpy=True).value_in_unit(unit.nanometer),
                          dtype=float)

    round_trip()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        round_trip()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def openmm_device(system, platform) -> str:
    """What an OpenMM platform runs on: its DeviceName (GPU platforms) or thread count (CPU)."""
    import openmm as mm

    chosen = mm.Platform.getPlatformByName(platform)
    names = chosen.getPropertyNames()
    context = mm.Context(system, mm.VerletIntegrator(0.001), chosen)
    if "DeviceName" in names:
        return chosen.getPropertyValue(context, "DeviceName")
    if "Threads" in names:
        return f"{chosen.getPropertyValue(context, 'Threads')} threads"
    return ""


# ---------------------------------------------------------------------------------------------
# cellforce


def source_revision() -> str:
    """$CELLFORCE_REVISION when set (a copy of the tree whose .git is stale, as on the GPU
    machine), else `git describe --always --dirty` of the repository, or 'unknown'."""
    if os.environ.get("CELLFORCE_REVISION"):
        return os.environ["CELLFORCE_REVISION"]
    try:
        proc = subprocess.run(["git", "-C", str(REPO_ROOT), "describe", "--always", "--dirty"],
                              capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"
    return proc.stdout.strip() if proc.returncode == 0 else "unknown"


class CellforceError(RuntimeError):
    """The cellforce command line exited non-zero; the message is its stderr."""


def cellforce_command(exe, case: Case, backend, precision, out_h5, extra_args=(), repeats=1):
    """Argument list of `cellforce forces` for a case. --frame 0: read_extxyz reads the first
    frame, and cellforce's default is the last one."""
    args = [str(exe), "forces", str(case.path), "--frame", "0", "--out", str(out_h5), "--overwrite",
            "--cutoff", repr(float(case.cutoff)), "--cutoff-mode", case.mode,
            "--mixing", case.mixing, "--backend", backend, "--precision", precision,
            "--dim", str(case.dim), "--repeats", str(repeats)]
    for name, sigma, epsilon in case.types:
        args += ["--type", f"{name}:{float(sigma)!r}:{float(epsilon)!r}"]
    for a, b, sigma, epsilon in case.pairs:
        args += ["--pair", f"{a}:{b}:{float(sigma)!r}:{float(epsilon)!r}"]
    return args + [str(a) for a in extra_args]


def _plain(value):
    """An HDF5 attribute as a plain Python value."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def read_cellforce_h5(path) -> dict:
    """forces, energies, energy, virial and the root attributes of a cellforce output file."""
    with h5py.File(path, "r") as f:
        return {"forces": f["forces"][()], "energies": f["energies"][()],
                "energy": float(f["energy"][()]), "virial": f["virial"][()],
                "attrs": {k: _plain(v) for k, v in f.attrs.items()}}


def run_cellforce(exe, case: Case, backend, precision, out_h5, extra_args=(), repeats=1) -> dict:
    """Run `cellforce forces` on a case and return its results (see read_cellforce_h5)."""
    args = cellforce_command(exe, case, backend, precision, out_h5, extra_args, repeats)
    proc = subprocess.run(args, capture_output=True, text=True)
    if proc.returncode != 0:
        message = (proc.stderr.strip() or proc.stdout.strip() or "(no message)").splitlines()
        raise CellforceError(f"exit {proc.returncode}: {' | '.join(message)}")
    return read_cellforce_h5(out_h5)


# ---------------------------------------------------------------------------------------------
# Metrics (ref is the reference; every force array is N x dim)


def _norms(forces):
    return np.linalg.norm(np.asarray(forces, dtype=float), axis=1)


def relative_force_errors(forces, ref) -> np.ndarray:
    """|dF_i| / |F_ref_i| per particle."""
    d = _norms(np.asarray(forces) - np.asarray(ref))
    return d / np.maximum(_norms(ref), np.finfo(float).tiny)


def openmm_force_errors(forces, ref) -> np.ndarray:
    """OpenMM's test metric 2 |dF_i| / (|F1_i| + |F2_i|) per particle."""
    d = _norms(np.asarray(forces) - np.asarray(ref))
    return 2 * d / np.maximum(_norms(forces) + _norms(ref), np.finfo(float).tiny)


def max_error_over_rms(forces, ref) -> float:
    """max_i |dF_i| / F_rms, F_rms = sqrt(mean |F_ref_i|^2)."""
    d = _norms(np.asarray(forces) - np.asarray(ref))
    return float(d.max() / np.sqrt(np.mean(_norms(ref) ** 2)))


def energy_relative_error(energy, ref) -> float:
    """|E - E_ref| / |E_ref|."""
    return abs(energy - ref) / abs(ref)


def energies_error(energies, ref) -> float:
    """max_i |e_i - e_ref_i| / mean_i |e_ref_i| (per-particle energies)."""
    ref = np.asarray(ref, dtype=float)
    return float(np.abs(np.asarray(energies) - ref).max() / np.abs(ref).mean())


def virial_error(virial, ref) -> float:
    """max |W - W_ref| / max |W_ref| over the tensor's components."""
    ref = np.asarray(ref, dtype=float)
    return float(np.abs(np.asarray(virial) - ref).max() / np.abs(ref).max())


def force_metrics(forces, ref) -> dict:
    """Every force metric of forces against ref, as floats."""
    rel = relative_force_errors(forces, ref)
    omm = openmm_force_errors(forces, ref)
    return {"median_rel": float(np.median(rel)), "max_rel": float(rel.max()),
            "median_openmm": float(np.median(omm)), "max_openmm": float(omm.max()),
            "max_dF_over_Frms": max_error_over_rms(forces, ref)}


# ---------------------------------------------------------------------------------------------
# Formatting of report numbers


def fmt_err(value) -> str:
    """An error or tolerance for a table: '-' for none, '0' for exactly 0, else 1.2e-05."""
    if value is None:
        return "-"
    return "0" if value == 0 else f"{value:.1e}"


def fmt_ms(seconds) -> str:
    """A time in seconds as milliseconds for a table, 4 significant digits ('-' for none)."""
    return "-" if seconds is None else f"{1e3 * seconds:.4g}"
