"""Scene files, `bhem-hpc run`, ParaView output, checkpoints and restarts."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import meshio
import numpy as np
import pytest
from helpers import BASE, newton_tolerance

from bhem_hpc.geometry.surface import HermiteSurface
from bhem_hpc.io import read_checkpoint
from bhem_hpc.run import RunError, RunOptions, build_model, run_scene
from bhem_hpc.scene import SceneError, load_scene


@pytest.fixture
def workdir(shared_tmp_path):
    return shared_tmp_path


def write(comm, directory: Path, text: str, name: str = "scene.toml") -> Path:
    path = directory / name
    if comm.rank == 0:
        path.write_text(text)
    comm.Barrier()
    return path


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda s: s.replace("young = 1.0e4", 'young = "stiff"'),
            r"key 'material.young' must be a number, got 'stiff'",
        ),
        (
            lambda s: s.replace("dt = 0.01", "dt = 0.0"),
            r"key 'time.dt' must be a number in \[1e-12, 1000\] \(time step \[s\]\), got 0.0",
        ),
        (
            lambda s: s.replace("dt = 0.01", "dt = 1e-320"),
            r"key 'time.dt' must be a number in \[1e-12, 1000\] \(time step \[s\]\), got 1e-320",
        ),
        (
            lambda s: s.replace("steps = 6", "duration = 1e308"),
            r"key 'time.duration' must be a number > 0 \[s\], a whole number .*got 1e\+308",
        ),
        (
            lambda s: s.replace("patches = [3, 2]", "patches = [100000, 100000]"),
            r"key 'surface.patches' must be 2 integers >= 1, at most 1000000 patches in all",
        ),
        (lambda s: s.replace("steps = 6", "steps = 6\nduration = 1.0"), "exactly one of 'steps' and 'duration'"),
        (
            lambda s: s.replace("steps = 6", "duration = 1e-9"),
            r"key 'time.duration' must be a number > 0 \[s\], a whole number \(1..10000000\) of time steps "
            r"dt = 0.01, got 1e-09",
        ),
        (lambda s: s.replace("steps = 6", "duration = 0.055"), r"time steps dt = 0.01, got 0.055"),
        (
            lambda s: s.replace("steps = 6", f"steps = {2**63 - 1}"),
            r"key 'time.steps' must be an integer in 1..10000000",
        ),
        (
            lambda s: s.replace("damping = { mass = 0.5 }", "contact = true") + (
                "\n[[colliders]]\ntype = 'needles'\norigin = [0, 0, 0]\nspacing = [0.1, 0.1]\n"
                "count = [-1, 5]\nlength = 0.1\nradius = 0.01\n"
            ),
            r"key 'colliders\[0\].count' must be 2 integers >= 1, at most 100000 needles in all, got \[-1, 5\]",
        ),
        (lambda s: s.replace("patches = [3, 2]", "patches = [3, 2]\ncolour = 1"), r"unknown key 'surface.colour'"),
        (lambda s: s.replace("[material]\n", "[material]\nyoungs = 1\n"), r"unknown key 'material.youngs'"),
        (lambda s: s.replace("poisson = 0.3", ""), r"missing key 'material.poisson'"),
        (lambda s: s.replace("poisson = 0.3", "poisson = 0.7"), r"material.poisson = 0.7 is invalid"),
        (lambda s: s.replace("damping = { mass = 0.5 }", "damping = {}"), r"'effects.damping' lists no coefficient"),
        (lambda s: s.replace("damping = { mass = 0.5 }", "contact = true"), r"no 'colliders' and no self-collision"),
        (lambda s: s.replace("damping = { mass = 0.5 }", "friction = 0.3"), r"need 'effects.contact' as well"),
        (
            lambda s: s + "\n[[colliders]]\ntype = 'plane'\npoint = [0, 0, 0]\nnormal = [0, 0, 1]\n",
            r"'colliders' is given but 'effects.contact' is not listed",
        ),
        (
            lambda s: s.replace("damping = { mass = 0.5 }", "contact = true\nfriction = -0.1"),
            r"key 'effects.friction' must be a number >= 0",
        ),
        (
            lambda s: s.replace("damping = { mass = 0.5 }", "contact = true")
            + "\n[[colliders]]\ntype = 'sphere'\ncenter = [0, 0, 0]\nradius = -1.0\n",
            r"key 'colliders\[0\].radius' must be a number > 0",
        ),
        (
            lambda s: s.replace("damping = { mass = 0.5 }", "contact = true")
            + "\n[[colliders]]\ntype = 'mesh'\nfile = 'missing.obj'\n",
            r"key 'colliders\[0\].file' must be an existing regular file",
        ),
        (
            lambda s: s.replace("damping = { mass = 0.5 }", "contact = true")
            + "\n[[colliders]]\ntype = 'plane'\npoint = [0, 0, 0]\nnormal = [0, 0, 0]\n",
            r"key 'colliders\[0\]': plane normal is zero",
        ),
        (
            lambda s: s.replace("damping = { mass = 0.5 }", "contact = { push_out = 0.0 }\nself_collision = true"),
            r"key 'effects.contact.push_out' must be a number > 0",
        ),
        (
            lambda s: s.replace(
                "damping = { mass = 0.5 }", "contact = { metric = 'stiffness' }\nself_collision = true"
            ),
            r"key 'effects.contact.metric' must be one of \('mass', 'jacobian'\), got 'stiffness'",
        ),
        (lambda s: s.replace("damping = { mass = 0.5 }", "wind = 3"), r"unknown effect 'effects.wind'"),
        (
            lambda s: s.replace('corners = ["max_min"]', 'corners = ["min_min"]'),
            r"constraints\[1\] and constraints\[0\] both constrain node \(0, 0\), kind x, component 0",
        ),
        (
            lambda s: s.replace('corners = ["min_min"]', "nodes = [[9, 0]]"),
            r"names node \(9, 0\), which does not exist",
        ),
        (lambda s: s.replace('kinds = ["x"]', 'kinds = ["x", "d3"]'), r"key 'constraints\[1\].kinds' must be"),
        (lambda s: s + "\n[solver]\nhessian = 'approx'\n",
         r"key 'solver.hessian' must be 'exact' or 'pseudo' or 'projected' or 'adaptive' or 'trust_region'"),
        (lambda s: s.replace("damping = { mass = 0.5 }", "pressure = 2.0") + "\n[solver]\nhessian = 'trust_region'\n",
         r"key 'solver.hessian' = 'trust_region' minimizes a potential, which the follower load effects.pressure = "
         r"2.0 does not have"),
        (lambda s: s.replace("dt = 0.01\nsteps = 6", "static = true") + "\n[solver]\nhessian = 'trust_region'\n",
         r"key 'solver.hessian' must be 'exact' or 'pseudo' or 'projected' or 'adaptive' \(a static scene\), "
         r"got 'trust_region'"),
        (lambda s: s.replace("[output]", "[outputs]"), r"unknown key 'outputs'"),
        (lambda s: "effects = 3\n" + s.replace("[effects]", "[unused]"), r"key 'effects' must be a table, got 3"),
    ],
)
def test_bad_scenes_name_file_key_and_expectation(comm, workdir, edit, message):
    path = write(comm, workdir, edit(BASE))
    with pytest.raises(SceneError, match=message) as info:
        load_scene(path)
    assert str(path) in str(info.value)


def test_only_listed_effects_are_built(comm, workdir):
    plain = build_model(load_scene(write(comm, workdir, BASE.replace("damping = { mass = 0.5 }", ""))), comm)
    assert not hasattr(plain, "pressure") and not hasattr(plain, "mass_damping")
    pressured = build_model(
        load_scene(write(comm, workdir, BASE.replace("damping = { mass = 0.5 }", "pressure = 2.0"), "p.toml")), comm
    )
    # The pressure constant appears in the residual only when the scene lists pressure.
    assert pressured.pressure in pressured.ufl_residual.constants()
    assert len(pressured.ufl_residual.constants()) == len(plain.ufl_residual.constants()) + 1
    # A scene without contact runs without ever importing the contact machinery (fresh process;
    # the ray tracer of the collision package draws last.png after the last step).
    if comm.rank == 0:
        code = (
            "import sys\n"
            "from pathlib import Path\n"
            "from bhem_hpc.run import RunOptions, run_scene\n"
            f"run_scene(RunOptions(Path({str(workdir / 'scene.toml')!r}), Path({str(workdir / 'nocontact')!r}), "
            "steps=1, progress=False))\n"
            "for name in ('bhem_hpc.contact', 'bhem_hpc.contact.detection'):\n"
            "    assert name not in sys.modules, name + ' imported'\n"
        )
        env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "PMI_"))}
        subprocess.run([sys.executable, "-c", code], check=True, env=env)


def test_run_writes_series_summary_checkpoint_and_restarts_exactly(comm, workdir):
    scene = write(comm, workdir, BASE)
    full = run_scene(RunOptions(scene, workdir / "full", progress=False), comm)
    assert len(full["steps"]) == 6 and full["time"] == pytest.approx(0.06)
    assert full["dofs"] == 3 * 4 * 12 and full["ranks"] == comm.size
    step = full["steps"][-1]
    for key in ("assembly_s", "factorization_s", "linear_solve_s", "collision_s", "output_s", "newton_iterations",
                "refactorizations", "chord_iterations", "krylov_iterations"):  # fmt: skip
        assert key in step
    totals = full["solver_totals"]
    assert totals["refactorizations"] == sum(s["refactorizations"] for s in full["steps"]) >= 1
    assert totals["chord_iterations"] + totals["refactorizations"] >= sum(s["newton_iterations"] for s in full["steps"])
    assert full["linear_solver"]["kind"] == "direct" and full["factorization"] == "reuse"
    assert set(step["energies"]) == {"membrane", "bending", "gravity", "kinetic", "external_work"}
    assert step["energies"]["external_work"] == pytest.approx(-step["energies"]["gravity"])
    comm.Barrier()
    # ParaView's file: an independent XML + HDF5 read, then meshio's XDMF time-series reader.
    root = ET.parse(workdir / "full" / "surface.xdmf").getroot()
    frames = root.findall(".//Grid[@GridType='Uniform']")
    times = [float(g.find("Time").get("Value")) for g in frames]
    np.testing.assert_allclose(times, [0.0, 0.02, 0.04, 0.06])
    with h5py.File(workdir / "full" / "surface.h5") as f:
        last = f["frames/3/geometry"][:]
        assert f["topology"].shape == (3 * 2 * 4, 4)
        for name in ("normal", "mean_curvature", "membrane_energy_density", "bending_energy_density"):
            assert np.all(np.isfinite(f[f"frames/3/{name}"][:]))
    with meshio.xdmf.TimeSeriesReader(workdir / "full" / "surface.xdmf") as reader:
        points, _ = reader.read_points_cells()
        assert reader.num_steps == 4
        np.testing.assert_allclose(points, h5py.File(workdir / "full" / "surface.h5")["frames/0/geometry"][:])
    assert last[:, 2].min() < -1e-3  # it fell
    # the moving corner followed its prescribed motion: x = 0.4 - 0.5 t
    arrays, attrs = read_checkpoint(workdir / "full" / "checkpoint.h5")
    assert attrs["step"] == 6
    np.testing.assert_allclose(arrays["position_nodal"][3, 0, 0], [0.4 - 0.5 * 0.06, 0.0, 0.0], atol=1e-14)

    run_scene(RunOptions(scene, workdir / "first", steps=3, progress=False), comm)
    run_scene(RunOptions(scene, workdir / "second", steps=3, restart=workdir / "first", progress=False), comm)
    restarted, attrs2 = read_checkpoint(workdir / "second" / "checkpoint.h5")
    assert attrs2["step"] == 6 and attrs2["time"] == pytest.approx(0.06)
    scale = np.abs(arrays["position_dofs"]).max()
    assert np.abs(restarted["position_dofs"] - arrays["position_dofs"]).max() <= 1e-12 * scale
    assert np.abs(restarted["velocity_dofs"] - arrays["velocity_dofs"]).max() <= 1e-10


def test_a_run_continues_with_other_solver_settings(comm, workdir, caplog):
    # e.g. the iterative solver where MUMPS' factorization ran out of memory
    scene = write(comm, workdir, BASE)
    run_scene(RunOptions(scene, workdir / "full", progress=False), comm)
    run_scene(RunOptions(scene, workdir / "first", steps=3, progress=False), comm)
    method = '[solver]\nlinear = "iterative"\nfactorization = "fresh"\noptions = { ksp_rtol = 1e-4 }\n'
    other = write(comm, workdir, BASE + method, "other.toml")
    with caplog.at_level(logging.WARNING, logger="bhem_hpc.run"):
        summary = run_scene(RunOptions(other, workdir / "second", steps=3, restart=workdir / "first",
                                       progress=False), comm)  # fmt: skip
    assert "instead of the checkpoint's {}" in caplog.text
    assert summary["linear_solver"]["kind"] == "iterative" and summary["factorization"] == "fresh"
    expected = {"linear": "iterative", "factorization": "fresh", "options": {"ksp_rtol": 1e-4}}
    assert summary["solution_method"] == expected
    full, _ = read_checkpoint(workdir / "full" / "checkpoint.h5")
    continued, attrs = read_checkpoint(workdir / "second" / "checkpoint.h5")
    assert attrs["step"] == 6 and summary["solver_totals"]["krylov_iterations"] > 0
    difference = np.abs(continued["position_dofs"] - full["position_dofs"]).max()
    assert 0 < difference <= newton_tolerance(load_scene(scene), full["position_dofs"])  # not bit for bit
    # the physics itself stays fixed: another material is another scene
    stiffer = write(comm, workdir, BASE.replace("young = 1.0e4", "young = 2.0e4") + method, "stiffer.toml")
    with pytest.raises(RunError, match="different scene or resolution"):
        run_scene(RunOptions(stiffer, workdir / "third", steps=1, restart=workdir / "first", progress=False), comm)


def test_run_refuses_to_overwrite_and_foreign_restarts(comm, workdir):
    scene = write(comm, workdir, BASE)
    run_scene(RunOptions(scene, workdir / "a", steps=1, progress=False), comm)
    with pytest.raises(RunError, match="exists and is not empty: pass --force"):
        run_scene(RunOptions(scene, workdir / "a", steps=1, progress=False), comm)
    finer = write(comm, workdir, BASE.replace("patches = [3, 2]", "patches = [4, 2]"), "finer.toml")
    with pytest.raises(RunError, match="different scene or resolution"):
        run_scene(RunOptions(finer, workdir / "b", steps=1, restart=workdir / "a", progress=False), comm)
    assert not (workdir / "b").exists()  # nothing written before the check
    if comm.rank == 0:
        blocked = workdir / "file"
        blocked.write_text("")
    comm.Barrier()
    with pytest.raises(RunError, match="cannot be written"):
        run_scene(RunOptions(scene, workdir / "file" / "sub", steps=1, progress=False), comm)


def test_scene_point_constraint_moves_a_material_point(comm, workdir):
    text = (
        BASE.replace("steps = 6", "steps = 3")
        + """
