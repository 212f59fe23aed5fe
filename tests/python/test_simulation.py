"""cellforce.Simulation: MD from Python. From a scene file it runs bitwise as `cellforce run` does
(the thermo CSV's energies, on the same backend and precision: a binary Langevin mixture with an
explicit pair, a [minimize]d random start under NVE, a 2D liquid); from arrays it continues a
scene's state bitwise as the scene's own simulation does; the state views are the state (bitwise
get_state's, read-only on the host, on the device with cuda); reporters come at the multiples of
their interval across run() calls; set_positions gives the forces of ForceKernel at the new
positions, set_box scales or refuses; minimize() converges or names the particle; bad input is
named. The cuda instances skip where no CUDA device can be used."""
from __future__ import annotations

import csv
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

import cellforce
from here import cuda_missing

ROOT = Path(__file__).resolve().parents[2]
EXE = os.environ.get("CELLFORCE_EXE", str(ROOT / "build" / "cellforce"))
SYSTEMS = ROOT / "systems"


def backends():
    return [pytest.param("cpu"), pytest.param("cuda", marks=pytest.mark.skipif(bool(cuda_missing()),
                                                                               reason=cuda_missing() or "-"))]


def cli_thermo(tmp_path: Path, scene: str, steps: int, backend: str) -> dict[int, dict[str, float]]:
    out = tmp_path / f"{Path(scene).stem}-{backend}.csv"
    subprocess.run([EXE, "run", str(SYSTEMS / scene), "--steps", str(steps), "--backend", backend, "--quiet",
                    "--overwrite", "--thermo-file", str(out)], check=True, capture_output=True, text=True,
                   cwd=tmp_path)
    with open(out) as f:
        return {int(r["step"]): {k: float(v) for k, v in r.items()} for r in csv.DictReader(f)}


@pytest.mark.parametrize("backend", backends())
@pytest.mark.parametrize("scene,steps,every", [("kob_andersen.toml", 400, 200), ("overlap_random.toml", 400, 200),
                                               ("lj_2d.toml", 400, 200)])
def test_a_scene_runs_as_the_cli_runs_it_bitwise(tmp_path, scene, steps, every, backend):
    want = cli_thermo(tmp_path, scene, steps, backend)
    sim = cellforce.Simulation.from_scene(SYSTEMS / scene, backend=backend)
    assert sim.backend == backend
    got = {0: sim.thermo}
    sim.add_reporter(lambda s: got.__setitem__(s.step, s.thermo), every)
    sim.run(steps)
    assert sorted(got) == sorted(want)
    for step, row in want.items():
        for key in ("kinetic", "potential", "total"):
            assert got[step][key] == row[f"{key}_energy"], (step, key)


@pytest.mark.parametrize("backend", backends())
def test_arrays_continue_a_scene_bitwise_and_the_views_are_the_state(backend):
    """A Simulation made from a scene's state (positions, velocities, species, per-type masses,
    pairs, the integrator) runs as the scene's own one does, bitwise; its views are get_state's."""
    scene = cellforce.Simulation.from_scene(SYSTEMS / "kob_andersen.toml", backend=backend)
    x, v, f = scene.get_state()
    import tomllib

    with open(SYSTEMS / "kob_andersen.toml", "rb") as handle:
        spec = tomllib.load(handle)
    kinds = spec["types"]
    masses = {t["name"]: t.get("mass", 1.0) for t in kinds}
    species = scene.species
    assert species.dtype == np.uint32 and 0 < np.count_nonzero(species) < len(species)  # A and B
    arrays = cellforce.Simulation(
        scene.box, x, periodic=scene.periodic, cutoff=spec["interactions"]["cutoff"],
        types={t["name"]: (t["sigma"], t["epsilon"]) for t in kinds},
        pairs={tuple(p["types"]): (p["sigma"], p["epsilon"]) for p in spec["interactions"]["pairs"]},
        mode=spec["interactions"]["mode"], species=[kinds[i]["name"] for i in species], masses=masses,
        velocities=v, seed=spec["initial"]["seed"], integrator="langevin", dt=spec["integrator"]["dt"],
        temperature=spec["integrator"]["temperature"], friction=spec["integrator"].get("friction", 1.0),
        precision="mixed", backend=backend)  # mixed: a scene's default precision
    assert np.array_equal(arrays.get_state()[2], f)
    for sim in (scene, arrays):
        sim.run(30)
    for a, b in zip(scene.get_state(), arrays.get_state()):
        assert np.array_equal(a, b)
    views = [scene.positions, scene.velocities, scene.forces]
    if backend == "cpu":
        assert all(isinstance(w, np.ndarray) and not w.flags.writeable for w in views)
        host = views
    else:
        cupy = pytest.importorskip("cupy")
        host = [cupy.asnumpy(cupy.from_dlpack(w)) for w in views]
    for w, a in zip(host, scene.get_state()):
        assert np.array_equal(w, a)


def test_reporters_come_at_their_steps_across_runs():
    sim = lattice_sim()
    seen = []
    sim.add_reporter(lambda s: seen.append(("a", s.step)), 5)
    sim.add_reporter(lambda s: seen.append(("b", s.step)), 7)
    sim.run(8)
    sim.run(9)
    assert seen == [("a", 5), ("b", 7), ("a", 10), ("b", 14), ("a", 15)]
    assert sim.step == 17 and sim.time == pytest.approx(17 * sim.dt)
    with pytest.raises(ValueError, match="every: 0"):
        sim.add_reporter(lambda s: None, 0)
    with pytest.raises(ValueError, match="steps: -1"):
        sim.run(-1)
    sim.run(20, progress=True)  # tqdm's bar, or a line without it
    assert sim.step == 37


