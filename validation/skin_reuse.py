"""Skin reuse in `cellforce run`: speed against the skin, and what it does to energy conservation.

For each backend x precision x skin, runs the LJ liquid (fcc at density 0.8442, T0 = 1.44, rc 2.5
truncated, dt 0.005, NVE) for --steps steps with `[neighbor] skin`, and reports the builds of the
cell structure (stages 1-3), steps per build, time per step and the speed-up over skin 0, with
the drift and RMS fluctuation of E_total/N from the thermo CSV (the error side: reuse is exact,
so these must match skin 0 to the run's own noise). With --audit, every reused step also counts
missed and repeated pairs against a fresh host search (slow: use small systems).

    python validation/skin_reuse.py --cellforce build/cellforce [--backends cpu cuda]
        [--precisions double mixed] [--cells 20] [--steps 2000] [--skins 0 0.1 0.2 0.3 0.4 0.5]
        [--audit] --json out.json [--md table.md]

Runs one at a time (timings). Exit status: 0 when every run finished, 1 when one failed.
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import lj
from nve_drift import SCENE, drift_and_rms  # the same liquid; [neighbor] is appended



def parse(stdout: str) -> dict:
    def grab(pattern, cast=float):
        m = re.search(pattern, stdout)
        return cast(m.group(1)) if m else None
    return {
        "steps_per_s": grab(r"([0-9.]+) steps/s"),
        "ms_per_step": grab(r"([0-9.]+) ms per step"),
        "forces_ms_per_step": grab(r"per step \(ms\): forces ([0-9.]+)"),
        "builds": grab(r"neighbour structure: .*?(\d+) builds", int),
        "evaluations": grab(r"builds in (\d+) evaluations", int),
        "max_reused_displacement": grab(r"largest displacement served ([0-9.eE+-]+)"),
        "missed_pairs": grab(r"missed pairs (\d+)", int),
        "repeated_pairs": grab(r"repeated pairs (\d+)", int),
        "engine": grab(r"steps; (.*), precision", str) or "",
        # per force evaluation, ms: stages 1-3 (cell IDs incl. count, sort, collision cells), traversal
        "build_ms_per_evaluation": sum(grab(p) or 0.0 for p in (r"cell IDs ([0-9.]+)", r"sort ([0-9.]+)",
                                                                 r"collision cells ([0-9.]+)")),
        "traversal_ms_per_evaluation": grab(r"traversal ([0-9.]+)"),
    }


def table(rows: list[dict]) -> str:
    out = ["| backend | precision | N | skin | builds | steps per build | stages 1-3, ms per evaluation "
           "| traversal, ms per evaluation | ms per step | speed-up vs skin 0 "
           "| drift of E/N per unit time | RMS of E/N | missed, repeated pairs |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    zero: dict = {}
    for r in rows:
        if r["skin"] == 0 and r["ms_per_step"]:
            zero.setdefault((r["backend"], r["precision"], r["n"]), []).append(r["ms_per_step"])
    base = {k: sum(v) / len(v) for k, v in zero.items()}  # the mean of the skin-0 runs
    for r in rows:
        ref = base.get((r["backend"], r["precision"], r["n"]))
        speed = f"{ref / r['ms_per_step']:.2f}" if ref and r["ms_per_step"] else "-"
        per_build = f"{r['steps'] / max(1, r['builds']):.1f}"
        audit = (f"{r['missed_pairs']}, {r['repeated_pairs']}" if r.get("missed_pairs") is not None else "not audited")
        out.append(f"| {r['backend']} | {r['precision']} | {r['n']} | {r['skin']:g} | {r['builds']} | {per_build} "
                   f"| {r.get('build_ms_per_evaluation', float('nan')):.3f} "
                   f"| {r.get('traversal_ms_per_evaluation') or float('nan'):.3f} "
                   f"| {r['ms_per_step']:.3f} | {speed} | {r['drift']:+.2e} | {r['rms']:.2e} | {audit} |")
    return "\n".join(out) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cellforce", required=True)
    parser.add_argument("--backends", nargs="+", choices=["cpu", "cuda"], default=["cpu"])
    parser.add_argument("--precisions", nargs="+", choices=["single", "mixed", "double"], default=["double"])
    parser.add_argument("--cells", type=int, default=20)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--skins", type=float, nargs="+", default=[0, 0.1, 0.2, 0.3, 0.4, 0.5])
    parser.add_argument("--audit", action="store_true")
    parser.add_argument("--device", default="", help="machine label stored in the JSON")
    parser.add_argument("--json", type=Path, required=True)
    parser.add_argument("--md", type=Path, default=None)
    parser.add_argument("--repeats", type=int, default=1, help="runs of each skin (interleaved), for the spread")
    args = parser.parse_args()
    rows, failed = [], []
    n = 4 * args.cells ** 3

    def write():
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({
            "command": " ".join(["python", *sys.argv]), "revision": lj.source_revision(),
            "device": args.device,
            "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "failed": failed, "rows": rows}, indent=1))
        if args.md:
            args.md.write_text(table(rows))

    with tempfile.TemporaryDirectory(prefix="cellforce-skin-") as work:
        for backend in args.backends:
            for precision in args.precisions:
                for skin in [k for _ in range(args.repeats) for k in args.skins]:
                    tag = f"{backend}_{precision}_{skin}_{len(rows)}"
                    thermo = Path(work) / f"{tag}.csv"
                    scene = Path(work) / f"{tag}.toml"
                    # Always a length: a scene without one gets skin auto (pair lists on CUDA).
                    neighbor = f"[neighbor]\nskin = {skin}" + (f"\naudit = {str(args.audit).lower()}" if skin > 0 else "")
                    scene.write_text(SCENE.format(cells=args.cells, mode="truncate", dt=0.005, steps=args.steps,
                                                  backend=backend, precision=precision, thermo=thermo)
                                     + neighbor + "\n")
                    proc = subprocess.run([args.cellforce, "run", str(scene), "--quiet"],
                                          capture_output=True, text=True)
                    label = f"{backend} {precision} N={n} skin={skin:g}"
                    if proc.returncode != 0:
                        failed.append(f"{label}: {proc.stderr.strip()}")
                        print(f"failed: {label}: {proc.stderr.strip()}", flush=True)
                        write()
                        continue
                    drift, rms, _ = drift_and_rms(thermo, n)
                    row = {"backend": backend, "precision": precision, "n": n, "steps": args.steps,
                           "skin": skin, "drift": drift, "rms": rms, **parse(proc.stdout)}
                    if row["builds"] is None:  # skin 0 prints no reuse line: one build per step
                        row["builds"] = args.steps
                    rows.append(row)
                    write()
                    print(f"{label:36s} builds {row['builds']}  {row['ms_per_step']} ms/step  "
                          f"drift {drift:+.2e}  RMS {rms:.2e}", flush=True)
    write()
    if args.md:
        print(table(rows))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
