"""Edge supports by name: a rigid diaphragm and symmetry planes on a cylindrical roof (the quarter
model gives the whole roof's answer, and the linear response the Kirchhoff-Love reference), hinges,
and the errors of supports that do not fit their edge."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.geometry import bspline as B
from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import AreaLoad, Loads, ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.studies.references import ROOF_DEFLECTION

DEG = np.pi / 180


def roof_deflection(comm, quarter: bool, load: float = 0.09, degree: int | None = None) -> float:
    """Vertical deflection at the middle of a free edge of the roof (R 25, L 50, 80 degrees, h 0.25,
    E 4.32e8, nu 0, self-weight ``load`` per area), scaled to the weight 90 (linear for small loads);
    Hermite patches, or B-splines of ``degree``."""
    shapes = S if degree is None else B
    spline = {} if degree is None else {"degree": degree}
    if quarter:
        rest = shapes.cylinder(25.0, 25.0, 8, 8, **spline, closed=False, angle=40 * DEG, seam_angle=50 * DEG)
        supports = [bcs.diaphragm_edge(rest, "xi1_min", "z"), *bcs.symmetry_edge(rest, "xi1_max", "z"),
                    *bcs.symmetry_edge(rest, "xi2_max", "x")]  # fmt: skip
    else:
        rest = shapes.cylinder(25.0, 50.0, 16, 16, **spline, closed=False, angle=80 * DEG, seam_angle=50 * DEG)
        supports = [bcs.diaphragm_edge(rest, "xi1_min", "z"), bcs.diaphragm_edge(rest, "xi1_max", "z")]
    loads = Loads(area_loads=(AreaLoad((0.0, -load, 0.0)),))
    model = ShellModel(rest, Material(4.32e8, 0.0, 0.25, 1.0), loads, supports, comm=comm)
    with ShellSolver(model) as solver:
        solver.solve()
    at = (np.array(25.0), np.array(50 * DEG))
    return float(model.state_surface().evaluate(*at).x[1] - rest.evaluate(*at).x[1]) * 90.0 / load


def test_a_quarter_roof_with_symmetry_planes_gives_the_whole_roof(comm):
    quarter, whole = roof_deflection(comm, True), roof_deflection(comm, False)
    assert abs(quarter / whole - 1) < 1e-5  # the same mesh: equal to the Newton tolerance
    assert abs(-quarter / ROOF_DEFLECTION - 1) < 5e-3


@pytest.mark.parametrize("degree", [2, 3])
def test_symmetry_planes_on_b_splines_tie_the_second_row(comm, degree):
    """On B-splines the second row of control points follows the boundary row in the plane (a tie):
    the quarter roof gives the whole roof's answer (its spline space is a little larger: 1e-5)."""
    quarter, whole = roof_deflection(comm, True, degree=degree), roof_deflection(comm, False, degree=degree)
    assert abs(quarter / whole - 1) < 2e-5, (quarter, whole)
    if degree == 3:
        assert abs(-quarter / ROOF_DEFLECTION - 1) < 5e-3


def test_hinged_is_simply_supported_on_both_discretizations():
    for rest in (S.flat_rectangle(1.0, 0.5, 4, 2), B.flat_rectangle(1.0, 0.5, 4, 2, degree=2)):
        hinge, support = bcs.hinged_edge(rest, "xi2_max"), bcs.support_edge(rest, "xi2_max")
        assert hinge.kinds == support.kinds and np.array_equal(hinge.nodes, support.nodes)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda r: bcs.symmetry_edge(r, "xi1_max", "x"), r"does not lie in a plane normal to x"),
        (lambda r: bcs.diaphragm_edge(r, "xi1_min", "w"), r"plane normal 'w' must be one of"),
        (lambda r: bcs.symmetry_edge(r, "xi2_min", "x"), r"does not cross the plane normal to x at right angles"),
        (lambda r: ShellModel(r, Material(1.0, 0.0, 0.1, 1.0), Loads(), [bcs.NodalTie(np.array([[0, 1]]),
                                                                                     np.array([[0, 0]]), (0,))]),
         r"ties join control points of B-spline surfaces only"),
        (lambda r: bcs.diaphragm_edge(S.cylinder(1.0, 1.0, 2, 8), "xi2_min", "z"), r"closed in that direction"),
    ],
)
def test_supports_that_do_not_fit_their_edge_are_refused(make, message):
    roof = S.cylinder(1.0, 1.0, 4, 4, closed=False, angle=np.pi / 2)  # xi2 edges are lines along z at 0 and 90 deg
    with pytest.raises(bcs.BoundaryConditionError, match=message):
        make(roof)


