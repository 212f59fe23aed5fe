"""validation/reports/stability.md: the stiff and extreme cases, and the NVE drift table.

The cases are GoogleTests (tests/stability_test.cpp) run on every backend and precision; with
CELLFORCE_STABILITY_LOG=FILE each check is appended to FILE as a JSON line (case, title, backend,
precision, item, expected, got, pass). This script renders one or more such logs (one per machine)
and the JSON of validation/nve_drift.py as Markdown, plus a plot of drift and fluctuation against
the time step.

    CELLFORCE_STABILITY_LOG=h100.jsonl build/tests/cellforce_tests --gtest_filter='*Stability*'
    python validation/stability_report.py --log "H100 machine=h100.jsonl" [--log "dev=dev.jsonl"] \
        [--drift drift.json ...] --md validation/reports/stability.md --png validation/reports/stability-drift.png

Exit status 1 when a logged check failed (the report is still written), 0 otherwise.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections import OrderedDict, defaultdict
from pathlib import Path

PRECISIONS = ["double", "mixed", "single"]
NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def load_log(path: Path) -> list[dict]:
    rows = []
    for line in path.read_text().splitlines():
        if line.strip():
            rows.append(json.loads(line))
    return rows


def summarize(values: list[str], expected: str, passed: bool) -> str:
    """One table cell for the backends of one precision: the common value, or the worst."""
    if all(v.startswith("error") for v in values):
        return "refused" if passed else "refused, but: " + values[0]
    if len(set(values)) == 1:
        return values[0]
    nums = []
    for v in values:
        m = NUMBER.match(v)
        if not m:
            return "; ".join(sorted(set(values)))
        nums.append(float(m.group(0)))
    if expected.startswith("<="):
        return f"{max(nums):.2e} (worst)"
    return f"{min(nums):.9g} .. {max(nums):.9g}"


def case_tables(machine: str, rows: list[dict]) -> tuple[list[str], int]:
    out, failures = [], 0
    backends = list(OrderedDict.fromkeys(r["backend"] for r in rows))
    out.append(f"## {machine}\n")
    out.append("Checks passed per backend and precision:\n")
    out.append("| backend | " + " | ".join(PRECISIONS) + " |")
    out.append("|---|" + "---|" * len(PRECISIONS))
    for b in backends:
        cells = []
        for p in PRECISIONS:
            sel = [r for r in rows if r["backend"] == b and r["precision"] == p]
            ok = sum(r["pass"] for r in sel)
            cells.append(f"{ok}/{len(sel)}" if sel else "-")
        out.append(f"| {b} | " + " | ".join(cells) + " |")
    out.append("")
    by_case: dict[int, list[dict]] = defaultdict(list)
    for r in rows:
        by_case[r["case"]].append(r)
    for number in sorted(by_case):
        case_rows = by_case[number]
        out.append(f"### {number}. {case_rows[0]['title']}\n")
        out.append("| check | should give | " + " | ".join(PRECISIONS) + " |")
        out.append("|---|---|" + "---|" * len(PRECISIONS))
        items = list(OrderedDict.fromkeys(r["item"] for r in case_rows))
        messages = OrderedDict()
        for item in items:
            sel = [r for r in case_rows if r["item"] == item]
            expected = sel[0]["expected"]
            cells = []
            for p in PRECISIONS:
                ps = [r for r in sel if r["precision"] == p]
                if not ps:
                    cells.append("-")
                    continue
                ok = all(r["pass"] for r in ps)
                failures += sum(not r["pass"] for r in ps)
                text = summarize([r["got"] for r in ps], expected, ok)
                if not ok:
                    bad = ", ".join(r["backend"] for r in ps if not r["pass"])
                    text = f"**FAILED** ({bad}): " + "; ".join(r["got"] for r in ps if not r["pass"])
                cells.append(text.replace("|", "\\|"))
                for r in ps:
                    if r["got"].startswith("error") and item not in messages:
                        messages[item] = r["got"].removeprefix("error: ")
            esc = lambda t: t.replace("|", "\\|")
            out.append(f"| {esc(item)} | {esc(expected)} | " + " | ".join(cells) + " |")
        if messages:
            out.append("\nMessages (first backend):\n")
            for item, msg in messages.items():
                out.append(f"- {item}: `{msg}`")
        out.append("")
    return out, failures


def drift_section(paths: list[Path], png: Path | None) -> list[str]:
    rows, sources = [], []
    for p in paths:
        data = json.loads(p.read_text())
        sources.append(f"- `{data.get('command', '')}` at {data.get('revision', '?')}, {data.get('date', '')}")
        for r in data["rows"]:
            r["device"] = data.get("device", p.stem)
            rows.append(r)
        for f in data.get("failed", []):
            sources.append(f"  - run that did not finish: {f}")
    out = ["## 12. NVE energy drift and fluctuation against the time step\n",
           "fcc start at density 0.8442, T0 1.44, rc 2.5, velocity Verlet, the same reduced time "
           "for every time step. Per particle: drift = least-squares slope of E/N against time, "
           "RMS = fluctuation of E/N about its mean. Each cell: drift / RMS.\n"]
    out += sources + [""]
    keys = sorted(OrderedDict.fromkeys((r["device"], r["backend"], r["n"], r["mode"], r["dt"]) for r in rows))
    out.append("| device | backend | N | cutoff | dt | steps | " + " | ".join(PRECISIONS) + " |")
    out.append("|---|---|---|---|---|---|" + "---|" * len(PRECISIONS))
    for device, backend, n, mode, dt in keys:
        sel = {r["precision"]: r for r in rows if (r["device"], r["backend"], r["n"], r["mode"], r["dt"]) == (device, backend, n, mode, dt)}
        steps = next(iter(sel.values()))["steps"]
        cells = [f"{sel[p]['drift_per_particle_per_time']:+.2e} / {sel[p]['rms_per_particle']:.2e}" if p in sel else "-"
                 for p in PRECISIONS]
        out.append(f"| {device} | {backend} | {n} | {mode} | {dt} | {steps} | " + " | ".join(cells) + " |")
    out.append("")
    if png and rows:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
        groups = OrderedDict.fromkeys((r["device"], r["backend"], r["n"], r["mode"], r["precision"]) for r in rows)
        for g in groups:
            sel = sorted((r for r in rows if (r["device"], r["backend"], r["n"], r["mode"], r["precision"]) == g),
                         key=lambda r: r["dt"])
            dts = [r["dt"] for r in sel]
            style = "-" if g[3] == "force-shift" else "--"
            label = f"{g[1]} N={g[2]} {g[3]} {g[4]}"
            axes[0].loglog(dts, [abs(r["drift_per_particle_per_time"]) for r in sel], style, marker="o", label=label)
            axes[1].loglog(dts, [r["rms_per_particle"] for r in sel], style, marker="o", label=label)
        axes[0].set_title("|drift| of E/N per unit time")
        axes[1].set_title("RMS fluctuation of E/N")
        for ax in axes:
            ax.set_xlabel("time step dt (reduced)")
            ax.grid(True, which="both", alpha=0.3)
        axes[1].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(png, dpi=120)
        out.append(f"![drift and fluctuation against dt]({png.name})\n")
    return out


def skin_section(paths: list[Path]) -> list[str]:
    """Item 11's cost and benefit: validation/skin_reuse.py's runs, one table per file."""
    from skin_reuse import table
    out = ["## 11. Skin reuse: speed against the skin\n",
           "`cellforce run` of the LJ liquid (fcc at 0.8442, T0 1.44, rc 2.5 truncated, dt 0.005, NVE) with "
           "`[neighbor] skin`; times from the run's performance summary (host arrays: each step uploads the "
           "positions and downloads the forces, and integrates on the host). Stages 1-3 = cell IDs (with the "
           "count), sort, collision cells, per force evaluation, averaged over the run (reused steps cost "
           "only the displacement check). Drift and RMS of E/N must not depend on the skin: reuse is exact.\n"]
    for p in paths:
        data = json.loads(p.read_text())
        out.append(f"`{data.get('command', '')}` at {data.get('revision', '?')}, {data.get('device', '')}, "
                   f"{data.get('date', '')}\n")
        out.append(table(data["rows"]))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", action="append", default=[], help="MACHINE=FILE (JSON lines)")
    parser.add_argument("--drift", type=Path, nargs="*", default=[])
    parser.add_argument("--skin", type=Path, nargs="*", default=[], help="JSON of validation/skin_reuse.py")
    parser.add_argument("--md", type=Path, required=True)
    parser.add_argument("--png", type=Path, default=None)
    parser.add_argument("--header", type=Path, default=None, help="Markdown put before the tables")
    args = parser.parse_args()
    out = ["# Stiff and extreme cases (issue 6)\n"]
    if args.header:
        out.append(args.header.read_text().rstrip() + "\n")
    out.append("Each check comes from tests/stability_test.cpp (GoogleTest, every backend x precision). "
               "A cell gives the value for its precision; where the backends differ it gives the worst "
               "(error metrics) or the range. Tolerances: double 1e-12 (analytic, median, energy) and "
               "1e-11 (max |dF|/F_rms); float pairs (single, mixed) 4e-6 analytic, 1e-5 median "
               "(2e-6 in case 8), 1e-4 max |dF|/F_rms, 1e-5 energy.\n")
    failures = 0
    for spec in args.log:
        machine, _, file = spec.partition("=")
        tables, bad = case_tables(machine, load_log(Path(file)))
        out += tables
        failures += bad
    if args.skin:
        out += skin_section(args.skin)
    if args.drift:
        out += drift_section(args.drift, args.png)
    args.md.write_text("\n".join(out) + "\n")
    print(f"wrote {args.md}; {failures} failed checks")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
