"""The validation cases: each configuration in systems/validation/ with the force fields run on it.

`quick` marks the small set that CI runs (CPU backend, well under a minute in all).
"""

from __future__ import annotations

from lj import REPO_ROOT, Case, read_extxyz

SYSTEMS = "systems/validation"
ONE_TYPE = [("A", 1.0, 1.0)]
BINARY = [("A", 1.0, 1.0), ("B", 0.88, 0.5)]


def _half_box(xyz: str) -> float:
    """Half the (cubic) box edge of a configuration file, to full double precision.

    NaN while the file is missing, so that importing the cases never fails: every script
    checks that a case's file exists before it runs the case (parity.py: check_setup, which
    says that make_systems.py makes the file)."""
    if not (REPO_ROOT / xyz).is_file():
        return float("nan")
    lengths = read_extxyz(REPO_ROOT / xyz)[2]
    if len(set(lengths)) != 1:
        raise ValueError(f"{xyz}: box is not cubic")
    return 0.5 * float(lengths[0])


CASES = [
    Case("lj_liquid_truncate", f"{SYSTEMS}/lj_liquid.xyz", 3, 2.5, "truncate", ONE_TYPE,
         description="LJ liquid, 4000 particles, density 0.8442, kT 1.44, plain truncation"),
    Case("lj_liquid_shift", f"{SYSTEMS}/lj_liquid.xyz", 3, 2.5, "shift", ONE_TYPE,
         description="LJ liquid, energy shifted to 0 at rc"),
    Case("lj_liquid_force_shift", f"{SYSTEMS}/lj_liquid.xyz", 3, 2.5, "force-shift", ONE_TYPE,
         quick=True, description="LJ liquid, energy and force shifted to 0 at rc"),
    Case("lj_gas_truncate", f"{SYSTEMS}/lj_gas.xyz", 3, 2.5, "truncate", ONE_TYPE,
         description="dilute LJ gas, 1000 particles, density 0.02 (few pairs, sparse cells)"),
    Case("binary_lb_truncate", f"{SYSTEMS}/binary_lb.xyz", 3, 2.5, "truncate", BINARY,
         quick=True, description="80:20 A/B mixture (B: sigma 0.88, eps 0.5), Lorentz-Berthelot"),
    Case("binary_lb_force_shift", f"{SYSTEMS}/binary_lb.xyz", 3, 2.5, "force-shift", BINARY,
         description="A/B mixture, Lorentz-Berthelot, force shift"),
    Case("binary_geometric_shift", f"{SYSTEMS}/binary_lb.xyz", 3, 2.5, "shift", BINARY,
         mixing="geometric",
         description="A/B mixture, geometric mixing of sigma and epsilon, shift"),
    Case("binary_pair_override", f"{SYSTEMS}/binary_lb.xyz", 3, 2.5, "truncate", BINARY,
         pairs=[("A", "B", 0.8, 1.5)],
         description="A/B mixture, explicit A-B pair (sigma 0.8, eps 1.5) over Lorentz-Berthelot"),
    Case("lj_cluster_open_truncate", f"{SYSTEMS}/lj_cluster_open.xyz", 3, 2.5, "truncate",
         ONE_TYPE, quick=True, description="500-particle cluster, open boundaries on every axis"),
    Case("lj_droplet_truncate", f"{SYSTEMS}/lj_droplet.xyz", 3, 2.5, "truncate", ONE_TYPE,
         description="2000-particle droplet in a periodic box of ~1000x its volume"),
    Case("lj_small_half_box", f"{SYSTEMS}/lj_small_half_box.xyz", 3,
         _half_box(f"{SYSTEMS}/lj_small_half_box.xyz"), "truncate", ONE_TYPE, quick=True,
         description="256-particle liquid with rc = L/2 exactly (the largest cutoff allowed)"),
    Case("lj_2d_truncate", f"{SYSTEMS}/lj_2d.xyz", 2, 2.5, "truncate", ONE_TYPE, quick=True,
         description="2D liquid, 1024 particles, area density 0.7, periodic in x and y"),
    Case("lj_2d_force_shift", f"{SYSTEMS}/lj_2d.xyz", 2, 2.5, "force-shift", ONE_TYPE,
         description="2D liquid, force shift"),
]

BY_NAME = {case.name: case for case in CASES}