QUARTER_ROOF = """
[surface]
kind = "cylinder"
radius = 25.0
length = 25.0
patches = [8, 8]
closed = false
angles = [0.8726646259971648, 1.5707963267948966]

[material]
young = 4.32e8
poisson = 0.0
thickness = 0.25
density = 1.0

[time]
static = true

[effects]
area_loads = [{ force = [0.0, -0.09, 0.0] }]

[[constraints]]
type = "diaphragm"
edge = "xi1_min"
normal = "z"

[[constraints]]
type = "symmetry"
edge = "xi1_max"
normal = "z"

[[constraints]]
type = "symmetry"
edge = "xi2_max"
normal = "x"
"""


@pytest.mark.parametrize("degree", [None, 3])
def test_a_quarter_roof_scene_gives_the_api_answer(comm, tmp_path, degree):
    from bhem_hpc.run import build_model
    from bhem_hpc.scene import load_scene

    path = tmp_path / "roof.toml"
    spline = 'closed = false\ndiscretization = "bspline3"'
    text = QUARTER_ROOF if degree is None else QUARTER_ROOF.replace("closed = false", spline)
    if comm.rank == 0:
        path.write_text(text)
    path = comm.bcast(path)
    comm.Barrier()
    scene = load_scene(path)
    kinds = [(0, 2), (0, 2), (1, 3), (0, 1), (2, 3)] if degree is None else [(0,)] * 5
    assert [c.constraint.kinds for c in scene.constraints] == kinds
    model = build_model(scene, comm)
    with ShellSolver(model) as solver:
        solver.solve()
    at = (np.array(25.0), np.array(50 * DEG))
    deflection = float(model.state_surface().evaluate(*at).x[1] - scene.surface.evaluate(*at).x[1]) * 1000
    assert abs(deflection / roof_deflection(comm, True, degree=degree) - 1) < 1e-9


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace('normal = "x"', ""), r"missing key 'constraints\[2\].normal'"),
        (lambda t: t.replace('normal = "x"', 'normal = "q"'), r"key 'constraints\[2\].normal' must be one of"),
        (lambda t: t.replace('normal = "x"', 'normal = "y"'), r"constraints\[2\].edge' = 'xi2_max': symmetry plane"),
        (lambda t: t.replace("closed = false\n", ""), r"key .surface.closed. must be false for an open sector"),
    ],
)
def test_bad_support_keys_name_the_key(tmp_path, edit, message):
    from bhem_hpc.scene import SceneError, load_scene

    path = tmp_path / "roof.toml"
    path.write_text(edit(QUARTER_ROOF))
    with pytest.raises(SceneError, match=message):
        load_scene(path)


def test_contact_with_tied_control_points_is_refused(tmp_path):
    from bhem_hpc.scene import SceneError, load_scene

    text = (
        QUARTER_ROOF.replace("closed = false", 'closed = false\ndiscretization = "bspline3"')
        .replace("static = true", "dt = 0.01\nsteps = 2")
        .replace("[effects]", "[effects]\ncontact = true")
        + '\n[[colliders]]\ntype = "plane"\npoint = [0.0, 0.0, 0.0]\nnormal = [0.0, 1.0, 0.0]\n'
    )
    path = tmp_path / "roof.toml"
    path.write_text(text)
    with pytest.raises(SceneError, match=r"contact effects and symmetry planes on a B-spline surface cannot"):
        load_scene(path)
