#!/usr/bin/env python3
r"""Where an MD step's device time goes: every kernel of a window of `cellforce bench` steps, timed
by Nsight Compute (at its base clocks, or the GPU's own with --clock-control none; kernels
serialised), summed per kernel and divided by the steps in the window (the launches of the kick-drift kernels, gated or not: one per Verlet step).

  python3 validation/step_profile.py --cellforce build-gpu-bin/cellforce --sizes 32000 1048576 --out $OUT
  (--bench-args="--skin 0.6 --neighbor-list": the configuration, as `cellforce bench` takes it)

Each row: the kernel (its name without template arguments), launches in the window, us per step
(its total / steps), us per launch (median), and DRAM bytes per launch over the duration (GB/s),
so that a kernel can be set against its bandwidth floor. The list build's passes (`list_rows`)
run once per build: their us per step is their cost spread over the steps a build serves.
Writes step_profile.md and step_profile.json to --out.
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import re
import shlex
import statistics
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

METRICS = ["gpu__time_duration.sum", "dram__bytes.sum"]


def short_name(name: str) -> str:
    """`void ns::kernel<T, ...>(args)` -> `kernel`."""
    full = name
    name = re.sub(r"\(.*$", "", name.replace("(anonymous namespace)", "anon"))
    depth, out = 0, []
    for ch in name:  # drop template arguments, nested ones too
        if ch == "<":
            depth += 1
        elif ch == ">":
            depth = max(depth - 1, 0)  # `unnamed>::` in ncu's short form
        elif depth == 0:
            out.append(ch)
    base = "".join(out).split()[-1].split("::")[-1]
    if base == "list_rows":  # the build's passes apart: list_rows<Traits, Fill, Real, Accum>
        args, depth, cur = [], 0, ""
        inner = full[full.find("list_rows<") + len("list_rows<"):]
        for ch in inner:
            if ch in "<(":
                depth += 1
            elif ch in ">)":
                if depth == 0:
                    break
                depth -= 1
            if ch == "," and depth == 0:
                args.append(cur.strip())
                cur = ""
            else:
                cur += ch
        args.append(cur.strip())
        if len(args) > 1:  # its ListPass, as Nsight Compute prints it: 0, 1, 2
            base += {"0": " (count)", "1": " (mirrored)", "2": " (fill)"}.get(args[1][-1:], f" ({args[1]})")
    return base


def profile(binary: str, n: int, steps: int, skip: int, count: int, extra: list[str], clocks: str = "base") -> dict:
    command = ["ncu", "--clock-control", clocks, "--launch-skip", str(skip), "--launch-count", str(count),
               "--metrics", ",".join(METRICS),
               "--csv", binary, "bench", "--sizes", str(n), "--backend", "cuda", "--steps", str(steps),
               "--warmup", "5", "--samples", "2", "--no-reference"] + extra
    p = subprocess.run(command, capture_output=True, text=True, timeout=550)
    text = p.stdout[p.stdout.find('"ID"'):] if '"ID"' in p.stdout else ""
    launches: dict[str, dict] = defaultdict(dict)
    for rec in csv.DictReader(io.StringIO(text)):
        unit, value = rec.get("Metric Unit", ""), float(rec["Metric Value"].replace(",", "") or 0)
        scale = {"ns": 1e-3, "us": 1.0, "usecond": 1.0, "ms": 1e3, "msecond": 1e3, "nsecond": 1e-3,
                 "byte": 1.0, "Kbyte": 1e3, "Mbyte": 1e6, "Gbyte": 1e9}.get(unit, 1.0)
        entry = launches[rec["ID"]]
        entry["kernel"] = short_name(rec["Kernel Name"])
        entry[rec["Metric Name"]] = value * scale
    if not launches:
        return {"n": n, "error": f"ncu exit {p.returncode}: {(p.stderr or p.stdout).strip()[-400:]}"}
    per: dict[str, list[dict]] = defaultdict(list)
    for entry in launches.values():
        per[entry["kernel"]].append(entry)
    # A Verlet step launches one kick-drift kernel: the gated one, or the plain one on the steps the
    # host runs itself (after a closed gate). A gated launch that finds the gate shut returns at
    # once and is counted too (a few per window: the steps are slightly overcounted).
    window_steps = sum(len(per[k]) for k in per if "kick_drift" in k)
    rows = []
    for kernel, items in per.items():
        us = [e.get("gpu__time_duration.sum", 0.0) for e in items]
        dram = [e.get("dram__bytes.sum", 0.0) for e in items]
        rows.append({"kernel": kernel, "launches": len(items), "us_total": sum(us),
                     "us_per_step": sum(us) / window_steps if window_steps else float("nan"),
                     "us_median": statistics.median(us),
                     "gb_per_s": sum(dram) / sum(us) / 1e3 if sum(us) else 0.0,
                     "bytes_per_launch": statistics.median(dram)})
    rows.sort(key=lambda r: -r["us_total"])
    return {"n": n, "steps": window_steps, "launches": len(launches), "rows": rows,
            "us_per_step": sum(r["us_total"] for r in rows) / window_steps if window_steps else float("nan")}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cellforce", required=True)
    ap.add_argument("--sizes", type=int, nargs="+", default=[32000, 1048576])
    ap.add_argument("--steps", type=int, default=160, help="bench steps (the window lies inside them)")
    ap.add_argument("--skip", type=int, default=150, help="launches skipped (set-up, warm-up)")
    ap.add_argument("--count", type=int, default=500, help="launches timed")
    ap.add_argument("--precision", default="mixed")
    ap.add_argument("--bench-args", default="--skin 0.6 --neighbor-list")
    ap.add_argument("--clock-control", default="base", choices=["base", "none"],
                    help="Nsight Compute's clocks: base (locked, the default) or none (the GPU's own, as a bench runs)")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    extra = ["--precision", args.precision] + shlex.split(args.bench_args)
    args.out.mkdir(parents=True, exist_ok=True)
    results, lines, failed = [], [], False
    for n in args.sizes:
        r = profile(args.cellforce, n, args.steps, args.skip, args.count, extra, args.clock_control)
        results.append(r)
        if "error" in r:
            failed = True
            lines.append(f"N = {n:,}: {r['error']}\n")
            continue
        lines += [f"N = {n:,}: {r['steps']} steps in a window of {r['launches']} launches, "
                  f"{r['us_per_step']:.1f} us per step at "
                  f"{'ncu' if args.clock_control == 'base' else 'the GPU'}'s clocks (`cellforce bench {' '.join(extra)}`)", "",
                  "| kernel | launches | us per step | us per launch (median) | DRAM GB/s | DRAM MB per launch |",
                  "|---|---|---|---|---|---|"]
        for row in r["rows"]:
            lines.append(f"| {row['kernel']} | {row['launches']} | {row['us_per_step']:.2f} | {row['us_median']:.2f} | "
                         f"{row['gb_per_s']:.0f} | {row['bytes_per_launch'] / 1e6:.2f} |")
        lines.append("")
    (args.out / "step_profile.json").write_text(json.dumps(results, indent=1))
    table = "\n".join(lines) + "\n"
    (args.out / "step_profile.md").write_text(table)
    print(table)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
