"""The README's Python examples (section "Python") run as written, from the repository's root: each
```python block executed in a fresh namespace, and nothing it computes is NaN (the CuPy example
skips without CuPy and a CUDA device, the ASE one without ASE)."""
from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"


def python_blocks():
    text = README.read_text()
    section = text.split("\n## Python\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, flags=re.S)


def test_the_readme_has_its_examples():
    assert len(python_blocks()) >= 4


@pytest.mark.parametrize("index", range(len(python_blocks())))
def test_readme_example_runs(index, monkeypatch):
    code = python_blocks()[index]
    if "ase" in code:
        pytest.importorskip("ase")
    if "cupy" in code:
        cupy = pytest.importorskip("cupy")
        import cellforce

        if not cellforce.built_with_cuda:
            pytest.skip("this cellforce was built without CUDA")
        try:
            cupy.cuda.runtime.getDeviceCount()
        except cupy.cuda.runtime.CUDARuntimeError as e:
            pytest.skip(f"no CUDA device ({e})")
    monkeypatch.chdir(ROOT)  # the examples run from the repository's root (its paths are relative to it)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, f"README.md python block {index}", "exec"), {})
    printed = out.getvalue()
    assert printed.strip(), "the example printed nothing"
    assert "nan" not in printed.lower()
