#!/usr/bin/env python3
r"""A/B of the pair-list build between two `cellforce` binaries, in one call on one GPU.

For each size, the two binaries run `cellforce bench` of the in.lj fluid with pair lists (skin 0.6,
mixed precision, no reference), interleaved, --repeats times each; the table gives the median
steps/s per binary and their ratio. With --ncu, Nsight Compute then times --kernel (by default
the list build's `list_rows`; `list_force_kernel` for the evaluations) of each binary at each
size: the median duration of 6 captured launches, each kernel apart (the build's count, mirrored
and fill passes of its second and third builds: `count 1,745.0 / fill 1,128.7 / mirrored 144.8`).
Until 2026-11-26 the passes' launches, the first build's included, shared one median.

  python3 validation/list_build_ab.py --base old/cellforce --new build-gpu-bin/cellforce \
      --sizes 32000 256000 1048576 --repeats 2 --ncu --out $OUT
  (--bench-args=--langevin: the same A/B of Langevin steps)

Writes TAG.md (the table) and TAG.json (every run; --tag, list_build_ab by default) to --out.
--skin 0 runs both with the cells traversed every step instead of pair lists. Exits 1 when a
run failed (its row says why).
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from step_profile import short_name  # the build's passes apart, as the step profile names them

SEARCH: list[str] = []  # search_args(--skin), set by main


def search_args(skin: float) -> list[str]:
    """The neighbour search of both binaries: pair lists with `skin`, or with 0 the cells every step."""
    return ["--skin", f"{skin:g}"] + (["--neighbor-list"] if skin > 0 else [])


def bench(binary: str, n: int, seconds: float, work: Path, extra: list[str]) -> dict:
    out = work / "row.json"
    out.unlink(missing_ok=True)
    command = [binary, "bench", "--sizes", str(n), "--precision", "mixed", "--backend", "cuda"] + SEARCH + [
               "--seconds", f"{seconds:g}", "--no-reference", "--json", str(out)] + extra
    p = subprocess.run(command, capture_output=True, text=True)
    try:
        row = json.loads(out.read_text())["rows"][0]
    except Exception:  # noqa: BLE001 - no row: the run's own words
        return {"error": f"exit {p.returncode}: {(p.stderr or p.stdout).strip()[-500:]}"}
    if p.returncode != 0 and "error" not in row:
        row["error"] = f"exit {p.returncode}: {p.stderr.strip()[-500:]}"
    return row


US_PER = {"ns": 1e-3, "nsecond": 1e-3, "us": 1.0, "usecond": 1.0, "ms": 1e3, "msecond": 1e3}  # Nsight's units


def ncu_times(text: str) -> dict[str, list[float]]:
    """Nsight Compute's --csv output -> each kernel's launch durations (us), by step_profile's
    short name (the build's passes apart: `list_rows (count)`, `(mirrored)`, `(fill)`)."""
    text = text[text.find('"ID"'):] if '"ID"' in text else ""
    times: dict[str, list[float]] = {}
    for rec in csv.DictReader(io.StringIO(text)):
        if rec.get("Metric Name") == "gpu__time_duration.sum":
            value = float(rec["Metric Value"].replace(",", ""))
            us = value * US_PER.get(rec.get("Metric Unit", "us"), 1.0)
            times.setdefault(short_name(rec["Kernel Name"]), []).append(us)
    return times


def ncu_kernel(binary: str, n: int, extra: list[str], kernel: str) -> dict:
    """Median duration (us) of the captured launches of `kernel` (a regex), each kernel (each pass
    of the build) apart (a median over different passes would mean nothing), and how many were
    captured. For the build's passes the first build's two
    are skipped (it has no masks yet: its fill walks every column again), so that the six captured
    are the count, mirrored and fill passes of the second and third builds."""
    skip = "2" if kernel == "list_rows" else "0"
    command = ["ncu", "--kernel-name", f"regex:{kernel}", "--launch-skip", skip, "--launch-count", "6",
               "--metrics", "gpu__time_duration.sum", "--csv", binary, "bench", "--sizes", str(n), "--precision",
               "mixed", "--backend", "cuda"] + SEARCH + ["--steps", "60", "--warmup", "5",
               "--samples", "2", "--no-reference"] + extra
    p = subprocess.run(command, capture_output=True, text=True, timeout=300)
    times = ncu_times(p.stdout)
    if not times:
        return {"error": f"ncu exit {p.returncode}: {(p.stderr or p.stdout).strip()[-300:]}"}
    return {"kernel": kernel, "launches": sum(len(v) for v in times.values()),
            "by_kernel": {name: {"us_median": statistics.median(v), "launches": len(v)}
                          for name, v in sorted(times.items())}}


def ncu_cell(result: dict) -> str:
    """A table cell: the median per kernel (`count 1,742 / fill 1,128`), or '-'."""
    by = result.get("by_kernel")
    if not by:
        return "-"
    if len(by) == 1:
        return f"{next(iter(by.values()))['us_median']:,.1f}"
    return " / ".join(f"{name.split('(')[-1].rstrip(')') if '(' in name else name} {v['us_median']:,.1f}"
                      for name, v in by.items())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="the binary before the change")
    ap.add_argument("--new", required=True, help="the binary with it")
    ap.add_argument("--sizes", type=int, nargs="+", default=[32000, 256000, 1048576])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=1.5)
    ap.add_argument("--ncu", action="store_true", help="also time --kernel with Nsight Compute")
    ap.add_argument("--kernel", default="list_rows",
                    help="the kernels --ncu times (a regex): list_rows (the build's passes, the default) or "
                         "list_force_kernel (the force evaluations the lists serve)")
    ap.add_argument("--bench-args", default="",
                    help="more `cellforce bench` arguments for both, written --bench-args=--langevin")
    ap.add_argument("--skin", type=float, default=0.6,
                    help="pair lists with this skin (the default 0.6); 0: the cells traversed every step")
    ap.add_argument("--tag", default="list_build_ab", help="the output files' name: TAG.md and TAG.json")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    global SEARCH
    SEARCH = search_args(args.skin)
    extra = shlex.split(args.bench_args)
    args.out.mkdir(parents=True, exist_ok=True)
    runs, failed = [], False
    lines = [f"| N | base steps/s | new steps/s | new / base | base {args.kernel} us | new {args.kernel} us |",
             "|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory(prefix="cellforce-ab-") as tmp:
        work = Path(tmp)
        for n in args.sizes:
            rates = {"base": [], "new": []}
            for _ in range(args.repeats):
                for label in ("base", "new"):  # interleaved: drifts of the machine fall on both
                    row = bench(getattr(args, label), n, args.seconds, work, extra)
                    runs.append({"n": n, "binary": label, **row})
                    if "error" in row:
                        failed = True
                        print(f"{n} {label}: {row['error']}", flush=True)
                    else:
                        rates[label].append(row["steps_per_second"])
                        pad = (f", list slots / pairs {row['list_slots'] / row['list_pairs']:.4f}"
                               if row.get("list_pairs") else "")  # the layout's padding (binaries from 2026-11-26 on)
                        print(f"{n} {label}: {row['steps_per_second']:.1f} steps/s{pad}", flush=True)
            med = {k: statistics.median(v) if v else float("nan") for k, v in rates.items()}
            kern = {"base": {}, "new": {}}
            if args.ncu:
                for label in ("base", "new"):
                    kern[label] = ncu_kernel(getattr(args, label), n, extra, args.kernel)
                    runs.append({"n": n, "binary": label, "ncu": kern[label]})
            us = {k: ncu_cell(v) for k, v in kern.items()}
            lines.append(f"| {n:,} | {med['base']:,.0f} | {med['new']:,.0f} | {med['new'] / med['base']:.3f} | "
                         f"{us['base']} | {us['new']} |")
            (args.out / f"{args.tag}.json").write_text(json.dumps(runs, indent=1))
    table = "\n".join(lines) + "\n"
    (args.out / f"{args.tag}.md").write_text(table)
    print(table)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
