"""NVE energy conservation of `cellforce run`: drift and fluctuation of the total energy.

For each backend x cutoff mode x time step x precision x size, runs an LJ liquid (fcc at density
0.8442, T0 = 1.44, rc 2.5, velocity Verlet) for --steps steps (or for --time in reduced time, the
same span for every time step), reads the thermo CSV (every 20 steps) and reports, per particle:
the drift (least-squares slope of E_total/N against time) and the RMS fluctuation of E_total/N
about its mean, with the run's speed. The scenes have no [neighbor] section: skin auto (pair lists
with a skin of 0.24 rc on CUDA since 2026-11-25; no skin on the CPU, and on CUDA before).

    python validation/nve_drift.py --cellforce build/cellforce [--backends cpu cuda]
        [--precisions single mixed double] [--cells 5 20] [--steps 20000 | --time 100]
        [--dt 0.002 0.005 0.01] [--mode truncate force-shift] --json out.json

Exit status: 0 when every run finished, 1 when one failed, 2 usage error.
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import subprocess
import sys
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

import lj

SCENE = """
[system]
dimension = 3
[particles]
lattice = "fcc"
cells = [{cells}, {cells}, {cells}]
density = 0.8442
[[types]]
name = "A"
[interactions]
cutoff = 2.5
mode = "{mode}"
[initial]
temperature = 1.44
seed = 2026
[integrator]
kind = "nve"
dt = {dt}
[run]
steps = {steps}
backend = "{backend}"
precision = "{precision}"
[output]
thermo_every = 20
thermo_file = "{thermo}"
"""


def drift_and_rms(csv_path: Path, n: int):
    data = np.genfromtxt(csv_path, delimiter=",", names=True)
    t, e = data["time"], data["total_energy"] / n
    slope = np.polyfit(t, e, 1)[0]
    return float(slope), float(np.sqrt(np.mean((e - e.mean()) ** 2))), float(e[-1] - e[0])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cellforce", required=True)
    parser.add_argument("--backends", nargs="+", choices=["cpu", "cuda"], default=["cpu"])
    parser.add_argument("--precisions", nargs="+", choices=["single", "mixed", "double"],
                        default=["single", "mixed", "double"])
    parser.add_argument("--cells", nargs="+", type=int, default=[5])
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--time", type=float, default=None,
                        help="run each time step for this reduced time (steps = time / dt)")
    parser.add_argument("--dt", type=float, nargs="+", default=[0.005])
    parser.add_argument("--mode", choices=lj.MODES, nargs="+", default=["force-shift"])
    parser.add_argument("--jobs", type=int, default=1, help="runs at a time")
    parser.add_argument("--device", default="", help="machine label stored in the JSON")
    parser.add_argument("--json", type=Path, required=True)
    args = parser.parse_args()
    rows, failed = [], []
    with tempfile.TemporaryDirectory(prefix="cellforce-nve-") as work:
        runs = [(b, m, dt, c, p) for b in args.backends for m in args.mode for dt in args.dt
                for c in args.cells for p in args.precisions]
        lock = threading.Lock()

        def write():
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps({
                "command": " ".join(["python", *sys.argv]), "revision": lj.source_revision(),
                "device": args.device,
                "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
                "failed": failed, "rows": rows}, indent=1))

        def one(run):
            backend, mode, dt, cells, precision = run
            steps = int(round(args.time / dt)) if args.time else args.steps
            tag = f"{backend}_{mode}_{dt}_{cells}_{precision}"
            thermo = Path(work) / f"{tag}.csv"
            scene = Path(work) / f"{tag}.toml"
            scene.write_text(SCENE.format(cells=cells, mode=mode, dt=dt, steps=steps,
                                          backend=backend, precision=precision, thermo=thermo))
            proc = subprocess.run([args.cellforce, "run", str(scene), "--quiet"],
                                  capture_output=True, text=True)
            n = 4 * cells ** 3
            label = f"{backend} {mode} dt={dt} {precision} N={n}"
            if proc.returncode != 0:
                with lock:
                    failed.append(f"{label}: {proc.stderr.strip()}")
                    write()
                print(f"failed: {label}: {proc.stderr.strip()}", flush=True)
                return
            drift, rms, change = drift_and_rms(thermo, n)
            rate = re.search(r"([0-9.]+) steps/s", proc.stdout)
            engine = re.search(r"steps; (.*), precision", proc.stdout)
            row = {"backend": backend, "precision": precision, "n": n, "steps": steps,
                   "dt": dt, "mode": mode, "drift_per_particle_per_time": drift,
                   "rms_per_particle": rms, "change_per_particle": change,
                   "steps_per_s": float(rate.group(1)) if rate else None,
                   "engine": engine.group(1) if engine else ""}
            with lock:
                rows.append(row)
                write()  # after every run: a run cut short by a time limit keeps what finished
            print(f"{label:44s} drift {drift:+.2e}  RMS {rms:.2e}  "
                  f"{row['steps_per_s']} steps/s  ({row['engine']})", flush=True)

        with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
            list(pool.map(one, runs))
        order = {r: k for k, r in enumerate(runs)}
        rows.sort(key=lambda r: order[(r["backend"], r["mode"], r["dt"], round((r["n"] / 4) ** (1 / 3)), r["precision"])])
        write()
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
