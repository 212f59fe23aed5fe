#!/usr/bin/env python3
"""cellforce-lammps against LAMMPS's own lj/cut (ctest lammps_parity; plain Python 3, no packages).

For in.lj (4,000 atoms; LAMMPS's lists rebuilt every step so that its own run is exact), in.binary
(two types, explicit pair_coeff lines, pair_modify shift yes), the same with the unlike pair mixed
by LAMMPS (arithmetic), the same as four runs with the unlike pair changed between the second and
third (the engine made twice, no more, as the program reports), in.2d (800 atoms in the plane) and
in.lj with `-sf opt` (LAMMPS's lj/cut/opt, and cellforce under that name), in double precision on the CPU backend (--backend cuda: on
the GPU, the same checks; with --gpus G as well, each run's count of ranks on each GPU checked
against the rank rule, rank r on GPU r mod G, as the program reports the device each rank's engine was
given; one node, so the rule's node-local rank is the rank):
cellforce-lammps on 1, 2 and 4 ranks (each run checked to be on that many) against `lmp` on one
rank, the thermo of steps 0 to 100 every 10. Step 0's E_pair and pressure agree to 1e-10 relative,
every column of step 100 to 1e-6, and the rank counts with each other to 1e-9 on every row; the
per-atom energies and stresses (compute pe/atom, stress/atom) summed agree with LAMMPS's to 1e-10 on
each of steps 0 to 3. A
script with another pair style, a pair_coeff cutoff of its own (also under -sf opt, where LAMMPS's
own would take it), or pair_modify tail yes is refused naming the command; a rank that cannot make its
engine stops every rank, named. Exits 1 on a failure,
77 (a skip) where mpiexec cannot start two processes."""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

COLUMNS = ("Step", "Temp", "E_pair", "E_mol", "TotEng", "Press")


def mpirun(mpiexec: str, ranks: int) -> list[str]:
    command = [mpiexec, "-np", str(ranks)]
    if "mpich" not in Path(mpiexec).resolve().name:  # Open MPI's flags
        command += ["--oversubscribe"] + (["--allow-run-as-root"] if os.geteuid() == 0 else [])
    return command


