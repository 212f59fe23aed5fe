"""ForceKernel.compute on arrays on a CUDA device (CuPy, PyTorch, and producers of
__cuda_array_interface__ or DLPack alone): the results of the same values as NumPy arrays, bitwise
(the cuda backend, every precision); results as the input framework's device arrays, written in
place where the caller gives them; the call queued on the array's stream or the one given; no copy
through the host (a CUPTI trace of the calls by PyTorch's profiler); bad input named. Each test
skips where its framework or a CUDA device is missing (here: CI's machine); the GPU machine has
CuPy and PyTorch."""
from __future__ import annotations

import json

import numpy as np
import pytest

import cellforce
from here import cuda_missing
from xyz import SYSTEMS, read_xyz

cupy = pytest.importorskip("cupy", reason="CuPy is not installed (the device tests need CuPy; PyTorch's too)")
BINARY = {"A": (1.0, 1.0), "B": (0.88, 0.5)}


def missing() -> str:
    """Why the device tests cannot run here (empty: they can)."""
    if cuda_missing():
        return cuda_missing()
    try:
        if cupy.cuda.runtime.getDeviceCount() == 0:
            return "CuPy sees no CUDA device"
    except cupy.cuda.runtime.CUDARuntimeError as e:
        return f"CuPy sees no CUDA device ({e})"
    return ""


pytestmark = pytest.mark.skipif(bool(missing()), reason=missing() or "-")


def binary():
    box, periodic, species, x = read_xyz(SYSTEMS / "binary_lb.xyz")
    index = np.array([list(BINARY).index(s) for s in species], dtype=np.int32)
    return box, periodic, index, x


class InterfaceOnly:
    """A producer with __cuda_array_interface__ alone (version 3, naming its stream), over a CuPy
    array's memory: the protocol as Numba or any library without DLPack gives it."""

    def __init__(self, a, stream: int | None = None):
        self._a = a
        self.__cuda_array_interface__ = dict(a.__cuda_array_interface__)
        self.__cuda_array_interface__["version"] = 3
        if stream is not None:
            self.__cuda_array_interface__["stream"] = stream


class DlpackOnly:
    """A producer with DLPack alone (no __cuda_array_interface__), over a CuPy array."""

    def __init__(self, a):
        self._a = a
        self.streams = []

    def __dlpack__(self, stream=None, **kwargs):
        self.streams.append(stream)
        return self._a.__dlpack__(stream=stream, **kwargs)

    def __dlpack_device__(self):
        return self._a.__dlpack_device__()


@pytest.mark.parametrize("precision", ["double", "mixed", "single"])
def test_cupy_arrays_give_the_numpy_results_bitwise(precision):
    box, periodic, index, x = binary()
    k = cellforce.ForceKernel(box=box, periodic=periodic, types=BINARY, precision=precision, backend="cuda")
    host = k.compute(x, types=index, energy=True, virial=True)
    r = k.compute(cupy.asarray(x), types=cupy.asarray(index), energy=True, virial=True)
    assert isinstance(r.forces, cupy.ndarray) and isinstance(r.energy, cupy.ndarray)
    for a in (r.forces, r.energies, r.energy, r.virial):  # the module's memory in place, not CuPy's copy
        assert not isinstance(a.data.mem, cupy.cuda.memory.PooledMemory)
    assert r.forces.shape == x.shape and r.energies.shape == (len(x),) and r.energy.shape == ()
    assert r.virial.shape == (3, 3)
    k.synchronize()
    assert np.array_equal(cupy.asnumpy(r.forces), host.forces)
    assert np.array_equal(cupy.asnumpy(r.energies), host.energies)
    assert float(r.energy) == host.energy
    assert np.array_equal(cupy.asnumpy(r.virial), host.virial)
    # float32 positions and uint32 types on the device: the host call's on the same values
    x32 = x.astype(np.float32)
    want = k.compute(x32, types=index.astype(np.uint32)).forces
    got = k.compute(cupy.asarray(x32), types=cupy.asarray(index.astype(np.uint32))).forces
    assert np.array_equal(cupy.asnumpy(got), want)


def test_torch_tensors_give_the_numpy_results_bitwise():
    torch = pytest.importorskip("torch")
    box, periodic, index, x = binary()
    k = cellforce.ForceKernel(box=box, periodic=periodic, types=BINARY, backend="cuda")
    host = k.compute(x, types=index, energy=True)
    r = k.compute(torch.from_numpy(x).cuda(), types=torch.from_numpy(index).cuda(), energy=True)
    assert isinstance(r.forces, torch.Tensor) and r.forces.is_cuda and r.forces.dtype == torch.float64
    torch.cuda.synchronize()
    assert np.array_equal(r.forces.cpu().numpy(), host.forces)
    assert r.energy.item() == host.energy


