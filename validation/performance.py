#!/usr/bin/env python3
r"""The performance issue's report: `cellforce bench` of the LAMMPS in.lj fluid against OpenMM's CUDA
platform, at several sizes, in one call on one machine (`measure`), and its tables and plot (`report`).

measure, per size N and precision P:
- `cellforce bench --sizes N --precision P --backend cuda --seconds S` with pair lists (--skin auto,
  the default: cellforce's own skin, 0.24 rc or 0.18 rc in lean memory; or a length given with
  --skin): steps/s, particle-steps/s,
  stage times, memory per particle, median force error against a double-precision evaluation of the
  last configuration, NVE drift (the bench's JSON row, kept as it came; stdout appended to bench.log);
- for N <= --chapter-max, the chapter's configuration (`--chapter`), mixed precision only;
- OpenMM CUDA in the same precision on the same fcc lattice (md_peer.py's timing: NonbondedForce
  CutoffPeriodic 2.5, no dispersion correction, VerletIntegrator, warm-up excluded);
- mixed only: the forces of cellforce's last configuration (mixed run) from OpenMM CUDA mixed and
  double; OpenMM mixed's median relative force error against OpenMM double, and cellforce's own
  mixed forces against the same OpenMM double forces (a cross-check of the bench's error);
- with --largest N, after the sizes: cellforce alone at N (the largest system, 100M particles on an
  H100 in lean memory), mixed, pair lists, `--steps --warmup --samples 2 --no-reference` (the
  bench's default warm-up of 50 steps, as every other row; a double
  reference and OpenMM would not fit beside it), the row noted as such.
performance.json (rewritten whole after every size), performance-table.md and bench.log go to --out
(and nothing else: the device tool returns a limited number of files).
Exits 1 when a run failed (its row says why).

report: the Markdown tables (per precision; the chapter's configuration), the targets, and a plot
of particle-steps/s against N (matplotlib; only this subcommand needs it).

  python3 validation/performance.py measure --cellforce build-gpu-bin/cellforce \
      --sizes 32000 256000 1048576 4194304 16777216 --precisions mixed single --seconds 1.5 \
      --openmm-max 17000000 --cells-max 1048576 --chapter-max 32000 --largest 100000000 \
      --out perf --commit $(git rev-parse --short HEAD)
  python3 validation/performance.py report --json perf/performance.json \
      --md perf/performance-table.md --plot perf/performance.png
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from md_peer import DT, fcc_positions, lj_system, openmm_steps_per_second  # noqa: E402

OPENMM_RATE = 3.0e8  # rough OpenMM CUDA particle-steps/s: sets its steps for ~--seconds (md_peer.py's rule)
WARMUP = 50


# ---------------------------------------------------------------------------------------------- measure


def fcc_cells_for(n: float) -> int:
    """fcc unit cells per axis whose 4 c^3 particles are nearest to n (as `cellforce bench` rounds)."""
    return max(1, int(math.floor((n / 4.0) ** (1.0 / 3.0) + 0.5)))


def device_name() -> str:
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                             text=True, timeout=60).stdout
        return out.strip().splitlines()[0].strip()
    except Exception:  # noqa: BLE001 - the report says unknown
        return "unknown"


def clean(value):
    """JSON-safe copy: NaN and infinities become null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [clean(v) for v in value]
    return value


def write_atomically(path: Path, text: str) -> None:
    partial = path.with_name(path.name + ".partial")
    partial.write_text(text)
    os.replace(partial, path)


# cellforce's configurations: "list" (a skin and pair lists, the fastest; with --skin auto, cellforce's
# own choice: on CUDA for rc 2.5, 0.6 where the lists run in fast memory and 0.45 in lean; a length
# instead names it), "default" (no skin: the cells traversed on every step; the name is kept for the
# rows of earlier reports, when it was a scene's default) and the chapter's own.
def configuration_args(configuration: str, skin: str) -> list[str]:
    lists = ["--label", "list"] if skin == "auto" else ["--skin", skin, "--neighbor-list", "--label", "list"]
    return {"list": lists, "default": ["--skin", "0"], "chapter": ["--chapter"]}[configuration]


