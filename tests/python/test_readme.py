"""The README's Python examples (section "Python") run as written: each ```python block executed in
a fresh namespace, and nothing it computes is NaN."""
from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[2] / "README.md"


def python_blocks():
    text = README.read_text()
    section = text.split("\n## Python\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, flags=re.S)


def test_the_readme_has_its_examples():
    assert len(python_blocks()) >= 3


@pytest.mark.parametrize("index", range(len(python_blocks())))
def test_readme_example_runs(index):
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
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, f"README.md python block {index}", "exec"), {})
    printed = out.getvalue()
    assert printed.strip(), "the example printed nothing"
    assert "nan" not in printed.lower()