[[point_constraints]]
at = [0.37, 0.21]
motion = { type = "linear", velocity = [0.0, 0.0, 0.2] }
"""
    )
    scene = load_scene(write(comm, workdir, text, "point.toml"))
    point = scene.point_constraints[0]
    start = scene.surface.evaluate(np.array(0.37), np.array(0.21)).x
    np.testing.assert_allclose(point.target_at(0.5), start + [0.0, 0.0, 0.1])
    run_scene(RunOptions(workdir / "point.toml", workdir / "point", progress=False), comm)
    arrays, _ = read_checkpoint(workdir / "point" / "checkpoint.h5")
    final = HermiteSurface(scene.surface.grid, arrays["position_nodal"])
    reached = final.evaluate(np.array(0.37), np.array(0.21)).x
    np.testing.assert_allclose(reached, start + [0.0, 0.0, 0.2 * 0.03], atol=1e-8)
    with pytest.raises(SceneError, match=r"key 'point_constraints\[0\].at': parameter xi1=2.0 lies outside"):
        load_scene(write(comm, workdir, text.replace("at = [0.37, 0.21]", "at = [2.0, 0.21]"), "bad.toml"))


@pytest.mark.parametrize("name", ["drape", "twisting", "locking", "drape-corners", "parasol", "hanging", "drape-cotton",
                                  "shear", "locking-cotton"])
def test_shipped_scenes_are_valid(name):
    scene = load_scene(Path(__file__).resolve().parents[1] / "jobs" / f"{name}.toml")
    assert scene.steps >= 100 and not scene.static
    assert scene.constraints


def test_static_scene_with_loads(comm, workdir):
    text = """