def run_bench(binary: str, n: int, precision: str, seconds: float, out: Path, work: Path, configuration: str,
              skin: str, save: bool, timing: list[str] | None = None) -> dict:
    """One `cellforce bench` call for one size; its JSON row, or a row with an "error" when it gave none.
    Its JSON and saved configuration go to `work` (a scratch folder: --out keeps three files only).
    `timing`: the bench's timing arguments instead of `--seconds seconds`."""
    json_path = work / f"cf-{n}-{configuration}-{precision}.json"
    json_path.unlink(missing_ok=True)
    timing = timing if timing is not None else ["--seconds", f"{seconds:g}"]
    command = [str(Path(binary).resolve()), "bench", "--sizes", str(n), "--precision", precision, "--backend",
               "cuda", *timing, "--json", str(json_path)] + configuration_args(configuration, skin)
    if save:  # the last configuration, for OpenMM's force error on it
        command += ["--save-final", str(work / f"final-{precision}")]
    p = subprocess.run(command, capture_output=True, text=True)
    with open(out / "bench.log", "a") as log:
        log.write(f"$ {shlex.join(command)}\n{p.stdout}")
        if p.stderr:
            log.write(f"[stderr]\n{p.stderr}")
        log.write(f"[exit {p.returncode}]\n\n")
    try:
        rows = json.loads(json_path.read_text())["rows"]
        row = rows[0]
    except Exception:  # noqa: BLE001 - a crash before the JSON: a row of its own
        cells = fcc_cells_for(n)
        row = {"engine": "cellforce", "configuration": configuration, "precision": precision,
               "n": 4 * cells ** 3, "fcc_cells": cells,
               "error": f"bench exited {p.returncode} without a row: {(p.stderr or p.stdout).strip()[-1000:]}"}
    if p.returncode != 0 and "error" not in row:
        row["error"] = f"bench exited {p.returncode}: {p.stderr.strip()[-1000:]}"
    return row


def openmm_row(cells: int, precision: str, seconds: float) -> dict:
    """OpenMM CUDA's steps/s on the fcc lattice of `cells` unit cells per axis (md_peer.py's timing)."""
    n = 4 * cells ** 3
    row = {"engine": "openmm-cuda", "precision": precision, "n": n}
    try:
        import openmm
        row["version"] = openmm.__version__
        steps = max(100, int(seconds * OPENMM_RATE / n))
        r = openmm_steps_per_second(cells, precision, steps, warmup=WARMUP)
        row.update({"steps_per_second": r["steps_per_second"],
                    "particle_steps_per_second": r["steps_per_second"] * r["particles"],
                    "steps": r["steps"], "seconds": r["seconds"], "device_name": r["device"]})
    except Exception as e:  # noqa: BLE001 - reported in the table
        row["error"] = f"{type(e).__name__}: {e}"
    return row


def openmm_forces(positions, edge: float, precisions: list[str]) -> dict:
    """Forces (kJ/mol/nm = reduced units with sigma = epsilon = 1) of md_peer.py's OpenMM system on CUDA, one
    context per precision (one at a time), by precision."""
    import openmm
    from openmm import unit

    system = lj_system(len(positions), edge)
    forces = {}
    for precision in precisions:
        context = openmm.Context(system, openmm.VerletIntegrator(DT), openmm.Platform.getPlatformByName("CUDA"),
                                 {"Precision": precision})
        context.setPositions(positions * unit.nanometer)
        f = context.getState(getForces=True).getForces(asNumpy=True)
        forces[precision] = f.value_in_unit(unit.kilojoule_per_mole / unit.nanometer)
        del context
    return forces


def median_relative_error(f, ref) -> float:
    """Median over particles of |F - F_ref| / |F_ref|, leaving out particles whose |F_ref| is 0."""
    import numpy as np

    norm = np.linalg.norm(ref, axis=1)
    keep = norm > 0
    if not keep.any():
        return math.nan
    return float(np.median(np.linalg.norm(f[keep] - ref[keep], axis=1) / norm[keep]))


