#!/usr/bin/env python3
r"""Checks that the includes of cellforce's sources run the layers one way (README, "Layout"):

  core  ->  state  ->  search/forces/integrators (src/cpu, src/md, src/reference; cuda/search,
            cuda/forces, cuda/integrate)  ->  backends (src/backends, cuda/backend)  ->  public API
            (src/api)  ->  I/O (src/io)  ->  scenes (src/scene)  ->  the CLI (src/cli) and the
            Python module (src/python)

A file may include files of its own folder and of lower layers only, never a sibling of its own
layer; within cuda/ the folders are ordered search -> forces -> integrate -> backend
(cuda/README.md), and the shared helpers at cuda/'s top are below all of them. Two exceptions: the
integrators' per-particle arithmetic (md/verlet_step.h, md/fire_step.h), which the CUDA kernels
share with the host loop, and cuda/backend's implementations of src/backends' interfaces. The public
headers (include/cellforce) are the API's; lower layers may include their leaf headers (options,
errors, export macros). The application (src/cli, src/scene, src/python) reaches the engine only through the
public API: besides it, it includes src/core, src/state, src/io and itself. Prints every include
that runs against this and exits 1 if there is one.

  python3 validation/include_layers.py [--root DIR]
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

# (layer, rank within cuda/) of each folder; lower may be included by higher.
LAYERS = {
    "src/core": 0,
    "src/state": 1,
    "src/cpu": 2, "src/md": 2, "src/reference": 2,
    "cuda": 2, "cuda/search": 2, "cuda/forces": 2, "cuda/integrate": 2,
    "src/backends": 3, "cuda/backend": 3,
    "src/api": 4,
    "src/io": 5, "src/scene": 6, "src/cli": 7, "src/python": 7, "src/lammps": 7,
}
# Headers of a layer-2 folder that its siblings share: the integrators' per-particle arithmetic,
# written once for the host loop and the CUDA kernels.
SHARED = {"md/verlet_step.h", "md/fire_step.h"}
# The application is a client of the public API: besides it, only these folders.
CLIENT_FOLDERS = {"src/cli", "src/scene", "src/python", "src/lammps"}
CLIENT_MAY_USE = {"src/core", "src/state", "src/io", "src/scene", "src/cli"}
CUDA_ORDER = {"cuda": 0, "cuda/search": 1, "cuda/forces": 2, "cuda/integrate": 3, "cuda/backend": 4}
LEAF_PUBLIC = {"cellforce/options.hpp", "cellforce/error.hpp", "cellforce/export.hpp"}
SOURCES = ("*.h", "*.hpp", "*.cpp", "*.cu", "*.cuh")


def folder_of(path: Path, root: Path) -> str:
    rel = path.relative_to(root).parent.as_posix()
    return rel


def resolve(include: str, src: Path, root: Path) -> Path | None:
    """The repository file an include names: relative to src/, cuda/, include/ or the file's folder."""
    for base in (root / "src", root / "cuda", root / "include", src.parent):
        candidate = base / include
        if candidate.is_file():
            return candidate
    return None


def rank(folder: str) -> tuple[int, int]:
    return LAYERS[folder], CUDA_ORDER.get(folder, 0)


def self_test() -> int:
    """The check on small trees: each include against the layers is found, the allowed ones are not."""
    import tempfile
    cases = {  # file -> (its text, the violations expected in the tree with it)
        "src/core/a.h": ('#include "backends/b.h"\n', 1),            # core reaching up
        "src/cli/c.cpp": ('#include "md/md.h"\n#include "io/x.h"\n', 1),  # the app past the API; io is fine
        "cuda/search/d.cuh": ('#include "forces/e.cuh"\n', 1),       # search after forces
        "cuda/forces/f.cu": ('#include "md/verlet_step.h"\n#include "search/g.cuh"\n', 0),  # allowed
        "src/md/h.cpp": ('#include "cpu/i.h"\n', 1),                 # a sibling of the same layer
    }
    stubs = ["src/backends/b.h", "src/md/md.h", "src/io/x.h", "cuda/forces/e.cuh", "src/md/verlet_step.h",
             "cuda/search/g.cuh", "src/cpu/i.h"]
    failed = 0
    for name, (text, expected) in cases.items():
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp)
            for stub in stubs:
                (root / stub).parent.mkdir(parents=True, exist_ok=True)
                (root / stub).write_text("")
            (root / name).parent.mkdir(parents=True, exist_ok=True)
            (root / name).write_text(text)
            found = len(check(root))
            ok = found == expected
            failed += not ok
            print(f"{'ok' if ok else 'FAIL'} {name}: {found} found, {expected} expected")
    return 1 if failed else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parent.parent)
    ap.add_argument("--self-test", action="store_true", help="check the checker on small trees")
    args = ap.parse_args()
    if args.self_test:
        return self_test()
    root = args.root.resolve()
    bad = check(root)
    for line in bad:
        print(line)
    print(f"{len(bad)} includes against the layers")
    return 1 if bad else 0


def check(root: Path) -> list[str]:
    bad: list[str] = []
    files = [p for top in ("src", "cuda") for pattern in SOURCES for p in (root / top).rglob(pattern)]
    for src in sorted(files):
        here = folder_of(src, root)
        if here not in LAYERS:
            bad.append(f"{src.relative_to(root)}: folder {here} has no layer (validation/include_layers.py)")
            continue
        for number, line in enumerate(src.read_text().splitlines(), 1):
            m = re.match(r'\s*#\s*include\s+[<"]([^">]+)[">]', line)
            if not m:
                continue
            name = m.group(1)
            if name.startswith("cellforce/"):
                if LAYERS[here] < LAYERS["src/api"] and name not in LEAF_PUBLIC:
                    bad.append(f"{src.relative_to(root)}:{number}: {name} (the public API) below src/api")
                continue
            target = resolve(name, src, root)
            if target is None:
                continue  # a system or third-party header
            there = folder_of(target, root)
            if here in CLIENT_FOLDERS and there in LAYERS and there not in CLIENT_MAY_USE and there != here:
                bad.append(f"{src.relative_to(root)}:{number}: {name} ({there}): the application uses the public "
                           "API (include/cellforce), not the engine's layers")
                continue
            if there not in LAYERS or there == here or name in SHARED:
                continue
            if here == "cuda/backend" and there == "src/backends":
                continue  # the CUDA implementations of the backends' interfaces
            (lh, ch), (lt, ct) = rank(here), rank(there)
            upward = lt > lh or (lt == lh and here.startswith("cuda") and there.startswith("cuda") and ct > ch)
            sideways = lt == lh and not (here.startswith("cuda") and there.startswith("cuda")) and there != "src/state"
            if upward or sideways:
                bad.append(f"{src.relative_to(root)}:{number}: {name} ({there}, layer {lt}) from {here} (layer {lh})")
    return bad


if __name__ == "__main__":
    sys.exit(main())
