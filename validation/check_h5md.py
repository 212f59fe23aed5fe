"""Checks an H5MD trajectory written by cellforce (src/io/h5md_writer.h) with h5py and MDAnalysis.

    python validation/check_h5md.py FILE.h5 [--expect-frames K]

h5py: the H5MD 1.1 layout: /h5md version [1, 1], author and creator names (fixed-length strings);
for each /particles group, the box's dimension, boundary and edges; position (and velocity,
force) values of shape frames x n x D in float64; step (integer, strictly increasing) and time
(float, non-decreasing) shared with box/edges, velocity, force and the observables through hard
links; finite values; species (n integers) within the names of its `names` attribute; each
/observables element one float per frame; with --expect-frames, the frame count.

MDAnalysis (3D files only: its H5MD reader refuses other box dimensions): the file is read with
MDAnalysis's H5MDReader and every frame compared with h5py's values: positions, velocities and
forces (MDAnalysis holds them in float32: they must equal the float32 rounding of the file's
float64), box edges (angles 90), time, step and observables (exact). The values are in reduced LJ
units without `unit` attributes, so the reader runs with convert_units=False, and since H5MD
holds no topology the trajectory is loaded onto Universe.empty(n).

Exit status: 0 every check passed, 1 a check failed, 2 usage error, unreadable file, or h5py or
MDAnalysis missing (pip install -r validation/requirements.txt).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field

import numpy as np

try:
    import h5py
except ImportError:  # pragma: no cover - reported below
    h5py = None

TIME_DEPENDENT = ("position", "velocity", "force")


@dataclass
class Group:
    """What h5py read of one /particles group: the reference MDAnalysis is compared with."""

    name: str
    dim: int = 0
    n: int = 0
    frames: int = 0
    boundary: list = field(default_factory=list)
    edges: np.ndarray | None = None  # frames x D (a fixed box repeated per frame)
    edges_time_dependent: bool = False
    values: dict = field(default_factory=dict)  # element -> frames x n x D
    step: np.ndarray | None = None
    time: np.ndarray | None = None


class Report:
    def __init__(self):
        self.failures: list[str] = []
        self.checks = 0

    def check(self, ok, message):
        self.checks += 1
        if not ok:
            self.failures.append(message)
        return bool(ok)


def text(value):
    """An attribute's string(s) as str: h5py gives fixed-length strings as bytes."""
    if isinstance(value, (bytes, np.bytes_)):
        return value.decode("utf-8")
    if isinstance(value, np.ndarray):
        return [text(v) for v in value.tolist()]
    if isinstance(value, list):
        return [text(v) for v in value]
    return str(value)


def fixed_length_string(obj, name):
    type_id = obj.attrs.get_id(name).get_type()
    return isinstance(type_id, h5py.h5t.TypeStringID) and not type_id.is_variable_str()


def storage(dset):
    if dset.chunks is None:
        return "contiguous"
    out = f"chunks {dset.chunks}"
    if dset.compression:
        out += f", {dset.compression} level {dset.compression_opts}"
    if dset.shuffle:
        out += " + shuffle"
    return out


def check_with_h5py(path, expect_frames, report):
    groups = []
    summary = []
    with h5py.File(path, "r") as f:
        # /h5md metadata
        if report.check("h5md" in f, "no /h5md group"):
            h5md = f["h5md"]
            version = h5md.attrs.get("version")
            report.check(version is not None and np.issubdtype(np.asarray(version).dtype, np.integer)
                         and list(np.asarray(version)) == [1, 1], f"/h5md version is {version!r}, not [1, 1]")
            for sub, names in (("author", ("name",)), ("creator", ("name", "version"))):
                if not report.check(sub in h5md, f"no /h5md/{sub} group"):
                    continue
                for attr in names:
                    if report.check(attr in h5md[sub].attrs, f"/h5md/{sub} has no '{attr}' attribute"):
                        report.check(fixed_length_string(h5md[sub], attr),
                                     f"/h5md/{sub} '{attr}' is not a fixed-length string (H5MD 1.1 asks for one)")
            if "creator" in h5md and "name" in h5md["creator"].attrs:
                summary.append(f"creator {text(h5md['creator'].attrs['name'])} "
                               f"{text(h5md['creator'].attrs.get('version', b'?'))}")

        if not report.check("particles" in f and len(f["particles"]) > 0, "no /particles group"):
            return groups, summary
        for name, g in f["particles"].items():
            groups.append(check_group(f, name, g, expect_frames, report, summary))

        if "observables" in f:
            ref = groups[0]
            names = []
            for name, obs in f["observables"].items():
                where = f"/observables/{name}"
                if not report.check(isinstance(obs, h5py.Group) and "value" in obs, f"{where} has no value"):
                    continue
                names.append(name)
                value = obs["value"]
                report.check(value.shape == (ref.frames,) and value.dtype.kind == "f",
                             f"{where}/value: shape {value.shape} {value.dtype}, expected ({ref.frames},) floats")
                for axis in ("step", "time"):
                    report.check(axis in obs and obs[axis] == f[f"particles/{ref.name}/position/{axis}"],
                                 f"{where}/{axis} is not a hard link to /particles/{ref.name}/position/{axis}")
            summary.append("observables: " + (", ".join(names) or "none"))
    return groups, summary