def run(command: list[str], cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    # one thread a rank; Open MPI's shared-memory transport without the cross-process copies that
    # containers forbid
    env = dict(os.environ, OMP_NUM_THREADS="1", OMPI_MCA_rmaps_base_oversubscribe="1",
               OMPI_MCA_btl_vader_single_copy_mechanism="none")
    return subprocess.run(command, cwd=cwd, capture_output=True, text=True, env=env, timeout=timeout)


def thermo(output: str) -> dict[int, list[float]]:
    rows, inside = {}, False
    for line in output.splitlines():
        words = line.split()
        if tuple(words) == COLUMNS:
            inside = True
            continue
        if inside and len(words) == len(COLUMNS):
            try:
                values = [float(w) for w in words]
            except ValueError:
                inside = False
                continue
            rows[int(values[0])] = values[1:]
        elif inside:
            inside = False
    return rows


def relative(a: float, b: float) -> float:
    return abs(a - b) / max(abs(b), 1e-300)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cellforce-lammps", required=True)
    ap.add_argument("--lmp", required=True)
    ap.add_argument("--mpiexec", required=True)
    ap.add_argument("--systems", required=True, help="systems/lammps")
    ap.add_argument("--backend", default="cpu", choices=("cpu", "cuda"),
                    help="cellforce's backend (cuda: on the GPU machine; the same checks in double precision)")
    ap.add_argument("--gpus", type=int, default=0,
                    help="with --backend cuda: the GPUs the ranks see; each run's ranks a GPU checked (rank r on GPU r mod G)")
    args = ap.parse_args()
    # the runs' folder is a scratch one: paths given relative to here are made absolute
    systems = Path(args.systems).resolve()
    for name in ("cellforce_lammps", "lmp", "mpiexec"):
        given = getattr(args, name)
        if os.sep in given and Path(given).exists():
            setattr(args, name, str(Path(given).resolve()))
    failures = []

    def check(ok: bool, what: str) -> None:
        print(("ok   " if ok else "FAIL ") + what, flush=True)
        if not ok:
            failures.append(what)

    ours = ["--cellforce-backend", args.backend, "--cellforce-precision", "double"]
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        # Where MPI cannot start two processes here (a machine without the means), the test skips
        # (exit 77) with the reason; everything after this is a failure of cellforce-lammps's.
        probe = run(mpirun(args.mpiexec, 2) + [sys.executable, "-c", "pass"], work)
        if probe.returncode != 0:
            print("skipped: mpiexec cannot start two processes here: " + (probe.stderr or probe.stdout).strip()[-400:])
            return 77
        # in.binary with the unlike pair left to LAMMPS's mixing (arithmetic): the mixed values reach cellforce
        mixed = work / "in.mixed"
        mixed.write_text((systems / "in.binary").read_text().replace("pair_coeff      1 2 1.5 0.8\n", "")
                         .replace("pair_modify     shift yes", "pair_modify     shift yes mix arithmetic"))
        # in.binary as four runs, the unlike pair's coefficients changed before the third and the last
        # without setup (`pre no`): a context is kept across runs only while the physics is the same
        runs = work / "in.runs"
        runs.write_text((systems / "in.binary").read_text().replace(
            "run             ${steps}\n",
            "run             25\nrun             25\npair_coeff      1 2 1.2 0.9\nrun             25\n"
            "run             25 pre no\n"))
        cases = [("in.lj", ["-var", "cells", "10", "-var", "every", "1", "-var", "check", "yes"]), ("in.binary", []),
                 (str(mixed), []), (str(runs), []),
                 ("in.2d", []), ("in.lj", ["-var", "cells", "10", "-var", "every", "1", "-var", "check", "yes",
                                           "-sf", "opt"])]
        for script, variables in cases:
            base = ["-in", str(systems / script), "-log", "none", *variables]  # (an absolute path stays)
            if "-sf" in variables:  # LAMMPS's own with its suffix, cellforce's under the suffixed name
                script += " -sf opt"
            p = run(mpirun(args.mpiexec, 1) + [args.lmp, *base], work)
            check(p.returncode == 0, f"{script}: lmp ran ({p.stderr.strip()[-300:]})")
            want = thermo(p.stdout)
            by_ranks = {}
            for ranks in (1, 2, 4):
                p = run(mpirun(args.mpiexec, ranks) + [args.cellforce_lammps, *base, *ours], work)
                check(p.returncode == 0 and "computed by cellforce" in p.stdout and f"on {ranks} procs" in p.stdout,
                      f"{script}, {ranks} ranks: cellforce-lammps ran on {ranks} procs, naming cellforce "
                      f"({p.stderr.strip()[-300:]})")
                got = thermo(p.stdout)
                by_ranks[ranks] = got
                if script == str(runs):  # made for the first run and again for the changed pair only
                    check("2 calls that made the engine" in p.stdout,
                          f"{script}, {ranks} ranks: the engine made for the first run and the changed pair_coeff")
                if args.backend == "cuda" and args.gpus > 0:
                    on = [sum(1 for r in range(ranks) if r % args.gpus == g) for g in range(args.gpus)]
                    placement = ", ".join(f"{count} on GPU {g}" for g, count in enumerate(on) if count)
                    check(f"cellforce-lammps: ranks: {placement}\n" in p.stdout,
                          f"{script}, {ranks} ranks: placed {placement} (the rank rule over {args.gpus} GPUs)")
                check(sorted(got) == sorted(want) and 0 in got and 100 in got,
                      f"{script}, {ranks} ranks: thermo rows {sorted(got)}")
                if 0 not in got or 100 not in got or 0 not in want or 100 not in want:
                    continue
                for name, k in (("E_pair", 1), ("Press", 4)):
                    r = relative(got[0][k], want[0][k])
                    check(r <= 1e-10, f"{script}, {ranks} ranks: step 0 {name} {got[0][k]!r} vs LAMMPS's {want[0][k]!r} "
                                      f"(relative {r:.1e} <= 1e-10)")
                worst = max(relative(a, b) for a, b in zip(got[100], want[100]) if b != 0)
                check(worst <= 1e-6, f"{script}, {ranks} ranks: step 100 within {worst:.1e} of LAMMPS's (<= 1e-6)")
            if all(r in by_ranks and by_ranks[r] for r in (1, 2, 4)):
                worst = max(relative(a, b) for r in (2, 4) for step in by_ranks[1]
                            for a, b in zip(by_ranks[r].get(step, []), by_ranks[1][step]) if b != 0)
                check(worst <= 1e-9, f"{script}: 2 and 4 ranks within {worst:.1e} of 1 rank on every row (<= 1e-9)")

        # Per-atom energy and stress (compute pe/atom, stress/atom), summed: LAMMPS's own on one rank and
        # cellforce's on two, on each of steps 0 to 3 (consecutive calls that ask for them: each call's
        # tallies are its own), to 1e-10 of the largest sum
        per_atom = work / "in.per_atom"
        per_atom.write_text((systems / "in.lj").read_text().replace(
            "thermo_modify   format float %.15g",
            "compute pa all pe/atom\ncompute sp all reduce sum c_pa\ncompute sa all stress/atom NULL\n"
            "compute ss all reduce sum c_sa[1] c_sa[2] c_sa[3] c_sa[4] c_sa[5] c_sa[6]\n"
            "thermo_style custom step pe c_sp c_ss[1] c_ss[2] c_ss[3] c_ss[4] c_ss[5] c_ss[6]\n"
            "thermo_modify   format float %.15g").replace("thermo          10", "thermo          1"))
        rows = {}
        for name, command in (("lmp", mpirun(args.mpiexec, 1) + [args.lmp]),
                              ("cellforce", mpirun(args.mpiexec, 2) + [args.cellforce_lammps, *ours])):
            p = run(command + ["-in", str(per_atom), "-log", "none", "-var", "cells", "6", "-var", "steps", "3",
                               "-var", "every", "1", "-var", "check", "yes"], work)
            lines = p.stdout.splitlines()
            header = next((i for i, line in enumerate(lines) if line.split()[:2] == ["Step", "PotEng"]), None)
            rows[name] = [[float(v) for v in line.split()[1:]] for line in lines[header + 1:header + 5]] \
                if header is not None else []
        ok = len(rows["lmp"]) == 4 and len(rows["cellforce"]) == 4 and all(
            len(row) == 8 for name in rows for row in rows[name])
        for step in range(4):
            ours_row = rows["cellforce"][step] if ok else []
            theirs = rows["lmp"][step] if ok else []
            scale = max((abs(v) for v in theirs[2:5]), default=1.0)
            worst = max((abs(a - b) / scale for a, b in zip(ours_row[2:], theirs[2:])), default=float("inf"))
            check(ok and relative(ours_row[1], theirs[1]) <= 1e-10 and worst <= 1e-10,
                  f"per-atom energy and stress summed, 2 ranks, step {step}: {ours_row} vs LAMMPS's {theirs} "
                  f"(stress within {worst:.1e} of the largest diagonal sum)")
            check(ok and relative(ours_row[1], ours_row[0]) <= 1e-12,
                  f"step {step}: per-atom energies sum to the potential energy (both normalised by the atoms)")

        # Refusals: another pair style, a cutoff of its own for a type pair
        text = (systems / "in.lj").read_text()
        refused = {
            "coul": text.replace("pair_style      lj/cut 2.5", "pair_style      lj/cut/coul/long 2.5"),
            "cutoff": text.replace("pair_coeff      1 1 1.0 1.0 2.5", "pair_coeff      1 1 1.0 1.0 2.0"),
            "tail": text.replace("neighbor        0.3 bin", "pair_modify     tail yes\nneighbor        0.3 bin"),
        }
        # (the cutoff's refusal with -sf opt too: lj/cut/opt is cellforce's, not LAMMPS's, which takes it)
        for name, body, suffix in (("coul", refused["coul"], []), ("cutoff", refused["cutoff"], []),
                                   ("cutoff", refused["cutoff"], ["-sf", "opt"]), ("tail", refused["tail"], [])):
            script = work / f"in.{name}"
            script.write_text(body)
            p = run(mpirun(args.mpiexec, 2) + [args.cellforce_lammps, "-in", str(script), "-log", "none",
                                                "-var", "cells", "4", *suffix, *ours], work)
            out = p.stdout + p.stderr
            line = {"coul": "pair_style      lj/cut/coul/long 2.5", "cutoff": "pair_coeff      1 1 1.0 1.0 2.0",
                    "tail": "run"}[name]  # the tail's refusal comes at the run's start
            reason = {"coul": "refused", "cutoff": "differs from pair_style's", "tail": "tail yes"}[name]
            check(p.returncode != 0 and reason in out and line in out,
                  f"{name} {' '.join(suffix)}: refused, naming the line ({out.strip()[-300:]!r})")

        # One rank that cannot make its engine (device 99, or no CUDA at all) while the other can: every
        # rank stops at once, the failing one named (not the other left waiting in LAMMPS)
        if "mpich" not in Path(args.mpiexec).resolve().name:  # Open MPI's MPMD form
            one = [args.cellforce_lammps, "-in", str(systems / "in.lj"), "-log", "none", "-var", "cells", "4"]
            command = (mpirun(args.mpiexec, 1) + one + ["--cellforce-backend", "cpu"] + [":", "-np", "1"] + one
                       + ["--cellforce-backend", "cuda", "--cellforce-device", "99"])
            try:
                p = run(command, work, timeout=60)
                out = p.stdout + p.stderr
                check(p.returncode != 0 and "rank 1 (1 of 2 ranks failed this check)" in out,
                      f"a rank without its engine stops every rank, named ({out.strip()[-300:]!r})")
            except subprocess.TimeoutExpired:
                check(False, "a rank without its engine stops every rank: the job still ran after 60 s")
    print(f"{len(failures)} failed" if failures else "all passed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