def test_interface_and_dlpack_producers_and_the_stream_they_name():
    """__cuda_array_interface__ alone (its stream used) and DLPack alone (asked for in the order of
    the stream given): the NumPy results; results as DLPack arrays CuPy reads in place."""
    box, periodic, index, x = binary()
    k = cellforce.ForceKernel(box=box, periodic=periodic, types=BINARY, backend="cuda")
    want = k.compute(x, types=index).forces
    stream = cupy.cuda.Stream(non_blocking=True)
    xd, td = cupy.asarray(x), cupy.asarray(index)
    cupy.cuda.Device().synchronize()
    r = k.compute(InterfaceOnly(xd, stream.ptr), types=InterfaceOnly(td))
    stream.synchronize()
    assert np.array_equal(cupy.asnumpy(cupy.from_dlpack(r.forces)), want)
    producer = DlpackOnly(xd)
    r = k.compute(producer, types=td, stream=stream)
    assert producer.streams == [stream.ptr]
    stream.synchronize()
    assert np.array_equal(cupy.asnumpy(cupy.from_dlpack(r.forces)), want)


SPIN = r"""
extern "C" __global__ void spin(long long cycles) {
  const long long start = clock64();
  while (clock64() - start < cycles) {
  }
}"""


def delay(stream, seconds: float = 0.05):
    """Queues a kernel on `stream` that spins for about `seconds` (at 2 GHz)."""
    kernel = cupy.RawKernel(SPIN, "spin")
    with stream:
        kernel((1,), (1,), (np.int64(seconds * 2e9),))


def test_a_call_waits_for_the_stream_its_arrays_name_and_holds_them():
    """Positions written on a producer's stream behind a long kernel: the call reads the new ones,
    on the stream their interface names and on another stream given (which waits for it); a
    temporary whose only reference is the call's is not reused before the call has run."""
    box, periodic, index, x = binary()
    k = cellforce.ForceKernel(box=box, periodic=periodic, types=BINARY, backend="cuda")
    moved = x + np.random.default_rng(3).normal(0.0, 0.01, x.shape)
    want_old, want_new = k.compute(x, types=index).forces, k.compute(moved, types=index).forces
    producer, caller = cupy.cuda.Stream(non_blocking=True), cupy.cuda.Stream(non_blocking=True)
    xd, td, new, old = cupy.asarray(x), cupy.asarray(index), cupy.asarray(moved), cupy.asarray(x)
    cupy.cuda.Device().synchronize()
    delay(producer)
    with producer:
        xd[...] = new
    r = k.compute(InterfaceOnly(xd, producer.ptr), types=InterfaceOnly(td))  # on the producer's stream
    producer.synchronize()
    assert np.array_equal(cupy.asnumpy(cupy.from_dlpack(r.forces)), want_new)
    delay(producer)
    with producer:
        xd[...] = old
    r = k.compute(InterfaceOnly(xd, producer.ptr), types=td, stream=caller)  # the caller's waits for it
    caller.synchronize()
    assert np.array_equal(cupy.asnumpy(cupy.from_dlpack(r.forces)), want_old)
    delay(caller)
    r = k.compute(cupy.asarray(moved), types=td, stream=caller)  # the temporary: held by the call alone
    for _ in range(4):
        cupy.full(x.shape, 1e3)  # on the default stream, where the temporary's memory would be reused
    caller.synchronize()
    k.synchronize()
    assert np.array_equal(cupy.asnumpy(r.forces), want_new)


def test_calls_on_a_stream_in_place_and_into_the_callers_arrays():
    """A loop on a non-blocking CuPy stream (the current stream, named by the arrays' interface):
    forces written into the caller's array, bitwise the host call's at each step's positions, and
    the results of calls whose arrays were dropped at once do not disturb the kept ones."""
    box, periodic, index, x = binary()
    k = cellforce.ForceKernel(box=box, periodic=periodic, types=BINARY, backend="cuda")
    rng = np.random.default_rng(7)
    stream = cupy.cuda.Stream(non_blocking=True)
    with stream:
        xd = cupy.asarray(x)
        f = cupy.full(x.shape, np.nan)
        kept = []
        for step in range(20):
            xd += cupy.asarray(rng.normal(scale=0.002, size=x.shape))
            r = k.compute(xd, types=cupy.asarray(index), forces=f, energy=True)
            assert r.forces is f
            k.compute(xd, types=cupy.asarray(index), energy=True, virial=True)  # dropped at once
            kept.append((xd.copy(), f.copy(), r.energy))
    stream.synchronize()
    k.synchronize()
    for xs, fs, e in kept:
        host = k.compute(cupy.asnumpy(xs), types=index, energy=True)
        assert np.array_equal(cupy.asnumpy(fs), host.forces)
        assert float(e) == host.energy