def check_group(f, name, g, expect_frames, report, summary):
    where = f"/particles/{name}"
    out = Group(name)
    if not report.check("box" in g, f"{where} has no box"):
        return out
    box = g["box"]
    dim = box.attrs.get("dimension")
    report.check(dim is not None and np.issubdtype(np.asarray(dim).dtype, np.integer) and int(dim) in (2, 3),
                 f"{where}/box dimension is {dim!r}")
    out.dim = int(dim) if dim is not None else 0
    boundary = text(box.attrs.get("boundary", []))
    out.boundary = boundary
    report.check(len(boundary) == out.dim and all(b in ("periodic", "none") for b in boundary),
                 f"{where}/box boundary is {boundary!r}")
    if "boundary" in box.attrs:
        report.check(fixed_length_string(box, "boundary"), f"{where}/box boundary is not a fixed-length string")

    if not report.check("position" in g and "value" in g["position"], f"{where} has no position/value"):
        return out
    pos = g["position/value"]
    report.check(pos.ndim == 3 and pos.shape[2] == out.dim, f"{where}/position/value has shape {pos.shape}")
    out.frames, out.n = pos.shape[0], pos.shape[1]
    if expect_frames is not None:
        report.check(out.frames == expect_frames, f"{where}: {out.frames} frames, expected {expect_frames}")

    position = g["position"]
    if report.check("step" in position and position["step"].shape == (out.frames,)
                    and position["step"].dtype.kind in "iu", f"{where}/position/step: not {out.frames} integers"):
        out.step = position["step"][()]
        report.check(np.all(np.diff(out.step) > 0), f"{where}/position/step does not increase strictly: {out.step}")
    if report.check("time" in position and position["time"].shape == (out.frames,)
                    and position["time"].dtype.kind == "f", f"{where}/position/time: not {out.frames} floats"):
        out.time = position["time"][()]
        report.check(np.all(np.diff(out.time) >= 0), f"{where}/position/time decreases: {out.time}")

    for element in TIME_DEPENDENT:
        if element not in g:
            continue
        value = g[f"{element}/value"]
        if not report.check(value.shape == (out.frames, out.n, out.dim) and value.dtype == np.float64,
                            f"{where}/{element}/value: shape {value.shape} {value.dtype}, expected "
                            f"{(out.frames, out.n, out.dim)} float64"):
            continue
        out.values[element] = value[()]
        report.check(np.all(np.isfinite(out.values[element])), f"{where}/{element}/value holds non-finite values")
        if element != "position":
            for axis in ("step", "time"):
                report.check(axis in g[element] and g[f"{element}/{axis}"] == position[axis],
                             f"{where}/{element}/{axis} is not a hard link to position/{axis}")

    if report.check("edges" in box or all(b == "none" for b in boundary), f"{where}/box has no edges"):
        if "edges" in box and isinstance(box["edges"], h5py.Group):
            out.edges_time_dependent = True
            edges = box["edges/value"]
            if report.check(edges.shape == (out.frames, out.dim), f"{where}/box/edges/value has shape {edges.shape}"):
                out.edges = edges[()]
            for axis in ("step", "time"):
                report.check(axis in box["edges"] and box[f"edges/{axis}"] == position[axis],
                             f"{where}/box/edges/{axis} is not a hard link to position/{axis} (H5MD requires it)")
        elif "edges" in box:
            edges = box["edges"][()]
            report.check(edges.shape == (out.dim,), f"{where}/box/edges has shape {edges.shape}")
            out.edges = np.tile(edges, (out.frames, 1))
        if out.edges is not None:
            for a, b in enumerate(boundary[: out.dim]):
                if b == "periodic":
                    report.check(np.all(out.edges[:, a] > 0) and np.all(np.isfinite(out.edges[:, a])),
                                 f"{where}/box/edges: periodic axis {a} has length {out.edges[:, a]}")

    species_text = "no species"
    if "species" in g:
        species = g["species"]
        report.check(species.shape == (out.n,) and species.dtype.kind in "iu",
                     f"{where}/species: shape {species.shape} {species.dtype}, expected ({out.n},) integers")
        values = species[()]
        names = text(species.attrs.get("names", []))
        if report.check(len(names) > 0, f"{where}/species has no 'names' attribute"):
            report.check(values.size == 0 or (values.min() >= 0 and values.max() < len(names)),
                         f"{where}/species holds values outside 0..{len(names) - 1}")
            counts = [f"{n}: {int(np.sum(values == k))}" for k, n in enumerate(names)]
            species_text = "species " + ", ".join(counts)

    elements = [e for e in TIME_DEPENDENT if e in out.values]
    steps = f"steps {out.step[0]}..{out.step[-1]}" if out.step is not None and out.step.size else "no steps"
    summary.append(f"{where}: {out.n} particles, {out.dim}D, boundary {' '.join(boundary)}; {out.frames} frames "
                   f"({steps}); {', '.join(elements)}; {species_text}")
    summary.append(f"{where}/position/value: {storage(pos)}")
    return out


