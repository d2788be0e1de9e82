"""Trimmed surfaces in scenes: jobs/trimmed-flag.toml runs, its output and pictures show only the
kept region, and a ``[trim]`` table that does not fit its scene is refused by file and key."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import write_scene

from bhem_hpc.io.render import TrimmedSurface, _trace, camera_rays, render
from bhem_hpc.io.xdmf import read_frame, read_trim_loops
from bhem_hpc.run import RunOptions, run_scene
from bhem_hpc.scene import SceneError, load_scene

FLAG = Path(__file__).resolve().parents[1] / "jobs" / "trimmed-flag.toml"


def test_the_trimmed_flag_runs_and_shows_only_its_half_disk(comm, shared_tmp_path):
    """5 steps of cotton (trust region): no dt halving; the output keeps the quads of the half disk
    (pi / 8 of the sheet, within the output's resolution) and the trim's loops; the picture of the
    trimmed sheet covers fewer pixels than the whole sheet's, and about its share."""
    out = shared_tmp_path / "flag"
    run_scene(RunOptions(FLAG, out, steps=5, progress=False), comm)
    if comm.rank != 0:
        return
    steps = json.loads((out / "summary.json").read_text())["steps"]
    assert len(steps) == 5 and sum(s["dt_halvings"] + s["recoveries"] for s in steps) == 0
    import h5py

    with h5py.File(out / "surface.h5", "r") as f:
        kept, params = f["topology"].shape[0], f["parameters"].shape[0]
    whole = 30 * 30 * 4 * 4  # patches times the output density's quads per patch
    assert kept / whole == pytest.approx(np.pi / 8, rel=0.02)
    loops = read_trim_loops(out / "surface.h5")
    scene = load_scene(FLAG)
    assert len(loops) == 1 and np.allclose(loops[0], scene.trim.loops[0])
    surface, _ = read_frame(out / "surface.h5")
    eye, directions = camera_rays(surface, 120, 90)  # one camera for both: the whole sheet's
    trimmed = np.isfinite(_trace(TrimmedSurface(surface, tuple(loops)), eye, directions)[0]).sum()
    full = np.isfinite(_trace(surface, eye, directions)[0]).sum()
    assert 0.3 * full < trimmed < 0.6 * full
    _, framed = render(TrimmedSurface(surface, tuple(loops)), 120, 90)  # framed on the half disk: larger
    assert framed.sum() > trimmed
    assert (out / "last.png").stat().st_size > 0 and params > 0


FLAG_TEXT = FLAG.read_text()


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace("[0.000000, 1.000000]\n]]", "[0.010000, 1.000000]\n]]"),
         r"trimmed-flag-bad.toml: trim.loops\[0\] is not closed"),
        (lambda t: t.replace("[0.000268, 0.983640]", "[-0.2, 0.983640]"),
         r"trim.loops\[0\] leaves the patch's parameter domain \[0, 1\] x \[0, 1\]: point 1"),
        (lambda t: t.replace('hessian = "trust_region"', 'hessian = "trust_region"\nquadrature = "reduced"'),
         r"table 'trim' with solver.quadrature = 'reduced'"),
        (lambda t: t.replace("damping = { mass = 0.5 }", "damping = { mass = 0.5 }\ncontact = { push_out = 1e-4 }\n"
                             "[[colliders]]\ntype = \"plane\"\npoint = [0.0, 0.0, -2.0]\nnormal = [0.0, 0.0, 1.0]"),
         r"table 'trim' with effects.contact by impulses: a trimmed surface meets others by IPC"),
        (lambda t: t.replace("damping = { mass = 0.5 }", "damping = { mass = 0.5 }\n"
                             "line_loads = [{ edge = \"xi2_min\", traction = [0.0, 0.0, -1.0] }]"),
         r"effects.line_loads\[0\] acts on edge 'xi2_min', which the trim cuts"),
        (lambda t: t + "\n[[point_constraints]]\nat = [0.05, 0.05]\n",
         r"point_constraints\[0\] at \(xi1, xi2\) = \(0.05, 0.05\) lies outside the trimmed surface"),
        (lambda t: t.replace("loops = [[", "loops = [[[0.5, 0.5]], ["),
         r"key 'trim.loops' must be a list of loops"),
    ],
    ids=["open", "outside", "reduced", "contact", "line-load", "point", "short"],
)
def test_a_trim_that_does_not_fit_is_refused_by_file_and_key(comm, shared_tmp_path, edit, message):
    path = write_scene(comm, shared_tmp_path / "trimmed-flag-bad.toml", edit(FLAG_TEXT))
    with pytest.raises(SceneError, match=message):
        load_scene(path)


def test_a_trimmed_rings_collision_mesh_keeps_only_the_ring(comm, shared_tmp_path):
    """jobs/trimmed-ring-onto-cloth.toml: the ring's IPC collision mesh holds the lattice triangles
    of the annulus (its share of the sheet within a lattice cell's resolution), none in the hole;
    two steps of the job (the ring falls towards the cloth) converge without a recovery."""
    from bhem_hpc.contact.ipc_setup import shell_mesh
    from bhem_hpc.run import build_model
    from bhem_hpc.scene.loader import load_any_scene

    job = FLAG.with_name("trimmed-ring-onto-cloth.toml")
    ring = load_any_scene(job).bodies[1]
    mesh = shell_mesh(build_model(ring, comm), 4, 472.6, 3.18e-4)
    whole = 2 * (12 * 4) ** 2
    annulus = np.pi * (0.14**2 - 0.05**2) / 0.3**2
    assert len(mesh.triangles) / whole == pytest.approx(annulus, rel=0.03)
    centres = mesh.rest[mesh.triangles].mean(axis=1)
    assert np.linalg.norm(centres[:, :2], axis=1).min() > 0.045  # the ring lies about the origin
    summary = run_scene(RunOptions(job, shared_tmp_path / "ring", steps=2, progress=False), comm)
    assert sum(s["recoveries"] + s["dt_halvings"] for s in summary["steps"]) == 0
