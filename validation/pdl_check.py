#!/usr/bin/env python3
r"""Programmatic dependent launch's rule, checked in the built code: a kernel that may start before
the kernel it follows has ended (griddepcontrol.wait in PTX, ACQBULK in SASS) touches global memory
before that wait only through the parameters the kernels before it cannot be writing, and never
reads through the non-coherent path (ld.global.nc, ldu) what those kernels write.

Why (performance.md records the case): the gated force kernels are launched as programmatic
dependents of each other, so kernel k + 1 runs its blocks' first instructions while kernel k still
writes the positions (`ranked`), the rank-order state (`then`) and the step gate (`gate`). nvcc
reads a `const __restrict__` pointer through the non-coherent path, which it takes as unchanging
while the kernel runs, and ptxas may then move such a read of `ranked` before griddepcontrol.wait:
the fused Verlet runs diverge. A non-coherent read that the schedule happens to leave after the wait
is as wrong, hence the PTX check below. The checks, over every instantiation of every kernel that
waits (the code of one architecture, --arch):

  order (PTX): global loads, stores, atomics and asynchronous copies before griddepcontrol.wait go
      through the rule's `before_wait` parameters only (the source's intent);
  order (SASS): the same for the machine code, after ptxas scheduled it (LDG, LDGSTS, STG, ATOMG,
      REDG, RED, generic LD / ST / ATOM, the TMA copies before ACQBULK);
  non-coherent (PTX): no ld.global.nc or ldu whose base pointer is one of the rule's `chain_writes`,
      or cannot be traced to a parameter;
  the wait itself: not predicated, and no branch before it that may jump past it, no call before it.

A kernel that waits and has no rule here fails the check: a new programmatic dependent states what
its chain writes. Base pointers are found by walking each address back through the PTX registers
to the parameter a cvta.to.global converts (struct parameters through their address, mov of the
parameter symbol then ld.param [%rd+offset]); in SASS, to every kernel-parameter constant
(c[0x0][...], placed by the cubin's EIATTR_PARAM_CBANK and KPARAM_INFO) its address is computed
from. Registers written more than once count every write, in any order (an over-approximation
within a function: a false alarm rather than a miss). "Before the wait" is before it in the code,
which the branch rule above makes the same as before it in time.

  python3 validation/pdl_check.py build/cellforce        (any binary or object with CUDA code)
  python3 validation/pdl_check.py --self-test            (saved code of the fused force kernel that
                                                         must fail and pass: SASS that reads
                                                         `ranked` before the wait, PTX that reads it
                                                         non-coherently, the PTX of `ranked` without
                                                         __restrict__ and two mutations of it)

Tools: cuobjdump and nvdisasm from --tool-dir (ctest passes the build's CUDA toolkit), PATH, the
CUDA toolkit, or the PyPI wheels nvidia-cuda-cuobjdump and nvidia-cuda-nvdisasm (validation/
requirements.txt puts them in .venv). Exit 0: every check passed; 1: a check failed, or the tools
or a rule's kernel were not found (each failure names the kernel, the instruction and the
parameter); 77: no binary held code for --arch.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import sysconfig
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Rule:
    source: str                   # the file that defines the kernel (its parameters' names, by ordinal)
    before_wait: frozenset[str]   # parameters that may be read before the wait: written before the chain began
    chain_writes: frozenset[str]  # parameters the kernels of the chain write: never read non-coherently


# The kernels launched as programmatic dependents (cuda/forces/list_forces.cu, list_forces).
RULES = {
    "list_force_kernel": Rule(
        source="cuda/forces/list_forces.cu",
        # the list's lengths and group chunks come from the build, which completed before the
        # gated evaluations began (the kernel reads them before the wait)
        before_wait=frozenset({"length", "group_chunks"}),
        # the positions in rank order (the kernel before wrote them as its `next`), the chunk's
        # rank-order state that the fused kick-drift updates, and the step gate
        chain_writes=frozenset({"ranked", "then", "gate"}),
    ),
}


# --- tools -------------------------------------------------------------------------------------

def find_tool(name: str, folder: Path | None) -> Path | None:
    """`name` from `folder` (the build's CUDA toolkit), PATH, the CUDA toolkit, or an nvidia-* wheel in
    this Python's site-packages."""
    if folder and (folder / name).is_file():
        return folder / name
    found = shutil.which(name)
    if found:
        return Path(found)
    for home in (os.environ.get("CUDA_HOME"), os.environ.get("CUDA_PATH"), "/usr/local/cuda"):
        if home and (Path(home) / "bin" / name).is_file():
            return Path(home) / "bin" / name
    for site in {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}:
        for candidate in sorted(Path(site).glob(f"nvidia/cu*/bin/{name}")):
            if not os.access(candidate, os.X_OK):
                try:
                    candidate.chmod(candidate.stat().st_mode | 0o111)  # wheels may drop the execute bit
                except OSError:
                    continue
            return candidate
    return None


def cuobjdump(binary: Path, what: str, tools: dict[str, Path], arch: str) -> str:
    """One architecture's code only: a binary built for several holds each kernel once per architecture."""
    env = dict(os.environ, PATH=f"{tools['nvdisasm'].parent}{os.pathsep}{os.environ.get('PATH', '')}")
    done = subprocess.run([str(tools["cuobjdump"]), "-arch", arch, what, str(binary)], capture_output=True,
                          text=True, env=env)
    if done.returncode != 0 and "does not contain device code" not in done.stderr:
        raise SystemExit(f"cuobjdump {what} {binary}: {done.stderr.strip()}")
    return done.stdout


# --- the kernels' parameter names, from their source -------------------------------------------

def parameter_names(source: Path, kernel: str) -> list[str]:
    """The names of `kernel`'s parameters in order, from its __global__ definition in `source`."""
    text = re.sub(r"//[^\n]*|/\*.*?\*/", "", source.read_text(), flags=re.S)
    for m in re.finditer(r"\b" + re.escape(kernel) + r"\s*\(", text):
        if "__global__" not in text[max(0, m.start() - 400):m.start()]:
            continue
        depth, angle, start, names = 1, 0, m.end(), []
        for i in range(m.end(), len(text)):
            c = text[i]
            if c in "([{":
                depth += 1
            elif c in ")]}":
                depth -= 1
            elif c == "<":
                angle += 1
            elif c == ">":
                angle -= 1
            if (c == "," and depth == 1 and angle == 0) or depth == 0:
                decl = re.sub(r"=.*", "", text[start:i], flags=re.S).strip()
                names.append(re.findall(r"[A-Za-z_]\w*", decl)[-1])
                start = i + 1
                if depth == 0:
                    return names
    raise SystemExit(f"{source}: no __global__ definition of {kernel}")


def rule_for(function: str) -> tuple[str, Rule] | None:
    for kernel, rule in RULES.items():
        if f"{len(kernel)}{kernel}" in function:  # the Itanium mangling of the kernel's name
            return kernel, rule
    return None


def demangled(name: str) -> str:
    tool = shutil.which("c++filt")
    if not tool:
        return name
    out = subprocess.run([tool, name], capture_output=True, text=True).stdout.strip()
    return re.sub(r"cellforce::cuda::\(anonymous namespace\)::", "", out) or name


# --- PTX ---------------------------------------------------------------------------------------

@dataclass
class Ptx:
    name: str
    lines: list[str]  # the body's statements, one a line, without the trailing ';'


def ptx_functions(text: str) -> list[Ptx]:
    """Every .entry's body as statements. The body ends where its braces close (nvcc nests blocks:
    `{ .reg ...; shfl...; }` on one line, or a `{` line and a `}` line), and a line may hold
    several statements."""
    out, current, depth = [], None, 0
    for raw in text.splitlines():
        line = raw.split("//", 1)[0].strip()
        m = re.match(r"(?:\.\w+\s+)*\.entry\s+([\w$]+)\s*\(", line)
        if m:
            current, depth = Ptx(m.group(1), []), 0
            out.append(current)
            continue
        if current is None or not line:
            continue
        opened = depth > 0
        depth += line.count("{") - line.count("}")
        if not opened and depth == 0:
            continue  # the parameter list, .maxntid and the like
        for statement in line.split(";"):
            statement = statement.strip()
            while statement.startswith("{") and not statement.startswith("{%"):
                statement = statement[1:].strip()  # a block opens (not a {%r1, %r2} vector)
            while statement.endswith("}") and statement.count("{") < statement.count("}"):
                statement = statement[:-1].strip()  # a block closes
            if statement and not statement.startswith("."):  # not a .reg / .shared declaration
                current.lines.append(statement)
        if depth <= 0:
            current, depth = None, 0
    return out


REG = re.compile(r"%\w+")


def ptx_parse(line: str) -> tuple[str, list[str], list[str], str | None]:
    """(opcode, destination registers, source registers, parameter 'K+off' for ld.param)."""
    line = re.sub(r"^@!?%\w+\s+", "", line)
    parts = line.split(None, 1)
    op = parts[0]
    rest = parts[1] if len(parts) > 1 else ""
    param = None
    pm = re.search(r"_param_(\d+)(?:\+(\d+))?\]", rest)
    if op.startswith("ld.param") and pm:
        param = f"{pm.group(1)}+{pm.group(2) or 0}"
    if op.startswith(("st.", "red.", "bra", "ret", "bar", "griddepcontrol", "membar", "fence", "prefetch")) \
            or rest.startswith("["):
        return op, [], REG.findall(rest), param
    # destinations: the first operand (a register or a {vector}); sources: everything after it
    if rest.startswith("{"):
        close = rest.index("}")
        dest, src = rest[:close + 1], rest[close + 1:]
    else:
        dest, _, src = rest.partition(",")
    return op, REG.findall(dest), REG.findall(src), param


def ptx_walk(regs: list[str], defs: dict[str, list[int]], follow) -> None:
    """Every statement that writes one of `regs`, then every one that writes a register `follow`
    returned for a statement before, and so on (each register once)."""
    seen, stack = set(), list(regs)
    while stack:
        r = stack.pop()
        if r not in seen:
            seen.add(r)
            for j in defs.get(r, []):
                stack.extend(follow(j))


def ptx_bases(fn: Ptx, index: int, defs: dict[str, list[int]], parsed: list) -> set[str]:
    """The parameters ('K+off') that the address of statement `index` is based on: values a
    cvta.to.global converts, walked back through arithmetic (loads from memory end a walk: a value
    read from memory is data, not the kernel's pointer)."""
    address = re.search(r"\[([^\]]+)\]", fn.lines[index])
    bases: set[str] = set()

    def data(op: str) -> bool:
        return op.startswith(("ld.", "atom."))

    def to_parameter(j: int) -> list[str]:  # the ld.param slots a converted value comes from
        op, _, src, param = parsed[j]
        if param is not None:
            bases.add(param)
            return []
        return [] if data(op) else src

    def to_conversion(j: int) -> list[str]:
        op, _, src, param = parsed[j]
        if op.startswith("cvta.to.global"):
            ptx_walk(src[:1], defs, to_parameter)
            return []
        return src if param is None and not data(op) else []

    ptx_walk(REG.findall(address.group(1)) if address else [], defs, to_conversion)
    return bases


def ptx_global(op: str) -> bool:
    """Whether an instruction may touch global memory: ld, ldu, st, atom, red in the global space or
    generic (no space: it may be global), and the asynchronous copies (cp.async*, whose source is
    global)."""
    parts = op.split(".")
    if parts[0] in ("ld", "ldu", "st", "atom", "red"):
        spaces = {"global", "shared", "local", "const", "param", "tex"} & set(parts[1:])
        return not spaces or "global" in spaces
    return parts[0].startswith("cp") and "async" in parts


def ptx_non_coherent(op: str) -> bool:
    """Reads through the non-coherent path: ld.global.nc and ldu (a uniform load, also read-only)."""
    parts = op.split(".")
    return (parts[0] == "ld" and "nc" in parts) or parts[0] == "ldu"


def ptx_statements(fn: Ptx) -> tuple[list, dict[str, list[int]]]:
    """Each statement parsed (ptx_parse), and the statements that write each register."""
    parsed = [ptx_parse(l) for l in fn.lines]
    # A struct parameter may be read through its address: mov.b64 %rd7, NAME_param_11; then
    # ld.param.u64 %rd9, [%rd7+8] reads parameter 11's field at 8.
    address_of = {m.group(1): m.group(2) for l in fn.lines
                  if (m := re.match(r"mov\.[bu]64\s+(%\w+),\s*[\w$]+_param_(\d+)\s*$", l))}
    for i, (op, dst, src, param) in enumerate(parsed):
        m = re.search(r"\[(%\w+)(?:\+(\d+))?\]", fn.lines[i])
        if op.startswith("ld.param") and param is None and m and m.group(1) in address_of:
            parsed[i] = (op, dst, src, f"{address_of[m.group(1)]}+{m.group(2) or 0}")
    defs: dict[str, list[int]] = {}
    for i, (_, dst, _, _) in enumerate(parsed):
        for r in dst:
            defs.setdefault(r, []).append(i)
    return parsed, defs


def check_ptx(fn: Ptx, names: list[str], rule: Rule) -> list[str]:
    parsed, defs = ptx_statements(fn)
    waits = [i for i, l in enumerate(fn.lines) if re.search(r"(^|\s)griddepcontrol\.wait\b", l)]
    if not waits:
        return ["PTX: no griddepcontrol.wait (the kernel would read what the kernel before writes without waiting)"]
    wait = waits[0]
    problems = []
    if fn.lines[wait].startswith("@"):
        problems.append(f"PTX: the wait is predicated ('{fn.lines[wait]}'): every thread must wait")
    labels = {l[:-1]: i for i, l in enumerate(fn.lines) if re.fullmatch(r"[\w$]+:", l)}
    for i in range(wait):
        op = parsed[i][0]
        if op.startswith("bra"):
            target = fn.lines[i].split()[-1]
            if labels.get(target, -1) > wait:
                problems.append(f"PTX: '{fn.lines[i]}' before the wait jumps past it")
        elif op.startswith("call"):
            problems.append(f"PTX: '{fn.lines[i]}' before the wait (a call's accesses are not checked)")

    def name(k: int) -> str:
        return names[k] if k < len(names) else f"parameter {k}"

    def label(slot: str) -> str:
        k, off = slot.split("+")
        return name(int(k)) if off == "0" else f"{name(int(k))}+{off}"

    for i, line in enumerate(fn.lines):
        op = parsed[i][0]
        if not ptx_global(op):
            continue
        bases = ptx_bases(fn, i, defs, parsed)
        params = {name(int(b.split("+")[0])) for b in bases}
        traced = ", ".join(sorted(map(label, bases))) or "nothing traced"
        if i < wait and (not params or not params <= rule.before_wait):
            problems.append(f"PTX order: '{line}' before griddepcontrol.wait, based on {traced} "
                            f"(allowed before the wait: {', '.join(sorted(rule.before_wait))})")
        if ptx_non_coherent(op) and (not params or params & rule.chain_writes):
            problems.append(f"PTX non-coherent: '{line}' reads {traced}: the kernels of the chain write "
                            f"{', '.join(sorted(rule.chain_writes))}, so read them coherently (no __restrict__ "
                            f"on those pointers)")
    return problems


# --- SASS --------------------------------------------------------------------------------------

@dataclass
class Sass:
    name: str
    code: list[tuple[int, str]] = field(default_factory=list)  # (address, instruction)


def sass_functions(text: str) -> list[Sass]:
    out, current = [], None
    instr = re.compile(r"\s*/\*([0-9a-f]{4,})\*/\s+(.*?)\s*;")
    for line in text.splitlines():
        if "Function :" in line:
            current = Sass(line.split("Function :", 1)[1].strip())
            out.append(current)
        elif current is not None:
            m = instr.match(line)
            if m:
                current.code.append((int(m.group(1), 16), m.group(2)))
    return out


def kernel_params(elf: str) -> dict[str, tuple[int, list[tuple[int, int, int]]]]:
    """Per function: the parameter constant bank's base and (ordinal, offset, size) of each parameter."""
    out: dict[str, tuple[int, list]] = {}
    name, base, params, attribute = None, None, [], ""
    for line in elf.splitlines():
        if line.startswith(".nv.info."):
            if name and base is not None:
                out[name] = (base, params)
            name, base, params = line[len(".nv.info."):].strip(), None, []
        elif name:
            m = re.search(r"Attribute:\s*(\w+)", line)
            if m:
                attribute = m.group(1)
            m = re.search(r"Ordinal\s*:\s*(0x[0-9a-f]+)\s+Offset\s*:\s*(0x[0-9a-f]+)\s+Size\s*:\s*(0x[0-9a-f]+)", line)
            if m:
                params.append(tuple(int(g, 16) for g in m.groups()))
            m = re.match(r"\s*Value:\s*0x[0-9a-f]+\s+(0x[0-9a-f]+)\s*$", line)
            if m and attribute == "EIATTR_PARAM_CBANK":  # bank offset in the low half, size in the high
                base = int(m.group(1), 16) & 0xFFFF
    if name and base is not None:
        out[name] = (base, params)
    return out


SASS_OP = re.compile(r"^(@!?U?P\w+\s+)?([\w.]+)\s*(.*)$")
SASS_REG = re.compile(r"\b(U?R\d+)\b")
GLOBAL_SASS = re.compile(r"^(LDG|LDGSTS|STG|ATOMG|REDG|RED|LD|ST|ATOM|UTMALDG|UTMASTG|UBLKCP)(\.|$)")


def sass_width(op: str) -> int:
    if ".128" in op:
        return 4
    if ".64" in op or ".WIDE" in op or op.startswith(("CS2R", "D")) or "F64" in op.split(".")[1:2]:
        return 2
    return 1


def sass_regs(operand: str) -> list[str]:
    """The registers an operand names; R2.64 names R2 and R3."""
    out = []
    for m in re.finditer(r"\b(U?R)(\d+)(\.64)?\b", operand):
        out.append(f"{m.group(1)}{m.group(2)}")
        if m.group(3):
            out.append(f"{m.group(1)}{int(m.group(2)) + 1}")
    return out


def check_sass(fn: Sass, names: list[str], params: tuple[int, list[tuple[int, int, int]]] | None,
               rule: Rule) -> list[str]:
    wait = next((i for i, (_, s) in enumerate(fn.code) if SASS_OP.match(s).group(2) == "ACQBULK"), None)
    if wait is None:
        return ["SASS: no ACQBULK (griddepcontrol.wait)"]
    problems = []
    if SASS_OP.match(fn.code[wait][1]).group(1):
        problems.append(f"SASS: the wait is predicated ('{fn.code[wait][1]}'): every thread must wait")
    for address, text in fn.code[:wait]:
        op = SASS_OP.match(text).group(2)
        if op.startswith(("BRA", "JMP", "BRX", "JMX")):
            target = re.search(r"0x[0-9a-f]+", text.split(None, 2)[-1] if op.startswith(("BRA", "JMP")) else "")
            if target is None or int(target.group(0), 16) > fn.code[wait][0]:
                problems.append(f"SASS: /*{address:04x}*/ '{text}' before ACQBULK may jump past it")
        elif op.startswith("CALL"):
            problems.append(f"SASS: /*{address:04x}*/ '{text}' before ACQBULK (a call's accesses are not checked)")
    base, slots = params if params else (0x210, [])

    def param_of(offset: int) -> str:
        for ordinal, off, size in slots:
            if base + off <= offset < base + off + size:
                return names[ordinal] if ordinal < len(names) else f"parameter {ordinal}"
        return f"c[0x0][{offset:#x}]"

    parsed = []
    for _, text in fn.code[:wait]:
        m = SASS_OP.match(text)
        op, rest = m.group(2), m.group(3)
        operands = [o.strip() for o in re.split(r",(?![^\[]*\])", rest)] if rest else []
        dest = []
        if operands and re.fullmatch(r"U?R\d+", operands[0]):
            first = int(operands[0].lstrip("UR"))
            prefix = "UR" if operands[0].startswith("UR") else "R"
            dest = [f"{prefix}{first + k}" for k in range(sass_width(op))]
        parsed.append((op, operands, dest))

    for i, (op, operands, _) in enumerate(parsed):
        if not GLOBAL_SASS.match(op):
            continue
        address = next((o for o in operands if "[" in o), "")
        address = address[address.rfind("["):]  # desc[URx][Ry.64]: the last bracket is the address
        todo, seen, reached = sass_regs(address), set(), set()
        while todo:
            r = todo.pop()
            if r in seen or r in ("RZ", "URZ"):
                continue
            seen.add(r)
            for j in range(i - 1, -1, -1):  # every earlier write of r (over-approximation)
                jop, jops, jdest = parsed[j]
                if r not in jdest:
                    continue
                for o in jops[1:]:
                    for c in re.findall(r"c\[0x0\]\[(0x[0-9a-f]+)\]", o):
                        if int(c, 16) >= base:
                            reached.add(int(c, 16))
                if not GLOBAL_SASS.match(jop) and not jop.startswith("LDS"):
                    for o in jops[1:]:
                        todo.extend(sass_regs(re.sub(r"c\[0x0\]\[0x[0-9a-f]+\]", "", o)))
        found = sorted({param_of(c) for c in reached})
        if not found or not set(found) <= rule.before_wait:
            problems.append(f"SASS order: /*{fn.code[i][0]:04x}*/ '{fn.code[i][1]}' before ACQBULK, based on "
                            f"{', '.join(found) or 'nothing traced'} "
                            f"(allowed before the wait: {', '.join(sorted(rule.before_wait))})")
    return problems


# --- driver ------------------------------------------------------------------------------------

def check_binary(binary: Path, tools: dict[str, Path], arch: str) -> int:
    ptx = ptx_functions(cuobjdump(binary, "-ptx", tools, arch))
    sass = sass_functions(cuobjdump(binary, "-sass", tools, arch))
    if not ptx and not sass:
        print(f"skipped: {binary} holds no {arch} code")
        return 77
    elf = kernel_params(cuobjdump(binary, "-elf", tools, arch))
    names_of: dict[str, list[str]] = {}
    failures = 0
    checked: dict[str, list[int]] = {kernel: [0, 0] for kernel in RULES}  # PTX, SASS

    def names(kernel: str, rule: Rule) -> list[str]:
        if kernel not in names_of:
            names_of[kernel] = parameter_names(ROOT / rule.source, kernel)
        return names_of[kernel]

    def report(fn_name: str, problems: list[str]) -> None:
        nonlocal failures
        if problems:
            failures += 1
            if failures <= 20:  # the first functions in full; the count of the rest at the end
                print(f"FAIL {demangled(fn_name)}")
                for p in problems[:4]:
                    print(f"     {p}")
                if len(problems) > 4:
                    print(f"     ({len(problems) - 4} more)")

    for fn in ptx:
        waits = any(re.search(r"(^|\s)griddepcontrol\.wait\b", l) for l in fn.lines)
        found = rule_for(fn.name)
        if waits and found is None:
            report(fn.name, ["waits (griddepcontrol.wait) but has no rule in validation/pdl_check.py's RULES"])
        elif found:
            kernel, rule = found
            report(fn.name, check_ptx(fn, names(kernel, rule), rule))
            checked[kernel][0] += 1
    for fn in sass:
        waits = any(SASS_OP.match(s).group(2) == "ACQBULK" for _, s in fn.code)
        found = rule_for(fn.name)
        if waits and found is None:
            report(fn.name, ["waits (ACQBULK) but has no rule in validation/pdl_check.py's RULES"])
        elif found:
            kernel, rule = found
            params = elf.get(fn.name)
            if params is None:
                report(fn.name, ["SASS: no parameter layout (EIATTR_PARAM_CBANK, KPARAM_INFO) in the cubin"])
            else:
                report(fn.name, check_sass(fn, names(kernel, rule), params, rule))
            checked[kernel][1] += 1
    missing = []
    for kernel, (in_ptx, in_sass) in checked.items():
        print(f"{kernel}: {in_ptx} instantiations checked in PTX, {in_sass} in SASS; parameters "
              f"{', '.join(names_of.get(kernel, [])) or '-'}")
        if not in_ptx or not in_sass or in_ptx != in_sass:
            missing.append(kernel)
    if missing:
        print(f"FAIL {binary}: {', '.join(missing)} not found in both the PTX and the SASS for {arch} "
              f"(the check needs both: build with the default architecture, which embeds both)")
        return 1
    print(f"{binary}: {failures} functions failed" if failures else f"{binary}: every check passed")
    return 1 if failures else 0


def self_test() -> int:
    """The checks on saved code (validation/testing/pdl/): each case must fail or pass as stated."""
    here = ROOT / "validation" / "testing" / "pdl"
    rule = RULES["list_force_kernel"]
    names = parameter_names(ROOT / rule.source, "list_force_kernel")
    ok = True
    # SASS heads of the fused kernel (validation/reports/data/ab-2026-11-27.tar.xz,
    # file ab-2026-11-27k/c91-sass-fused-kernel-head.txt): head_k
    # (`ranked` const __restrict__, read after ACQBULK by the schedule) and fix_k (`ranked` without
    # __restrict__) pass; c90_k reads ranked (c[0x0][0x318]) before ACQBULK.
    slots = (0x210, [(0, 0, 0x100), (1, 0x100, 8), (2, 0x108, 8), (3, 0x110, 8), (4, 0x118, 8), (5, 0x120, 8)])
    sections: dict[str, Sass] = {}
    for line in (here / "fused-kernel-sass-heads.txt").read_text().splitlines():
        if line.startswith("== "):
            sections[line[3:].strip()] = Sass(line[3:].strip())
        elif sections and re.match(r"[0-9a-f]{4} ", line):
            addr, text = line.split(" ", 1)
            list(sections.values())[-1].code.append((int(addr, 16), text.strip()))
    for case, expect in (("head_k", None), ("fix_k", None), ("c90_k", "ranked")):
        problems = check_sass(sections[case], names, slots, rule)
        good = (not problems) if expect is None else any(expect in p and "0120" in p for p in problems)
        ok &= good
        print(f"{'ok  ' if good else 'FAIL'} SASS {case}: {len(problems)} findings"
              + "".join(f"\n       {p}" for p in problems[:3]))
    # PTX of the fused kernel, whole: ea60bce (ranked read through ld.global.nc) and c91 (without).
    c91 = (here / "fused-kernel-ptx-c91.ptx").read_text()
    cases = [("ea60bce", (here / "fused-kernel-ptx-ea60bce.ptx").read_text(), ("non-coherent", "ranked")),
             ("c91", c91, None)]
    # c91's PTX with one mutation each, which the check must find: a coherent read of the fused
    # kick-drift's state (`then`, a struct parameter read through its address) made non-coherent, and
    # the wait moved below the first read of `ranked`.
    fn = ptx_functions(c91)[0]
    parsed, defs = ptx_statements(fn)

    def first_read(param: int) -> str:
        return next(fn.lines[i] for i, (op, _, _, _) in enumerate(parsed)
                    if op.startswith("ld.global.") and ".nc" not in op
                    and any(b.split("+")[0] == str(param) for b in ptx_bases(fn, i, defs, parsed)))
    then_read = first_read(names.index("then"))
    cases.append(("c91, then read non-coherently", c91.replace(then_read, then_read.replace("ld.global.", "ld.global.nc.", 1), 1),
                  ("non-coherent", "then")))
    ranked_read = first_read(names.index("ranked"))
    wait = "griddepcontrol.wait;"
    late = c91.replace(wait, "", 1).replace(ranked_read + ";", ranked_read + ";\n" + wait, 1)
    cases.append(("c91, the wait after a read of ranked", late, ("PTX order", "ranked")))
    for case, text, expect in cases:
        problems = check_ptx(ptx_functions(text)[0], names, rule)
        good = (not problems) if expect is None else any(all(e in p for e in expect) for p in problems)
        ok &= good
        print(f"{'ok  ' if good else 'FAIL'} PTX {case}: {len(problems)} findings"
              + "".join(f"\n       {p}" for p in problems[:3]))
    return 0 if ok else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("binary", nargs="*", type=Path, help="executables, libraries or objects with CUDA code")
    ap.add_argument("--self-test", action="store_true", help="check the saved cases in validation/testing/pdl")
    ap.add_argument("--arch", default="sm_90", help="the architecture whose code is checked (default sm_90)")
    ap.add_argument("--tool-dir", type=Path, help="look for cuobjdump and nvdisasm here first (a CUDA toolkit's bin)")
    args = ap.parse_args()
    if args.self_test:
        return self_test()
    if not args.binary:
        ap.error("name a binary to check, or --self-test")
    tools = {t: find_tool(t, args.tool_dir) for t in ("cuobjdump", "nvdisasm")}
    if not all(tools.values()):
        print("FAIL cuobjdump or nvdisasm not found (a CUDA toolkit's, or pip install nvidia-cuda-cuobjdump "
              "nvidia-cuda-nvdisasm; bash .ci/setup puts them in .venv)")
        return 1
    results = [check_binary(binary, tools, args.arch) for binary in args.binary]
    if 1 in results:
        return 1
    return 0 if 0 in results else 77


if __name__ == "__main__":
    raise SystemExit(main())
