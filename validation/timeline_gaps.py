#!/usr/bin/env python3
r"""Where the device idles during `cellforce bench` steps: a timeline of a bench run (Nsight
Systems, or, where it is not installed, the CUPTI injection library built from
validation/bench/cupti_trace.cpp, --tracer; only the latter has run so far: the GPU machine has no
Nsight Systems), its GPU operations (kernels, copies, sets) in the
steady part of the run, and every gap between one operation's end and the next one's start, with
what the host was doing meanwhile.

  python3 validation/timeline_gaps.py --cellforce build-gpu-bin/cellforce --n 1048576 --out $OUT \
      [--tracer build-gpu-bin/libcellforce-cupti-trace.so]
  (--bench-args="--skin 0.6 --neighbor-list --precision mixed": the configuration)

A gap is starvation when the next operation was launched after the previous one ended (the host
was late: it waited on the device, or worked, before it launched); otherwise it is the device's own
turnaround between queued operations. Starvation gaps are booked to the host API call that ended
last before the late launch (e.g. cudaStreamSynchronize: a read of a count), the others to the pair
of operations around them. The steady part runs from the kick-drift launch --steady of the way
from the run's end to the last kick-drift (set-up, warm-up and the run's closing downloads
excluded). Writes timeline_gaps.md (the tables) and timeline_gaps.json.
"""
from __future__ import annotations

import argparse
import bisect
import csv
import io
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path


def short(name: str) -> str:
    """A kernel's name without namespaces, template arguments or parameters."""
    if name.startswith("["):  # [CUDA memcpy Device-to-Host], [CUDA memset]
        return name
    depth, out = 0, ""
    for ch in name.replace("(anonymous namespace)", "anon"):
        if ch == "<":
            depth += 1
        elif ch == ">":
            depth = max(depth - 1, 0)
        elif depth == 0:
            out += ch
    return out.split("(")[0].split("::")[-1].split(" ")[-1] or name[:40]


def demangle(ops: list[dict]) -> None:
    """CUPTI's kernel names are mangled: demangled with c++filt where it is installed, then short();
    the list build's passes apart (list_rows (count), (mirrored), (fill))."""
    mangled = sorted({o["name"] for o in ops if o["name"].startswith("_Z")})
    if not mangled:
        return
    try:
        plain = subprocess.run(["c++filt"], input="\n".join(mangled), capture_output=True, text=True,
                               check=True).stdout.split("\n")
    except (OSError, subprocess.CalledProcessError):
        plain = mangled
    names = {}
    for m, d in zip(mangled, plain):
        name = short(d)
        if name == "list_rows" and "ListPassE" in m:
            name += {"0": " (count)", "1": " (mirrored)", "2": " (fill)"}.get(m.split("ListPassE")[1][:1], "")
        names[m] = name
    for o in ops:
        o["name"] = names.get(o["name"], o["name"])


def read_report(rep: Path, report: str, work: Path) -> list[dict]:
    prefix = work / report
    p = subprocess.run(["nsys", "stats", "--report", report, "--format", "csv", "--force-export", "true",
                        "--output", str(prefix), str(rep)], capture_output=True, text=True)
    files = sorted(work.glob(f"{report}*.csv"))
    if not files:
        raise RuntimeError(f"nsys stats {report}: {(p.stderr or p.stdout)[-600:]}")
    return list(csv.DictReader(io.StringIO(files[0].read_text())))


