#!/usr/bin/env python3
r"""The embedding issue's benchmark: an embedding code's own loop around `Context::compute_device`
(`cellforce bench --embed`: velocity Verlet in two kernels on its own stream, the forces from
compute_device on device arrays, the context's defaults) against `Context::step` (`cellforce bench`,
pair lists, the defaults) and OpenMM CUDA (md_peer.py's timing), in.lj, one precision, in one call on
one machine, size by size. Writes embed.json (the rows as they came), embed-table.md and bench.log to
--out; exits 1 when a run failed.

  python3 validation/embed_table.py --cellforce .device/new/cellforce \
      --sizes 32000 256000 1048576 4194304 --precision mixed --seconds 1.5 --out $OUT/embed
Targets (issue 47): embed >= 0.8 x step from 256,000 particles, >= 0.5 x at 32,000; >= 2 x OpenMM.
"""
from __future__ import annotations

import argparse
import datetime
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from performance import device_name, fcc_cells_for, openmm_row, run_bench  # noqa: E402


def rate(row: dict) -> float:
    v = row.get("steps_per_second")
    return float(v) if isinstance(v, (int, float)) else float("nan")


def table(rows: list[dict], precision: str) -> str:
    lines = [f"| N | embed (compute_device loop) | `step()` | OpenMM CUDA | embed / step | embed / OpenMM | target |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        e, s, o = rate(r["embed"]), rate(r["step"]), rate(r["openmm"])
        need = 0.5 if r["n"] < 256000 else 0.8
        met = e >= need * s and e >= 2 * o
        lines.append(f"| {r['n']:,} | {e:,.0f} | {s:,.0f} | {o:,.0f} | {e / s:.2f} | {e / o:.2f} | "
                     f"{need} x step, 2 x OpenMM: {'met' if met else 'not met'} |")
    return "\n".join(lines) + f"\n\n{precision} precision, steps/s (median of the bench's samples).\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cellforce", required=True)
    ap.add_argument("--sizes", type=int, nargs="+", default=[32000, 256000, 1048576, 4194304])
    ap.add_argument("--precision", default="mixed")
    ap.add_argument("--seconds", type=float, default=1.5)
    ap.add_argument("--commit", default=None)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench.log").write_text("")
    rows, failed = [], False
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        for n in args.sizes:
            timing = ["--seconds", f"{args.seconds:g}", "--no-reference"]
            step = run_bench(args.cellforce, n, args.precision, args.seconds, out, work, "list", "auto", False, timing)
            embed = run_bench(args.cellforce, n, args.precision, args.seconds, out, work, "list", "auto", False,
                              timing + ["--embed"])
            openmm = openmm_row(fcc_cells_for(n), args.precision, args.seconds)
            row = {"n": step.get("n", n), "step": step, "embed": embed, "openmm": openmm}
            failed = failed or any("error" in r for r in (step, embed, openmm))
            rows.append(row)
            print(f"N {row['n']}: embed {rate(embed):.0f}, step {rate(step):.0f}, OpenMM {rate(openmm):.0f} steps/s",
                  flush=True)
    doc = {"device": device_name(), "date": datetime.date.today().isoformat(), "commit": args.commit,
           "precision": args.precision, "rows": rows}
    (out / "embed.json").write_text(json.dumps(doc, indent=1, default=str))
    md = f"{doc['device']}, {doc['date']}, cellforce {args.commit or '?'}\n\n" + table(rows, args.precision)
    (out / "embed-table.md").write_text(md)
    print(md)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
