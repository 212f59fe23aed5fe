"""Error against run time: every cellforce and OpenMM choice on one system.

Each row's error is against OpenMM Reference (double precision): median and max over particles
of |dF_i|/|F_i|, and the total energy's relative error. Time is the median wall time of one force
evaluation: for cellforce the output's `evaluation_time` (measured in C++ around one engine
evaluate call on host arrays, host<->device copies included, which also computes per-particle
energies and the virial; median over all --repeats calls, the first included; `pipeline_time`
is stored too), for OpenMM setPositions + getState(forces, energy) + conversion to numpy in
Python (after one untimed warm-up), once with the neighbour list kept (the same positions every
time) and once with it rebuilt at every evaluation (positions alternating with a translated
copy), since every cellforce evaluation runs the whole search. For every OpenMM platform but
Reference, one more row times the round trip alone (setPositions + getState(positions) +
conversion to numpy, no forces): the part of OpenMM's time that is not force work. It has no
error (its error fields are null).

    python validation/error_vs_time.py --cellforce build/cellforce \\
        --xyz systems/validation/lj_liquid_32k.xyz --cutoff 2.5 --mode truncate --out data.json \\
        [--repeats 21] [--openmm-platforms Reference CPU CUDA] [--backends cpu cuda]

Exit status: 0 every requested row ran or was skipped as unavailable, 1 some row failed,
2 usage error.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import lj

PRECISIONS = ("single", "mixed", "double")


def cellforce_choices(backends):
    """(backend, precision, options) for every cellforce row."""
    choices = []
    if "cpu" in backends:
        choices += [("cpu", p, {"accumulation": a}) for p in PRECISIONS
                    for a in ("jacobi", "gauss-seidel")]
    if "cuda" in backends:
        for p in PRECISIONS:
            choices += [("cuda", p, {"traversal": t, "sort": s, "accumulation": "jacobi"})
                        for t in ("warp", "thread") for s in ("cub", "chapter")]
            choices.append(("cuda", p, {"traversal": "warp", "sort": "cub",
                                        "accumulation": "gauss-seidel"}))
    return choices


def openmm_choices(platforms):
    """(platform, precision) for every OpenMM row; None: the CPU platform's only precision."""
    return [(name, p) for name in platforms for p in ((None,) if name == "CPU" else PRECISIONS)]


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _gpus() -> list[str]:
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version",
                              "--format=csv,noheader"], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return []
    return [line.strip() for line in out.stdout.splitlines() if line.strip()]


def machine_info() -> dict:
    import openmm

    return {"cpu": _cpu_model(), "cores": os.cpu_count(), "gpus": _gpus(),
            "os": platform.platform(), "python": sys.version.split()[0],
            "numpy": np.__version__, "openmm": openmm.__version__}


NO_ERRORS = {"median_rel_err": None, "max_rel_err": None, "energy_rel_err": None}


