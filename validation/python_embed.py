#!/usr/bin/env python3
r"""The Python issue's speed: an embedding code's velocity Verlet written in Python (CuPy's kernels on
a stream of its own around `ForceKernel.compute` on CuPy arrays, the forces written into the loop's
own array) against the same loop in C++ (`cellforce bench --embed`: two kernels of its own around
`Context::compute_device`), in.lj (fcc, density 0.8442, T 1.44, rc 2.5, dt 0.005, NVE), one precision,
size by size in one call, with OpenMM CUDA's steps/s on the same system in the same call (the
project's peer; md_peer.py's timing; a row's error where OpenMM cannot be imported). Also the host's time inside one force call: `ForceKernel.compute` from
Python against `compute_device` from C++ (the bench's compute_device_host_us), whose difference is
the module's overhead a call where the host sets the pace (small N; where the device does, a call's
host time also holds its wait for room in the launch queue). Writes python-embed.json and python-embed.md to --out.

  python3 validation/python_embed.py --cellforce .device/new/cellforce --sizes 4000 32000 1048576 \
      --precision mixed --seconds 2 --out $OUT/pyembed
Targets (issue 48): the Python loop >= 0.8 x the C++ loop at 1M; the overhead <= 20 us a call.
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from performance import device_name, fcc_cells_for, openmm_row, run_bench  # noqa: E402

DENSITY, TEMPERATURE, CUTOFF, DT = 0.8442, 1.44, 2.5, 0.005


def fcc(cells: int):
    a = (4.0 / DENSITY) ** (1.0 / 3.0)
    base = np.array([[0, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5], [0, 0.5, 0.5]])
    grid = np.stack(np.meshgrid(*[np.arange(cells)] * 3, indexing="ij"), axis=-1).reshape(-1, 1, 3)
    return ((grid + base[None]).reshape(-1, 3) * a), a * cells


def python_loop(cells: int, precision: str, seconds: float, samples: int = 5) -> dict:
    import cupy as cp

    import cellforce

    x, edge = fcc(cells)
    n = len(x)
    rng = np.random.default_rng(1)
    v = rng.normal(0.0, math.sqrt(TEMPERATURE), x.shape)
    v -= v.mean(axis=0)
    kick_drift = cp.ElementwiseKernel(
        "float64 f, float64 inv_mass, float64 h, float64 dt, bool drift", "float64 v, float64 x",
        "v += h * f * inv_mass; if (drift) x += dt * v;", "cellforce_bench_kick_drift")
    k = cellforce.ForceKernel(box=[edge] * 3, cutoff=CUTOFF, precision=precision, backend="cuda")
    stream = cp.cuda.Stream(non_blocking=True)
    with stream:
        xd, vd = cp.asarray(x), cp.asarray(v)
        inv_mass = cp.ones((n, 1))
        f = cp.empty_like(xd)
        call_seconds, calls = 0.0, 0

        def steps(count: int, observe: bool = False):
            nonlocal call_seconds, calls
            r = None
            for s in range(count):
                kick_drift(f, inv_mass, 0.5 * DT, DT, True, vd, xd)
                t0 = time.perf_counter()
                r = k.compute(xd, forces=f, energy=observe and s + 1 == count)
                call_seconds += time.perf_counter() - t0
                calls += 1
                kick_drift(f, inv_mass, 0.5 * DT, DT, False, vd, xd)
            return r

        def total_energy() -> float:
            r = steps(1, observe=True)
            stream.synchronize()
            k.synchronize()
            return float(r.energy) + 0.5 * float(cp.sum(vd * vd))

        k.compute(xd, forces=f)
        e0 = total_energy()
        steps(50)  # warm-up: the first builds and the pool's first blocks
        stream.synchronize()
        count, t = 10, 0.0
        while t < 0.1:  # calibration: steps for one sample
            t0 = time.perf_counter()
            steps(count)
            stream.synchronize()
            t = time.perf_counter() - t0
            count *= 2 if t < 0.1 else 1
        per_sample = max(10, int(count * (seconds / samples) / t))
        rates, call_seconds, calls = [], 0.0, 0
        for _ in range(samples):
            t0 = time.perf_counter()
            steps(per_sample)
            stream.synchronize()
            rates.append(per_sample / (time.perf_counter() - t0))
        k.synchronize()
        e1 = total_energy()
    return {"n": n, "steps_per_second": statistics.median(rates), "samples": rates, "steps": per_sample * samples,
            "compute_host_us": 1e6 * call_seconds / calls, "energy_per_particle": [e0 / n, e1 / n],
            "description": k.description}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cellforce", required=True)
    ap.add_argument("--sizes", type=int, nargs="+", default=[4000, 32000, 1048576])
    ap.add_argument("--precision", default="mixed")
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--commit", default=None)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.log").write_text("")
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for n in args.sizes:
            cells = fcc_cells_for(n)
            cxx = run_bench(args.cellforce, n, args.precision, args.seconds, out, Path(scratch), "list", "auto", False,
                            ["--seconds", f"{args.seconds:g}", "--no-reference", "--embed"])
            py = python_loop(cells, args.precision, args.seconds)
            openmm = openmm_row(cells, args.precision, args.seconds)
            rows.append({"n": py["n"], "python": py, "cxx": cxx, "openmm": openmm})
            print(f"N {py['n']}: Python {py['steps_per_second']:.0f}, C++ {cxx.get('steps_per_second')} steps/s; "
                  f"call {py['compute_host_us']:.1f} us vs {cxx.get('compute_device_host_us')} us", flush=True)
    lines = ["| N | Python loop (steps/s) | C++ loop (steps/s) | OpenMM CUDA (steps/s) | Python / C++ | "
             "Python / OpenMM | `compute` host us (Python) | `compute_device` host us (C++) | overhead us a call |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        p, c = r["python"], r["cxx"]
        cs, cu = c.get("steps_per_second", float("nan")), c.get("compute_device_host_us", float("nan"))
        o = r["openmm"].get("steps_per_second", float("nan"))
        lines.append(f"| {r['n']:,} | {p['steps_per_second']:,.0f} | {cs:,.0f} | {o:,.0f} | "
                     f"{p['steps_per_second'] / cs:.2f} | {p['steps_per_second'] / o:.2f} | "
                     f"{p['compute_host_us']:.1f} | {cu:.1f} | {p['compute_host_us'] - cu:.1f} |")
    doc = {"device": device_name(), "date": datetime.date.today().isoformat(), "commit": args.commit,
           "precision": args.precision, "rows": rows}
    (out / "python-embed.json").write_text(json.dumps(doc, indent=1, default=str))
    md = (f"{doc['device']}, {doc['date']}, cellforce {args.commit or '?'}, {args.precision} precision\n\n" +
          "\n".join(lines) + "\n")
    (out / "python-embed.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
