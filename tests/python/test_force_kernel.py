"""The Python module's ForceKernel on NumPy arrays: bitwise the numbers of `cellforce
forces` (the CLI, the same C++ API) on systems/validation for the same backend and precision (the
cuda instances skip, with the library's reason, where no CUDA device can be used); ghosts
summed over slabs equal the whole periodic system (double: 1e-12 relative); bad input raises a
TypeError or ValueError naming the argument. Run by ctest (python_module) with PYTHONPATH at the
build's python/ folder and CELLFORCE_EXE at the CLI."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest

import cellforce
from here import cuda_missing
from xyz import SYSTEMS, read_xyz

ROOT = Path(__file__).resolve().parents[2]
EXE = os.environ.get("CELLFORCE_EXE", str(ROOT / "build" / "cellforce"))
BINARY = {"A": (1.0, 1.0), "B": (0.88, 0.5)}  # binary_lb.xyz's types (systems/validation/README.md)


def cli_forces(tmp_path: Path, xyz: Path, precision: str, types: dict, dim: int = 3, backend: str = "cpu"):
    out = tmp_path / f"{xyz.stem}-{precision}-{backend}.h5"
    command = [EXE, "forces", str(xyz), "-o", str(out), "--backend", backend, "--precision", precision,
               "--cutoff", "2.5", "--dim", str(dim)]
    for name, (sigma, epsilon) in types.items():
        command += ["--type", f"{name}:{sigma}:{epsilon}"]
    subprocess.run(command, check=True, capture_output=True, text=True)
    with h5py.File(out, "r") as f:
        return (np.array(f["forces"]), np.array(f["energies"]), float(np.array(f["energy"])),
                np.array(f["virial"]))


@pytest.mark.parametrize("backend", ["cpu", "cuda"])
@pytest.mark.parametrize("precision", ["double", "mixed", "single"])
@pytest.mark.parametrize("name,dim", [("binary_lb", 3), ("lj_cluster_open", 3), ("lj_2d", 2)])
def test_numpy_is_the_cli_bitwise(tmp_path, name, dim, precision, backend):
    if backend == "cuda" and cuda_missing():
        pytest.skip(cuda_missing())
    xyz = SYSTEMS / f"{name}.xyz"
    box, periodic, species, x = read_xyz(xyz)
    types = BINARY if name == "binary_lb" else {"A": (1.0, 1.0)}
    forces, energies, energy, virial = cli_forces(tmp_path, xyz, precision, types, dim, backend)
    k = cellforce.ForceKernel(box=box[:dim], periodic=periodic[:dim], cutoff=2.5, types=types,
                              precision=precision, backend=backend)
    r = k.compute(np.ascontiguousarray(x[:, :dim]), types=species, energy=True, virial=True)
    assert r.forces.shape == (len(species), dim)
    assert not r.forces.flags.owndata and not r.virial.flags.owndata  # handed out in place, not copied
    assert np.array_equal(r.forces, forces.reshape(r.forces.shape))
    assert np.array_equal(r.energies, energies.reshape(-1))
    assert r.energy == energy
    assert np.array_equal(r.virial, virial.reshape(dim, dim))


def test_index_types_and_float32_positions_are_the_names_and_float64_values():
    box, periodic, species, x = read_xyz(SYSTEMS / "binary_lb.xyz")
    k = cellforce.ForceKernel(box=box, periodic=periodic, types=BINARY, backend="cpu")
    by_name = k.compute(x, types=species)
    index = np.array([k.type_names.index(s) for s in species])
    for dtype in (np.int32, np.uint32):
        assert np.array_equal(k.compute(x, types=index.astype(dtype)).forces, by_name.forces)
    x32 = x.astype(np.float32)
    assert np.array_equal(k.compute(x32, types=species).forces, k.compute(x32.astype(np.float64), types=species).forces)


def test_periodic_takes_numpy_bools_and_one_kernel_serves_two_threads():
    import threading

    box, periodic, species, x = read_xyz(SYSTEMS / "lj_liquid.xyz")
    k = cellforce.ForceKernel(box=box, periodic=np.array(periodic), backend="cpu")
    want = k.compute(x).forces
    got = [None] * 4

    def run(slot):
        got[slot] = k.compute(x).forces

    threads = [threading.Thread(target=run, args=(s,)) for s in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for g in got:
        assert np.array_equal(g, want)


def test_ghost_slabs_sum_to_the_whole_periodic_system():
    """Two slabs along x, each with the periodic images within rc as ghosts (x open): the locals'
    forces and the energies summed equal the whole periodic system's (double, 1e-12)."""
    box, periodic, species, x = read_xyz(SYSTEMS / "lj_liquid.xyz")
    rc, L = 2.5, box[0]
    whole = cellforce.ForceKernel(box=box, periodic=periodic, backend="cpu").compute(x, energy=True, virial=True)
    slab = cellforce.ForceKernel(box=box, periodic=[False, True, True], backend="cpu")
    forces = np.full_like(whole.forces, np.nan)
    energy, virial = 0.0, np.zeros((3, 3))
    for lo, hi in ((0.0, L / 2), (L / 2, L)):
        own = np.where((x[:, 0] >= lo) & (x[:, 0] < hi))[0]
        ghosts = []
        for shift in (-L, 0.0, L):
            xs = x[:, 0] + shift
            near = np.where(((xs >= lo - rc) & (xs < lo)) | ((xs >= hi) & (xs < hi + rc)))[0]
            ghosts.append(np.column_stack([xs[near], x[near, 1:]]))
        rows = np.ascontiguousarray(np.vstack([x[own]] + ghosts))
        r = slab.compute(rows, energy=True, virial=True, n_ghost=len(rows) - len(own))
        # float32 rows and int32 types on the ghost path: the float64 / uint32 results of the same values
        r32 = slab.compute(rows.astype(np.float32), types=np.zeros(len(rows), dtype=np.int32),
                           n_ghost=len(rows) - len(own))
        assert np.array_equal(r32.forces, slab.compute(rows.astype(np.float32).astype(np.float64),
                                                       types=np.zeros(len(rows), dtype=np.uint32),
                                                       n_ghost=len(rows) - len(own)).forces)
        with pytest.raises(ValueError, match="types: particle 0 has type index -1"):
            slab.compute(rows, types=np.full(len(rows), -1, dtype=np.int32), n_ghost=len(rows) - len(own))
        forces[own] = r.forces
        energy += r.energy
        virial += r.virial
        assert r.virials.shape == (len(own), 3, 3)
    assert np.max(np.abs(forces - whole.forces)) <= 1e-12 * np.max(np.abs(whole.forces))
    assert abs(energy - whole.energy) <= 1e-12 * np.sum(np.abs(whole.energies))
    assert np.max(np.abs(virial - whole.virial)) <= 1e-12 * np.max(np.abs(whole.virial))