def col(row: dict, *names: str) -> str:
    for n in names:
        if n in row:
            return row[n]
    for k in row:  # column names differ between Nsight Systems versions
        if any(re.sub(r"\W", "", n).lower() == re.sub(r"\W", "", k).lower() for n in names):
            return row[k]
    raise KeyError(f"none of {names} in {list(row)}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cellforce", required=True)
    ap.add_argument("--n", type=int, default=1048576)
    ap.add_argument("--steps", type=int, default=300, help="bench steps (0: none given, --bench-args=--seconds S)")
    ap.add_argument("--steady", type=float, default=0.7, help="the last fraction of the kick-drift launches analysed")
    ap.add_argument("--bench-args", default="--skin 0.6 --neighbor-list --precision mixed")
    ap.add_argument("--top", type=int, default=20)
    ap.add_argument("--tracer", help="the CUPTI injection library (cupti_trace.cpp) instead of nsys")
    ap.add_argument("--trace-file", type=Path, help="analyse this cupti_trace.cpp output instead of running")
    ap.add_argument("--keep-trace", action="store_true", help="copy the CUPTI trace to --out (trace.csv.xz)")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    bench = [args.cellforce, "bench", "--sizes", str(args.n), "--backend", "cuda", "--warmup", "20", "--samples", "2",
             "--no-reference"] + (["--steps", str(args.steps)] if args.steps > 0 else []) + shlex.split(args.bench_args)
    ops, calls = [], []
    with tempfile.TemporaryDirectory(prefix="cellforce-timeline-") as tmp:
        work = Path(tmp)
        if args.tracer or args.trace_file:
            trace = args.trace_file or work / "trace.csv"
            if not args.trace_file:
                env = dict(os.environ, CUDA_INJECTION64_PATH=str(Path(args.tracer).resolve()), CF_TRACE_OUT=str(trace))
                p = subprocess.run(bench, capture_output=True, text=True, timeout=500, env=env)
                if p.returncode != 0 or not trace.exists():
                    print(f"traced bench exit {p.returncode}: {(p.stderr or p.stdout)[-800:]}")
                    return 1
                if args.keep_trace:
                    subprocess.run(["xz", "-T4", "-k", "-6", str(trace)], check=False)
                    shutil.copy(str(trace) + ".xz", args.out / "trace.csv.xz")
            for rec in csv.reader(io.StringIO(trace.read_text())):
                kind, start, end, corr, name = rec[0], int(rec[1]), int(rec[2]), rec[3], rec[4]
                if kind == "D":
                    print(f"warning: CUPTI {name} records")
                elif kind == "R":
                    calls.append({"start": start, "end": end, "name": name, "corr": corr})
                else:
                    ops.append({"start": start, "end": end, "name": short(name) if kind == "K" else name.split(" ")[0],
                                "corr": corr})
        else:
            rep = work / "run"
            command = ["nsys", "profile", "--trace", "cuda", "--sample", "none", "--cpuctxsw", "none", "--output",
                       str(rep), "--force-overwrite", "true"] + bench
            p = subprocess.run(command, capture_output=True, text=True, timeout=500)
            if p.returncode != 0:
                print(f"nsys profile exit {p.returncode}: {(p.stderr or p.stdout)[-800:]}")
                return 1
            rep = rep.with_suffix(".nsys-rep")
            for r in read_report(rep, "cuda_gpu_trace", work):
                start, dur = int(col(r, "Start (ns)", "Start")), int(col(r, "Duration (ns)", "Duration"))
                ops.append({"start": start, "end": start + dur, "name": short(col(r, "Name")),
                            "corr": col(r, "CorrId", "Correlation ID", "CorrID")})
            for r in read_report(rep, "cuda_api_trace", work):
                start, dur = int(col(r, "Start (ns)", "Start")), int(col(r, "Duration (ns)", "Duration"))
                calls.append({"start": start, "end": start + dur, "name": col(r, "Name"),
                              "corr": col(r, "CorrID", "CorrId", "Correlation ID")})
    ops.sort(key=lambda o: o["start"])
    calls.sort(key=lambda c: c["start"])
    demangle(ops)
    launch_of = {c["corr"]: c for c in calls}
    # The steady window: from the kick-drift launch (1 - steady) of the way through the run to the
    # last one (the run's end, its downloads and output, after it).
    kicks = [i for i, o in enumerate(ops) if "kick_drift" in o["name"]]
    if len(kicks) < 2:
        print("no kick-drift kernels in the trace: not an MD run")
        return 1
    steady = ops[kicks[int(len(kicks) * (1 - args.steady))]: kicks[-1] + 1]
    span = steady[-1]["end"] - steady[0]["start"]
    busy = sum(o["end"] - o["start"] for o in steady)
    # A step is a force evaluation that ran: a gated chunk queues a few steps past the one where the
    # gate closes, and their kernels return at once (shut: the kick-drift after its loads, ~2/3 of
    # its time, the force kernel at once). Counting kick-drifts made the steps ~12% too many at 1M;
    # a shut force kernel takes a few percent of a real one's time. Without pair lists: kick-drifts.
    force_us = sorted(o["end"] - o["start"] for o in steady if o["name"] == "list_force_kernel")
    if force_us:
        typical = force_us[len(force_us) // 2]
        steps = sum(1 for o in steady if o["name"] == "list_force_kernel" and o["end"] - o["start"] > 0.3 * typical)
        shut = sum(1 for o in steady if o["name"] == "list_force_kernel") - steps
    else:
        steps, shut = sum(1 for o in steady if "kick_drift" in o["name"]), 0
    starved: dict[str, list[int]] = defaultdict(list)
    turnaround: dict[str, list[int]] = defaultdict(list)
    ends = [c["end"] for c in calls]

    for a, b in zip(steady, steady[1:]):
        gap = b["start"] - a["end"]
        if gap <= 0:
            continue
        launch = launch_of.get(b["corr"])
        if launch and launch["start"] > a["end"]:
            # the host's last call that ended before this launch began (not the launch itself)
            k = bisect.bisect_right(ends, launch["start"]) - 1
            while k >= 0 and calls[k] is launch:
                k -= 1
            before = calls[k]["name"] if k >= 0 else "?"
            starved[f"{before} -> {launch['name']} ({b['name']})"].append(gap)
        else:
            turnaround[f"{a['name']} -> {b['name']}"].append(gap)
    per = 1e-3 / max(steps, 1)  # ns -> us per step

    def table(title: str, groups: dict[str, list[int]]) -> list[str]:
        rows = sorted(groups.items(), key=lambda kv: -sum(kv[1]))[: args.top]
        out = [f"### {title}", "", "| where | count | us per step | us each (mean) |", "|---|---|---|---|"]
        out += [f"| {k} | {len(v)} | {sum(v) * per:.2f} | {sum(v) / len(v) / 1e3:.1f} |" for k, v in rows]
        return out + [""]

    host: dict[str, list[int]] = defaultdict(list)  # the host's calls within the window, by name
    for c in calls:
        if steady[0]["start"] <= c["start"] <= steady[-1]["end"]:
            host[c["name"]].append(c["end"] - c["start"])
    gpu: dict[str, list[int]] = defaultdict(list)  # the device's operations in the window, by name
    for o in steady:
        gpu[o["name"]].append(o["end"] - o["start"])
    idle_starved = sum(sum(v) for v in starved.values())
    idle_turn = sum(sum(v) for v in turnaround.values())
    lines = [f"N = {args.n:,}, {steps} steps in the steady window, {shut} shut (queued past a closed gate) "
             f"(`cellforce bench {args.bench_args}`): "
             f"{span * per:.1f} us per step, of which GPU operations {busy * per:.1f}, idle with the host late "
             f"{idle_starved * per:.1f}, idle between queued operations {idle_turn * per:.1f}", ""]
    lines += table("GPU operations (time on the device)", gpu)
    lines += table("Idle with the host late (the call the host ended last before the launch)", starved)
    lines += table("Idle between queued operations", turnaround)
    lines += table("The host's runtime calls in the window (time inside them, not idle)", host)
    text = "\n".join(lines)
    (args.out / "timeline_gaps.md").write_text(text + "\n")
    (args.out / "timeline_gaps.json").write_text(json.dumps(
        {"n": args.n, "steps": steps, "span_ns": span, "busy_ns": busy, "gpu": gpu, "starved": starved,
         "turnaround": turnaround}, indent=0))
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
