"""Molecular dynamics from Python: cellforce.Simulation, a Lennard-Jones system integrated by the
library's own MD loop (Context::step, on the CPU or on the GPU where the state stays), made from a
scene file as `cellforce run` makes it or from arrays, with reporters called every N steps (as
OpenMM's are) and a progress bar for long runs."""
from __future__ import annotations

import json
import sys
from typing import Callable, Mapping, Sequence

import numpy as np

from ._cellforce import SimulationCore

_FRAMEWORKS = {"dlpack": 0, "cupy": 1, "torch": 2, "jax": 3}


def _options(backend, precision, device, skin, options) -> list[tuple[str, str]]:
    """The engine options as Context::set_option takes them (keys and values as text), in order."""
    out = []
    for key, value in (("backend", backend), ("precision", precision), ("device", device), ("skin", skin)):
        if value is not None:
            out.append((key, str(value)))
    for key, value in (options or {}).items():
        if isinstance(value, bool):
            value = "true" if value else "false"
        out.append((str(key), str(value)))
    return out


def _host_rows(array, name: str, n: int | None, dim: int) -> np.ndarray:
    """An (n, dim) float64 C-contiguous host copy of `array` (a device array is copied through the
    host: set_* calls take host arrays), or a ValueError / TypeError naming `name`."""
    if hasattr(array, "__cuda_array_interface__") or hasattr(array, "__dlpack_device__"):
        try:
            device_type = array.__dlpack_device__()[0] if hasattr(array, "__dlpack_device__") else 2
        except Exception:  # noqa: BLE001 - no DLPack after all: read it through its interface below
            device_type = 2
        if device_type in (2, 13):  # CUDA memory: through the framework's own copy to the host
            if hasattr(array, "get"):  # CuPy
                array = array.get()
            elif hasattr(array, "cpu"):  # PyTorch
                array = array.detach().cpu().numpy()
            else:
                array = np.asarray(array)
    try:
        a = np.ascontiguousarray(array, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise TypeError(f"{name}: expected an (n, {dim}) array of numbers ({e})") from None
    if a.ndim != 2 or a.shape[1] != dim or (n is not None and a.shape[0] != n):
        want = f"({n if n is not None else 'n'}, {dim})"
        raise ValueError(f"{name}: shape {a.shape}; expected {want}")
    return a


class Simulation:
    """A Lennard-Jones MD simulation whose state lives where the backend computes (the GPU with
    'cuda': nothing crosses to the host between reports).

    Simulation(box, positions, ...) makes one from arrays; Simulation.from_scene(path) from a scene
    file (systems/*.toml) as `cellforce run` starts it, bit for bit. run(steps) advances it;
    thermo, positions, velocities and forces read it; set_positions, set_velocities and set_box
    change it in place; minimize() relaxes it with FIRE. Units are the caller's (lengths as the
    positions, energies as epsilon, masses as given, time as dt).

    box: edge lengths (2 or 3); positions: (n, dim) array (any periodic image; wrapped into the box);
    periodic: which axes wrap (default all); cutoff: pairs interact for r < cutoff; types:
    {name: (sigma, epsilon)} (default one type 'A': (1, 1)), indexed in the dict's order; pairs:
    {(a, b): (sigma, epsilon)} explicit pair values; mixing: 'lorentz-berthelot' or 'geometric';
    mode: 'truncate', 'shift' or 'force-shift'; species: each particle's type, as names or indices
    (default all the first type); masses: {name: mass}, one number for all, or (n,) per particle
    (default 1); velocities: (n, dim), else drawn from Maxwell-Boltzmann at initial_temperature
    (energy units, kT) with `seed` (the centre of mass at rest for 'nve'), else zero; integrator:
    'nve' (velocity Verlet) or 'langevin' (BAOAB at `temperature` kT with `friction` 1/time, noise
    keyed by `seed`); dt: the time step; precision: 'single', 'mixed' or 'double'; backend: 'cpu',
    'cuda' or 'auto'; device: the CUDA device; skin: 'auto' or a length; options: any other engine
    option (set_option's keys, e.g. {'neighbor-list': True}); step: the step counter to start at;
    arrays: how device views are handed out ('auto': CuPy, PyTorch or JAX, whichever is imported
    first in that order, else DLPack; or one of 'cupy', 'torch', 'jax', 'dlpack'; a DLPack array is
    taken once, by a framework's from_dlpack).
    """

    def __init__(self, box: Sequence[float], positions, *, periodic=None, cutoff: float = 2.5,
                 types: Mapping[str, tuple[float, float]] | None = None,
                 pairs: Mapping[tuple[str, str], tuple[float, float]] | None = None,
                 mixing: str = "lorentz-berthelot", mode: str = "truncate", species=None, masses=None,
                 velocities=None, initial_temperature: float | None = None, seed: int = 1,
                 integrator: str = "nve", dt: float = 0.005, temperature: float = 1.0, friction: float = 1.0,
                 precision: str = "double", backend: str = "auto", device: int = 0, skin="auto",
                 options: Mapping[str, object] | None = None, step: int = 0, arrays: str = "auto"):
        box = [float(b) for b in box]
        dim = len(box)
        if dim not in (2, 3):
            raise ValueError(f"box: {dim} edge lengths; expected 2 or 3")
        x = _host_rows(positions, "positions", None, dim)
        n = len(x)
        # The physics (periodic, types, pairs) is read by the compiled core, as ForceKernel reads it;
        # here only the type names, in the dict's order, for species and masses by name.
        if types is not None and not isinstance(types, Mapping):
            raise TypeError("types: expected {name: (sigma, epsilon)}")
        types = None if types is None else dict(types)
        names = ["A"] if types is None else [str(name) for name in types]

        def index_of(name, what):
            if name not in names:
                raise ValueError(f"{what}: unknown type '{name}'")
            return names.index(name)

        if species is None:
            type_index = np.zeros(n, dtype=np.uint32)
        else:
            given = np.asarray(species)
            if given.shape != (n,):
                raise ValueError(f"species: shape {given.shape}; expected ({n},)")
            if given.dtype.kind in "iu":
                bad = np.nonzero((given < 0) | (given >= len(names)))[0]
                if len(bad):
                    raise ValueError(f"species: particle {bad[0]} has type index {given[bad[0]]} "
                                     f"({len(names)} types)")
                type_index = given.astype(np.uint32)
            else:
                lookup = {name: i for i, name in enumerate(names)}
                try:
                    type_index = np.array([lookup[str(s)] for s in given], dtype=np.uint32)
                except KeyError as e:
                    i = next(i for i, s in enumerate(given) if str(s) not in lookup)
                    raise ValueError(f"species: particle {i} has the unknown type {e}") from None
        if masses is None:
            m = np.ones(n)
        elif isinstance(masses, Mapping):
            per_type = np.ones(len(names))
            for name, mass in masses.items():
                per_type[index_of(name, "masses")] = float(mass)
            m = per_type[type_index]
        elif np.ndim(masses) == 0:
            m = np.full(n, float(masses))
        else:
            m = np.ascontiguousarray(masses, dtype=np.float64)
            if m.shape != (n,):
                raise ValueError(f"masses: shape {m.shape}; expected ({n},)")
        v = None if velocities is None else _host_rows(velocities, "velocities", n, dim)
        self._core = SimulationCore(
            box, periodic, float(cutoff), mode, mixing, types, None if pairs is None else dict(pairs),
            _options(backend, precision, device, skin, options),
            integrator, float(dt), float(temperature), float(friction), int(seed), x, type_index,
            np.ascontiguousarray(m, dtype=np.float64), v,
            None if initial_temperature is None else float(initial_temperature), int(step))
        self._setup(arrays)

    @classmethod
    def from_scene(cls, path, *, backend: str | None = None, precision: str | None = None,
                   device: int | None = None, skin=None, options: Mapping[str, object] | None = None,
                   arrays: str = "auto") -> "Simulation":
        """The scene file's system as `cellforce run` starts it (its particles, types, interactions,
        [initial] velocities, [integrator], [run] and [neighbor] engine options, [minimize]), at
        step 0: the same numbers as the CLI, step by step, on the same backend and precision (a
        start whose first step would throw particles apart is refused, as the CLI refuses it for a
        run of any length). backend, precision, device, skin and options replace the scene's. The
        scene's [run] steps is scene_steps; its [output] is the CLI's (a Simulation reports through
        its reporters)."""
        self = cls.__new__(cls)
        self._core = SimulationCore.from_scene(str(path), _options(backend, precision, device, skin, options))
        self._setup(arrays)
        return self

    def _setup(self, arrays: str) -> None:
        if arrays != "auto" and arrays not in _FRAMEWORKS:
            raise ValueError(f"arrays: '{arrays}'; expected 'auto', 'cupy', 'torch', 'jax' or 'dlpack'")
        self._arrays = arrays
        self.reporters: list[tuple[int, Callable[["Simulation"], None]]] = []

    # ---- running ----
    def add_reporter(self, callback: Callable[["Simulation"], None], every: int) -> None:
        """Calls callback(simulation) after every step whose number is a multiple of `every`, during
        run() (OpenMM's reporters' rule); the state and thermo it reads are that step's."""
        if int(every) < 1:
            raise ValueError(f"every: {every}; expected >= 1")
        if not callable(callback):
            raise TypeError("callback: expected a callable taking the simulation")
        self.reporters.append((int(every), callback))

    def run(self, steps: int, *, progress: bool = False) -> None:
        """Advances `steps` steps. Reporters are called at their steps; with progress=True a
        progress bar (tqdm's, in a notebook or a terminal; a line on stderr without tqdm) follows
        the run. An integration that diverges, or a force that is not finite, raises ValueError
        naming the particle and the steps."""
        steps = int(steps)
        if steps < 0:
            raise ValueError(f"steps: {steps}; expected >= 0")
        bar = _progress(steps) if progress else None
        slice_ = max(1, steps // 200) if bar else steps
        done = 0
        try:
            while done < steps:
                now = self._core.step_count
                chunk = min(steps - done, slice_)
                for every, _ in self.reporters:
                    chunk = min(chunk, every - now % every)
                after = now + chunk
                due = [callback for every, callback in self.reporters if after % every == 0]
                self._core.step(chunk, bool(due) or done + chunk == steps)
                done += chunk
                for callback in due:
                    callback(self)
                if bar:
                    bar.update(chunk)
        finally:
            if bar:
                bar.close()

    def minimize(self, *, force_tolerance: float = 100.0, max_steps: int = 10000, dt: float = 0.001,
                 dt_max: float | None = None, max_displacement: float = 0.1) -> dict:
        """FIRE on the positions until every |F_i| < force_tolerance (velocities left zero); raises
        ValueError naming the particle with the largest force when it does not converge within
        max_steps (the state is then as before). Returns steps, initial/final energy and largest
        force, and the particle with the final largest force."""
        return self._core.minimize(float(force_tolerance), int(max_steps), float(dt),
                                   float(10 * dt if dt_max is None else dt_max), float(max_displacement))

    # ---- the state ----
    @property
    def thermo(self) -> dict:
        """The state's thermodynamics now: step, time, kinetic, potential and total energy,
        temperature (2 KE / degrees of freedom), pressure (NaN with an open axis) and the virial
        (dim, dim) as NumPy; a reduction where the state lives."""
        return self._core.thermo()

    def _view(self, which: int):
        return self._core.state_view(which, _framework(self._arrays))

    @property
    def positions(self):
        """(n, dim) float64: the positions where the state lives, read in place (wrapped into the box
        on periodic axes): a read-only NumPy view on the cpu backend, a device array with cuda (see
        `arrays`; not to be written: set_positions changes them). A view follows the state as it
        changes (run, minimize, set_*): read after a change, it shows the state after it (a forces
        view on the cpu backend excepted: read `forces` again after a step). While a view lives,
        set_box is refused (BufferError: a new box may give the state new arrays); get_state()
        copies."""
        return self._view(0)

    @property
    def velocities(self):
        """(n, dim) float64: the velocities where the state lives, read in place (as positions)."""
        return self._view(1)

    @property
    def forces(self):
        """(n, dim) float64: the forces at the positions where the state lives, read in place (as
        positions; on the cpu backend the forces alternate between two arrays from one evaluation to
        the next, so a view held across a step shows an older evaluation's: read it again)."""
        return self._view(2)

    def get_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Host copies (NumPy) of positions, velocities and forces."""
        return self._core.get_state()

    def set_positions(self, positions) -> None:
        """New positions (n, dim; host or device array) for the live state, wrapped into the box; the
        forces are evaluated at them (velocities and step kept). A position that is not finite, or
        two particles on one point, raises ValueError naming them and leaves the state as it was."""
        self._core.set_positions(_host_rows(positions, "positions", self.n, self.dim))

    def set_velocities(self, velocities) -> None:
        """New velocities (n, dim; host or device array), finite."""
        self._core.set_velocities(_host_rows(velocities, "velocities", self.n, self.dim))

    def set_box(self, box: Sequence[float], *, periodic=None, scale_positions: bool = False) -> None:
        """A new box for the live state (edge lengths; periodic: one truth value per axis, default
        the axes' rule now): positions scaled with the edges (scale_positions) or wrapped into the
        new box, the forces evaluated again. A box the state cannot take (a periodic edge below twice
        the cutoff) raises ValueError naming it and leaves the state as it was; BufferError while a
        view of the state (positions, velocities, forces) lives."""
        lengths = [float(b) for b in box]
        periodic = self.periodic if periodic is None else [bool(p) for p in periodic]
        self._core.set_box(lengths, periodic, bool(scale_positions))

    def statistics(self) -> dict:
        """The library's statistics as a dict (Context::statistics_json, docs/library.md)."""
        return json.loads(self._core.statistics_json())

    # ---- what it is ----
    n = property(lambda self: self._core.n, doc="the particle count")
    dim = property(lambda self: self._core.dim, doc="2 or 3")
    step = property(lambda self: self._core.step_count, doc="the step counter")
    time = property(lambda self: self._core.step_count * self._core.dt, doc="step x dt")
    dt = property(lambda self: self._core.dt, doc="the time step")
    box = property(lambda self: list(self._core.box), doc="the box's edge lengths now")
    periodic = property(lambda self: list(self._core.periodic), doc="which axes wrap")
    type_names = property(lambda self: self._core.type_names, doc="the types in index order")
    species = property(lambda self: self._core.species, doc="(n,) uint32: each particle's type index (a copy)")
    masses = property(lambda self: self._core.masses, doc="(n,) float64: each particle's mass (a copy)")
    scene_steps = property(lambda self: self._core.scene_steps, doc="a scene's [run] steps (None otherwise)")
    backend = property(lambda self: self._core.backend, doc="'cpu' or 'cuda': the backend in use")
    description = property(lambda self: self._core.description, doc="the engine in words")
    neighbor = property(lambda self: self._core.neighbor, doc="the neighbour structure in words")


def _framework(arrays: str) -> int:
    if arrays != "auto":
        return _FRAMEWORKS[arrays]
    for name in ("cupy", "torch", "jax"):
        if name in sys.modules:
            return _FRAMEWORKS[name]
    return _FRAMEWORKS["dlpack"]


class _LineProgress:
    """A progress line on stderr where tqdm is not installed."""

    def __init__(self, total: int):
        self.total, self.done = total, 0

    def update(self, count: int) -> None:
        self.done += count
        sys.stderr.write(f"\rstep {self.done}/{self.total}")
        sys.stderr.flush()

    def close(self) -> None:
        sys.stderr.write("\n")


def _progress(total: int):
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return _LineProgress(total)
    return tqdm(total=total, unit="step")
