#!/usr/bin/env python3
"""Time LAMMPS's in.lj (systems/lammps/in.lj) run by `cellforce-lammps` (cellforce computing
pair_style lj/cut on every rank) and by LAMMPS's own `lmp -sf opt` (lj/cut/opt), over MPI ranks, in
one call on one machine; and with cellforce's CUDA backend against `cellforce run` of the same
system (validation/md_peer.py's scene).

Every run is the script unchanged but for its variables: `-var cells C -var steps S -var every 1
-var check yes` (neighbour lists and ghosts rebuilt whenever an atom moved half the skin: both
engines exact; LAMMPS's benchmark settings `every 20 check no` miss pairs). The times are LAMMPS's
own: its loop time and the MPI task timing breakdown (Pair = the force engine, host <-> device copies
included; Neigh; Comm; Modify = fix nve; Output; Other). The last thermo row's E_pair of each
cellforce run is compared with LAMMPS's own run (CPU rows: at the same ranks, to 1e-8; GPU rows, mixed
precision: LAMMPS's run on all cores, to 1e-3); a larger difference fails the script.

Rows (see --help): `cpu` — every rank count in --ranks, for each size in --cpu-cells, three runs:
LAMMPS lj/cut/opt (one core a rank), cellforce-lammps CPU backend with one thread a rank (the same
cores), and cellforce-lammps with the node's cores shared among its ranks (cores / ranks threads);
`gpu` — for each size in --gpu-cells, cellforce-lammps CUDA backend on 1..R ranks sharing the one
GPU, `cellforce run` on the CUDA backend, and LAMMPS lj/cut/opt on all cores.

  python3 validation/lammps_scaling.py --cellforce-lammps build/cellforce-lammps --lmp lmp \\
      --cellforce build/cellforce --md lammps.md --json lammps.json
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import re
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from md_peer import cellforce_steps_per_second  # noqa: E402

SCRIPT = HERE.parent / "systems" / "lammps" / "in.lj"
SECTIONS = ("Pair", "Neigh", "Comm", "Output", "Modify", "Other")


def thermo_rows(text: str) -> dict[int, list[float]]:
    """The thermo rows of a LAMMPS output (Step Temp E_pair E_mol TotEng Press) by step: the other five
    columns."""
    rows = re.findall(r"^\s*(\d+)\s+([-0-9.eE+]+)\s+([-0-9.eE+]+)\s+([-0-9.eE+]+)\s+([-0-9.eE+]+)\s+([-0-9.eE+]+)\s*$",
                      text, re.M)
    return {int(r[0]): [float(v) for v in r[1:]] for r in rows}


def parse_log(text: str) -> dict:
    """LAMMPS's summary of a run: loop time, ranks, steps, atoms, the timing breakdown (avg seconds) and
    the last thermo row (Step Temp E_pair E_mol TotEng Press)."""
    m = re.search(r"Loop time of ([0-9.eE+-]+) on (\d+) procs for (\d+) steps with (\d+) atoms", text)
    if not m:
        raise RuntimeError("no 'Loop time' line in LAMMPS's output")
    row = {"loop_seconds": float(m.group(1)), "ranks": int(m.group(2)), "steps": int(m.group(3)),
           "atoms": int(m.group(4))}
    row["ms_per_step"] = 1e3 * row["loop_seconds"] / max(row["steps"], 1)
    for name in SECTIONS:
        s = re.search(rf"^{name}\s*\|\s*([0-9.eE+-]+)?\s*\|\s*([0-9.eE+-]+)", text, re.M)
        if s:
            row[f"{name.lower()}_ms_per_step"] = 1e3 * float(s.group(2)) / max(row["steps"], 1)
    rows = thermo_rows(text[:m.start()])
    if rows:
        step = max(rows)
        temp, epair, _, etotal, press = rows[step]
        row.update({"last_step": step, "temperature": temp, "e_pair": epair, "total_energy": etotal,
                    "pressure": press})
    line = re.search(r"^cellforce-lammps: rank 0 computes on .*$", text, re.M)
    if line:
        row["engine"] = line.group(0)
    return row


def run_lammps(mpirun: list[str], ranks: int, program: list[str], cells: int, steps: int, env: dict, folder: Path,
               binding: list[str], log: Path, timeout: float) -> dict:
    command = [*mpirun, "-np", str(ranks), *binding, *program, "-in", str(SCRIPT), "-var", "cells", str(cells),
               "-var", "steps", str(steps), "-var", "every", "1", "-var", "check", "yes", "-log", "none"]
    try:
        p = subprocess.run(command, capture_output=True, text=True, cwd=folder, env={**os.environ, **env},
                           timeout=timeout)
        out, rc = p.stdout + p.stderr, p.returncode
    except subprocess.TimeoutExpired as e:  # its partial output comes as bytes
        def text(b) -> str:
            return b.decode(errors="replace") if isinstance(b, bytes) else (b or "")
        out, rc = f"{text(e.stdout)}{text(e.stderr)}\n[timed out after {timeout} s]", 124
    with open(log, "a") as f:
        f.write(f"$ {' '.join(f'{k}={v}' for k, v in env.items())} {shlex.join(command)}\n{out}\n[exit {rc}]\n\n")
    row = {"command": shlex.join(command), "env": env}
    try:
        row.update(parse_log(out))
    except RuntimeError as e:
        row["error"] = f"{e} (exit {rc}): {out.strip()[-600:]}"
    if rc != 0 and "error" not in row:
        row["error"] = f"exit {rc}: {out.strip()[-600:]}"
    return row


def cores() -> int:
    return len(os.sched_getaffinity(0))


def fmt(v, digits=2) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.{digits}f}" if isinstance(v, float) else str(v)


def sci(v) -> str:
    return "-" if v is None else f"{v:.1e}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cellforce-lammps", required=True)
    ap.add_argument("--lmp", required=True, help="LAMMPS's own binary (the baseline)")
    ap.add_argument("--cellforce", help="the cellforce CLI, for `cellforce run` beside the GPU rows")
    ap.add_argument("--mpirun", default="mpirun", help="the MPI launcher with its own flags")
    ap.add_argument("--cpu-cells", type=int, nargs="*", default=[20, 40], help="fcc cells per axis (4 C^3 atoms)")
    ap.add_argument("--cpu-steps", type=int, nargs="*", default=[200, 100], help="steps, one per --cpu-cells")
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    ap.add_argument("--gpu-cells", type=int, nargs="*", default=[])
    ap.add_argument("--gpu-steps", type=int, nargs="*", default=[], help="steps, one per --gpu-cells")
    ap.add_argument("--gpu-ranks", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--gpu-precision", default="mixed")
    ap.add_argument("--timeout", type=float, default=300)
    ap.add_argument("--md", required=True)
    ap.add_argument("--json", required=True)
    ap.add_argument("--log", default=None, help="every command and its output (default: beside --json)")
    args = ap.parse_args()
    if len(args.cpu_steps) != len(args.cpu_cells) or len(args.gpu_steps) != len(args.gpu_cells):
        ap.error("give one step count for each size")

    mpirun = shlex.split(args.mpirun)
    log = Path(args.log or Path(args.json).with_suffix(".log"))
    log.write_text("")
    ncores = cores()
    core_binding = ["--bind-to", "core", "--map-by", "core"]
    rows, failed = [], False
    lmp = [args.lmp, "-sf", "opt"]
    ours = [args.cellforce_lammps]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for cells, steps in zip(args.cpu_cells, args.cpu_steps):
            for ranks in args.ranks:
                runs = [("lammps lj/cut/opt", lmp, {}, core_binding),
                        ("cellforce cpu, 1 thread a rank", ours,
                         {"CELLFORCE_BACKEND": "cpu", "CELLFORCE_PRECISION": "double", "CELLFORCE_THREADS": "1",
                          "OMP_NUM_THREADS": "1"}, core_binding)]
                if ranks < ncores:
                    per = max(1, ncores // ranks)
                    runs.append((f"cellforce cpu, {per} threads a rank", ours,
                                 {"CELLFORCE_BACKEND": "cpu", "CELLFORCE_PRECISION": "double",
                                  "CELLFORCE_THREADS": str(per), "OMP_NUM_THREADS": str(per)},
                                 ["--bind-to", "core", "--map-by", f"slot:PE={per}"]))
                for name, program, env, binding in runs:
                    row = run_lammps(mpirun, ranks, program, cells, steps, env, folder, binding, log, args.timeout)
                    row.update({"table": "cpu", "run": name, "cells": cells, "np": ranks, "threads":
                                int(env.get("CELLFORCE_THREADS", "1"))})
                    rows.append(row)
                    failed |= "error" in row
                    print(f"cpu {cells} {ranks} {name}: {fmt(row.get('ms_per_step'))} ms/step {row.get('error', '')}",
                          flush=True)
        for cells, steps in zip(args.gpu_cells, args.gpu_steps):
            for ranks in args.gpu_ranks:
                env = {"CELLFORCE_BACKEND": "cuda", "CELLFORCE_PRECISION": args.gpu_precision,
                       "CELLFORCE_THREADS": "1", "OMP_NUM_THREADS": "1"}
                row = run_lammps(mpirun, ranks, ours, cells, steps, env, folder, core_binding, log, args.timeout)
                row.update({"table": "gpu", "run": "cellforce-lammps cuda", "cells": cells, "np": ranks})
                rows.append(row)
                failed |= "error" in row
                print(f"gpu {cells} {ranks}: {fmt(row.get('ms_per_step'))} ms/step {row.get('error', '')}", flush=True)
            row = run_lammps(mpirun, ncores, lmp, cells, steps, {}, folder, core_binding, log,
                             args.timeout)
            row.update({"table": "gpu", "run": "lammps lj/cut/opt", "cells": cells, "np": ncores})
            rows.append(row)
            failed |= "error" in row
            if args.cellforce:
                n = 4 * cells ** 3
                row = {"table": "gpu", "run": "cellforce run", "cells": cells, "np": 1, "atoms": n}
                try:
                    r = cellforce_steps_per_second(args.cellforce, cells, args.gpu_precision, max(steps, 1000), folder)
                    row.update({"ms_per_step": r["ms_per_step"], "steps": r["steps"],
                                "pair_ms_per_step": r["forces_ms_per_step"], "summary": r["summary"]})
                except RuntimeError as e:
                    row["error"] = str(e)
                    failed = True
                rows.append(row)

    # E_pair at the last step against LAMMPS's own run of the same size: at the same ranks in the CPU
    # table, at any ranks in the GPU table (LAMMPS runs there on all cores only)
    reference = {(r["table"], r["cells"], r["np"] if r["table"] == "cpu" else 0, r.get("last_step")): r.get("e_pair")
                 for r in rows if r["run"].startswith("lammps") and "e_pair" in r}
    for r in rows:
        ref = reference.get((r["table"], r["cells"], r["np"] if r["table"] == "cpu" else 0, r.get("last_step")))
        if ref and "e_pair" in r and not r["run"].startswith("lammps"):
            r["e_pair_rel_diff"] = abs(r["e_pair"] - ref) / abs(ref)
            # a wrong energy fails the script: double on the same ranks agrees to rounding; mixed, after
            # chaos has had the run's steps to part the trajectories, to far better than 1e-3
            limit = 1e-8 if r["table"] == "cpu" else 1e-3
            if r["e_pair_rel_diff"] > limit:
                r["error"] = f"E_pair {r['e_pair']} differs from LAMMPS's {ref} by {r['e_pair_rel_diff']:.1e} (> {limit:g})"
                failed = True

    device = ""
    if args.gpu_cells:
        try:
            device = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                                    text=True).stdout.strip()
        except OSError:
            device = "(nvidia-smi not found)"
    cpu_model = next((line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")),
                     "?")
    md = [f"Run {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC on {ncores} cores ({cpu_model})"
          + (f" and {device}" if device else "") + ".", ""]
    by = {}
    for r in rows:
        by.setdefault((r["table"], r["cells"], r["np"]), {})[r["run"]] = r
    if args.cpu_cells:
        md += ["| atoms | ranks | LAMMPS lj/cut/opt ms/step | cellforce 1 thread a rank ms/step | ratio | "
               "cellforce cores/ranks threads ms/step | ratio | E_pair vs LAMMPS |",
               "|---|---|---|---|---|---|---|---|"]
        for cells in args.cpu_cells:
            for ranks in args.ranks:
                runs = by.get(("cpu", cells, ranks), {})
                base = runs.get("lammps lj/cut/opt", {})
                one = runs.get("cellforce cpu, 1 thread a rank", {})
                many = next((v for k, v in runs.items() if k.startswith("cellforce cpu,") and k != "cellforce cpu, 1 thread a rank"), {})
                b = base.get("ms_per_step")
                md.append(f"| {4 * cells ** 3:,} | {ranks} | {fmt(b)} | {fmt(one.get('ms_per_step'))} | "
                          f"{fmt(b / one['ms_per_step'] if b and one.get('ms_per_step') else None)} | "
                          f"{fmt(many.get('ms_per_step'))}{' (' + str(many.get('threads')) + ')' if many else ''} | "
                          f"{fmt(b / many['ms_per_step'] if b and many.get('ms_per_step') else None)} | "
                          f"{sci(one.get('e_pair_rel_diff'))} |")
        md += ["", "ratio: LAMMPS's time over cellforce's (above 1: cellforce faster).", ""]
    if args.gpu_cells:
        md += ["| atoms | run | ranks | ms/step | Pair | Neigh | Comm | Modify | Other | E_pair vs LAMMPS |",
               "|---|---|---|---|---|---|---|---|---|---|"]
        for cells in args.gpu_cells:
            for r in [r for r in rows if r["table"] == "gpu" and r["cells"] == cells]:
                md.append(f"| {4 * cells ** 3:,} | {r['run']} | {r['np']} | {fmt(r.get('ms_per_step'), 3)} | "
                          + " | ".join(fmt(r.get(f"{s.lower()}_ms_per_step"), 3) for s in
                                       ("Pair", "Neigh", "Comm", "Modify", "Other"))
                          + f" | {sci(r.get('e_pair_rel_diff'))} |")
        md += ["", "Pair ... Other: LAMMPS's timing breakdown, ms a step (avg over ranks); `cellforce run`'s Pair "
               "is its forces' device time a step.", ""]
    errors = [f"- {r['table']} {r['cells']} np {r['np']} {r['run']}: {r['error']}" for r in rows if "error" in r]
    if errors:
        md += ["Failed runs:", *errors, ""]
    Path(args.md).write_text("\n".join(md))
    Path(args.json).write_text(json.dumps({"cores": ncores, "cpu": cpu_model, "device": device, "rows": rows},
                                          indent=1))
    print("\n".join(md))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
