"""Static scenes that follow a path: path.csv, path.png, one frame and checkpoint per converged point,
continuation from a checkpoint, failures that keep the converged part; probes in dynamic runs;
scene errors of the path, probe and load keys."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from helpers import BASE, REPO

from bhem_hpc.run import RunError, RunOptions, run_scene
from bhem_hpc.scene import SceneError, load_scene
from bhem_hpc.studies.paths import ShallowArch
from bhem_hpc.studies.references import shallow_arch_load

ARCH = ShallowArch()
ARCH_SCENE = REPO / "jobs" / "shallow-arch.toml"


def write(comm, path: Path, text: str) -> Path:
    if comm.rank == 0:
        path.write_text(text)
    comm.Barrier()
    return path


def rows(directory: Path, name: str = "path.csv") -> list[dict]:
    with open(directory / name, newline="") as f:
        return list(csv.DictReader(f))


def run(scene: Path, out: Path, comm, **options) -> dict:
    return run_scene(RunOptions(scene, out, progress=False, **options), comm)


def test_the_shipped_arch_scene_is_the_reference_arch():
    scene = load_scene(ARCH_SCENE)
    (force, profile), = scene.effects.area_loads
    assert force[2] == pytest.approx(-ARCH.unit_load, rel=1e-12) and profile == "sin(pi * xi1)"
    assert scene.surface.evaluate(np.array(0.5), np.array(0.0)).x[2] == pytest.approx(ARCH.rise, rel=1e-9)
    assert scene.path_plan.method == "arc_length" and [p.name for p in scene.probes] == ["mid"]


def test_an_arc_length_scene_writes_its_path_and_continues_from_a_checkpoint(comm, shared_tmp_path):
    full = shared_tmp_path / "full"
    summary = run(ARCH_SCENE, full, comm)
    table = rows(full)
    factors = np.array([float(r["load_factor"]) for r in table])
    rises = (ARCH.rise + np.array([float(r["mid_uz"]) for r in table])) / ARCH.gyration_radius
    assert np.abs(factors - shallow_arch_load(rises, ARCH.initial_rise)).max() < 2e-3 * 5.78
    assert [r["event"] for r in table if r["event"]] == ["limit", "limit"]
    # the limits located at the load factor's extrema (Marguerre: rise^2 = (e^2 - 4) / 3), not at
    # the next point (5.66 and 1.46 there), and the path ended exactly at its range's bound
    extreme_rise = np.sqrt((ARCH.initial_rise**2 - 4) / 3)
    expected = [shallow_arch_load(sign * extreme_rise, ARCH.initial_rise) for sign in (1, -1)]
    located = [float(r["event_load_factor"]) for r in table if r["event"]]
    assert np.abs(np.array(located) - expected).max() < 2e-3 * 5.78, (located, expected)
    assert [e["kind"] for s in summary["steps"] for e in s["events"]] == ["limit", "limit"]
    assert factors[-1] == 7.0 and factors[-2] < 7.0
    assert summary["status"] == "completed" and len(summary["steps"]) == len(table)
    assert (full / "path.png").stat().st_size > 10_000
    import h5py

    with h5py.File(full / "surface.h5") as f:  # a frame per point, timed by the arc length
        times = [float(f[f"frames/{k}"].attrs["time"]) for k in range(len(f["frames"]))]
    assert times == [float(r["arc_length"]) for r in table]
    # stopped after 5 points (λ rising) and after 12 (falling, past the first limit), continued in
    # place: the same path, bit for bit
    half = shared_tmp_path / "half"
    run(ARCH_SCENE, half, comm, steps=5)
    assert len(rows(half)) == 6
    run(ARCH_SCENE, half, comm, restart=half, steps=7)
    assert [r["event"] for r in rows(half) if r["event"]] == ["limit"]
    assert float(rows(half)[-1]["load_factor"]) < float(rows(half)[-2]["load_factor"])
    run(ARCH_SCENE, half, comm, restart=half)
    assert rows(half) == table
    finished = (half / "summary.json").read_text()
    with pytest.raises(RunError, match=r"the path is complete: the checkpoint is its last point"):
        run(ARCH_SCENE, half, comm, restart=half)
    assert (half / "summary.json").read_text() == finished  # refusing leaves the finished run as it was


def test_a_failing_path_step_keeps_the_converged_part(comm, shared_tmp_path):
    text = ARCH_SCENE.read_text().split("[path]")[0] + (
        '[solver]\noptions = { snes_max_it = 6 }\n\n[path]\nmethod = "load"\nlevels = [1.0, 2.0, 6.5]\nmax_cuts = 1\n'
    )
    scene = write(comm, shared_tmp_path / "fails.toml", text)
    out = shared_tmp_path / "out"
    with pytest.raises(RunError, match=r"path step 3 at load factor [0-9.]+ failed: load factor 6.5 not reached"):
        run(scene, out, comm)
    table = rows(out)
    assert [float(r["load_factor"]) for r in table] == [0.0, 1.0, 2.0]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and "load factor 6.5" in summary["error"]
    from bhem_hpc.io import read_checkpoint

    _, attrs = read_checkpoint(out / "checkpoint.h5")
    assert (attrs["step"], attrs["load_factor"]) == (2, 2.0)
    assert (out / "path.png").is_file()


def test_displacement_control_from_a_scene(comm, shared_tmp_path):
    text = ARCH_SCENE.read_text().split("[path]")[0] + (
        '[path]\nmethod = "displacement"\nprobe = "mid"\ncomponent = "z"\ntarget = -0.02\nsteps = 4\n'
    )
    out = shared_tmp_path / "out"
    run(write(comm, shared_tmp_path / "displacement.toml", text), out, comm)
    table = rows(out)
    np.testing.assert_allclose([float(r["mid_uz"]) for r in table], [0, -0.005, -0.01, -0.015, -0.02], atol=1e-12)
    assert [float(r["load_factor"]) for r in table][-1] == pytest.approx(
        shallow_arch_load((ARCH.rise - 0.02) / ARCH.gyration_radius, ARCH.initial_rise), abs=0.012
    )


def test_probes_of_a_dynamic_run(comm, shared_tmp_path):
    text = BASE + '\n[[probes]]\nname = "corner"\nat = [0.4, 0.3]\n'
    out = shared_tmp_path / "out"
    run(write(comm, shared_tmp_path / "probes.toml", text), out, comm)
    table = rows(out, "probes.csv")
    assert [int(r["step"]) for r in table] == list(range(7))
    assert float(table[0]["corner_uz"]) == 0.0 and float(table[-1]["corner_uz"]) < -1e-4  # it falls
    assert float(table[-1]["corner_z"]) == pytest.approx(float(table[-1]["corner_uz"]), abs=1e-15)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace('method = "arc_length"', 'method = "riks"'), r"key 'path.method' must be one of"),
        (lambda t: t.replace("initial_step = 1.0e-4", "initial_step = -1.0"), r"path.initial_step = -1.0 is invalid"),
        (lambda t: t.replace("max_steps = 200", "max_steps = 0"), r"path.max_steps = 0 is invalid"),
        (lambda t: t.replace("load_factor_range = [-1.0, 7.0]", "load_factor_range = [2.0, 7.0]"),
         r"path.load_factor_range = \[2, 7\] is invalid: it must contain the start, load factor 0"),
        (lambda t: t.replace("at = [0.5, 0.025]", "at = [1.5, 0.025]"), r"key 'probes\[0\].at' must be 2 numbers"),
        (lambda t: t.replace('profile = "sin(pi * xi1)"', 'profile = "sin(pi * x)"'), r"unknown name 'x'"),
        (lambda t: t.replace('height = "', 'height = "1 / 0 * '), r"key 'surface.height' must be an expression finite"),
        (lambda t: t.replace('method = "arc_length"', 'method = "displacement"\nprobe = "tip"'),
         r"key 'path.probe' must be the name of a probe \['mid'\], got 'tip'"),
        (lambda t: t.replace("static = true", "dt = 0.01\nsteps = 2"), r"table 'path' needs a static scene"),
        (lambda t: t.replace('method = "arc_length"', 'method = "load"\nlevels = []'), r"path.levels must be a non"),
    ],
)
def test_bad_path_probe_and_load_keys_are_refused(tmp_path, edit, message):
    path = tmp_path / "bad.toml"
    path.write_text(edit(ARCH_SCENE.read_text()))
    with pytest.raises(SceneError, match=message):
        load_scene(path)