def test_results_stay_on_the_device_and_cross_no_host_copy(tmp_path):
    """The result arrays are device memory handed out in place (the pointer the kernel wrote), and a CUPTI trace of steady calls (PyTorch's
    profiler, which sees every CUDA copy in the process) holds no copy as large as the forces;
    the same trace does hold the copy of the forces to the host made afterwards on purpose."""
    torch = pytest.importorskip("torch")
    from torch.profiler import ProfilerActivity, profile

    n = 4000
    rng = np.random.default_rng(11)
    x = cupy.asarray(rng.random((n, 3)) * 16.0)
    k = cellforce.ForceKernel(box=[16.0, 16.0, 16.0], backend="cuda")
    for _ in range(5):
        r = k.compute(x)
    k.synchronize()
    attributes = cupy.cuda.runtime.pointerGetAttributes(r.forces.data.ptr)
    assert attributes.type == 2 and attributes.device == k.device  # cudaMemoryTypeDevice
    with profile(activities=[ProfilerActivity.CUDA]) as prof:
        for _ in range(10):
            r = k.compute(x, energy=True, virial=True)
        k.synchronize()
        torch.cuda.synchronize()
        marker = torch.empty(1, device="cuda")  # the calls' copies end here
        marker.fill_(1.0)
        torch.cuda.synchronize()
        host = cupy.asnumpy(r.forces)
    trace = tmp_path / "trace.json"
    prof.export_chrome_trace(str(trace))
    events = json.loads(trace.read_text())["traceEvents"]
    copies = [e for e in events if e.get("cat") == "gpu_memcpy"]
    forces_bytes = n * 3 * 8
    large = [e for e in copies if e.get("args", {}).get("bytes", 0) >= forces_bytes]
    assert len(large) == 1, [(e["name"], e["args"].get("bytes")) for e in copies]  # the copy made on purpose
    assert "DtoH" in large[0]["name"] and host.shape == (n, 3)


def test_bad_device_input_is_named():
    box, periodic, index, x = binary()
    k = cellforce.ForceKernel(box=box, periodic=periodic, types=BINARY, backend="cuda")
    xd = cupy.asarray(x)
    with pytest.raises(TypeError, match="positions: expected a C-contiguous array"):
        k.compute(cupy.asfortranarray(xd))
    with pytest.raises(TypeError, match="positions: expected float64 or float32 values, not"):
        k.compute(xd.astype(cupy.int64))
    with pytest.raises(ValueError, match=r"positions: shape \(\d+, 2\); expected \(n, 3\)"):
        k.compute(cupy.ascontiguousarray(xd[:, :2]))
    with pytest.raises(TypeError, match="types: with positions on a CUDA device"):
        k.compute(xd, types=["A"] * len(x))
    with pytest.raises(TypeError, match="types: an array on the host; the positions are on CUDA device 0"):
        k.compute(xd, types=index)
    with pytest.raises(TypeError, match="forces: an array on the host; the positions are on CUDA device 0"):
        k.compute(xd, forces=np.zeros(x.shape))
    with pytest.raises(TypeError, match="forces: expected float64, not float32"):
        k.compute(xd, forces=cupy.zeros(x.shape, dtype=cupy.float32))
    with pytest.raises(ValueError, match="n_ghost: ghosts are computed from host arrays"):
        k.compute(xd, n_ghost=3)
    with pytest.raises(TypeError, match="positions: an array on a CUDA device, but this kernel computes on the cpu"):
        cellforce.ForceKernel(box=box, periodic=periodic, backend="cpu").compute(xd)
    bad = xd.copy()
    bad[7, 1] = cupy.nan
    k.compute(bad)  # queued: the device finds it
    with pytest.raises(ValueError, match="particle 7"):
        k.synchronize()
    types = cupy.asarray(index)
    types[5] = 9
    k.compute(xd, types=types)
    with pytest.raises(ValueError, match="particle 5"):
        k.synchronize()
    assert np.array_equal(cupy.asnumpy(k.compute(xd, types=cupy.asarray(index)).forces),
                          k.compute(x, types=index).forces)


def test_arrays_on_another_device_are_refused():
    if cupy.cuda.runtime.getDeviceCount() < 2:
        pytest.skip("one CUDA device here: no other device to hold the arrays")
    box, periodic, index, x = binary()
    k = cellforce.ForceKernel(box=box, periodic=periodic, types=BINARY, backend="cuda", device=0)
    with cupy.cuda.Device(1):
        elsewhere, types_there = cupy.asarray(x), cupy.asarray(index)
    with pytest.raises(TypeError, match="positions: an array on CUDA device 1; this kernel computes on device 0"):
        k.compute(elsewhere)
    k1 = cellforce.ForceKernel(box=box, periodic=periodic, types=BINARY, backend="cuda", device=1)
    with pytest.raises(TypeError, match="types: an array on CUDA device 0; the positions are on CUDA device 1"):
        k1.compute(elsewhere, types=cupy.asarray(index))
    r = k1.compute(elsewhere, types=types_there)  # the kernel on device 1 takes them
    k1.synchronize()
    assert r.forces.device.id == 1
    assert np.array_equal(cupy.asnumpy(r.forces), k.compute(x, types=index).forces)