def lattice_sim(backend: str = "cpu", **kwargs) -> cellforce.Simulation:
    """An fcc liquid of 4^3 cells (256 particles, density 0.8442) at T 1.44, NVE."""
    a = (4 / 0.8442) ** (1 / 3)
    base = np.array([[0, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5], [0, 0.5, 0.5]])
    grid = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), axis=-1).reshape(-1, 1, 3)
    x = (grid + base[None]).reshape(-1, 3) * a
    return cellforce.Simulation([4 * a] * 3, x, initial_temperature=1.44, seed=5, backend=backend, **kwargs)


@pytest.mark.parametrize("backend", backends())
def test_new_positions_and_box_act_on_the_live_state(backend):
    sim = lattice_sim(backend)
    sim.run(10)
    x = sim.get_state()[0] + np.random.default_rng(2).normal(0.0, 0.01, (sim.n, 3))
    sim.set_positions(x)
    kernel = cellforce.ForceKernel(box=sim.box, backend=backend)
    want = kernel.compute(x).forces
    got = sim.get_state()[2]
    assert np.max(np.abs(got - want)) <= 1e-12 * np.max(np.abs(want))
    assert sim.step == 10
    edge = sim.box[0]
    sim.set_box([edge * 1.01] * 3, scale_positions=True)
    assert np.allclose(sim.get_state()[0], np.mod(x, edge) * 1.01, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="cutoff"):
        sim.set_box([4.0] * 3)
    assert sim.box == [edge * 1.01] * 3
    bad = x.copy()
    bad[9] = bad[8]
    with pytest.raises(ValueError, match="particles 8 and 9"):
        sim.set_positions(bad)
    with pytest.raises(ValueError, match=r"positions: shape \(255, 3\); expected \(256, 3\)"):
        sim.set_positions(x[:-1])


@pytest.mark.parametrize("backend", backends())
def test_views_follow_the_state_and_hold_the_box(backend):
    """A view taken before set_positions and steps shows the state after them (in place); set_box is
    refused while a view lives (a new box may move the arrays) and runs once the views are gone."""
    sim = lattice_sim(backend, arrays="dlpack")
    view = sim.positions
    if backend == "cuda":  # a DLPack array is taken once, here by CuPy
        cupy = pytest.importorskip("cupy")
        view = cupy.from_dlpack(view)
    x = sim.get_state()[0] + 0.01

    def host(v):
        return v if backend == "cpu" else cupy.asnumpy(v)

    sim.set_positions(x)
    assert np.array_equal(host(view), sim.get_state()[0])
    sim.run(3)
    assert np.array_equal(host(view), sim.get_state()[0])
    with pytest.raises(BufferError, match="1 view"):
        sim.set_box([b * 1.01 for b in sim.box], scale_positions=True)
    del view
    sim.set_box([b * 1.01 for b in sim.box], scale_positions=True)


def test_minimize_relaxes_or_names_the_particle():
    rng = np.random.default_rng(4)
    x = rng.random((300, 3)) * 8.0
    sim = cellforce.Simulation([8.0] * 3, x, backend="cpu")
    with pytest.raises(ValueError, match="particle"):
        sim.minimize(force_tolerance=1.0, max_steps=3)
    r = sim.minimize(force_tolerance=1.0)
    assert r["final_max_force"] < 1.0 < r["initial_max_force"]
    assert r["final_energy"] < r["initial_energy"]
    assert np.max(np.linalg.norm(sim.get_state()[2], axis=1)) < 1.0


def test_bad_input_is_named():
    x = np.random.default_rng(1).random((20, 3)) * 10
    with pytest.raises(ValueError, match="box: 4 edge lengths"):
        cellforce.Simulation([10.0] * 4, x)
    with pytest.raises(ValueError, match=r"positions: shape \(20, 3\); expected \(n, 2\)"):
        cellforce.Simulation([10.0] * 2, x)
    with pytest.raises(ValueError, match="species: particle 2 has the unknown type 'C'"):
        cellforce.Simulation([10.0] * 3, x, types={"A": (1, 1)}, species=["A", "A", "C"] + ["A"] * 17)
    with pytest.raises(ValueError, match=r"species: particle 0 has type index 3 \(1 types\)"):
        cellforce.Simulation([10.0] * 3, x, species=np.full(20, 3))
    with pytest.raises(ValueError, match=r"masses: shape \(19,\); expected \(20,\)"):
        cellforce.Simulation([10.0] * 3, x, masses=np.ones(19))
    with pytest.raises(ValueError, match="integrator: 'nvt'"):
        cellforce.Simulation([10.0] * 3, x, integrator="nvt")
    with pytest.raises(ValueError, match="mass"):
        cellforce.Simulation([10.0] * 3, x, masses=0.0)
    with pytest.raises(ValueError, match="options: unknown engine option 'skins'"):
        cellforce.Simulation.from_scene(SYSTEMS / "lj_gas.toml", options={"skins": 1})
    with pytest.raises(ValueError, match="nowhere.toml"):
        cellforce.Simulation.from_scene(SYSTEMS / "nowhere.toml")
    with pytest.raises(ValueError, match="arrays: 'numpy'"):
        cellforce.Simulation([10.0] * 3, x, arrays="numpy")
