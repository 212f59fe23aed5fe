"""Merge error_vs_time.py outputs (e.g. one per machine) into a markdown table and a plot.

Rows without an error (OpenMM's round trip alone, no forces) are in the table, not the plot.

    python validation/plot_error_vs_time.py data1.json [data2.json ...] \\
        --md validation/reports/error-vs-time.md --png validation/reports/error-vs-time.png
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.ticker import FuncFormatter, NullFormatter  # noqa: E402

from lj import fmt_err, fmt_ms  # noqa: E402

ERROR_FLOOR = 1e-17  # errors below this (exact agreement gives 0) are drawn at the floor
PRECISION_ORDER = {"single": 0, "mixed": 1, "double": 2}
PRECISION_COLOUR = {"single": "tab:blue", "mixed": "tab:orange", "double": "tab:green"}
OPTION_ORDER = {"warp": 0, "thread": 1, "cub": 0, "chapter": 1, "jacobi": 0, "gauss-seidel": 1,
                "reused": 0, "rebuilt": 1}
# One marker per method: filled for cellforce, large and hollow for OpenMM.
CELLFORCE_MARKERS = ["o", "s", "D", "^", "v", "P", "h", "<", ">", "d", "p", "8"]
OPENMM_MARKERS = ["*", "H", "p", "X", "8", "d", "^", "v", "<", ">", "s", "o"]
SAME_SYSTEM = ("xyz", "n_particles", "dim", "cutoff", "mode", "types")


def engine_name(row) -> str:
    return f"cellforce {row['platform']}" if row["engine"] == "cellforce" \
        else f"OpenMM {row['platform']}"


def round_trip(row) -> bool:
    """An OpenMM row timing setPositions + getState(positions) alone: no forces, no error."""
    return row["options"].get("what") == "round trip"


def algorithm(row) -> str:
    options = row["options"]
    if round_trip(row):
        return "round trip only (no forces)"
    if row["engine"] == "openmm":
        return f"neighbour list {options['neighbour_list']}" if "neighbour_list" in options else "-"
    if row["platform"] == "cuda":
        return f"{options['traversal']}, {options['sort']} sort, {options['accumulation']}"
    return options["accumulation"]


def method(row, hosts) -> str:
    """Legend entry of a row: engine, platform and algorithm (and the host's core count for
    rows run on a host CPU, when the data come from several hosts)."""
    options = row["options"]
    if row["engine"] == "openmm":
        label = f"OpenMM {row['platform']}"
        if "neighbour_list" in options:
            label += f", list {options['neighbour_list']}"
    elif row["platform"] == "cuda":
        label = f"cellforce cuda {options['traversal']}/{options['sort']}"
        if options["accumulation"] != "jacobi":
            label += f", {options['accumulation']}"
    else:
        label = f"cellforce {row['platform']} {options['accumulation']}"
    on_host = row["platform"] in ("cpu", "CPU", "Reference")
    return f"{label} ({row['host'].split(', ')[-1]})" if on_host and len(hosts) > 1 else label


def load(paths):
    """Every file's data; the system must be the same in all of them."""
    data = [json.loads(Path(p).read_text()) for p in paths]
    first = data[0]["system"]
    for path, d in zip(paths, data):
        differs = [k for k in SAME_SYSTEM if d["system"][k] != first[k]]
        if differs:
            raise SystemExit(f"{path}: system differs from {paths[0]} in {differs}")
    return data


def sorted_rows(data):
    rows = [row for d in data for row in d["rows"]]
    return sorted(rows, key=lambda r: (r["engine"], r["platform"],
                                       PRECISION_ORDER.get(r["precision"], 9),
                                       [OPTION_ORDER.get(v, 9) for v in r["options"].values()],
                                       r["device"]))


def device_name(row) -> str:
    """The device column: cellforce's CUDA engine string less its traversal and sort."""
    if row["engine"] == "cellforce" and row["platform"] == "cuda":
        return row["device"].split(",")[0]
    return row["device"]