def test_bad_input_names_the_argument():
    k = cellforce.ForceKernel(box=[10.0, 10.0, 10.0], types={"A": (1.0, 1.0)}, backend="cpu")
    x = np.random.default_rng(3).random((50, 3)) * 10
    with pytest.raises(ValueError, match=r"positions: shape \(50, 2\); expected \(n, 3\)"):
        k.compute(np.ascontiguousarray(x[:, :2]))
    with pytest.raises(TypeError, match="positions: expected float64 or float32"):
        k.compute(x.astype(np.int64))
    with pytest.raises(TypeError, match="positions: expected a C-contiguous array"):
        k.compute(np.asfortranarray(x))
    with pytest.raises(TypeError, match="positions"):
        k.compute("not an array")
    bad = x.copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match="particle 7"):
        k.compute(bad)
    with pytest.raises(ValueError, match="types: particle 3 has the unknown type 'C'"):
        k.compute(x, types=["A"] * 3 + ["C"] + ["A"] * 46)
    with pytest.raises(ValueError, match=r"types: shape \(49,\); expected \(50,\)"):
        k.compute(x, types=np.zeros(49, dtype=np.int32))
    with pytest.raises(TypeError, match="types: expected int32 or uint32"):
        k.compute(x, types=np.zeros(50, dtype=np.int64))
    with pytest.raises(ValueError, match="n_ghost: 51 ghosts of 50 particles"):
        k.compute(x, n_ghost=51)
    with pytest.raises(ValueError, match="box: 4 edge lengths"):
        cellforce.ForceKernel(box=[1.0, 2.0, 3.0, 4.0])
    with pytest.raises(ValueError, match="cubic"):
        cellforce.ForceKernel(box=[10.0, 10.0, 10.0], mode="cubic")
    with pytest.raises(ValueError, match="n_ghost: -1 ghosts of 50 particles"):
        k.compute(x, n_ghost=-1)
    with pytest.raises(TypeError, match="types: expected"):
        cellforce.ForceKernel(box=[10.0, 10.0, 10.0], types=[("A", 1.0, 1.0)])
    with pytest.raises(TypeError, match="periodic: expected a sequence of truth values"):
        cellforce.ForceKernel(box=[10.0, 10.0, 10.0], periodic=3)
    with pytest.raises(ValueError, match="pairs: unknown type 'C'"):
        cellforce.ForceKernel(box=[10.0, 10.0, 10.0], pairs={("A", "C"): (1.0, 1.0)})
    with pytest.raises(ValueError, match="periodic: 2 values for a box of 3 axes"):
        cellforce.ForceKernel(box=[10.0, 10.0, 10.0], periodic=[True, True])
    with pytest.raises(ValueError, match=r"forces: shape \(50, 2\); expected \(50, 3\)"):
        k.compute(x, forces=np.zeros((50, 2)))
    with pytest.raises(TypeError, match="forces: expected float64, not float32"):
        k.compute(x, forces=np.zeros((50, 3), dtype=np.float32))
    read_only = np.zeros((50, 3))
    read_only.flags.writeable = False
    with pytest.raises(TypeError, match="forces: expected a writable"):
        k.compute(x, forces=read_only)
    with pytest.raises(ValueError, match="energies: given, but energy=False"):
        k.compute(x, energies=np.zeros(50))
    with pytest.raises(ValueError, match="stream: host positions"):
        k.compute(x, stream=0)
    with pytest.raises(TypeError, match="stream: expected None"):
        k.compute(x, stream="default")


def test_results_into_the_callers_arrays():
    """forces= and energies= receive bitwise the values of a call that makes its own arrays, and
    are the arrays the Result holds."""
    k = cellforce.ForceKernel(box=[10.0, 10.0, 10.0], backend="cpu")
    x = np.random.default_rng(5).random((300, 3)) * 10
    fresh = k.compute(x, energy=True)
    f, e = np.full((300, 3), np.nan), np.full(300, np.nan)
    r = k.compute(x, energy=True, forces=f, energies=e)
    assert r.forces is f and r.energies is e
    assert np.array_equal(f, fresh.forces) and np.array_equal(e, fresh.energies)
    assert r.energy == fresh.energy
