#!/usr/bin/env python3
"""The table (and plot) of validation/device/lammps_gpus.sh's runs: in.lj by cellforce-lammps on 1..G
GPUs of a host, with LAMMPS's lj/cut/opt and `cellforce run` beside it (validation/reports/lammps.md,
"Several GPUs").

Reads the runs.txt that script writes (each run's header line, exit status and LAMMPS's summary
lines) and prints a Markdown table: atoms, GPUs, ranks, ms a step, LAMMPS's breakdown (Pair: the
force engine with its copies; Comm; Modify: fix nve; Other), the pair's own account (compute_local
and the engine's stages, ms a call averaged over ranks), the ranks by GPU as the program reported
them, for each size the speed-up over the fewest GPUs run at that size with as many ranks a GPU in
the same runs file (strong scaling; "-" where only one GPU count was run), and E_pair's largest
relative difference from LAMMPS's lj/cut/opt run of the same size over the thermo steps both printed
(every decomposition must agree with it; mixed precision keeps it to a few 1e-8). The script exits 1,
naming the run, where a run has no time (stopped or failed) or a nonzero exit, misses a thermo row
(every 10 steps and the last: a row of nan is no row) or differs from LAMMPS's E_pair by more than
1e-6. With --weak ATOMS_PER_GPU the runs whose atoms per GPU are within 5% of it form the
weak-scaling rows (efficiency: the one-GPU time over each time, in the same runs file). --plot draws
ms a step against GPUs with the ideal and the baselines, beside the weak-scaling efficiency
(matplotlib).

  python3 validation/lammps_gpus_report.py runs.txt [more.txt ...] --md gpus.md [--weak 16.7e6] [--plot gpus.png]
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lammps_scaling import parse_log, thermo_rows  # noqa: E402

SECTIONS = ("Pair", "Comm", "Modify", "Other")


def parse(text: str) -> list[dict]:
    """The runs of runs.txt: each block from a "== " header to the next, its header's settings and
    LAMMPS's summary as lammps_scaling.parse_log reads it."""
    runs = []
    for block in re.split(r"^(?=== )", text, flags=re.M):
        if not block.startswith("== "):
            continue
        header = block.splitlines()[0]
        run = {"header": header[3:]}
        runs.append(run)
        if m := re.match(r"== cellforce-lammps cuda (\w+): (\d+) GPUs \(([\d,]*)\), (\d+) ranks, cells (\d+), (\d+) steps",
                         header):
            run.update(engine="cellforce-lammps", precision=m[1], gpus=int(m[2]), ranks=int(m[4]), cells=int(m[5]),
                       steps=int(m[6]))
        elif m := re.match(r"== lammps lj/cut/opt: (\d+) ranks, cells (\d+), (\d+) steps", header):
            run.update(engine="lammps lj/cut/opt", gpus=0, ranks=int(m[1]), cells=int(m[2]), steps=int(m[3]))
        elif m := re.match(r"== cellforce run: 1 GPU, cells (\d+)", header):
            run.update(engine="cellforce run", gpus=1, ranks=1, cells=int(m[1]))
        run["atoms"] = 4 * run["cells"] ** 3 if "cells" in run else 0
        if m := re.search(r"^exit (\d+)", block, re.M):
            run["exit"] = int(m[1])
        if m := re.search(r"^ms per step ([\d.]+) forces ms per step", block, re.M):  # cellforce run
            run["ms"] = float(m[1])
            continue
        try:
            log = parse_log(block)
        except RuntimeError:  # no loop time: stopped or failed
            continue
        run.update(ms=log["ms_per_step"], atoms=log["atoms"], thermo=thermo_rows(block))
        for name in SECTIONS:
            run[name] = log.get(f"{name.lower()}_ms_per_step")
        if m := re.search(r"compute_local ([\d.]+) \(([\d.]+)\), of it the engine's stages ([\d.]+)", block):
            run.update(compute_local=float(m[1]), stages=float(m[3]))
        if m := re.search(r"^cellforce-lammps: ranks: (.*)$", block, re.M):
            run["placement"] = m[1]
    return runs