def markdown(data, paths) -> str:
    s = data[0]["system"]
    lines = ["# Error against run time", "",
             f"System: `{s['xyz']}`, N = {s['n_particles']}, {s['dim']}D, box "
             + " x ".join(f"{v:.6g}" for v in s["box"][:s["dim"]])
             + f", rc = {s['cutoff']}, {s['mode']}; types "
             + ", ".join(f"{n} {sg}/{e}" for n, sg, e in s["types"]) + ".", "",
             "Error: against OpenMM Reference (double precision) on the same machine's run; "
             "median and max over particles of |dF_i|/|F_i|, and |dE|/|E| of the total energy.",
             "",
             "Time: median wall time of one force evaluation; the two engines' times are taken "
             "differently. cellforce: `evaluation_time`, measured inside the C++ program around "
             "one engine evaluate call on host arrays: host<->device copies are included, "
             "process start and file input and output are not; every evaluation also computes "
             "the per-particle energies and the virial. Its median is over all the repeats with "
             "no warm-up: the first, cold evaluation (which also allocates the engine's working "
             "buffers, on the device for CUDA) is one of them. Pipeline: `pipeline_time`, the "
             "engine's own stages without the host copies. OpenMM: setPositions + "
             "getState(forces, energy) + conversion of the forces to numpy, timed in Python, so "
             "its time includes building the State object and the unit conversion in Python; "
             "one untimed warm-up evaluation comes before the timed ones, so its median leaves "
             "the first evaluation out. 'list reused': the same positions every time, so OpenMM "
             "keeps its neighbour list and most of its search is left out; 'list rebuilt': "
             "positions alternate with a copy translated by rc (same forces), so every "
             "evaluation rebuilds the list, as every cellforce evaluation runs its whole search. "
             "'round trip only (no forces)': for each OpenMM platform but Reference, "
             "setPositions + getState(positions) + conversion to numpy alone, with the same "
             "warm-up and repeats and the platform's default precision: the part of an OpenMM "
             "time that is not force work. It has no error, so it is in this table and not in "
             "the plot. OpenMM CPU has one precision (single-precision forces).", "",
             "## Runs", ""]
    for path, d in zip(paths, data):
        m = d["machine"]
        gpus = "; GPU " + ", ".join(m["gpus"]) if m["gpus"] else ""
        lines += [f"- `{path}` ({d['date']}, source revision {d['revision']}): "
                  f"`{d['command']}`  ",
                  f"  {m['cpu']}, {m['cores']} cores{gpus}; {m['os']}; Python {m['python']}, "
                  f"numpy {m['numpy']}, OpenMM {m['openmm']}"]
        lines += [f"  - skipped: {note}" for note in d["skipped"]]
        lines += [f"  - failed: {note}" for note in d["failed"]]
    lines += ["", "## Results", "",
              "| engine | device | precision | algorithm | time per evaluation (ms) | "
              "pipeline time (ms) | median rel. force error | max rel. force error | "
              "energy rel. error |", "|---" * 9 + "|"]
    for r in sorted_rows(data):
        lines.append(f"| {engine_name(r)} | {device_name(r)} | {r['precision']} | {algorithm(r)} | "
                     f"{fmt_ms(r['time_s'])} | {fmt_ms(r['pipeline_time_s'])} | "
                     f"{fmt_err(r['median_rel_err'])} | {fmt_err(r['max_rel_err'])} | "
                     f"{fmt_err(r['energy_rel_err'])} |")
    return "\n".join(lines) + "\n"


def plot(data, png):
    s = data[0]["system"]
    rows = [r for r in sorted_rows(data) if r["median_rel_err"] is not None]
    hosts = {r["host"] for r in rows}
    methods = list(dict.fromkeys(method(r, hosts) for r in rows))
    cellforce = [m for m in methods if m.startswith("cellforce")]
    openmm = [m for m in methods if not m.startswith("cellforce")]
    markers = {**dict(zip(cellforce, CELLFORCE_MARKERS * 2)),
               **dict(zip(openmm, OPENMM_MARKERS * 2))}
    fig, ax = plt.subplots(figsize=(12, 6.5), dpi=120)
    for r in rows:
        m = method(r, hosts)
        colour = PRECISION_COLOUR.get(r["precision"], "grey")
        x, y = 1e3 * r["time_s"], max(r["median_rel_err"], ERROR_FLOOR)
        if r["engine"] == "openmm":
            ax.scatter(x, y, marker=markers[m], s=260, facecolors="none", edgecolors=colour,
                       linewidths=2.2, zorder=4)
        else:
            ax.scatter(x, y, marker=markers[m], s=70, color=colour, edgecolors="black",
                       linewidths=0.6, alpha=0.85, zorder=3)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.axhline(ERROR_FLOOR, color="lightgrey", linestyle=":", zorder=1)
    ax.set_xlabel("time per force evaluation (ms), median")
    ax.set_ylabel("median relative force error vs OpenMM Reference\n"
                  f"(log; exact agreement, 0, drawn at {ERROR_FLOOR:.0e})")
    ax.set_title(f"{Path(s['xyz']).name}: N = {s['n_particles']}, rc = {s['cutoff']}, {s['mode']}")
    ax.grid(True, which="major", alpha=0.3)
    method_handles = [Line2D([], [], linestyle="none", marker=markers[m], markersize=8 if m in
                             cellforce else 11, color="black",
                             markerfacecolor="grey" if m in cellforce else "none", label=m)
                      for m in methods]
    colour_handles = [Line2D([], [], linestyle="none", marker="o", color=c, markersize=8, label=p)
                      for p, c in PRECISION_COLOUR.items()]
    first = ax.legend(handles=method_handles, title="method (marker)", loc="upper left",
                      bbox_to_anchor=(1.01, 1.0), fontsize=8)
    ax.add_artist(first)
    ax.legend(handles=colour_handles, title="precision (colour)", loc="lower left",
              bbox_to_anchor=(1.01, 0.0), fontsize=8)
    fig.tight_layout()
    fig.savefig(png, bbox_inches="tight", bbox_extra_artists=[first])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="+", type=Path, help="error_vs_time.py JSON files")
    parser.add_argument("--md", type=Path, required=True, help="markdown table to write")
    parser.add_argument("--png", type=Path, required=True, help="plot to write")
    args = parser.parse_args()
    data = load(args.data)
    args.md.parent.mkdir(parents=True, exist_ok=True)
    args.md.write_text(markdown(data, [str(p) for p in args.data]))
    args.png.parent.mkdir(parents=True, exist_ok=True)
    plot(data, args.png)
    return 0


if __name__ == "__main__":
    sys.exit(main())