def load_saved(prefix: str):
    import numpy as np

    positions = np.fromfile(f"{prefix}.positions.f64", dtype="<f8").reshape(-1, 3)
    forces = np.fromfile(f"{prefix}.forces.f64", dtype="<f8").reshape(-1, 3)
    return positions, forces


def delete_saved(row: dict) -> None:
    prefix = row.get("saved")
    if prefix:
        for suffix in (".positions.f64", ".forces.f64", ".positions.f64.partial", ".forces.f64.partial"):
            Path(prefix + suffix).unlink(missing_ok=True)


def force_errors(cf_row: dict, omm_mixed: dict) -> None:
    """OpenMM CUDA mixed's median force error (against OpenMM double) on cellforce's last mixed
    configuration, into omm_mixed; cellforce's saved forces against OpenMM double, into cf_row."""
    try:
        positions, cf_forces = load_saved(cf_row["saved"])
        edge = fcc_positions(int(cf_row["fcc_cells"]))[1]
        forces = openmm_forces(positions, edge, ["double", "mixed"])
        ref = forces["double"]
        omm_mixed["force_error_median"] = median_relative_error(forces["mixed"], ref)
        omm_mixed["force_error_reference"] = "OpenMM CUDA double, cellforce's last configuration (mixed run)"
        cf_row["openmm_double_force_error_median"] = median_relative_error(cf_forces, ref)
    except Exception as e:  # noqa: BLE001 - reported in the JSON
        omm_mixed["force_error_failure"] = f"{type(e).__name__}: {e}"


def measure(args: argparse.Namespace) -> int:
    with tempfile.TemporaryDirectory() as work:
        return measure_in(args, Path(work))


def measure_in(args: argparse.Namespace, work: Path) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {"device": device_name(), "date": datetime.date.today().isoformat(), "commit": args.commit or "unknown",
           "command": "python3 " + shlex.join(sys.argv), "rows": []}
    rows: list[dict] = doc["rows"]
    failed = False

    def save() -> None:
        write_atomically(out / "performance.json", json.dumps(clean(doc), indent=1))
        write_atomically(out / "performance-table.md", tables(doc))

    for n in args.sizes:
        run_openmm = not args.skip_openmm and (args.openmm_max is None or n <= args.openmm_max)
        for precision in args.precisions:
            print(f"[{n:,} {precision}] cellforce bench, pair lists", flush=True)
            cf = run_bench(args.cellforce, n, precision, args.seconds, out, work, "list", args.skin, save=True)
            rows.append(cf)
            failed |= "error" in cf
            print(f"  cellforce: {summary(cf)}", flush=True)
            if run_openmm:
                print(f"[{n:,} {precision}] OpenMM CUDA", flush=True)
                omm = openmm_row(int(cf["fcc_cells"]), precision, args.seconds)
                rows.append(omm)
                failed |= "error" in omm
                if precision == "mixed" and cf.get("saved"):
                    force_errors(cf, omm)
                    failed |= "force_error_failure" in omm
                print(f"  OpenMM CUDA: {summary(omm)}", flush=True)
            delete_saved(cf)
            save()
        for limit, config, label, what in ((args.cells_max, "default", "cells", "the cells on every step"),
                                           (args.chapter_max, "chapter", "chapter", "--chapter")):
            if n > limit:
                continue
            print(f"[{n:,} mixed] cellforce bench, {what}", flush=True)
            row = run_bench(args.cellforce, n, "mixed", args.seconds, out, work, config, args.skin, save=False)
            rows.append(row)
            failed |= "error" in row
            print(f"  {label}: {summary(row)}", flush=True)
            save()
    if args.largest:
        timing = ["--steps", str(args.largest_steps), "--warmup", str(args.largest_warmup), "--samples", "2",
                  "--no-reference"]
        print(f"[{args.largest:,} mixed] cellforce bench, pair lists, the largest run", flush=True)
        row = run_bench(args.cellforce, args.largest, "mixed", args.seconds, out, work, "list", args.skin, save=False,
                        timing=timing)
        row["note"] = (f"the largest run, in the same call after the sizes: {' '.join(timing)} (memory option "
                       f"{row.get('memory', 'unknown')}, auto being lean where fast would not fit; skin "
                       f"{fmt(row.get('skin'), '{:g}')} ({row.get('skin_requested', '?')}); "
                       f"{row.get('builds', '?')} builds in its timed steps, so the build's share is larger than "
                       "in a long run; no double reference, no OpenMM)")
        rows.append(row)
        failed |= "error" in row
        print(f"  largest: {summary(row)}", flush=True)
    save()
    print(tables(doc), flush=True)
    return 1 if failed else 0


