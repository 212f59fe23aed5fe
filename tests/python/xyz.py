"""Reading systems/validation's extended XYZ files (orthorhombic Lattice, species and positions,
pbc) for the Python tests, without a package of its own."""
from __future__ import annotations

from pathlib import Path

import numpy as np

SYSTEMS = Path(__file__).resolve().parents[2] / "systems" / "validation"


def read_xyz(path: Path):
    """(box [3], periodic [3], species [n], positions (n, 3) float64)."""
    lines = path.read_text().splitlines()
    n = int(lines[0])
    header = lines[1]
    lattice = [float(v) for v in header.split('Lattice="')[1].split('"')[0].split()]
    box = [lattice[0], lattice[4], lattice[8]]
    periodic = [v == "T" for v in header.split('pbc="')[1].split('"')[0].split()]
    rows = [line.split() for line in lines[2:2 + n]]
    species = [r[0] for r in rows]
    positions = np.array([[float(v) for v in r[1:4]] for r in rows], dtype=np.float64)
    return box, periodic, species, positions
