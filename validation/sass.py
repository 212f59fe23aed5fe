#!/usr/bin/env python3
r"""The SASS of one kernel, without a GPU: compiles a .cu file of cuda/ to a cubin with the flags of
a CMake build's compile_commands.json (sm_90 by default) and disassembles it with nvdisasm (the
toolkit here ships no cuobjdump or nvdisasm; the `nvidia-cuda-nvdisasm` wheel from PyPI has it).
Prints the kernel's instructions and a count of the ones that matter for a hot loop (local memory,
calls to slow paths, global loads and stores, barriers).

  python3 validation/sass.py --build build-gpu --file cuda/forces/list_forces.cu \
      --kernel 'list_force_kernelINS0_6detail6TraitsILi3ELb0ELb0ELNS_10CutoffModeE0ELb0EEELi1ENS0_13FixedParticleEfdEE'
  (--kernel: a substring of the mangled name; the bench's list force kernel is the one above:
   3D, one type, truncated, no observables, one thread per particle, fixed-point, mixed)

performance.md uses it for the instructions per list entry, the local memory of the cell-ID
kernel and the order of the kick-drift's loads.
"""
from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path


def nvdisasm(cache: Path) -> Path:
    """nvdisasm from PATH, the toolkit or this Python's wheels (pdl_check.find_tool; .ci/setup puts the
    wheel in .venv), else from the PyPI wheel, unpacked once into `cache`."""
    from pdl_check import find_tool  # validation/, beside this script
    tool = find_tool("nvdisasm", None)
    if tool:
        return tool
    found = list(cache.glob("**/bin/nvdisasm"))
    if not found:
        cache.mkdir(parents=True, exist_ok=True)
        subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "-d", str(cache),
                        "nvidia-cuda-nvdisasm"], check=True)
        for wheel in cache.glob("*.whl"):
            subprocess.run([sys.executable, "-m", "zipfile", "-e", str(wheel), str(cache / "x")], check=True)
        found = list(cache.glob("**/bin/nvdisasm"))
        if not found:
            sys.exit("nvdisasm not found in the nvidia-cuda-nvdisasm wheel")
    found[0].chmod(0o755)
    return found[0]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default="build-gpu", help="a CMake build folder with compile_commands.json")
    ap.add_argument("--file", required=True, help="the .cu file, as compile_commands.json names it")
    ap.add_argument("--kernel", required=True, help="a substring of the kernel's mangled name")
    ap.add_argument("--arch", default="sm_90")
    ap.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "cellforce-nvdisasm"))
    args = ap.parse_args()

    build = Path(args.build).resolve()
    target = str(Path(args.file).resolve())
    entry = next((e for e in json.loads((build / "compile_commands.json").read_text()) if e["file"] == target), None)
    if entry is None:
        sys.exit(f"{args.file}: not in {build}/compile_commands.json")
    cubin = Path(args.cache) / (Path(args.file).stem + ".cubin")
    cubin.parent.mkdir(parents=True, exist_ok=True)
    words = shlex.split(entry["command"])
    out, skip = [], False
    for w in words:  # the build's flags, with one real architecture and -cubin in place of -c / -o
        if skip:
            skip = False
            continue
        if w.startswith("--generate-code") or w.startswith("-Xcompiler=-fPIC"):
            continue
        if w == "-o":
            skip = True
            continue
        out.append("-cubin" if w == "-c" else w)
    out += [f"-arch={args.arch}", "-o", str(cubin)]
    subprocess.run(out, check=True, cwd=entry["directory"])
    text = subprocess.run([str(nvdisasm(Path(args.cache))), "-c", str(cubin)], check=True, capture_output=True,
                          text=True).stdout

    lines, on, names = [], False, set()
    for line in text.splitlines():
        if line.startswith(".text.") and line.rstrip().endswith(":"):
            on = args.kernel in line
            if on:
                names.add(line.rstrip(":"))
            continue
        if on:
            m = re.match(r"\s+/\*[0-9a-f]+\*/\s+(.*?)\s*;", line)
            if m:
                lines.append(m.group(1))
    if not lines:
        sys.exit(f"no kernel matches {args.kernel!r}")
    if len(names) > 1:
        print(f"# {len(names)} kernels match; their instructions follow one another")
    print("\n".join(lines))
    counts = {k: sum(1 for l in lines if re.search(p, l)) for k, p in
              [("instructions", r"."), ("local (LDL/STL)", r"\b(LDL|STL)"), ("calls", r"\bCALL"),
               ("global loads", r"\bLDG"), ("global stores", r"\bSTG"), ("barriers", r"\bBAR\b"),
               ("FP64", r"\bD(ADD|MUL|FMA)"), ("conversions", r"\b(F2F|I2F|F2I)")]}
    print("# " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