def summary(row: dict) -> str:
    if "error" in row:
        return "error: " + row["error"][:300]
    text = f"{fmt(row.get('steps_per_second'))} steps/s, {fmt(row.get('particle_steps_per_second'))} particle-steps/s"
    if row.get("force_error_median") is not None:
        text += f", force error median {fmt(row['force_error_median'], '{:.3g}')}"
    if row.get("openmm_double_force_error_median") is not None:
        text += f" (against OpenMM double {fmt(row['openmm_double_force_error_median'], '{:.3g}')})"
    if row.get("force_error_failure"):
        text += f", force error failed: {row['force_error_failure'][:200]}"
    return text


# ---------------------------------------------------------------------------------------------- report


def number(row: dict | None, key: str) -> float:
    v = (row or {}).get(key)
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else math.nan


def fmt(v, pattern: str = "{:,.0f}") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return pattern.format(v)


def fmt_rate(v) -> str:
    """Steps/s: whole numbers, one decimal below 100 (the largest run's)."""
    return fmt(v, "{:.1f}") if isinstance(v, (int, float)) and v < 100 else fmt(v)


def error_cell(row: dict) -> str:
    text = " ".join(str(row["error"]).split())[:80]
    return "error: " + text.replace("|", "\\|")


def ns_per_particle_step(row: dict | None) -> float:
    rate = number(row, "particle_steps_per_second")
    return 1e9 / rate if rate > 0 else math.nan


def find(rows: list[dict], engine: str, precision: str, n: int, configuration: str | None = None) -> dict | None:
    for r in rows:
        if r.get("engine") == engine and r.get("precision") == precision and r.get("n") == n and \
                (configuration is None or r.get("configuration") == configuration):
            return r
    return None


def cellforce_rows(rows: list[dict], configuration: str, precision: str) -> list[dict]:
    chosen = [r for r in rows if r.get("engine") == "cellforce" and r.get("configuration") == configuration
              and r.get("precision") == precision]
    return sorted(chosen, key=lambda r: r.get("n", 0))


def ratio(a: dict | None, b: dict | None) -> float:
    x, y = number(a, "steps_per_second"), number(b, "steps_per_second")
    return x / y if y > 0 else math.nan


def forces_from(cf: dict) -> str:
    """What evaluated the forces: pair lists (and their skin), or the traversal's form."""
    if not cf.get("neighbor_list"):
        return cf.get("traversal", "-")
    return "pair lists" + (f", skin {cf['skin']:g}" if isinstance(cf.get("skin"), (int, float)) else "")


