"""Scenes of several bodies (``[[bodies]]``): each body is the scene of one body it would be alone,
so one run of two bodies gives each body's run alone (within the Newton tolerance); its output is a
folder per body and one ParaView collection of every body; bad bodies are refused by name."""

from __future__ import annotations

import re
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
from helpers import REPO, frame_times, paraview_read, write_scene

from bhem_hpc import cli
from bhem_hpc.io import read_checkpoint, read_frame
from bhem_hpc.run import RunError, RunOptions, run_scene
from bhem_hpc.scene import SceneError, load_scene
from bhem_hpc.scene.loader import load_any_scene

SHARED = """
[time]
dt = 0.01
steps = 4
[solver]
options = { snes_rtol = 1e-12 }
[output]
every = 2
"""
#: Two bodies' tables, as a scene of one body writes them: steel Hermite and rubber B-splines.
BODIES = {
    "steel": """
[surface]
kind = "rectangle"
size = [0.2, 0.2]
patches = [4, 4]
discretization = "hermite"
[material]
young = 2.1e11
poisson = 0.3
thickness = 1e-3
density = 7850.0
[effects]
gravity = [0.0, 0.0, -9.81]
[[constraints]]
type = "clamp"
edge = "xi1_min"
[[probes]]
name = "tip"
at = [0.2, 0.1]
""",
    "rubber": """
[surface]
kind = "rectangle"
size = [0.2, 0.2]
origin = [0.3, 0.0, 0.0]
patches = [4, 4]
discretization = "bspline2"
[material]
young = 5.0e6
poisson = 0.49
thickness = 2e-3
density = 1100.0
[effects]
gravity = [0.0, 0.0, -9.81]
[[constraints]]
type = "fix"
corners = ["min_max", "max_max"]
kinds = ["x"]
components = [0, 1, 2]
""",
}


def _as_body(name: str, tables: str) -> str:
    """A scene of one body's tables as a ``[[bodies]]`` entry: every table header under ``bodies.``."""
    text = re.sub(r"^\[\[(\w+)\]\]", r"[[bodies.\1]]", tables, flags=re.M)
    text = re.sub(r"^\[(\w+)\]", r"[bodies.\1]", text, flags=re.M)
    return f'[[bodies]]\nname = "{name}"\n{text}'


def _pair(comm, directory: Path, edit=lambda s: s) -> Path:
    text = SHARED + "".join(_as_body(name, tables) for name, tables in BODIES.items())
    return write_scene(comm, directory / "pair.toml", edit(text))


