"""An ASE calculator over cellforce's ForceKernel.

    from cellforce.ase import CellforceCalculator
    atoms.calc = CellforceCalculator(cutoff=2.5, types={"Ar": (1.0, 1.0)}, mode="shift")
    atoms.get_potential_energy(), atoms.get_forces(), atoms.get_stress()

The cell must be orthorhombic (a diagonal cell matrix); each axis is periodic where atoms.pbc says
so. Atoms are mapped to types by chemical symbol, or by `species` ({symbol: type name}). Units are
the caller's: sigma in the positions' length unit, epsilon in the energy unit; forces are energy /
length, the stress energy / length^3 (ASE's Voigt order xx, yy, zz, yz, xz, xy, the sign of
ASE's: -virial / volume). mode="shift" (the default) is ASE's LennardJones without `smooth`: the
pair energy shifted to zero at the cutoff, the force not.
"""
from __future__ import annotations

import numpy as np
from ase.calculators.calculator import Calculator, PropertyNotImplementedError, all_changes

from ._cellforce import ForceKernel


class CellforceCalculator(Calculator):
    """Energy, per-atom energies, forces and stress by cellforce (CPU or CUDA) for ase.Atoms with an
    orthorhombic cell.

    cutoff: pairs interact for r < cutoff (length); types: {name: (sigma, epsilon)} (default
    {"Ar": (1.0, 1.0)}); species: {chemical symbol: type name} (default: a symbol is its type's
    name); pairs, mixing, mode, precision, backend: as ForceKernel's.
    """

    implemented_properties = ["energy", "free_energy", "energies", "forces", "stress"]

    def __init__(self, cutoff: float = 2.5, types: dict | None = None, species: dict | None = None,
                 pairs: dict | None = None, mixing: str = "lorentz-berthelot", mode: str = "shift",
                 precision: str = "double", backend: str = "auto", **kwargs):
        super().__init__(**kwargs)
        self.cutoff = float(cutoff)
        self.types = dict(types) if types is not None else {"Ar": (1.0, 1.0)}
        self.species = dict(species) if species is not None else {}
        self.pairs = dict(pairs) if pairs is not None else {}
        self.mixing, self.mode, self.precision, self.backend = mixing, mode, precision, backend
        self._kernel = None
        self._kernel_for = None

    def _kernel_of(self, box, pbc):
        # Made again where the cell or a setting changed (the settings are plain attributes).
        key = (tuple(box), tuple(pbc), self.cutoff, repr(self.types), repr(self.pairs), self.mixing, self.mode,
               self.precision, self.backend)
        if self._kernel_for != key:
            self._kernel = ForceKernel(box=list(box), periodic=list(pbc), cutoff=self.cutoff, types=self.types,
                                       pairs=self.pairs, mixing=self.mixing, mode=self.mode,
                                       precision=self.precision, backend=self.backend)
            self._kernel_for = key
        return self._kernel

    def calculate(self, atoms=None, properties=("energy",), system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        atoms = self.atoms
        cell = np.array(atoms.cell.array, dtype=np.float64)
        if np.any(cell != np.diag(np.diag(cell))):
            raise ValueError(f"CellforceCalculator: the cell is not orthorhombic (cellforce takes a diagonal cell): "
                             f"{cell.tolist()}")
        box = np.diag(cell)
        pbc = [bool(p) for p in atoms.pbc]
        for axis in range(3):
            if pbc[axis] and not box[axis] > 0:
                raise ValueError(f"CellforceCalculator: axis {axis} is periodic but the cell's edge is {box[axis]}")
        names = []
        for i, symbol in enumerate(atoms.get_chemical_symbols()):
            name = self.species.get(symbol, symbol)
            if name not in self.types:
                raise ValueError(f"CellforceCalculator: atom {i} ({symbol}) maps to the type '{name}', which is not in "
                                 f"types {sorted(self.types)} (give species={{'{symbol}': NAME}})")
            names.append(name)
        r = self._kernel_of(box, pbc).compute(np.ascontiguousarray(atoms.positions, dtype=np.float64), types=names,
                                              energy=True, virial=True)
        self.results["energy"] = r.energy
        self.results["free_energy"] = r.energy
        self.results["energies"] = r.energies
        self.results["forces"] = r.forces
        volume = float(np.prod(box))
        if volume > 0:
            w = -r.virial / volume  # ASE's stress: -virial / V
            self.results["stress"] = np.array([w[0, 0], w[1, 1], w[2, 2], w[1, 2], w[0, 2], w[0, 1]])
        elif "stress" in properties:
            raise PropertyNotImplementedError("CellforceCalculator: a stress needs a cell of nonzero volume")
