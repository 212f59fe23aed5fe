"""cellforce.ase.CellforceCalculator against ASE's own LennardJones (smooth off:
the pair energy shifted to zero at rc, which is cellforce's mode "shift") on a periodic liquid and
an open cluster of systems/validation: energy, per-atom energies, forces and stress to 1e-10
relative in double; ASE's finite-difference forces agree; bad input is named."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ase = pytest.importorskip("ase")
from ase import Atoms  # noqa: E402
from ase.calculators.fd import calculate_numerical_forces  # noqa: E402
from ase.calculators.lj import LennardJones  # noqa: E402

from cellforce.ase import CellforceCalculator  # noqa: E402
from xyz import SYSTEMS, read_xyz  # noqa: E402


def read(path: Path) -> Atoms:
    """A systems/validation file as ase.Atoms, species A and B as argon and krypton."""
    box, periodic, species, x = read_xyz(path)
    return Atoms(symbols=["Ar" if s == "A" else "Kr" for s in species], positions=x, cell=box, pbc=periodic)


def relative(a, b):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


@pytest.mark.parametrize("name", ["lj_small_half_box", "lj_cluster_open"])
def test_agrees_with_ase_lennard_jones(name):
    atoms = read(SYSTEMS / f"{name}.xyz")
    ref = atoms.copy()
    ref.calc = LennardJones(sigma=1.0, epsilon=1.0, rc=2.5, smooth=False)
    atoms.calc = CellforceCalculator(cutoff=2.5, types={"Ar": (1.0, 1.0)}, mode="shift", precision="double",
                                     backend="cpu")
    e_ref, e = ref.get_potential_energy(), atoms.get_potential_energy()
    assert abs(e - e_ref) <= 1e-10 * np.sum(np.abs(ref.get_potential_energies()))
    assert relative(atoms.get_potential_energies(), ref.get_potential_energies()) <= 1e-10
    assert relative(atoms.get_forces(), ref.get_forces()) <= 1e-10
    assert relative(atoms.get_stress(), ref.get_stress()) <= 1e-10
    assert atoms.pbc.all() == (name == "lj_small_half_box")


def test_forces_are_the_energy_gradient():
    atoms = read(SYSTEMS / "lj_small_half_box.xyz")
    atoms.calc = CellforceCalculator(cutoff=2.5, types={"Ar": (1.0, 1.0)}, mode="shift", backend="cpu")
    forces = atoms.get_forces()
    some = [0, 17, 101, 255]
    numeric = calculate_numerical_forces(atoms, eps=1e-5, iatoms=some)
    # central differences of a smooth pair potential: error ~ d^2 |F'''|, well below 1e-6 of the
    # largest force here (a pair crossing rc changes the energy continuously in mode shift)
    assert np.max(np.abs(numeric - forces[some])) <= 1e-6 * np.max(np.abs(forces))


def test_species_map_and_two_types_follow_the_mixing_rule():
    atoms = read(SYSTEMS / "binary_lb.xyz")
    mapped = CellforceCalculator(cutoff=2.5, types={"A": (1.0, 1.0), "B": (0.88, 0.5)},
                                 species={"Ar": "A", "Kr": "B"}, mode="truncate", backend="cpu")
    atoms.calc = mapped
    f = atoms.get_forces()
    plain = read(SYSTEMS / "binary_lb.xyz")
    plain.calc = CellforceCalculator(cutoff=2.5, types={"Ar": (1.0, 1.0), "Kr": (0.88, 0.5)}, mode="truncate",
                                     backend="cpu")
    assert np.array_equal(f, plain.get_forces())


def test_bad_input_is_named():
    atoms = read(SYSTEMS / "lj_small_half_box.xyz")
    atoms.calc = CellforceCalculator(cutoff=2.5, types={"Xe": (1.0, 1.0)}, backend="cpu")
    with pytest.raises(ValueError, match=r"atom 0 \(Ar\) maps to the type 'Ar', which is not in types \['Xe'\]"):
        atoms.get_potential_energy()
    tilted = read(SYSTEMS / "lj_small_half_box.xyz")
    cell = tilted.cell.array.copy()
    cell[1, 0] = 0.5
    tilted.set_cell(cell)
    tilted.calc = CellforceCalculator(cutoff=2.5, types={"Ar": (1.0, 1.0)}, backend="cpu")
    with pytest.raises(ValueError, match="the cell is not orthorhombic"):
        tilted.get_forces()