def test_two_bodies_run_as_each_runs_alone_with_a_folder_each_and_one_collection(comm, shared_tmp_path):
    summary = run_scene(RunOptions(_pair(comm, shared_tmp_path), shared_tmp_path / "pair", progress=False), comm)
    assert [b["name"] for b in summary["bodies"]] == ["steel", "rubber"] and summary["status"] == "completed"
    assert summary["dofs"] == sum(b["dofs"] for b in summary["bodies"]) and len(summary["steps"]) == 4
    out = shared_tmp_path / "pair"
    for name, tables in BODIES.items():
        alone = run_scene(RunOptions(write_scene(comm, shared_tmp_path / f"{name}.toml", SHARED + tables),
                                     shared_tmp_path / name, progress=False), comm)  # fmt: skip
        assert alone["dofs"] == next(b["dofs"] for b in summary["bodies"] if b["name"] == name)
        together, t1 = read_frame(out / name / "surface.h5")
        single, t2 = read_frame(shared_tmp_path / name / "surface.h5")
        rest, _ = read_frame(out / name / "surface.h5", 0)
        moved = np.abs(single.nodal - rest.nodal).max()
        assert t1 == t2 == pytest.approx(0.04) and moved > 1e-6
        # one solve stops at the stiffer body's residual floor, two at each one's own
        assert np.abs(together.nodal - single.nodal).max() <= 1e-6 * moved
    if comm.rank == 0:
        steel_probes = (out / "steel" / "probes.csv").read_text().splitlines()
        alone_probes = (shared_tmp_path / "steel" / "probes.csv").read_text().splitlines()
        assert steel_probes[0].startswith("step,time,tip_") and len(steel_probes) == 1 + 5  # every step, t = 0 .. 0.04
        assert [row.split(",")[:2] for row in steel_probes] == [row.split(",")[:2] for row in alone_probes]
        assert not (out / "rubber" / "probes.csv").exists() and (out / "last.png").stat().st_size > 1000
        collection = paraview_read(out / "bodies.pvd")[str(out / "bodies.pvd")][".pvd"]
        assert collection["times"] == [0.0, 0.02, 0.04]
        assert all(frame["leaves"] == 2 for frame in collection["frames"].values())
        # bhem-hpc render ray-traces every body of the last frame, each in its colour
        assert cli.main(["render", str(out), "--size", "120x90", "--out", str(shared_tmp_path / "both.png")]) == 0
        image = matplotlib.image.imread(shared_tmp_path / "both.png")[..., :3]
        covered = image.min(axis=2) < 0.99
        blue, orange = image[..., 2] > image[..., 0] + 0.2, image[..., 0] > image[..., 2] + 0.2
        assert (blue & covered).sum() > 20 and (orange & covered).sum() > 20
    comm.Barrier()
    # a second --force run replaces the first; a folder holding files of its own is kept and refused
    run_scene(RunOptions(_pair(comm, shared_tmp_path), out, steps=1, force=True, progress=False), comm)
    if comm.rank == 0:
        (out / "rubber" / "notes.txt").write_text("mine")
    comm.Barrier()
    with pytest.raises(RunError, match=r"did not write \(rubber/notes.txt\)"):
        run_scene(RunOptions(_pair(comm, shared_tmp_path), out, steps=1, force=True, progress=False), comm)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda s: s.replace('name = "rubber"', 'name = "steel"'),
         r"key 'bodies\[1\].name' must be a name no other body has .*got 'steel'"),
        (lambda s: s.replace("young = 5.0e6", 'young = "soft"'),
         r"body 'rubber' \(bodies\[1\]\): key 'material.young' must be a number, got 'soft'"),
        (lambda s: s.replace("[bodies.material]\nyoung = 5.0e6", "[bodies.materials]\nyoung = 5.0e6"),
         r"body 'rubber' \(bodies\[1\]\): missing key 'material'"),
        (lambda s: s.replace("young = 2.1e11\npoisson = 0.3\nthickness = 1e-3\ndensity = 7850.0\n", "")
         .replace("[bodies.material]\n[bodies.effects]", "[bodies.effects]"),
         r"body 'steel' \(bodies\[0\]\): missing key 'material'"),
        (lambda s: s + "\n[surface]\nkind = 'rectangle'\n",
         r"key 'surface' at the top of a scene of several bodies: a body's own table"),
        (lambda s: s.replace('name = "rubber"', 'name = "rubber"\ntime = { dt = 0.01, steps = 1 }'),
         r"key 'bodies\[1\].time': \[time\] is shared by all bodies"),
        (lambda s: s.replace("[bodies.effects]\ngravity", "[bodies.effects]\ncontact = true\ngravity", 1),
         r"body 'steel' \(bodies\[0\]\): 'effects.contact' is listed but there are no 'colliders'"),
        (lambda s: s + "\n[[colliders]]\ntype = 'plane'\npoint = [0, 0, -1]\nnormal = [0, 0, 1]\n",
         r"key 'colliders' is given but no body lists 'effects.contact'"),
        (lambda s: s.replace('name = "rubber"', 'name = "rubber"\ncolliders = []'),
         r"key 'bodies\[1\].colliders': \[colliders\] is shared by all bodies"),
        (lambda s: s.replace("steps = 4", "steps = 4\nstatic = true"), r"key 'time.static': a scene of several"),
        (lambda s: s.replace('name = "rubber"', 'name = "rubber"\ntype = "membrane"'),
         r"key 'bodies\[1\].type' must be one of shell, solid, cad_shell, got 'membrane'"),
        (lambda s: s.replace("at = [0.2, 0.1]", "at = [2.0, 0.5]"),
         r"body 'steel' \(bodies\[0\]\): key 'probes\[0\].at'"),
    ],
)  # fmt: skip
def test_bad_bodies_are_refused_naming_the_body_and_key(comm, shared_tmp_path, edit, message):
    path = _pair(comm, shared_tmp_path, edit)
    with pytest.raises(SceneError, match=message):
        load_any_scene(path)
    with pytest.raises(SceneError, match=message):
        run_scene(RunOptions(path, shared_tmp_path / "out", progress=False), comm)
    assert not (shared_tmp_path / "out").exists()


def test_a_scene_of_several_bodies_is_not_taken_by_one_body_commands(comm, shared_tmp_path):
    path = _pair(comm, shared_tmp_path)
    with pytest.raises(SceneError, match=r"lists \[\[bodies\]\] \(a scene of several bodies\)"):
        load_scene(path)


def test_a_body_of_type_shell_is_the_body_without_a_type(comm, shared_tmp_path):
    implicit = load_any_scene(_pair(comm, shared_tmp_path))
    typed = _pair(comm, shared_tmp_path, lambda s: s.replace('name = "rubber"', 'name = "rubber"\ntype = "shell"'))
    explicit = load_any_scene(typed)
    assert explicit.names == implicit.names
    for mine, theirs in zip(explicit.bodies, implicit.bodies, strict=True):
        for key in ("material", "effects", "dt", "steps", "hessian"):
            assert getattr(mine, key) == getattr(theirs, key)
        assert mine.surface.discretization == theirs.surface.discretization


def test_the_shipped_scene_of_two_bodies_loads(comm):
    scene = load_any_scene(REPO / "jobs" / "hanging-pair.toml")
    assert scene.names == ("cotton", "rubber")
    assert [b.surface.discretization for b in scene.bodies] == ["hermite", "bspline2"]