def number(v, digits=2) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="runs.txt of validation/device/lammps_gpus.sh (one or more)")
    ap.add_argument("--md", required=True)
    ap.add_argument("--weak", type=float, help="atoms per GPU of the weak-scaling rows")
    ap.add_argument("--plot")
    args = ap.parse_args()
    runs = []
    for index, name in enumerate(args.runs):
        for run in parse(Path(name).read_text()):
            runs.append(dict(run, file=index))
    done = [r for r in runs if "ms" in r]
    problems = [f"{r['header']}: no time (stopped or failed; exit {r.get('exit', '?')})" for r in runs if "ms" not in r]
    problems += [f"{r['header']}: exit {r['exit']}" for r in done if r.get("exit", 0) != 0]
    for r in done:
        if "steps" in r and r["engine"] != "cellforce run":
            missing = sorted((set(range(0, r["steps"] + 1, 10)) | {r["steps"]}) - set(r.get("thermo", {})))
            if missing:
                problems.append(f"{r['header']}: no thermo row (or not a number) at steps {missing}")
    lines = ["| atoms | engine | GPUs | ranks | ms/step | Pair | Comm | Modify | Other | compute_local | stages | "
             "speed-up | E_pair vs LAMMPS | ranks by GPU |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    lammps = {r["atoms"]: r for r in done if r["engine"] == "lammps lj/cut/opt"}
    fewest, counts = {}, {}

    def key(r):  # the same runs file, size and ranks a GPU
        return r["file"], r["atoms"], r["ranks"] // max(r["gpus"], 1)

    for r in done:
        if r["engine"] == "cellforce-lammps":
            counts.setdefault(key(r), set()).add(r["gpus"])
            if key(r) not in fewest or r["gpus"] < fewest[key(r)]["gpus"]:
                fewest[key(r)] = r
    for r in sorted(done, key=lambda r: (r["atoms"], r["engine"], r["file"], r["gpus"], r["ranks"])):
        mine = r["engine"] == "cellforce-lammps"
        speedup = fewest[key(r)]["ms"] / r["ms"] if mine and len(counts[key(r)]) > 1 else None
        agree = None
        if mine and r["atoms"] in lammps:
            theirs = lammps[r["atoms"]]["thermo"]
            steps = sorted(set(r["thermo"]) & set(theirs))
            if steps:  # E_pair, the second column after Step
                agree = max(abs(r["thermo"][k][1] - theirs[k][1]) / max(abs(theirs[k][1]), 1e-300) for k in steps)
                if agree > 1e-6:
                    problems.append(f"{r['header']}: E_pair {agree:.1e} relative from LAMMPS's (> 1e-6)")
        lines.append(f"| {r['atoms']:,} | {r['engine']} | {r['gpus'] or '-'} | {r['ranks']} | {number(r['ms'])} | "
                     + " | ".join(number(r.get(s)) for s in SECTIONS)
                     + f" | {number(r.get('compute_local'))} | {number(r.get('stages'))} | {number(speedup)} | "
                     f"{'-' if agree is None else f'{agree:.1e}'} | {r.get('placement', '-')} |")
    if problems:
        lines += ["", "Problems:"] + [f"- {p}" for p in problems]
    if args.weak:
        weak = [r for r in done if r["engine"] == "cellforce-lammps" and r["gpus"]
                and abs(r["atoms"] / r["gpus"] - args.weak) <= 0.05 * args.weak]
        one = {(r["file"], r["ranks"] // r["gpus"]): r for r in weak if r["gpus"] == 1}
        lines += ["", f"Weak scaling, about {args.weak:,.0f} atoms a GPU:", "",
                  "| GPUs | ranks | atoms | ms/step | efficiency |", "|---|---|---|---|---|"]
        for r in sorted(weak, key=lambda r: (r["file"], r["ranks"] // r["gpus"], r["gpus"])):
            ref = one.get((r["file"], r["ranks"] // r["gpus"]))
            lines.append(f"| {r['gpus']} | {r['ranks']} | {r['atoms']:,} | {number(r['ms'])} | "
                         f"{number(ref['ms'] / r['ms'] if ref else None)} |")
    Path(args.md).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    if args.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        # left: strong scaling (sizes run on more than one GPU count; the first runs file's where it
        # repeats), the ideal dotted grey, LAMMPS's lj/cut/opt on the host's cores (dash-dot) and
        # `cellforce run` on one GPU (dotted) as levels; right: weak scaling's efficiency
        fig, (strong, weak_ax) = plt.subplots(1, 2, figsize=(10, 4.2))
        first = {}  # the first runs file holding each size and ranks a GPU
        for r in done:
            if r["engine"] == "cellforce-lammps":
                first[key(r)[1:]] = min(first.get(key(r)[1:], r["file"]), r["file"])
        series = {}
        for r in done:
            if r["engine"] == "cellforce-lammps" and r["file"] == first[key(r)[1:]]:
                series.setdefault(key(r)[1:], []).append((r["gpus"], r["ms"]))
        gpus_run = sorted({r["gpus"] for r in done if r["engine"] == "cellforce-lammps"})
        sizes = sorted({atoms for (atoms, _), points in series.items() if len({g for g, _ in points}) > 1})
        colours = dict(zip(sizes, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
        for (atoms, per), points in sorted(series.items()):
            if atoms not in colours:
                continue
            points.sort()
            strong.plot([g for g, _ in points], [ms for _, ms in points], {1: "s--", 8: "^-."}.get(per, "o-"),
                                color=colours[atoms], label=f"{atoms / 1e6:.1f}M atoms, {per} rank(s) a GPU")
            strong.plot(gpus_run, [points[0][1] * points[0][0] / g for g in gpus_run], ":", color="grey", lw=0.8)
        for r in done:
            if r["atoms"] in colours and r["engine"] in ("lammps lj/cut/opt", "cellforce run"):
                strong.axhline(r["ms"], color=colours[r["atoms"]], lw=0.8, ls="-." if r["gpus"] == 0 else (0, (1, 3)))
                where = f"lj/cut/opt, {r['ranks']} cores" if r["gpus"] == 0 else "cellforce run, 1 GPU"
                strong.annotate(f"{r['atoms'] / 1e6:.1f}M {where}", (gpus_run[0], r["ms"]), fontsize=7,
                                ha="left", va="bottom", color=colours[r["atoms"]])
        strong.set_xticks(gpus_run)
        strong.set_xlabel("GPUs")
        strong.set_ylabel("ms a step")
        strong.set_yscale("log")
        strong.set_title("strong scaling (grey: ideal)", fontsize=9)
        strong.legend(fontsize=7)
        if args.weak:
            by_per = {}
            for r in weak:
                ref = one.get((r["file"], r["ranks"] // r["gpus"]))
                if ref and r["file"] == min(f for f, per in one if per == r["ranks"] // r["gpus"]):
                    by_per.setdefault(r["ranks"] // r["gpus"], []).append((r["gpus"], ref["ms"] / r["ms"]))
            for per, points in sorted(by_per.items()):
                if len(points) > 1:
                    points.sort()
                    weak_ax.plot([g for g, _ in points], [e for _, e in points], "o-", label=f"{per} rank(s) a GPU")
            weak_ax.axhline(0.8, color="grey", ls=":", lw=0.8)
            weak_ax.set_ylim(0, 1.05)
            weak_ax.set_xticks(gpus_run)
            weak_ax.set_xlabel("GPUs")
            weak_ax.set_ylabel("efficiency")
            weak_ax.set_title(f"weak scaling, {args.weak / 1e6:.1f}M atoms a GPU (grey: 0.8)", fontsize=9)
            weak_ax.legend(fontsize=7)
        else:
            weak_ax.set_axis_off()
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)
    for p in problems:
        print(f"lammps_gpus_report: {p}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
