"""Force parity of cellforce with OpenMM's Reference platform on the validation cases.

For each case: OpenMM Reference (double) gives the reference forces and total energy, a numpy
brute force gives the per-particle energies and the virial (and must itself agree with OpenMM to
~1e-10, else the oracle is broken); then `cellforce forces` runs for every backend x precision
and each row is checked against its precision's tolerances.

    python validation/parity.py --cellforce build/cellforce [--backend cpu cuda]
        [--precision single mixed double] [--quick] [--case NAME ...]
        [--report validation/reports/parity.md] [--json out.json] [--require-backends]

Exit status: 0 all rows within tolerance (unavailable backends skipped), 1 some row failed,
2 usage or setup error.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import lj
from cases import BY_NAME, CASES

# Largest allowed value of each judged metric, per row kind: "oracle" is OpenMM Reference
# against the numpy brute force (both double precision); "double", "single" and "mixed" are
# cellforce rows of that precision; "h5md" is the H5MD-input row (h5md_row), which must be
# bitwise equal. The precision rows lie 4x (single energy and virial) to ~400x above the worst
# values measured over all 13 cases on the CPU and CUDA backends (double: median |dF|/|F|
# 2.4e-15, max |dF|/F_rms 8.1e-14, energy 2e-14, virial 1.3e-14, e_i 4.2e-14, max OpenMM
# metric 8.3e-13; single and mixed: 1.7e-6, 1.3e-5, 2.5e-6, 2.5e-6, 7.4e-6, 1.9e-4). max
# |dF|/|F| and the median OpenMM metric are reported, not judged: per particle relative errors
# are large where |F| is small.
_SINGLE = {"median_rel": 1e-5, "max_dF_over_Frms": 1e-4, "energy_rel": 1e-5,
           "virial_rel": 1e-5, "energies_rel": 1e-4, "max_openmm": 2e-3}
TOLERANCES = {
    "oracle": {"median_rel": 1e-10, "max_dF_over_Frms": 1e-10, "energy_rel": 1e-10},
    "double": {"median_rel": 1e-12, "max_dF_over_Frms": 1e-11, "energy_rel": 1e-12,
               "virial_rel": 1e-12, "energies_rel": 1e-12, "max_openmm": 1e-10},
    "single": dict(_SINGLE),
    "mixed": dict(_SINGLE),
    "h5md": {"max_abs_diff": 0.0},
}
METRIC_NAMES = {
    "median_rel": "median |dF|/|F|",
    "max_rel": "max |dF|/|F|",
    "median_openmm": "median OpenMM metric",
    "max_openmm": "max OpenMM metric",
    "max_dF_over_Frms": "max |dF|/F_rms",
    "energy_rel": "energy rel.",
    "energies_rel": "e_i max/mean|e|",
    "virial_rel": "virial rel.",
    "max_abs_diff": "max abs. difference",
}


class SetupError(Exception):
    """Bad input to the check itself (exit status 2)."""


def judge(row: dict, tolerances: dict) -> dict:
    """Set row['status'] to PASS or FAIL and list the metrics over tolerance."""
    over = [k for k, tol in tolerances.items() if not row["metrics"].get(k, np.inf) <= tol]
    row["over_tolerance"] = over
    row["status"] = "FAIL" if over else "PASS"
    return row


def oracle_row(omm_forces, omm_energy, bf_forces, bf_energy, dim) -> dict:
    """OpenMM Reference against the numpy brute force (z forces must be 0 in 2D)."""
    padded = np.zeros_like(omm_forces)
    padded[:, :dim] = bf_forces
    metrics = lj.force_metrics(omm_forces, padded)
    metrics["energy_rel"] = lj.energy_relative_error(omm_energy, bf_energy)
    return judge({"comparison": "OpenMM Reference vs numpy", "backend": "-", "precision": "double",
                  "metrics": metrics}, TOLERANCES["oracle"])


def cellforce_row(args, case, backend, precision, workdir, omm_forces, omm_energy, brute) -> dict:
    """Run cellforce on a case and compare it with OpenMM (forces, energy) and numpy (e_i, W)."""
    row = {"comparison": f"cellforce {backend} {precision}", "backend": backend,
           "precision": precision, "metrics": {}}
    out = Path(workdir) / f"{case.name}_{backend}_{precision}.h5"
    try:
        result = lj.run_cellforce(args.cellforce, case, backend, precision, out)
    except lj.CellforceError as err:
        unavailable = any(s in str(err).lower() for s in lj.UNAVAILABLE)
        skip = unavailable and not args.require_backends
        row.update(status="skipped" if skip else "error", message=str(err))
        return row
    n = len(omm_forces)
    if result["forces"].shape != (n, case.dim):
        row.update(status="error", message=f"forces have shape {result['forces'].shape}, "
                   f"expected {(n, case.dim)}")
        return row
    _, bf_energies, _, bf_virial = brute
    metrics = lj.force_metrics(result["forces"], omm_forces[:, :case.dim])
    metrics["energy_rel"] = lj.energy_relative_error(result["energy"], omm_energy)
    metrics["energies_rel"] = lj.energies_error(result["energies"], bf_energies)
    metrics["virial_rel"] = lj.virial_error(result["virial"], bf_virial)
    row["metrics"] = metrics
    attrs = result["attrs"]
    row.update(engine=attrs.get("engine", ""), evaluation_time_s=attrs.get("evaluation_time"),
               cellforce_version=attrs.get("cellforce_version", ""))
    return judge(row, TOLERANCES[precision])


def h5md_row(args, case, workdir, positions, species, lengths, pbc) -> dict:
    """The same configuration as H5MD (species as integers, named "0", "1", ... by cellforce):
    cellforce cpu double must give bitwise the results it gives for the extended XYZ file."""
    row = {"comparison": "H5MD input = XYZ input", "backend": "cpu", "precision": "double",
           "metrics": {}}
    h5md = Path(workdir) / f"{case.name}.h5md"
    lj.write_h5md(h5md, positions, lj.type_indices(case, species), lengths, pbc, case.dim)
    names = {name: str(k) for k, (name, _, _) in enumerate(case.types)}
    as_h5md = dataclasses.replace(
        case, xyz=str(h5md), types=[(names[n], s, e) for n, s, e in case.types],
        pairs=[(names[a], names[b], s, e) for a, b, s, e in case.pairs])
    try:
        a = lj.run_cellforce(args.cellforce, case, "cpu", "double", Path(workdir) / "xyz.h5")
        b = lj.run_cellforce(args.cellforce, as_h5md, "cpu", "double", Path(workdir) / "h5md.h5")
    except lj.CellforceError as err:
        row.update(status="error", message=str(err))
        return row
    row["metrics"]["max_abs_diff"] = max(float(np.max(np.abs(a[k] - b[k]), initial=0.0))
                                         for k in ("forces", "energies", "energy", "virial"))
    return judge(row, TOLERANCES["h5md"])


def run_case(args, case, workdir) -> dict:
    """Every row of one case."""
    positions, species, lengths, pbc = lj.read_extxyz(case.path)
    system = lj.openmm_system(case, positions, species, lengths, pbc)
    omm_forces, omm_energy, _ = lj.openmm_forces(system, positions)
    sigma, eps = lj.pair_table(case)
    brute = lj.brute_force(positions, lj.type_indices(case, species), lengths, pbc, case.dim,
                           sigma, eps, case.cutoff, case.mode)
    rows = [oracle_row(omm_forces, omm_energy, brute[0], brute[2], case.dim)]
    if rows[0]["status"] != "PASS":
        rows[0]["message"] = "the numpy oracle disagrees with OpenMM: cellforce not run here"
    print_row(case.name, rows[0])
    if rows[0]["status"] == "PASS":
        for backend in args.backend:
            for precision in args.precision:
                rows.append(cellforce_row(args, case, backend, precision, workdir, omm_forces,
                                          omm_energy, brute))
                print_row(case.name, rows[-1])
        if "cpu" in args.backend:
            rows.append(h5md_row(args, case, workdir, positions, species, lengths, pbc))
            print_row(case.name, rows[-1])
    return {"name": case.name, "xyz": case.xyz, "description": case.description,
            "n_particles": len(positions), "dim": case.dim, "cutoff": case.cutoff,
            "mode": case.mode, "mixing": case.mixing, "types": case.types, "pairs": case.pairs,
            "box": [float(v) for v in lengths], "pbc": list(pbc),
            "openmm_energy": omm_energy, "rows": rows}


def print_row(case_name, row):
    metrics = "  ".join(f"{k}={lj.fmt_err(v)}" for k, v in row["metrics"].items())
    tail = f"  ({row['message']})" if "message" in row else ""
    print(f"{row['status']:7s} {case_name:26s} {row['comparison']:28s} {metrics}{tail}",
          flush=True)


def machine_info(results) -> list[str]:
    """Engines that cellforce reported, and the software versions."""
    import openmm

    engines = sorted({f"{r['backend']}: {r['engine']}" for c in results for r in c["rows"]
                      if r.get("engine")})
    versions = sorted({r["cellforce_version"] for c in results for r in c["rows"]
                       if r.get("cellforce_version")})
    return [f"cellforce {', '.join(versions) or '(no run)'}",
            *[f"engine {e}" for e in engines],
            f"OpenMM {openmm.__version__} (Reference platform, double precision), "
            f"numpy {np.__version__}, Python {sys.version.split()[0]}"]


def cell(text: str) -> str:
    """Text for a markdown table cell (a bare | would end the cell)."""
    return text.replace("|", "\\|")


def markdown(results, command, date, revision) -> str:
    """The parity report."""
    judged = [k for k in METRIC_NAMES if any(k in tol for tol in TOLERANCES.values())]
    lines = ["# Force parity with OpenMM's Reference platform", "",
             f"Command: `{command}`  ", f"Date: {date}, source revision {revision}  ",
             *[f"{line}  " for line in machine_info(results)], "",
             "What each metric compares: in a cellforce row (\"cellforce BACKEND PRECISION\"), "
             "the force metrics and the energy are cellforce against OpenMM Reference (double "
             "precision), and e_i and the virial are cellforce against the numpy brute force "
             "(`validation/lj.py`, double precision). In row \"OpenMM Reference vs numpy\", "
             "OpenMM Reference's forces and energy are checked against the numpy brute force, "
             "which must agree for the case's other rows to be run. |dF|/|F|: per particle, "
             "|F - F_ref| / |F_ref|. OpenMM metric: per particle, 2 |dF| / (|F| + |F_ref|) "
             "(the metric of OpenMM's own tests). F_rms: root mean square of |F_ref|, so max "
             "|dF|/F_rms is the largest force error relative to a typical force. Energy rel.: "
             "|E - E_ref| / |E_ref| of the total energy. e_i: max |e_i - e_i,ref| / mean "
             "|e_i,ref| over the per-particle energies. Virial: max component difference / max "
             "|W_ref| component. Row \"H5MD input = XYZ input\": the configuration written as "
             "H5MD (species as integers) must give bitwise the XYZ file's results (cpu, double; "
             "max abs. difference over forces, e_i, energy and virial, required to be 0).", "",
             "A row passes when every metric that its line in the tolerance table gives a "
             "value for is at most that value; '-' there means the metric is reported but "
             "not judged for that row. max |dF|/|F| and the median OpenMM metric are never "
             "judged: a particle with a small |F| has a large relative error for a tiny "
             "absolute one. The double, single and mixed tolerances lie 4x (single precision "
             "energy and virial) to ~400x above the worst values measured over all cases on the "
             "CPU and CUDA backends. "
             "Units: sigma = 1 nm, epsilon = 1 kJ/mol.", "",
             "## Tolerances (largest allowed value)", "",
             "| row | " + " | ".join(cell(METRIC_NAMES[k]) for k in judged) + " |",
             "|---" * (len(judged) + 1) + "|"]
    row_names = {"oracle": "OpenMM Reference vs numpy", "h5md": "H5MD input = XYZ input"}
    for name, tol in TOLERANCES.items():
        lines.append(f"| {row_names.get(name, f'cellforce, {name} precision')} | "
                     + " | ".join(lj.fmt_err(tol.get(k)) for k in judged) + " |")
    failed = [(c["name"], r["comparison"]) for c in results for r in c["rows"]
              if r["status"] in ("FAIL", "error")]
    skipped = {}
    for c in results:
        for r in c["rows"]:
            if r["status"] == "skipped":
                skipped.setdefault(r["message"], set()).add(r["comparison"])
    lines += ["", f"**Result: {'FAIL' if failed else 'PASS'}** "
              f"({sum(len(c['rows']) for c in results)} rows, {len(failed)} failed or in error, "
              f"{sum(r['status'] == 'skipped' for c in results for r in c['rows'])} skipped)."]
    if skipped:
        lines += ["", *[f"- skipped ({', '.join(sorted(rows))}): {message}"
                        for message, rows in skipped.items()]]
    for case in results:
        pairs = "; pairs " + ", ".join(f"{a}-{b} {s}/{e}" for a, b, s, e in case["pairs"]) \
            if case["pairs"] else ""
        lines += ["", f"## {case['name']}", "",
                  f"{case['description']}. `{case['xyz']}`: N = {case['n_particles']}, "
                  f"{case['dim']}D, box {' x '.join(f'{v:.6g}' for v in case['box'][:case['dim']])}"
                  f", pbc {''.join('T' if p else 'F' for p in case['pbc'][:case['dim']])}; "
                  f"rc = {case['cutoff']!r}, {case['mode']}, {case['mixing']}; types "
                  + ", ".join(f"{n} {s}/{e}" for n, s, e in case["types"]) + pairs
                  + f"; OpenMM energy {case['openmm_energy']:.10g} kJ/mol.", "",
                  "| comparison | status | " + " | ".join(map(cell, METRIC_NAMES.values()))
                  + " | one cold eval. (ms) |", "|---" * (len(METRIC_NAMES) + 3) + "|"]
        for row in case["rows"]:
            ms = row.get("evaluation_time_s")
            values = [lj.fmt_err(row["metrics"].get(k)) for k in METRIC_NAMES]
            status = row["status"] + (f": {cell(row['message'])}" if row["status"] == "error"
                                      else "")
            if row.get("over_tolerance"):
                status += " (" + ", ".join(row["over_tolerance"]) + ")"
            lines.append(f"| {row['comparison']} | {status} | " + " | ".join(values)
                         + f" | {lj.fmt_ms(ms)} |")
    return "\n".join(lines) + "\n"


def check_setup(args):
    """Usage and setup errors: the executable, its forces command, the configuration files."""
    exe = Path(args.cellforce)
    if not (exe.is_file() and os.access(exe, os.X_OK)):
        raise SetupError(f"{exe}: not an executable file")
    probe = subprocess.run([str(exe), "forces", "--help"], capture_output=True, text=True)
    if probe.returncode != 0 or "--cutoff-mode" not in probe.stdout:
        raise SetupError(f"{exe} has no `forces` command (`{exe} forces --help` does not "
                         "describe --cutoff-mode)")
    unknown = [name for name in args.case or [] if name not in BY_NAME]
    if unknown:
        raise SetupError(f"unknown cases {unknown}; known: {', '.join(BY_NAME)}")
    cases = [BY_NAME[name] for name in args.case] if args.case else CASES
    cases = [c for c in cases if c.quick or not args.quick]
    missing = [c.xyz for c in cases if not c.path.is_file()]
    if missing:
        raise SetupError(f"missing configuration files {missing} "
                         "(python validation/make_systems.py makes them)")
    return cases


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cellforce", required=True, help="path of the cellforce executable")
    parser.add_argument("--backend", nargs="+", choices=["cpu", "cuda"], default=["cpu"])
    parser.add_argument("--precision", nargs="+", choices=["single", "mixed", "double"],
                        default=["single", "mixed", "double"])
    parser.add_argument("--quick", action="store_true", help="only the cases marked quick (CI)")
    parser.add_argument("--case", nargs="+", metavar="NAME", help="only these cases")
    parser.add_argument("--report", type=Path, help="write the markdown report here")
    parser.add_argument("--json", type=Path, help="write every number here")
    parser.add_argument("--require-backends", action="store_true",
                        help="fail (rather than skip) when a backend is unavailable")
    args = parser.parse_args()
    try:
        cases = check_setup(args)
    except SetupError as err:
        print(f"parity.py: {err}", file=sys.stderr)
        return 2
    command = shlex.join(["python", *sys.argv])
    date = datetime.datetime.now().astimezone().isoformat(timespec="seconds")
    revision = lj.source_revision()
    with tempfile.TemporaryDirectory(prefix="cellforce-parity-") as workdir:
        results = [run_case(args, case, workdir) for case in cases]
    rows = [r for c in results for r in c["rows"]]
    failed = [r for r in rows if r["status"] in ("FAIL", "error")]
    skipped = [r for r in rows if r["status"] == "skipped"]
    print(f"\n{len(rows)} rows: {len(rows) - len(failed) - len(skipped)} passed, "
          f"{len(failed)} failed or in error, {len(skipped)} skipped")
    if args.report:
        args.report.parent.mkdir(parents=True, exist_ok=True)
        args.report.write_text(markdown(results, command, date, revision))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"command": command, "date": date,
                                         "revision": revision, "tolerances": TOLERANCES,
                                         "passed": not failed, "cases": results}, indent=1))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