#: The two sheets free (no constraints) with contact effects, dropped 5 mm onto a floor: their
#: contacts with it are each body's own.
DROPPED = {name: re.sub(r"\[\[constraints\]\]\n(?:[^\[\n].*\n)*", "", tables)
           .replace("[effects]", "[effects]\ncontact = true\nfriction = 0.3") for name, tables in BODIES.items()}
FLOOR = """
[[colliders]]
type = "plane"
point = [0.0, 0.0, -0.005]
normal = [0.0, 0.0, 1.0]
"""


def test_bodies_meet_the_scene_colliders_each_as_alone(comm, shared_tmp_path):
    """Each body with contact effects meets the scene's colliders as it would alone: the pair's run
    gives each body's run alone, both lying on the floor."""
    bodies = DROPPED
    shared = SHARED.replace("steps = 4", "steps = 8")
    pair = write_scene(comm, shared_tmp_path / "dropped.toml",
                  shared + FLOOR + "".join(_as_body(name, tables) for name, tables in bodies.items()))  # fmt: skip
    summary = run_scene(RunOptions(pair, shared_tmp_path / "pair", progress=False), comm)
    assert set(summary["contact"]) == {"steel", "rubber"} and max(s["contacts"] for s in summary["steps"]) > 0
    for name, tables in bodies.items():
        run_scene(RunOptions(write_scene(comm, shared_tmp_path / f"{name}.toml", shared + tables + FLOOR),
                             shared_tmp_path / name, progress=False), comm)  # fmt: skip
        together, _ = read_frame(shared_tmp_path / "pair" / name / "surface.h5")
        single, _ = read_frame(shared_tmp_path / name / "surface.h5")
        heights = together.nodal[..., 0, 2]
        assert heights.min() >= -0.005 + 0.5e-4 and heights.max() <= -0.005 + 1.5e-4  # on the floor, pushed out
        assert np.abs(together.nodal - single.nodal).max() <= 1e-8


def _rows(path: Path) -> list[str]:
    return path.read_text().splitlines()


def test_a_run_of_several_bodies_restarts_as_the_uninterrupted_run(comm, shared_tmp_path):
    """Two free sheets with contact dropped onto a floor, 8 steps (a checkpoint every 2): stopped
    after 4 and restarted in place, or into another directory, they end as the run that was not
    stopped, with its step records, probe rows and frames; a finished run or another scene's
    checkpoint is refused. Within round-off, not bit for bit: within one process a second run of a
    free sheet already differs from the first by about 1e-15 of its size (first runs in separate
    processes agree bit for bit; probably array alignment changing summation order)."""
    pair = write_scene(comm, shared_tmp_path / "dropped.toml", SHARED.replace("steps = 4", "steps = 8") + FLOOR
                  + "".join(_as_body(name, tables) for name, tables in DROPPED.items()))  # fmt: skip
    whole, part, other = (shared_tmp_path / name for name in ("whole", "part", "other"))
    reference = run_scene(RunOptions(pair, whole, progress=False), comm)
    assert max(s["contacts"] for s in reference["steps"]) > 0  # the restart continues contact
    run_scene(RunOptions(pair, part, steps=4, progress=False), comm)
    run_scene(RunOptions(pair, other, restart=part, progress=False), comm)
    continued = run_scene(RunOptions(pair, part, restart=part, progress=False), comm)
    tolerance = 1e-12
    expected, _ = read_checkpoint(whole / "checkpoint.h5")
    for out in (part, other):
        arrays, attrs = read_checkpoint(out / "checkpoint.h5")
        assert attrs["step"] == 8 and sorted(arrays) == sorted(expected)
        assert "position_dofs_1" in arrays and "velocity_dofs_0" in arrays
        for name, value in expected.items():
            assert np.abs(arrays[name] - value).max() <= tolerance * max(np.abs(value).max(), 1.0), (out, name)
    iterations = [s["newton_iterations"] for s in reference["steps"]]
    assert [s["newton_iterations"] for s in continued["steps"]] == iterations and len(iterations) == 8
    assert len(_rows(part / "steps.jsonl")) == 8
    if comm.rank == 0:
        for name in DROPPED:
            times = frame_times(whole / name)
            assert frame_times(part / name) == times and len(times) == 5
            assert frame_times(other / name) == times[2:]
        assert len(_rows(whole / "steel" / "probes.csv")) == 10  # a header and t = 0 .. 8 dt
        assert _rows(part / "steel" / "probes.csv")[0] == _rows(whole / "steel" / "probes.csv")[0]
        assert len(_rows(part / "steel" / "probes.csv")) == 10
    with pytest.raises(RunError, match="the checkpoint is at step 8, the scene's last"):
        run_scene(RunOptions(pair, shared_tmp_path / "again", restart=whole, progress=False), comm)
    with pytest.raises(RunError, match="from a different scene or resolution"):
        run_scene(RunOptions(_pair(comm, shared_tmp_path), shared_tmp_path / "again", restart=whole,
                             progress=False), comm)  # fmt: skip
    assert not (shared_tmp_path / "again").exists()
