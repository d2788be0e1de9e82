"""Scenes on B-spline surfaces: `surface.discretization`, spline boundary conditions, output, restart."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import BASE

from bhem_hpc.geometry.bspline import BSplineSurface
from bhem_hpc.io import read_checkpoint, read_frame
from bhem_hpc.run import RunOptions, run_scene
from bhem_hpc.scene import SceneError, load_scene


def spline_scene(degree: int, edit=lambda text: text) -> str:
    return edit(BASE.replace('kind = "rectangle"', f'kind = "rectangle"\ndiscretization = "bspline{degree}"'))


def write(comm, path, text):
    if comm.rank == 0:
        path.write_text(text)
    comm.Barrier()
    return path


@pytest.mark.parametrize("degree", [2, 3])
def test_spline_scene_runs_writes_frames_and_restarts_exactly(comm, shared_tmp_path, degree):
    scene = write(comm, shared_tmp_path / "scene.toml", spline_scene(degree))
    loaded = load_scene(scene)
    assert isinstance(loaded.surface, BSplineSurface) and loaded.surface.degree == degree
    c1, c2 = loaded.surface.node_shape
    # clamp at a corner holds the 2 x 2 corner control points; the moving corner is one control point
    clamp = loaded.constraints[0].constraint
    assert sorted(map(tuple, clamp.nodes.tolist())) == [(0, 0), (0, 1), (1, 0), (1, 1)] and clamp.kinds == (0,)
    full = run_scene(RunOptions(scene, shared_tmp_path / "full", progress=False), comm)
    assert full["dofs"] == 3 * c1 * c2 and len(full["steps"]) == 6
    arrays, _ = read_checkpoint(shared_tmp_path / "full" / "checkpoint.h5")
    # the moving corner control point (the surface's corner) followed x = 0.4 - 0.5 t
    np.testing.assert_allclose(arrays["position_nodal"][c1 - 1, 0, 0], [0.4 - 0.5 * 0.06, 0.0, 0.0], atol=1e-13)
    surface, time = read_frame(shared_tmp_path / "full" / "surface.h5")
    assert isinstance(surface, BSplineSurface) and time == pytest.approx(0.06)
    np.testing.assert_array_equal(surface.nodal, arrays["position_nodal"])
    assert surface.evaluate(np.array(0.4), np.array(0.3)).x[2] < -1e-3  # the free corner fell
    run_scene(RunOptions(scene, shared_tmp_path / "first", steps=3, progress=False), comm)
    run_scene(RunOptions(scene, shared_tmp_path / "second", steps=3, restart=shared_tmp_path / "first",
                         progress=False), comm)  # fmt: skip
    restarted, attrs = read_checkpoint(shared_tmp_path / "second" / "checkpoint.h5")
    assert attrs["step"] == 6
    np.testing.assert_array_equal(restarted["position_dofs"], arrays["position_dofs"])


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda s: s.replace('discretization = "bspline2"', 'discretization = "bspline4"'),
         r"key 'surface.discretization' must be one of \('hermite', 'bspline2', 'bspline3', 'nurbs'\), got 'bspline4'"),
        (lambda s: s.replace('kinds = ["x"]', 'kinds = ["d1"]'),
         r"table 'constraints\[1\]': constraint kinds \(1,\) must be a non-empty subset of \('x',\)"),
        (lambda s: s.replace('corners = ["min_min"]', "nodes = [[1, 1]]"),
         r"table 'constraints\[0\]': clamp on a B-spline surface needs boundary control points"),
        (lambda s: s.replace('patches = [3, 2]', 'patches = [3, 2]\ncorner = 1'),
         r"unknown key 'surface.corner'"),
        (lambda s: reduced(s.replace('discretization = "bspline2"', 'discretization = "bspline3"')),
         r"key 'solver.quadrature' must be 2, 3, 4 or 5: 'reduced' needs surface.discretization = 'bspline2', "
         r"not 'bspline3', got 'reduced'"),
        (lambda s: s.replace("[output]", '[solver]\nquadrature = "half"\n\n[output]'),
         r"key 'solver.quadrature' must be 2, 3, 4, 5 \(Gauss points per direction\) or 'reduced'"),
    ],
)  # fmt: skip
def test_bad_spline_scenes_name_the_key(comm, shared_tmp_path, edit, message):
    scene = write(comm, shared_tmp_path / "bad.toml", spline_scene(2, edit))
    with pytest.raises(SceneError, match=message):
        load_scene(scene)


def reduced(text: str) -> str:
    return text.replace("[output]", '[solver]\nquadrature = "reduced"\n\n[output]')


def test_a_scene_selects_the_reduced_rule(comm, shared_tmp_path):
    """The same falling sheet with the reduced rule and with 3 x 3 Gauss: the control points
    differ by less than 2 % of the largest displacement."""
    scene = write(comm, shared_tmp_path / "reduced.toml", reduced(spline_scene(2)))
    assert load_scene(scene).quadrature == "reduced"
    full_scene = write(comm, shared_tmp_path / "full.toml", spline_scene(2))
    positions = []
    for path, out in ((scene, "reduced"), (full_scene, "full")):
        run_scene(RunOptions(path, shared_tmp_path / out, steps=3, progress=False), comm)
        positions.append(read_checkpoint(shared_tmp_path / out / "checkpoint.h5")[0]["position_nodal"])
    rest = load_scene(full_scene).surface.nodal
    moved = np.abs(positions[1] - rest).max()
    assert moved > 1e-3 and np.abs(positions[0] - positions[1]).max() < 0.02 * moved


def test_a_periodic_spline_direction_needs_enough_spans(comm, shared_tmp_path):
    text = spline_scene(3).replace('kind = "rectangle"', 'kind = "cylinder"\nradius = 0.2\nlength = 0.5')
    text = text.replace("size = [0.4, 0.3]\n", "").replace("patches = [3, 2]", "patches = [3, 3]")
    scene = write(comm, shared_tmp_path / "cyl.toml", text.split("[[constraints]]")[0])
    needs = "table 'surface': a periodic xi2 direction of a degree-3 B-spline needs at least 4"
    with pytest.raises(SceneError, match=needs):
        load_scene(scene)