[surface]
kind = "rectangle"
size = [1.0, 0.1]
patches = [12, 1]

[material]
young = 1.0e6
poisson = 0.0
thickness = 0.01
density = 1000.0

[time]
static = true
load_steps = 2

[effects]
line_loads = [{ edge = "xi1_max", traction = [0.0, 0.0, -1.0e-5] }]

[[constraints]]
type = "clamp"
edge = "xi1_min"
"""
    summary = run_scene(RunOptions(write(comm, workdir, text, "static.toml"), workdir / "static", progress=False), comm)
    assert summary["static"] and [row["load_factor"] for row in summary["steps"]] == [0.0, 0.5, 1.0]
    comm.Barrier()
    with h5py.File(workdir / "static" / "surface.h5") as f:  # frames at the start and at each load level
        assert [float(f[f"frames/{k}"].attrs["time"]) for k in range(3)] == [0.0, 0.5, 1.0]
        tip_drop = -f["frames/2/geometry"][:, 2].min()
    ei = 1e6 * 0.1 * 0.01**3 / 12
    assert abs(tip_drop / (1e-5 * 0.1 / (3 * ei)) - 1) < 1e-4  # P L^3 / (3 EI)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"\x00\xff\xfe binary \x89PNG", r"not a text \(UTF-8\) file: byte 1 cannot be decoded"),
        (b"a = " + b"[" * 100_000 + b"]" * 100_000, r"nested too deeply to be a scene|not valid TOML"),
    ],
)
def test_hostile_scene_files_get_an_error_naming_the_file(comm, workdir, content, message):
    path = workdir / "hostile.toml"
    if comm.rank == 0:
        path.write_bytes(content)
    comm.Barrier()
    with pytest.raises(SceneError, match=rf"{path}: ({message})"):
        load_scene(path)