def precision_table(rows: list[dict], precision: str) -> list[str]:
    lines = [f"### {precision} precision", "",
             "| N | cellforce steps/s | OpenMM CUDA steps/s | cellforce / OpenMM | cellforce particle-steps/s | "
             "ns per particle-step | forces from | bytes/particle | force error median (cellforce, OpenMM mixed) "
             "| NVE drift |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    cross = []
    for cf in cellforce_rows(rows, "list", precision):
        n = cf["n"]
        omm = find(rows, "openmm-cuda", precision, n)
        omm_rate = "-" if omm is None else error_cell(omm) if "error" in omm else fmt(number(omm, "steps_per_second"))
        omm_err = fmt(number(omm, "force_error_median"), "{:.2e}")
        if "error" in cf:
            lines.append(f"| {n:,} | {error_cell(cf)} | {omm_rate} | - | - | - | - | - | -, {omm_err} | - |")
            continue
        lines.append(
            f"| {n:,} | {fmt_rate(number(cf, 'steps_per_second'))} | {omm_rate} | "
            f"{fmt(ratio(cf, omm if omm and 'error' not in omm else None), '{:.2f}')} | "
            f"{fmt(number(cf, 'particle_steps_per_second'), '{:.3e}')} | {fmt(ns_per_particle_step(cf), '{:.3g}')} | "
            f"{forces_from(cf)} | "
            f"{fmt(number(cf, 'bytes_per_particle'))} | "
            f"{fmt(number(cf, 'force_error_median'), '{:.2e}')}, {omm_err} | "
            f"{fmt(number(cf, 'nve_drift'), '{:.2e}')} |")
        if cf.get("openmm_double_force_error_median") is not None:
            cross.append(f"{n:,}: {fmt(number(cf, 'openmm_double_force_error_median'), '{:.2e}')}")
    if cross:
        lines += ["", "Cross-check: cellforce's own forces of its last configuration against OpenMM CUDA double "
                      "on it (median relative error): " + "; ".join(cross) + "."]
    return lines


def chapter_table(rows: list[dict], configuration: str = "chapter") -> list[str]:
    chapter = cellforce_rows(rows, configuration, "mixed")
    if not chapter:
        return []
    title = {"chapter": "### The chapter's configuration (mixed precision)\n\nA thread per collision cell, the "
                        "chapter's radix sort, cells >= 1.5 x 2h, a rebuild every step.",
             "default": "### The cells traversed on every step (mixed precision)\n\nNo skin: stages 1-3 and the "
                        "traversal (its form chosen by auto) on every step (`--skin 0`; a scene without "
                        "[neighbor] ran this until skin auto)."}
    lines = [title[configuration], "",
             f"| N | {configuration} steps/s | pair lists steps/s | lists / {configuration} | particle-steps/s | "
             "ns per particle-step | traversal form | sort | bytes/particle | force error median | NVE drift |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for ch in chapter:
        n = ch["n"]
        lists = find(rows, "cellforce", "mixed", n, "list")
        lists_rate = "-" if lists is None else error_cell(lists) if "error" in lists else \
            fmt(number(lists, "steps_per_second"))
        if "error" in ch:
            lines.append(f"| {n:,} | {error_cell(ch)} | {lists_rate} | - | - | - | - | - | - | - | - |")
            continue
        ok_lists = lists if lists and "error" not in lists else None
        lines.append(
            f"| {n:,} | {fmt(number(ch, 'steps_per_second'))} | {lists_rate} | "
            f"{fmt(ratio(ok_lists, ch), '{:.2f}')} | {fmt(number(ch, 'particle_steps_per_second'), '{:.3e}')} | "
            f"{fmt(ns_per_particle_step(ch), '{:.3g}')} | {ch.get('traversal', '-')} | {ch.get('sort', '-')} | "
            f"{fmt(number(ch, 'bytes_per_particle'))} | {fmt(number(ch, 'force_error_median'), '{:.2e}')} | "
            f"{fmt(number(ch, 'nve_drift'), '{:.2e}')} |")
    return lines


def targets(rows: list[dict]) -> list[str]:
    """The issue's targets, from the default mixed rows."""
    mixed = [r for r in cellforce_rows(rows, "list", "mixed") if "error" not in r]
    parts = []
    for cf in mixed:
        n = cf["n"]
        goal = 2.0 if n >= 256000 else 1.5
        omm = find(rows, "openmm-cuda", "mixed", n)
        r = ratio(cf, omm if omm and "error" not in omm else None)
        if math.isnan(r):
            parts.append(f"{n:,}: no OpenMM rate (target {goal:g}x)")
        else:
            parts.append(f"{n:,}: {r:.2f}x of OpenMM (target {goal:g}x) {'met' if r >= goal else 'missed'}")
    lines = ["Targets (mixed): " + ("; ".join(parts) if parts else "no mixed rows") + "."]
    million = find(rows, "cellforce", "mixed", 1048576, "list")
    if million is None or "error" in million:
        lines.append("1,048,576 particles at >= 2,000 steps/s: not measured.")
    else:
        rate = number(million, "steps_per_second")
        lines.append(f"1,048,576 particles at >= 2,000 steps/s: {fmt(rate)} steps/s, "
                     f"{'met' if rate >= 2000 else 'missed'}.")
    costs = [(r["n"], ns_per_particle_step(r)) for r in mixed if r["n"] >= 256000]
    costs = [(n, c) for n, c in costs if not math.isnan(c)]
    if len(costs) >= 2:
        spread = max(c for _, c in costs) / min(c for _, c in costs)
        lines.append(f"Cost per particle-step flat within 20% from 256,000 up: max / min {spread:.2f} over "
                     f"{', '.join(f'{n:,}' for n, _ in costs)} "
                     f"({', '.join(f'{c:.3g}' for _, c in costs)} ns), {'met' if spread <= 1.2 else 'missed'}.")
    else:
        lines.append("Cost per particle-step flat within 20% from 256,000 up: fewer than two sizes measured.")
    return lines


def tables(doc: dict) -> str:
    rows = doc.get("rows", [])
    versions = sorted({r["version"] for r in rows if r.get("engine") == "openmm-cuda" and r.get("version")})
    lines = [f"Measured on {doc.get('device', 'unknown')}, {doc.get('date', '?')}, cellforce at "
             f"{doc.get('commit', 'unknown')}" + (f", OpenMM {', '.join(versions)}" if versions else "") +
             f", in one call: `{doc.get('command', '?')}`. LAMMPS in.lj fluid (fcc 0.8442, rc 2.5 truncated, "
             "T 1.44, NVE, dt 0.005); steps/s of the timed steps, warm-up excluded. Force error: median over "
             "particles of |F - F_double| / |F_double| on cellforce's last configuration (cellforce: its own "
             "double evaluation; OpenMM mixed: OpenMM CUDA double). NVE drift: slope of E_total / N against time.",
             ""]
    precisions = sorted({r.get("precision") for r in rows if r.get("engine") == "cellforce"
                         and r.get("configuration") == "list"}, key=lambda p: (p != "mixed", str(p)))
    listed = [r for r in rows if r.get("configuration") == "list" and r.get("skin") is not None]
    skins = sorted({r["skin"] for r in listed})
    auto = any(r.get("skin_requested") == "auto" for r in listed)
    lines += [f"cellforce with pair lists (skin {', '.join(f'{x:g}' for x in skins)}"
              f"{' (auto: 0.24 rc, 0.18 rc where the lists run in lean memory)' if auto else ''}, rebuilt when a "
              "particle has moved more than skin / 2), against OpenMM CUDA in the same precision:", ""]
    for precision in precisions:
        lines += precision_table(rows, precision) + [""]
    for configuration in ("default", "chapter"):
        table = chapter_table(rows, configuration)
        if table:
            lines += table + [""]
    table = memory_table(rows)
    if table:
        lines += table + [""]
    lines += targets(rows)
    return "\n".join(lines) + "\n"


def memory_table(rows: list[dict]) -> list[str]:
    """Device memory by buffer (the bench's memory_by_buffer) of the mixed pair-list rows, bytes a
    particle: the buffers of 1 B a particle or more in some row, then the rest and the total. None
    where the rows have no breakdown (binaries before it)."""
    rows = sorted((r for r in rows if r.get("engine") == "cellforce" and r.get("configuration") == "list"
                   and r.get("precision") == "mixed" and r.get("memory_by_buffer")), key=lambda r: r["n"])
    if not rows:
        return []
    per = [{name: bytes_ / r["n"] for name, bytes_ in r["memory_by_buffer"]} for r in rows]
    names: list[str] = []
    for r in rows:
        for name, _ in r["memory_by_buffer"]:
            if name not in names and any(p.get(name, 0) >= 1 for p in per):
                names.append(name)
    lines = ["### Device memory by buffer (mixed, pair lists; bytes a particle)", "",
             "| buffer | " + " | ".join(f"{r['n']:,}" for r in rows) + " |",
             "|---|" + "---|" * len(rows)]
    for name in names:
        lines.append(f"| {name} | " + " | ".join(f"{p[name]:.1f}" if p.get(name) else "-" for p in per) + " |")
    lines.append("| the rest | " + " | ".join(f"{sum(v for k, v in p.items() if k not in names):.1f}"
                                             for p in per) + " |")
    lines.append("| total | " + " | ".join(fmt(number(r, "bytes_per_particle")) for r in rows) + " |")
    return lines


SERIES = [("cellforce", "list", "mixed", "cellforce mixed, pair lists", "C0", "o", "-"),
          ("cellforce", "list", "single", "cellforce single, pair lists", "C0", "s", "--"),
          ("cellforce", "default", "mixed", "cellforce mixed, cells every step", "C4", "v", "-"),
          ("cellforce", "chapter", "mixed", "cellforce, chapter's configuration, mixed", "C2", "^", "-"),
          ("openmm-cuda", None, "mixed", "OpenMM CUDA mixed", "C1", "o", "-"),
          ("openmm-cuda", None, "single", "OpenMM CUDA single", "C1", "s", "--")]


def plot(doc: dict, path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = doc.get("rows", [])
    fig, ax = plt.subplots(figsize=(7.5, 5))
    for engine, configuration, precision, label, color, marker, style in SERIES:
        points = sorted((r["n"], r["particle_steps_per_second"]) for r in rows
                        if r.get("engine") == engine and r.get("precision") == precision and "error" not in r
                        and (configuration is None or r.get("configuration") == configuration)
                        and isinstance(r.get("particle_steps_per_second"), (int, float)))
        if points:
            ax.plot(*zip(*points), marker=marker, linestyle=style, color=color, label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("particles N")
    ax.set_ylabel("particle-steps per second")
    ax.set_title(f"LAMMPS in.lj fluid, MD steps: {doc.get('device', 'unknown')}, {doc.get('date', '?')}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def report(args: argparse.Namespace) -> int:
    doc = json.loads(Path(args.json).read_text())
    text = tables(doc)
    Path(args.md).write_text(text)
    plot(doc, args.plot)
    print(text, end="")
    return 0


# ---------------------------------------------------------------------------------------------- main


def skin_argument(text: str) -> str:
    """--skin: auto, or a length > 0 (as the bench takes it)."""
    if text == "auto":
        return text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not auto or a length") from None
    if not value > 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r}: the pair-list configuration needs a skin > 0")
    return f"{value:g}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    m = sub.add_parser("measure", help="run cellforce bench and OpenMM CUDA, write performance.json")
    m.add_argument("--cellforce", required=True, help="the cellforce binary")
    m.add_argument("--sizes", type=int, nargs="+", default=[32000, 256000, 1048576, 4194304],
                   help="particle counts (each runs the nearest fcc lattice, 4 c^3)")
    m.add_argument("--precisions", nargs="+", default=["mixed", "single"])
    m.add_argument("--seconds", type=float, default=2.0, help="timed seconds per run (sets the steps)")
    m.add_argument("--skin", type=skin_argument, default="auto",
                   help="the pair-list configuration's skin: auto (cellforce's choice) or a length > 0")
    m.add_argument("--cells-max", type=int, default=4194304,
                   help="largest N that runs the cells-every-step configuration (mixed)")
    m.add_argument("--chapter-max", type=int, default=1048576,
                   help="largest N that also runs the chapter's configuration (mixed)")
    m.add_argument("--openmm-max", type=int, default=None, help="largest N that runs OpenMM (default: all)")
    m.add_argument("--skip-openmm", action="store_true")
    m.add_argument("--largest", type=int, default=None,
                   help="after the sizes, cellforce alone at this N (mixed, pair lists; e.g. 100000000)")
    m.add_argument("--largest-steps", type=int, default=60, help="the largest run's timed steps")
    m.add_argument("--largest-warmup", type=int, default=50,
                   help="the largest run's warm-up steps (default: the bench's, as for every other row)")
    m.add_argument("--commit", default=None, help="cellforce's commit, for the report")
    m.add_argument("--out", required=True, help="folder for performance.json, the table, bench.log")
    r = sub.add_parser("report", help="tables and plot from performance.json")
    r.add_argument("--json", required=True)
    r.add_argument("--md", required=True)
    r.add_argument("--plot", required=True)
    args = ap.parse_args()
    return measure(args) if args.command == "measure" else report(args)


if __name__ == "__main__":
    sys.exit(main())
