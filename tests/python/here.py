"""What this machine can run, for the Python tests: why the cuda backend cannot (as the library
says it; empty where it can), once per session."""
from __future__ import annotations

import functools

import numpy as np

import cellforce


@functools.cache
def cuda_missing() -> str:
    if not cellforce.built_with_cuda:
        return "this cellforce was built without CUDA"
    try:
        cellforce.ForceKernel(box=[10.0, 10.0, 10.0], backend="cuda").compute(np.zeros((1, 3)))
    except RuntimeError as e:
        return str(e)
    return ""