def errors(forces, energy, ref_forces, ref_energy, dim) -> dict:
    rel = lj.relative_force_errors(forces[:, :dim], ref_forces[:, :dim])
    return {"median_rel_err": float(np.median(rel)), "max_rel_err": float(rel.max()),
            "energy_rel_err": lj.energy_relative_error(energy, ref_energy)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cellforce", help="cellforce executable (needed with --backends)")
    parser.add_argument("--xyz", type=Path, required=True, help="extended XYZ configuration")
    parser.add_argument("--cutoff", type=float, default=2.5)
    parser.add_argument("--mode", choices=lj.MODES, default="truncate")
    parser.add_argument("--dim", type=int, choices=(2, 3), default=3)
    parser.add_argument("--type", action="append", metavar="NAME:SIGMA:EPSILON",
                        help="a particle type (default A:1:1); repeat for more")
    parser.add_argument("--out", type=Path, required=True, help="JSON output")
    parser.add_argument("--repeats", type=int, default=21, help="timed evaluations per row")
    parser.add_argument("--reference-repeats", type=int, default=3,
                        help="timed evaluations of OpenMM Reference (slow)")
    parser.add_argument("--openmm-platforms", nargs="*", default=["Reference", "CPU", "CUDA"],
                        help="OpenMM platforms (Reference always runs: it is the reference)")
    parser.add_argument("--backends", nargs="*", choices=["cpu", "cuda"], default=["cpu", "cuda"])
    args = parser.parse_args()
    if args.backends and not args.cellforce:
        parser.error("--cellforce is needed for --backends")
    if not args.xyz.is_file():
        parser.error(f"{args.xyz}: no such file")
    try:
        types = [(n, float(s), float(e)) for n, s, e in
                 (t.split(":") for t in args.type or ["A:1:1"])]
    except ValueError:
        parser.error(f"--type takes NAME:SIGMA:EPSILON, not {args.type}")
    xyz = args.xyz.resolve()
    case = lj.Case(xyz.stem, os.path.relpath(xyz, lj.REPO_ROOT), args.dim, args.cutoff,
                   args.mode, types)

    import openmm as mm

    available = {mm.Platform.getPlatform(i).getName() for i in range(mm.Platform.getNumPlatforms())}
    positions, species, lengths, pbc = lj.read_extxyz(xyz)
    system = lj.openmm_system(case, positions, species, lengths, pbc)
    host = f"{_cpu_model()}, {os.cpu_count()} cores"
    command = shlex.join(["python", *sys.argv])
    print(f"{case.xyz}: N = {len(positions)}, rc = {case.cutoff}, {case.mode}", flush=True)

    ref_forces, ref_energy, ref_time = lj.openmm_forces(system, positions, "Reference",
                                                        repeats=args.reference_repeats)
    rows, skipped, failed = [], [], []

    def add(row):
        rows.append(row)
        print(f"{row['label']:52s} {1e3 * row['time_s']:10.3f} ms  "
              f"median rel {lj.fmt_err(row['median_rel_err'])}  "
              f"max rel {lj.fmt_err(row['max_rel_err'])}  "
              f"energy {lj.fmt_err(row['energy_rel_err'])}", flush=True)

    add({"label": "OpenMM Reference double", "engine": "openmm", "platform": "Reference",
         "precision": "double", "options": {}, "time_s": ref_time, "pipeline_time_s": None,
         "repeats": args.reference_repeats, "device": host, "host": host,
         **errors(ref_forces, ref_energy, ref_forces, ref_energy, case.dim)})

    devices = {}  # OpenMM platform name: what it runs on
    for name, precision in openmm_choices(p for p in args.openmm_platforms if p != "Reference"):
        label = f"OpenMM {name} {precision or 'single'}"
        if name not in available:
            skipped.append(f"{label}: platform not available")
            print(f"skipped: {skipped[-1]}", flush=True)
            continue
        if name not in devices:
            device = lj.openmm_device(system, name)
            devices[name] = f"{host}, {device}" if name == "CPU" else device or host
        device = devices[name]
        # Twice: neighbour list kept (same positions), and rebuilt at every evaluation.
        for list_use in ("reused", "rebuilt"):
            forces, energy, seconds = lj.openmm_forces(
                system, positions, name, precision, repeats=args.repeats,
                rebuild=list_use == "rebuilt", shift=case.cutoff)
            add({"label": f"{label}, list {list_use}", "engine": "openmm", "platform": name,
                 "precision": precision or "single", "options": {"neighbour_list": list_use},
                 "time_s": seconds, "pipeline_time_s": None, "repeats": args.repeats,
                 "device": device, "host": host,
                 **errors(forces, energy, ref_forces, ref_energy, case.dim)})

    # The round trip alone, once per platform that ran (its default precision).
    for name, device in devices.items():
        seconds = lj.openmm_round_trip(system, positions, name, repeats=args.repeats)
        add({"label": f"OpenMM {name} round trip only (no forces)", "engine": "openmm",
             "platform": name, "precision": "-",
             "options": {"neighbour_list": "-", "what": "round trip"}, "time_s": seconds,
             "pipeline_time_s": None, "repeats": args.repeats, "device": device, "host": host,
             **NO_ERRORS})

    unavailable = set()  # backends found missing: their other rows are not tried
    with tempfile.TemporaryDirectory(prefix="cellforce-evt-") as workdir:
        for k, (backend, precision, options) in enumerate(cellforce_choices(args.backends)):
            if backend in unavailable:
                continue
            label = f"cellforce {backend} {precision} " + "/".join(options.values())
            extra = [a for key, value in options.items() for a in (f"--{key}", value)]
            try:
                result = lj.run_cellforce(args.cellforce, case, backend, precision,
                                          Path(workdir) / f"{k}.h5", extra, args.repeats)
            except lj.CellforceError as err:
                if any(s in str(err).lower() for s in lj.UNAVAILABLE):
                    unavailable.add(backend)
                    skipped.append(f"cellforce {backend} (every row): {err}")
                else:
                    failed.append(f"{label}: {err}")
                print(f"not run: {label}: {err}", flush=True)
                continue
            attrs = result["attrs"]
            add({"label": label, "engine": "cellforce", "platform": backend,
                 "precision": precision, "options": options, "time_s": attrs["evaluation_time"],
                 "pipeline_time_s": attrs.get("pipeline_time"), "repeats": args.repeats,
                 "device": attrs.get("engine", ""), "host": host,
                 "cellforce_version": attrs.get("cellforce_version", ""),
                 "pairs_tested": attrs.get("pairs_tested"),
                 "pairs_within_cutoff": attrs.get("pairs_within_cutoff"),
                 **errors(result["forces"], result["energy"], ref_forces, ref_energy, case.dim)})

    data = {"system": {"xyz": case.xyz, "n_particles": len(positions), "dim": case.dim,
                       "cutoff": case.cutoff, "mode": case.mode, "types": case.types,
                       "box": [float(v) for v in lengths], "pbc": list(pbc),
                       "reference_energy": ref_energy},
            "machine": machine_info(), "command": command, "revision": lj.source_revision(),
            "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "skipped": skipped, "failed": failed, "rows": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(data, indent=1))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
