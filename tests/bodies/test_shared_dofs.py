"""Conforming interfaces whose patches share their edge control points: the shared DOFs are found
(in either order, with refusals that say why an interface does not conform), groups meet at corners,
and the reduced solve keeps the patches together exactly: no gap, no consistency error in the patch
test, the one patch's cantilever and roof, and no failure at penalty factors where the displacement
penalty fails. The same on 2 ranks."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.bodies.coupling import InterfaceCoupling, penalty_stiffness, rest_frames
from bhem_hpc.bodies.petsc import StackedBlocks
from bhem_hpc.bodies.shared_dofs import conforming_edge_dofs, shared_groups
from bhem_hpc.geometry import bspline as B
from bhem_hpc.geometry import surface as S
from bhem_hpc.geometry.grid import ParameterGrid
from bhem_hpc.geometry.interfaces import InterfaceError, element_across, pair_edges
from bhem_hpc.model import bcs
from bhem_hpc.model.loads import Dynamics, LineLoad, Loads
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.dynamics import TimeStepper
from bhem_hpc.studies.interfaces_page import cantilever, patch_test, roof

DEG = np.pi / 180
STEEL = Material(2.0e11, 0.3, 0.01, 7800.0)


def _plane(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.stack([u, v, 0 * u], -1)


def _strip(x0: float, x1: float, spans: tuple[int, int], width: float, degree: int = 3) -> B.BSplineSurface:
    return B.from_callable(_plane, ParameterGrid(*spans, (x0, x1), (0.0, width), False, False), degree=degree)


def _joint(models, rests, pair, edges, material: Material, shared: bool, factor: float = 1e3) -> InterfaceCoupling:
    """The interface coupling of ``pair``: with shared DOFs only its angle term (the edges are one curve)."""
    quadrature = pair_edges(rests[pair[0]], edges[0], rests[pair[1]], edges[1], 1e-8)
    element = min(element_across(rests[pair[0]], edges[0]), element_across(rests[pair[1]], edges[1]))
    a_d, a_r = penalty_stiffness(material.young, material.poisson, material.thickness, element, factor)
    return InterfaceCoupling(StackedBlocks(models), pair, quadrature,
                             rest_frames(rests[pair[0]], rests[pair[1]], quadrature), (0.0 if shared else a_d, a_r))


def test_conforming_edges_share_their_control_points_in_either_order():
    first, second = _strip(0.0, 0.5, (3, 2), 0.2), _strip(0.5, 1.0, (4, 2), 0.2)
    shared = conforming_edge_dofs((first, second), (0, 1), ("xi1_max", "xi1_min"), 1e-9)
    c1 = first.node_shape[0]
    np.testing.assert_array_equal(shared.first, np.stack([np.zeros(5), (c1 - 1) * 5 + np.arange(5)], axis=1))
    np.testing.assert_array_equal(shared.second, np.stack([np.ones(5), np.arange(5)], axis=1))
    np.testing.assert_array_equal(shared.scale, np.ones(5))
    # the second patch turned about: its xi2 runs the other way along the edge
    turned = B.from_callable(lambda u, v: np.stack([u, 0.2 - v, 0 * u], -1),
                             ParameterGrid(4, 2, (0.5, 1.0), (0.0, 0.2), False, False), degree=3)  # fmt: skip
    reversed_ = conforming_edge_dofs((first, turned), (0, 1), ("xi1_max", "xi1_min"), 1e-9)
    np.testing.assert_array_equal(reversed_.second[:, 1], np.arange(5)[::-1])


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_conforming_hermite_edges_share_positions_and_slopes_along_the_edge_scaled_by_their_parameters(direction):
    """Hermite nodes share their positions and their derivatives along the edge: the second patch's
    parameter along it runs over 2.0 where the first's runs over 0.2 (and the other way round for
    direction -1), so its derivative is 0.1 (-0.1) times the first's; the derivatives across the edge
    and the cross derivatives are not shared."""
    first = S.from_callable(_plane, ParameterGrid(3, 2, (0.0, 0.5), (0.0, 0.2), False, False))

    def second_position(u, v):
        return np.stack([u, 0.1 + direction * (0.1 * v - 0.1), 0 * u], -1)

    second = S.from_callable(second_position, ParameterGrid(4, 2, (0.5, 1.0), (0.0, 2.0), False, False))
    shared = conforming_edge_dofs((first, second), (0, 1), ("xi1_max", "xi1_min"), 1e-9)
    nodes_a, nodes_b = 3 * 3 + np.arange(3), np.arange(3)[::int(direction)]
    np.testing.assert_array_equal(shared.first[:, 1], np.concatenate([4 * nodes_a, 4 * nodes_a + 2]))
    np.testing.assert_array_equal(shared.second[:, 1], np.concatenate([4 * nodes_b, 4 * nodes_b + 2]))
    np.testing.assert_allclose(shared.scale, [1.0] * 3 + [0.1 * direction] * 3, rtol=1e-14)
    for a, b, c in zip(shared.first[:, 1], shared.second[:, 1], shared.scale, strict=True):
        np.testing.assert_allclose(second.nodal.reshape(-1, 3)[b], c * first.nodal.reshape(-1, 3)[a], atol=1e-15)


@pytest.mark.parametrize(("second", "edge", "message"), [
    (lambda: _strip(0.5, 1.0, (4, 3), 0.2), "xi1_min", "have 5 and 6 control points"),
    (lambda: _strip(0.5, 1.0, (4, 2), 0.2, degree=2), "xi1_min", "degrees differ"),
    (lambda: _strip(0.6, 1.0, (4, 2), 0.2), "xi1_min", "control points lie 0.1 m apart"),
    (lambda: S.from_callable(_plane, ParameterGrid(4, 2, (0.5, 1.0), (0.0, 0.2), False, False)), "xi1_min",
     "a BSplineSurface and a HermiteSurface share no data"),
])  # fmt: skip
def test_interfaces_that_do_not_conform_are_refused_saying_why(second, edge, message):
    with pytest.raises(InterfaceError, match=message):
        conforming_edge_dofs((_strip(0.0, 0.5, (3, 2), 0.2), second()), (0, 1), ("xi1_max", edge), 1e-9)


def test_dofs_joined_through_others_are_one_unknown_represented_by_a_held_one():
    """Four patches at a corner: four pairs around it make one group of four, each a multiple of
    the held member that represents it (it carries the constraint); a loop whose coefficients
    contradict each other is refused."""
    members, representatives, coefficients = shared_groups(
        np.array([10, 20, 30, 40, 7]), np.array([20, 30, 40, 10, 8]), np.array([2.0, -1.0, 0.25, -2.0, 3.0]),
        preferred=np.array([30]))  # fmt: skip
    # x20 = 2 x10, x30 = -x20, x40 = x30 / 4, x10 = -2 x40 (the loop closes); x8 = 3 x7
    assert dict(zip(members.tolist(), representatives.tolist(), strict=True)) == {10: 30, 20: 30, 40: 30, 8: 7}
    np.testing.assert_allclose(coefficients, [3.0, -0.5, -1.0, 0.25])  # members 8, 10, 20, 40
    with pytest.raises(ValueError, match="DOF 10: the interfaces give it"):
        shared_groups(np.array([10, 20, 30]), np.array([20, 30, 10]), np.array([2.0, 1.0, 1.0]), np.array([]))


@pytest.mark.parametrize(("discretization", "fewer"), [("bspline3", 15), ("hermite", 18)])
def test_a_cantilever_of_two_patches_sharing_their_edge_has_no_gap_and_solves_at_any_penalty(comm, discretization,
                                                                                           fewer):  # fmt: skip
    """The steel strip cut at midspan (the interfaces page's): shared edge data leave no gap at
    the cut at all (round-off; the displacement penalty leaves 1.8e-12 m at alpha 1e3), the unknowns
    are fewer (cubic B-splines: 5 control points, 15; Hermite: 3 nodes' positions and slopes along
    the cut, 18), the tip deflection is the penalty joint's but for that joint's displacement
    compliance (1.0e-6 of it at alpha 10, 1.0e-8 at 1e3: it falls as 1/alpha), and the angle term
    alone solves up to alpha 1e6 (where the displacement penalty's Newton fails)."""
    shared = [cantilever(discretization, "shared", factor, comm) for factor in (1e1, 1e3, 1e6)]
    coupled = [cantilever(discretization, "coupled", factor, comm) for factor in (1e1, 1e3)]
    assert coupled[0][2].unknowns - shared[0][2].unknowns == fewer
    assert max(gap for _, gap, _ in shared) < 1e-15 and min(gap for _, gap, _ in coupled) > 1e-13
    assert not any(solve.failure for _, _, solve in shared + coupled)
    differences = [abs(a[0] / b[0] - 1) for a, b in zip(shared, coupled, strict=False)]
    assert differences[0] < 2e-6 and differences[1] < 2e-8, differences  # the displacement penalty's 1/alpha
    # the angle term's compliance falls towards the one patch's deflection: no locking
    tips = [abs(tip) for tip, _, _ in shared]
    assert tips[0] > tips[1] > tips[2] > 0.99 * tips[1]


@pytest.mark.parametrize("discretization", ["bspline3", "hermite"])
def test_the_patch_test_across_a_shared_edge_has_no_consistency_error(comm, discretization):
    """A steel strip of two halves pulled by a uniform traction (the interfaces page's): both halves
    move as one uniform stretch, as far from it as one patch (1.5e-6 of the stretch: the finite
    strain), where the penalty joint shifts the far half by its compliance (1.5e-4 of it)."""
    shared, _ = patch_test(discretization, "shared", comm)
    one, _ = patch_test(discretization, None, comm)
    coupled, _ = patch_test(discretization, "coupled", comm)
    assert shared == pytest.approx(one, rel=1e-3) and shared < 1e-5
    assert coupled > 50 * shared


@pytest.mark.parametrize("splits", [(1, 2), (2, 2)])
@pytest.mark.parametrize("discretization", ["bspline3", "hermite"])
def test_the_scordelis_lo_roof_of_patches_sharing_their_edges_gives_the_one_patch_value(comm, splits, discretization):
    """The roof (R 25, L 50, 80 degrees, h 0.25, E 4.32e8, nu 0, self-weight 90 per area) in cubic
    B-spline or Hermite patches of 12 x 12 spans in all, sharing their edges (2 x 2: four patches at
    one point, groups of four): the midside deflection is the one patch's within 3e-4 and the
    reference's (0.3006) within 5e-3, with no gap."""
    one, _, _ = roof(discretization, None, 1e3, comm=comm)
    joined, gap, solve = roof(discretization, "shared", 1e3, splits, comm)
    assert not solve.failure and gap < 1e-13
    assert abs(joined / one - 1) < 3e-4, (joined, one)
    assert abs(-joined / 0.3006 - 1) < 5e-3, joined


def test_patches_sharing_an_edge_hang_under_gravity_as_the_penalty_joint_lets_them(comm):
    """Time-stepped: two cotton-like rubber halves held along x = 0 fall under gravity for 4 steps
    with the acceleration stopping test (its mass solve on the shared unknowns): positions within
    1e-6 m of the penalty-joined pair's, and no gap at the cut."""
    rubber = Material(2.0e6, 0.45, 0.002, 1100.0)
    positions = []
    for shared in (True, False):
        rests = [_strip(0.0, 0.2, (3, 3), 0.2), _strip(0.2, 0.4, (3, 3), 0.2)]
        models = [ShellModel(rest, rubber, Loads(gravity=(0.0, 0.0, -9.81)), constraints, comm=comm,
                             dynamics=Dynamics(time_step=5e-3))
                  for rest, constraints in zip(rests, ([bcs.clamp_edge(rests[0], "xi1_min")], []), strict=True)]
        edges = ("xi1_max", "xi1_min")
        coupling = _joint(models, rests, (0, 1), edges, rubber, shared)
        dofs = conforming_edge_dofs(tuple(rests), (0, 1), edges, 1e-9) if shared else None
        with ShellSolver(models, prefix="bhem_shared_", contributions=[coupling], shared_dofs=dofs,
                         acceleration_tolerance=1e-3) as solver:  # fmt: skip
            stepper = TimeStepper(models, solver)
            for _ in range(4):
                stepper.advance()
        at = np.linspace(0.0, 0.2, 5)
        cut = [m.state_surface().evaluate(np.full(5, 0.2), at).x for m in models]
        if shared:
            assert np.abs(cut[0] - cut[1]).max() < 1e-15
        positions.append(np.concatenate([m.state_surface().evaluate(np.array([0.4]), at).x for m in models[1:]]))
    assert positions[0][:, 2].max() < -1e-3  # it fell
    np.testing.assert_allclose(positions[0], positions[1], atol=1e-6)


def _tube(discretization: str, z0: float, z1: float, start: float, spans: int = 2):
    """A tube of radius 0.1 m from z0 to z1 (``spans`` along it), closed in xi2 (8 spans around,
    from angle ``start``)."""

    def position(z, angle):
        return np.stack([0.1 * np.cos(angle + start), 0.1 * np.sin(angle + start), z], -1)

    grid = ParameterGrid(spans, 8, (z0, z1), (0.0, 2 * np.pi), False, True)
    return S.from_callable(position, grid) if discretization == "hermite" else B.from_callable(position, grid, degree=3)


@pytest.mark.parametrize(("discretization", "fewer"), [("bspline3", 24), ("hermite", 48)])
def test_tubes_stacked_along_a_closed_edge_share_it_from_any_start_and_stretch_as_one_tube(comm, discretization,
                                                                                         fewer):  # fmt: skip
    """Two rubber tubes stacked end to end, the upper one's angle starting a quarter turn on: their
    closed edges conform with the data shifted by two spans (8 control points or nodes shared, 24 or
    48 DOFs); clamped at the bottom and pulled along the axis at the top, the pair has no gap at the
    seam, stretches as the penalty-joined pair but for that joint's compliance ``T / a_d`` (within 5 %
    of it: 2e-4 of the stretch) and as the one tube of both their spans within 5e-3 (the C0 seam
    against a smooth tube on 2 + 2 spans)."""
    rubber = Material(2.0e6, 0.45, 0.002, 1100.0)
    pull = Loads(line_loads=(LineLoad("xi1_max", (0.0, 0.0, 50.0)),))
    whole = _tube(discretization, 0.0, 0.2, 0.0, spans=4)
    one = ShellModel(whole, rubber, pull, [bcs.clamp_edge(whole, "xi1_min")], comm=comm)
    with ShellSolver(one) as solver:
        solver.solve()
    at = (np.array(0.2), np.array(0.3))
    expected = one.state_surface().evaluate(*at).x - whole.evaluate(*at).x
    edges, tops, compliance = ("xi1_max", "xi1_min"), {}, 0.0
    for method in ("shared", "coupled"):
        rests = [_tube(discretization, 0.0, 0.1, 0.0), _tube(discretization, 0.1, 0.2, np.pi / 2)]
        shared = conforming_edge_dofs(tuple(rests), (0, 1), edges, 1e-9) if method == "shared" else None
        models = [ShellModel(rests[0], rubber, Loads(), [bcs.clamp_edge(rests[0], "xi1_min")], comm=comm),
                  ShellModel(rests[1], rubber, pull, [], comm=comm)]  # fmt: skip
        coupling = _joint(models, rests, (0, 1), edges, rubber, method == "shared")
        with ShellSolver(models, contributions=[coupling], shared_dofs=shared) as solver:
            solver.solve()
        if shared is None:
            compliance = 50.0 / coupling.displacement_stiffness
        else:
            assert 3 * len(shared) == fewer
            around = np.linspace(0.0, 2 * np.pi, 13)
            seam = [m.state_surface().evaluate(np.full(13, 0.1), around + offset).x
                    for m, offset in zip(models, (0.0, -np.pi / 2), strict=True)]  # fmt: skip
            assert np.abs(seam[0] - seam[1]).max() < 1e-14
        shifted = (at[0], at[1] - np.pi / 2)  # the same material point on the upper tube
        tops[method] = models[1].state_surface().evaluate(*shifted).x - rests[1].evaluate(*shifted).x
    scale = np.abs(expected).max()
    assert expected[2] > 1e-3 and abs((tops["coupled"] - tops["shared"])[2] / compliance - 1) < 0.05, tops
    assert np.abs(tops["coupled"] - tops["shared"])[:2].max() < 1e-9 * scale
    assert np.abs(tops["shared"] - expected).max() < 5e-3 * scale, (tops, expected)


def test_a_shared_point_one_body_moved_alone_is_the_mean_of_what_the_bodies_hold(comm):
    """The reduced unknowns of the bodies' states (``state_to_vector``) are each group's
    least-squares value: where one body's copy of a shared control point was moved alone (as an
    impulse response moves it), the unknown is the mean of the two copies, not one body's."""
    rests = [_strip(0.0, 0.5, (3, 2), 0.2), _strip(0.5, 1.0, (3, 2), 0.2)]
    models = [ShellModel(rest, STEEL, Loads(), [], comm=comm) for rest in rests]
    edges = ("xi1_max", "xi1_min")
    shared = conforming_edge_dofs(tuple(rests), (0, 1), edges, 1e-9)
    moved = rests[1].control.copy()
    moved[0, 2] += [0.0, 0.0, 0.01]  # the right strip's copy of the cut's third control point, lifted 1 cm
    models[1].set_state(B.BSplineSurface(rests[1].grid, 3, moved))
    with ShellSolver(models, contributions=[_joint(models, rests, (0, 1), edges, STEEL, True)],
                     shared_dofs=shared) as solver:  # fmt: skip
        solver.problem.state_to_vector(solver.x)
        solver.problem.update_state(solver.x)
    for model in models:
        np.testing.assert_allclose(model.state_surface().control[:, :, 2].max(), 0.005, rtol=1e-12)
    left, right = (m.state_surface().control for m in models)
    np.testing.assert_allclose(left[-1], right[0], atol=1e-15)
