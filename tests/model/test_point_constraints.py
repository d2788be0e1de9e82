"""Constraints at arbitrary material points by the augmented Lagrangian method (paper §6.1)."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import Dynamics, Loads, ModelError, PointConstraint, ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.dynamics import TimeStepper
from bhem_hpc.studies.study import flat_sheet

CLOTH = Material(young=1e4, poisson=0.3, thickness=1e-3, density=200.0)
PLATE = Material(young=1e6, poisson=0.3, thickness=0.01, density=1000.0)


@pytest.mark.parametrize("discretization", ["hermite", "bspline2"])
def test_a_material_point_follows_a_moving_target(comm, discretization):
    """A point inside a patch (a knot span) held by the augmented Lagrangian while the sheet falls."""
    rest = flat_sheet(discretization, 1.0, 1.0, 6, 6)
    start = rest.evaluate(np.array(0.37), np.array(0.61)).x
    m1, m2 = rest.node_shape

    def target(t):
        return start + np.array([0.0, 0.0, 0.5 * t])

    model = ShellModel(
        rest,
        CLOTH,
        Loads(gravity=(0.0, 0.0, -9.81)),
        [bcs.pin(np.array([[0, 0], [m1 - 1, m2 - 1]]))],
        comm=comm,
        dynamics=Dynamics(0.01),
        point_constraints=[PointConstraint(0.37, 0.61, target)],
    )
    with ShellSolver(model, prefix="alm_") as solver:
        stepper = TimeStepper(model, solver)
        for _ in range(5):
            stepper.advance()
            point = model.state_surface().evaluate(np.array(0.37), np.array(0.61)).x
            assert np.linalg.norm(point - target(stepper.time)) < 1e-8 * np.linalg.norm(target(stepper.time))
        assert solver.report.multiplier_updates > 0
    # the rest of the sheet fell: the point really was held against gravity
    assert model.state_surface().evaluate(np.array(0.5), np.array(0.0)).x[2] < -1e-3


def test_a_point_constraint_at_a_node_equals_the_nodal_constraint(comm):
    rest = S.flat_rectangle(1.0, 0.25, 8, 2)
    node = (3, 1)  # parameters (0.375, 0.125)
    goal = rest.nodal[node][0] + np.array([0.0, 0.01, 0.02])
    clamp = bcs.clamp(bcs.edge_nodes(rest.grid, "xi1_min"))
    results = []
    for use_point in (True, False):
        constraints = [clamp] if use_point else [clamp, bcs.prescribe(np.array([node]), ["x"], [0, 1, 2], goal)]
        points = [PointConstraint(0.375, 0.125, tuple(goal))] if use_point else []
        model = ShellModel(rest, PLATE, None, constraints, comm=comm, point_constraints=points)
        with ShellSolver(model, prefix="alm_static_") as solver:
            solver.solve(2)
        results.append(model.state_surface().nodal)
    scale = np.abs(results[1]).max()
    np.testing.assert_allclose(results[0], results[1], atol=1e-8 * scale)


def test_bad_point_constraints(comm):
    rest = S.flat_rectangle(1.0, 1.0, 2, 2)
    with pytest.raises(ModelError, match=r"point_constraints\[0\].components"):
        ShellModel(rest, CLOTH, comm=comm, point_constraints=[PointConstraint(0.5, 0.5, (0, 0, 0), (3,))])
    with pytest.raises(S.SurfaceError, match="xi2=1.5 lies outside"):
        ShellModel(rest, CLOTH, comm=comm, point_constraints=[PointConstraint(0.5, 1.5, (0, 0, 0))])