def check_with_mdanalysis(path, ref: Group, report):
    import MDAnalysis

    u = MDAnalysis.Universe.empty(ref.n, trajectory=True)
    u.load_new(path, format="H5MD", convert_units=False)
    trajectory = u.trajectory
    try:
        report.check(trajectory.n_frames == ref.frames,
                     f"MDAnalysis reads {trajectory.n_frames} frames, h5py {ref.frames}")
        with h5py.File(path, "r") as f:
            observables = {name: f[f"observables/{name}/value"][()] for name in f.get("observables", {})}
        compared = 0
        for ts in trajectory:
            i = ts.frame
            for element, attribute in (("position", "positions"), ("velocity", "velocities"), ("force", "forces")):
                if element not in ref.values:
                    continue
                got = getattr(ts, attribute)
                want = ref.values[element][i].astype(got.dtype)
                report.check(np.array_equal(got, want),
                             f"frame {i}: MDAnalysis {attribute} differ from h5py's (max |d| "
                             f"{np.max(np.abs(got.astype(np.float64) - ref.values[element][i])):.3g})")
            if ref.edges is not None:
                want = np.concatenate([ref.edges[i], [90.0, 90.0, 90.0]]).astype(ts.dimensions.dtype)
                report.check(np.array_equal(ts.dimensions, want),
                             f"frame {i}: MDAnalysis box {ts.dimensions} differs from h5py's {ref.edges[i]}")
            report.check(ts.time == ref.time[i], f"frame {i}: MDAnalysis time {ts.time}, h5py {ref.time[i]}")
            report.check(ts.data.get("step") == ref.step[i],
                         f"frame {i}: MDAnalysis step {ts.data.get('step')}, h5py {ref.step[i]}")
            for name, values in observables.items():
                report.check(ts.data.get(name) == values[i],
                             f"frame {i}: MDAnalysis observable {name} = {ts.data.get(name)}, h5py {values[i]}")
            compared += 1
        report.check(compared == ref.frames, f"MDAnalysis iterated {compared} frames, h5py holds {ref.frames}")
    finally:
        trajectory.close()
    return MDAnalysis.__version__, compared


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", help="the H5MD file")
    parser.add_argument("--expect-frames", type=int, default=None, metavar="K",
                        help="fail unless the trajectory holds K frames")
    args = parser.parse_args(argv)

    if h5py is None:
        print("check_h5md: h5py is not installed (pip install -r validation/requirements.txt)", file=sys.stderr)
        return 2
    try:
        import MDAnalysis  # noqa: F401
    except ImportError:
        print("check_h5md: MDAnalysis is not installed (pip install -r validation/requirements.txt)",
              file=sys.stderr)
        return 2
    if not h5py.is_hdf5(args.file):
        print(f"check_h5md: {args.file}: not an HDF5 file (or no such file)", file=sys.stderr)
        return 2

    report = Report()
    try:
        groups, summary = check_with_h5py(args.file, args.expect_frames, report)
    except Exception as e:  # a layout so broken that reading it raised
        report.failures.append(f"h5py could not read the file: {type(e).__name__}: {e}")
        groups, summary = [], []
    print(f"{args.file}:")
    for line in summary:
        print(f"  {line}")
    h5py_failures = len(report.failures)
    print(f"h5py {h5py.__version__}: {report.checks - h5py_failures} of {report.checks} checks passed")

    if groups and h5py_failures == 0:
        ref = groups[0]  # MDAnalysis reads the first particles group
        if ref.dim != 3:
            print(f"MDAnalysis: not run: the box is {ref.dim}D and MDAnalysis's H5MD reader reads 3D boxes only")
        else:
            before = report.checks
            try:
                version, frames = check_with_mdanalysis(args.file, ref, report)
                failed = len(report.failures) - h5py_failures
                print(f"MDAnalysis {version}: {frames} frames; {report.checks - before - failed} of "
                      f"{report.checks - before} comparisons with h5py equal (positions, velocities, forces as "
                      f"float32; box, time, step, observables)")
            except Exception as e:
                report.failures.append(f"MDAnalysis could not read the file: {type(e).__name__}: {e}")
    elif groups:
        print("MDAnalysis: not run: the h5py checks failed")

    for failure in report.failures[:50]:
        print(f"FAIL {failure}")
    if len(report.failures) > 50:
        print(f"... and {len(report.failures) - 50} more")
    print("FAILED" if report.failures else "PASSED")
    return 1 if report.failures else 0


if __name__ == "__main__":
    sys.exit(main())
