#!/usr/bin/env python3
"""The table (and plot) of validation/device/lammps_gpus.sh's runs: in.lj by cellforce-lammps on 1..G
GPUs of a host, with LAMMPS's lj/cut/opt and `cellforce run` beside it (validation/reports/lammps.md,
"Several GPUs").

Reads the runs.txt that script writes (each run's header line, exit status and LAMMPS's summary
lines) and prints a Markdown table: atoms, GPUs, ranks, ms a step, LAMMPS's breakdown (Pair: the
force engine with its copies; Comm; Modify: fix nve; Other), the pair's own account (compute_local
and the engine's stages, ms a call averaged over ranks), the ranks by GPU as the program reported
them, and for each size the speed-up over the fewest GPUs run at that size (strong scaling). With
--weak ATOMS_PER_GPU the runs whose atoms per GPU are within 5% of it form the weak-scaling rows
(efficiency: the one-GPU time over each time). --plot draws ms a step against GPUs (matplotlib).

  python3 validation/lammps_gpus_report.py runs.txt --md gpus.md [--weak 16.7e6] [--plot gpus.png]
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

SECTIONS = ("Pair", "Comm", "Modify", "Other")


def parse(text: str) -> list[dict]:
    runs, run = [], None
    for line in text.splitlines():
        if line.startswith("== "):
            run = {"header": line[3:]}
            runs.append(run)
            if m := re.match(r"== cellforce-lammps cuda (\w+): (\d+) GPUs \(([\d,]*)\), (\d+) ranks, cells (\d+), (\d+) steps",
                             line):
                run.update(engine="cellforce-lammps", precision=m[1], gpus=int(m[2]), ranks=int(m[4]),
                           cells=int(m[5]))
            elif m := re.match(r"== lammps lj/cut/opt: (\d+) ranks, cells (\d+), (\d+) steps", line):
                run.update(engine="lammps lj/cut/opt", gpus=0, ranks=int(m[1]), cells=int(m[2]))
            elif m := re.match(r"== cellforce run: 1 GPU, cells (\d+)", line):
                run.update(engine="cellforce run", gpus=1, ranks=1, cells=int(m[1]))
            continue
        if run is None:
            continue
        if m := re.match(r"exit (\d+)", line):
            run["exit"] = int(m[1])
        elif m := re.search(r"Loop time of ([\d.eE+-]+) on (\d+) procs for (\d+) steps with (\d+) atoms", line):
            run.update(loop=float(m[1]), steps=int(m[3]), atoms=int(m[4]))
        elif m := re.match(r"(Pair|Comm|Modify|Other)\s*\|\s*([\d.eE+-]+)?\s*\|\s*([\d.eE+-]+)", line):
            run[m[1]] = float(m[3])
        elif m := re.search(r"compute_local ([\d.]+) \(([\d.]+)\), of it the engine's stages ([\d.]+)", line):
            run.update(compute_local=float(m[1]), stages=float(m[3]))
        elif m := re.match(r"cellforce-lammps: ranks: (.*)", line):
            run["placement"] = m[1]
        elif m := re.match(r"ms per step ([\d.]+) forces ms per step ([\d.na]+)", line):
            run.update(ms=float(m[1]), atoms=4 * run["cells"] ** 3)
    for run in runs:
        if "loop" in run and run.get("steps"):
            run["ms"] = 1e3 * run["loop"] / run["steps"]
            for name in SECTIONS:
                if name in run:
                    run[name] = 1e3 * run[name] / run["steps"]
        run.setdefault("atoms", 4 * run["cells"] ** 3 if "cells" in run else 0)
    return runs


def number(v, digits=2) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", help="runs.txt of validation/device/lammps_gpus.sh")
    ap.add_argument("--md", required=True)
    ap.add_argument("--weak", type=float, help="atoms per GPU of the weak-scaling rows")
    ap.add_argument("--plot")
    args = ap.parse_args()
    runs = parse(Path(args.runs).read_text())
    done = [r for r in runs if "ms" in r]
    lines = ["| atoms | engine | GPUs | ranks | ms/step | Pair | Comm | Modify | Other | compute_local | stages | "
             "speed-up | ranks by GPU |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    fewest = {}
    for r in done:
        if r["engine"] == "cellforce-lammps":
            key = (r["atoms"], r["ranks"] // max(r["gpus"], 1))  # the same ranks a GPU
            if key not in fewest or r["gpus"] < fewest[key]["gpus"]:
                fewest[key] = r
    for r in sorted(done, key=lambda r: (r["atoms"], r["engine"], r["gpus"], r["ranks"])):
        base = fewest.get((r["atoms"], r["ranks"] // max(r["gpus"], 1))) if r["engine"] == "cellforce-lammps" else None
        speedup = base["ms"] / r["ms"] if base else None
        lines.append(f"| {r['atoms']:,} | {r['engine']} | {r['gpus'] or '-'} | {r['ranks']} | {number(r['ms'])} | "
                     + " | ".join(number(r.get(s)) for s in SECTIONS)
                     + f" | {number(r.get('compute_local'))} | {number(r.get('stages'))} | {number(speedup)} | "
                     f"{r.get('placement', '-')} |")
    failed = [r for r in runs if "ms" not in r]
    if failed:
        lines += ["", "Runs without a time (stopped or failed):"] + [f"- {r['header']} (exit {r.get('exit', '?')})"
                                                                      for r in failed]
    if args.weak:
        weak = [r for r in done if r["engine"] == "cellforce-lammps" and r["gpus"]
                and abs(r["atoms"] / r["gpus"] - args.weak) <= 0.05 * args.weak]
        one = {r["ranks"] // r["gpus"]: r for r in weak if r["gpus"] == 1}
        lines += ["", f"Weak scaling, about {args.weak:,.0f} atoms a GPU:", "",
                  "| GPUs | ranks | atoms | ms/step | efficiency |", "|---|---|---|---|---|"]
        for r in sorted(weak, key=lambda r: (r["ranks"] // r["gpus"], r["gpus"])):
            ref = one.get(r["ranks"] // r["gpus"])
            lines.append(f"| {r['gpus']} | {r['ranks']} | {r['atoms']:,} | {number(r['ms'])} | "
                         f"{number(ref['ms'] / r['ms'] if ref else None)} |")
    Path(args.md).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    if args.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(6, 4))
        series = {}
        for r in done:
            if r["engine"] == "cellforce-lammps":
                series.setdefault((r["atoms"], r["ranks"] // r["gpus"]), []).append((r["gpus"], r["ms"]))
        for (atoms, per), points in sorted(series.items()):
            points.sort()
            ax.plot([p[0] for p in points], [p[1] for p in points], "o-", label=f"{atoms:,} atoms, {per} ranks a GPU")
        ax.set_xlabel("GPUs")
        ax.set_ylabel("ms a step")
        ax.set_yscale("log")
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)
    return 0


if __name__ == "__main__":
    sys.exit(main())
