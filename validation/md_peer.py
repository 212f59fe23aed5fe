#!/usr/bin/env python3
"""Time steps of the LAMMPS in.lj fluid with `cellforce run` and with OpenMM's CUDA platform, side
by side, in one call on one machine.

The system: fcc at number density 0.8442 (4 x cells^3 particles), Lennard-Jones sigma = epsilon =
mass = 1, cutoff 2.5 (truncated, no dispersion correction), T0 = 1.44, dt 0.005, NVE.
OpenMM: NonbondedForce CutoffPeriodic, VerletIntegrator, precision single and mixed, on the CUDA
platform; `warmup` steps (context creation, kernel compilation, first neighbour list) are excluded,
then `steps` steps are timed to the end of a getState. cellforce: `cellforce run` of a generated
scene on the CUDA backend in the same precision, with no [neighbor] section: skin auto, which on
CUDA is pair lists with a skin of 0.24 rc (until 2026-11-25 it was no skin: the tables in
validation/reports/md-run.md before then are of the cells on every step); its own summary gives the
loop's steps/s (setup excluded), the forces' device time per step and the force engine's time per
evaluation.

Writes a Markdown table (--md) and the raw numbers (--json); exits 1 when a run fails.

  python3 validation/md_peer.py --cellforce build-gpu-bin/cellforce --cells 20 40 64 102 \
      --precisions single mixed --md md-peer.md --json md-peer.json
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DENSITY = 0.8442
CUTOFF = 2.5
DT = 0.005
T0 = 1.44


def fcc_positions(cells: int):
    import numpy as np

    a = (4.0 / DENSITY) ** (1.0 / 3.0)
    basis = np.array([[0, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5], [0, 0.5, 0.5]]) * a
    grid = np.stack(np.meshgrid(*[np.arange(cells)] * 3, indexing="ij"), axis=-1).reshape(-1, 3) * a
    positions = (grid[:, None, :] + basis[None, :, :]).reshape(-1, 3)
    return positions, a * cells


def lj_system(n: int, edge: float):
    """The in.lj fluid as an OpenMM System: n particles of mass 1 in a cubic periodic box, NonbondedForce
    CutoffPeriodic at CUTOFF, sigma = epsilon = 1, no charge, no dispersion correction, no switching."""
    import openmm

    system = openmm.System()
    system.setDefaultPeriodicBoxVectors(openmm.Vec3(edge, 0, 0), openmm.Vec3(0, edge, 0), openmm.Vec3(0, 0, edge))
    force = openmm.NonbondedForce()
    force.setNonbondedMethod(openmm.NonbondedForce.CutoffPeriodic)
    force.setCutoffDistance(CUTOFF)
    force.setUseDispersionCorrection(False)
    force.setUseSwitchingFunction(False)
    for _ in range(n):
        system.addParticle(1.0)
        force.addParticle(0.0, 1.0, 1.0)
    system.addForce(force)
    return system


def openmm_steps_per_second(cells: int, precision: str, steps: int, warmup: int) -> dict:
    import numpy as np
    import openmm
    from openmm import unit

    positions, edge = fcc_positions(cells)
    n = len(positions)
    system = lj_system(n, edge)
    integrator = openmm.VerletIntegrator(DT)
    platform = openmm.Platform.getPlatformByName("CUDA")
    context = openmm.Context(system, integrator, platform, {"Precision": precision})
    context.setPositions(positions * unit.nanometer)
    context.setVelocitiesToTemperature(T0 / 0.00831446261815324 * unit.kelvin, 87287)  # kT = 1.44 in kJ/mol
    integrator.step(warmup)
    context.getState(getEnergy=True)
    t0 = time.perf_counter()
    integrator.step(steps)
    state = context.getState(getEnergy=True)
    seconds = time.perf_counter() - t0
    energy = state.getPotentialEnergy().value_in_unit(unit.kilojoule_per_mole) / n
    device = platform.getPropertyValue(context, "DeviceName")
    del context
    return {"steps_per_second": steps / seconds, "steps": steps, "seconds": seconds, "particles": n,
            "potential_per_particle": energy, "device": device}


SCENE = """[system]
dimension = 3
[particles]
lattice = "fcc"
cells = [{cells}, {cells}, {cells}]
density = {density}
[[types]]
name = "A"
[interactions]
cutoff = {cutoff}
mode = "truncate"
[initial]
temperature = {t0}
seed = 87287
[integrator]
kind = "nve"
dt = {dt}
[run]
steps = {steps}
backend = "cuda"
precision = "{precision}"
[output]
thermo_every = {thermo_every}
"""


def number(pattern: str, text: str) -> float:
    m = re.search(pattern, text)
    return float(m.group(1)) if m else math.nan


def cellforce_steps_per_second(binary: str, cells: int, precision: str, steps: int, folder: Path,
                               traversal: str | None = None) -> dict:
    scene = folder / f"inlj_{cells}_{precision}.toml"
    scene.write_text(SCENE.format(cells=cells, density=DENSITY, cutoff=CUTOFF, t0=T0, dt=DT, steps=steps,
                                  precision=precision, thermo_every=steps))
    command = [str(Path(binary).resolve()), "run", str(scene), "--quiet"]
    if traversal:
        command += ["--traversal", traversal]
    p = subprocess.run(command, capture_output=True, text=True, cwd=folder)
    if p.returncode != 0:
        raise RuntimeError(f"cellforce run failed ({p.returncode}): {p.stderr.strip()[-2000:]}")
    out = p.stdout
    return {
        "steps_per_second": number(r"([0-9.]+) steps/s,", out),
        "ms_per_step": number(r"([0-9.]+) ms per step", out),
        "forces_ms_per_step": number(r"per step \(ms\): forces ([0-9.]+)", out),
        "integration_ms_per_step": number(r"\| integration ([0-9.]+)", out),
        "output_ms_per_step": number(r"\| output ([0-9.]+)", out),
        "host_ms_per_step": number(r"\| host and waits ([0-9.]+)", out),
        "bytes_per_step": number(r"host <-> device per step: ([0-9.e+]+) bytes", out),
        "engine_ms_per_evaluation": number(r"engine total ([0-9.]+)", out),
        "steps": steps,
        "summary": out[out.find("performance:"):].strip(),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cellforce", required=True)
    ap.add_argument("--cells", type=int, nargs="+", default=[20, 40, 64, 102])
    ap.add_argument("--precisions", nargs="+", default=["single", "mixed"])
    ap.add_argument("--seconds", type=float, default=3.0, help="target timed seconds per run (sets the steps)")
    ap.add_argument("--warmup", type=int, default=50)
    ap.add_argument("--skip-openmm", action="store_true")
    ap.add_argument("--traversals", nargs="+", default=[None],
                    help="cellforce's CUDA traversal forms to time (auto, warp, thread, tile; default: the run's own)")
    ap.add_argument("--md", required=True)
    ap.add_argument("--json", required=True)
    args = ap.parse_args()

    rows, failed = [], False
    device = "?"
    with tempfile.TemporaryDirectory() as tmp:
        for cells in args.cells:
            n = 4 * cells ** 3
            # steps for ~args.seconds at a rough 3e8 particle-steps/s (OpenMM) and 4e7 (cellforce), at least 100
            omm_steps = max(100, int(args.seconds * 3.0e8 / n))
            cf_steps = max(100, int(args.seconds * 4.0e7 / n))
            for precision in args.precisions:
                row = {"cells": cells, "particles": n, "precision": precision}
                for traversal in args.traversals:
                    key = "cellforce" if traversal is None else f"cellforce-{traversal}"
                    try:
                        row[key] = cellforce_steps_per_second(args.cellforce, cells, precision, cf_steps, Path(tmp),
                                                              traversal)
                    except Exception as e:  # noqa: BLE001 - reported in the table
                        row[key] = {"error": str(e)}
                        failed = True
                if not args.skip_openmm:
                    try:
                        row["openmm"] = openmm_steps_per_second(cells, precision, omm_steps, args.warmup)
                        device = row["openmm"]["device"]
                    except Exception as e:  # noqa: BLE001
                        row["openmm"] = {"error": str(e)}
                        failed = True
                rows.append(row)
                print(json.dumps({k: v for k, v in row.items()}, default=str)[:600], flush=True)

    if device == "?":
        try:
            device = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                                    text=True).stdout.strip().splitlines()[0]
        except Exception:  # noqa: BLE001
            pass
    today = datetime.date.today().isoformat()
    lines = [f"Measured on {device}, {today}, in one call: `python3 validation/md_peer.py --cellforce <binary> "
             f"--cells {' '.join(map(str, args.cells))} --precisions {' '.join(args.precisions)}`. in.lj fluid (fcc "
             f"0.8442, rc 2.5 truncated, NVE, dt 0.005); time steps per second, setup and warm-up excluded. "
             "cellforce: forces and integration as reported by its run summary (device time per step); engine: "
             "the force engine's time per evaluation (stage events, sampled); step / engine is the ratio the "
             "issue bounds by 1.3.", "",
             "| N | precision | traversal | cellforce steps/s | OpenMM CUDA steps/s | cellforce / OpenMM | "
             "cellforce ms/step | forces ms/step | integration ms/step | host+waits ms/step | engine ms/evaluation | "
             "step / engine | bytes/step |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r, key in [(r, k) for r in rows for k in r if k.startswith("cellforce")]:
        c, o = r.get(key, {}), r.get("openmm", {})
        traversal = key.partition("-")[2] or "default"
        cf_rate, omm_rate = c.get("steps_per_second", math.nan), o.get("steps_per_second", math.nan)
        ratio = cf_rate / omm_rate if omm_rate and not math.isnan(omm_rate) else math.nan
        step_over_engine = c.get("ms_per_step", math.nan) / c.get("engine_ms_per_evaluation", math.nan) \
            if c.get("engine_ms_per_evaluation") else math.nan
        def f(v, fmt="{:.4g}"):
            return "error" if v is None else ("-" if isinstance(v, float) and math.isnan(v) else fmt.format(v))
        lines.append(f"| {r['particles']:,} | {r['precision']} | {traversal} | "
                     f"{f(cf_rate) if 'error' not in c else 'error'} | "
                     f"{f(omm_rate) if 'error' not in o else ('error' if o else '-')} | {f(ratio, '{:.3f}')} | "
                     f"{f(c.get('ms_per_step', math.nan))} | {f(c.get('forces_ms_per_step', math.nan))} | "
                     f"{f(c.get('integration_ms_per_step', math.nan))} | {f(c.get('host_ms_per_step', math.nan))} | "
                     f"{f(c.get('engine_ms_per_evaluation', math.nan))} | {f(step_over_engine, '{:.3f}')} | "
                     f"{f(c.get('bytes_per_step', math.nan))} |")
    errors = [f"- {r['particles']:,} {r['precision']} {k}: {r[k]['error'][:400]}"
              for r in rows for k in r if isinstance(r.get(k), dict) and "error" in r[k]]
    if errors:
        lines += ["", "Errors:"] + errors
    Path(args.md).write_text("\n".join(lines) + "\n")
    Path(args.json).write_text(json.dumps({"device": device, "date": today, "rows": rows}, indent=1, default=str))
    print("\n".join(lines))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
