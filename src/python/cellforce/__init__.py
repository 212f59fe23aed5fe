"""cellforce from Python: Lennard-Jones forces by the cell search of GPU Gems 3, chapter 32, on the
CPU or a CUDA device.

    import numpy as np, cellforce
    k = cellforce.ForceKernel(box=[10.0, 10.0, 10.0], cutoff=2.5,
                              types={"A": (1.0, 1.0), "B": (0.88, 0.5)})
    r = k.compute(positions, types=None, energy=True, virial=True)
    r.forces, r.energy, r.energies, r.virial

positions are (n, dim) float64 or float32 arrays in your units, used in place where they live:
NumPy on the host (the results are NumPy arrays), or CuPy, PyTorch, JAX or any
__cuda_array_interface__ / DLPack array on a CUDA device (the results are arrays on that device,
the call queued on the array's stream). See ForceKernel.compute and Result. The module wraps the
C++ API (include/cellforce/cellforce.hpp): it computes nothing of its own.

Simulation runs molecular dynamics (the library's own loop, the state where the backend computes):
from a scene file as `cellforce run` starts it, or from arrays; see cellforce.Simulation.
"""
from ._cellforce import ForceKernel, Result, __version__, built_with_cuda
from .simulation import Simulation

__all__ = ["ForceKernel", "Result", "Simulation", "__version__", "built_with_cuda"]
