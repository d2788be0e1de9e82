"""Contact response between steps: no penetration, Coulomb friction, momentum, detection pieces."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import hairpin_model, momentum

from bhem_hpc.collision import Plane, Sphere
from bhem_hpc.collision.bezier import evaluate_many
from bhem_hpc.contact.broad_phase import overlapping_pairs
from bhem_hpc.contact.closest_points import project_to_patches
from bhem_hpc.contact.contacts import Contacts
from bhem_hpc.contact.detection import ColliderEntry, ContactDetector
from bhem_hpc.contact.petsc import ContactProjector
from bhem_hpc.contact.response import ContactHandler, ContactSettings
from bhem_hpc.geometry import surface as S
from bhem_hpc.geometry.surface import point_weights
from bhem_hpc.model.bcs import NodalConstraint, clamp, edge_nodes
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import Dynamics, Loads, ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.dynamics import TimeStepper
from bhem_hpc.solver.petsc import SolverError
from bhem_hpc.studies.study import flat_sheet

SHEET = Material(young=1e6, poisson=0.3, thickness=1e-3, density=500.0)
G = 9.81


def _incline(theta: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotation tilting the xy-plane by ``theta`` about y, and the tilted plane's normal."""
    c, s = np.cos(theta), np.sin(theta)
    rotation = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
    return rotation, rotation @ np.array([0.0, 0.0, 1.0])


def _slide(comm, theta_deg: float, mu: float, steps: int = 40, dt: float = 0.005) -> tuple[float, float]:
    """A 0.1 m sheet resting on a plane inclined by theta: mean downhill displacement after the run."""
    rotation, normal = _incline(np.radians(theta_deg))
    gap = ContactSettings().push_out
    rest = S.flat_rectangle(0.1, 0.1, 3, 3).transformed(rotation, gap * normal)
    model = ShellModel(rest, SHEET, Loads(gravity=(0.0, 0.0, -G)), comm=comm, dynamics=Dynamics(dt))
    plane = ColliderEntry(Plane([0.0, 0.0, 0.0], normal), mu)
    detector = ContactDetector(S.HermitePatches(rest.grid), [plane], samples_per_side=3)
    with ShellSolver(model, prefix="incline_") as solver:
        handler = ContactHandler(model, solver.problem, detector)
        stepper = TimeStepper(model, solver, contact=handler)
        before = model.state_surface().nodal[..., 0, :].copy()
        for _ in range(steps):
            stepper.advance()
        after = model.state_surface().nodal[..., 0, :]
        handler.close()
    downhill = rotation @ np.array([-1.0, 0.0, 0.0])
    lift = np.abs((after - before) @ normal).max()
    return float(((after - before) @ downhill).mean()), float(lift)


@pytest.mark.parametrize("theta, mu", [(20.0, 0.5), (35.0, 0.5), (30.0, 0.0)])
def test_sheet_on_an_incline_sticks_below_atan_mu_and_slides_above(comm, theta, mu):
    steps, dt = 40, 0.005
    displacement, lift = _slide(comm, theta, mu, steps, dt)
    th = np.radians(theta)
    acceleration = G * max(np.sin(th) - mu * np.cos(th), 0.0)
    expected = acceleration * dt**2 * steps * (steps + 1) / 2  # implicit Euler: x_N = sum_k k a dt^2
    if acceleration == 0.0:
        assert abs(displacement) < 1e-9  # sticks: tan(20 deg) = 0.36 < mu = 0.5
    else:
        assert displacement == pytest.approx(expected, rel=1e-3)
    assert lift < 1e-9  # it neither sinks into nor lifts off the plane


def _drop(comm, material, patches, collider, samples=2, steps=60, discretization="hermite"):
    """A 0.4 m sheet released 2 cm above z = 0 onto ``collider``: the stepper, the lowest signed
    distance of (8 * patches + 1)^2 dense points after each step, and the final surface."""
    sheet = flat_sheet(discretization, 0.4, 0.4, patches, patches)
    rest = sheet.transformed(np.eye(3), np.array([-0.2, -0.2, 0.02]))
    model = ShellModel(
        rest, material, Loads(gravity=(0.0, 0.0, -G)), comm=comm, dynamics=Dynamics(0.005, mass_damping=1.0)
    )
    patch_layout = model.discretization.patches
    detector = ContactDetector(patch_layout, [ColliderEntry(collider, 0.0)], samples_per_side=samples)
    u = np.linspace(0.0, 0.4, 8 * patches + 1)
    dense = np.meshgrid(u, u, indexing="ij")
    lowest = []
    with ShellSolver(model, prefix="drop_") as solver:
        handler = ContactHandler(model, solver.problem, detector)
        stepper = TimeStepper(model, solver, contact=handler)
        for _ in range(steps):
            stepper.advance()
            distance, _ = collider.signed_distance(model.state_surface().evaluate(*dense).x.reshape(-1, 3))
            lowest.append(distance.min())
        handler.close()
    return stepper, lowest, model.state_surface()


# the finer sampling's 150 steps take minutes: a long stability case (make stress)
@pytest.mark.parametrize("samples, tolerance", [(2, 1e-3), pytest.param(3, 3e-4, marks=pytest.mark.stress)])
def test_sheet_dropped_on_a_plane_never_penetrates_and_rests_at_the_push_out_distance(comm, samples, tolerance):
    """Corner first onto a plane tilted by 10 degrees. Contacts hold at the samples; between them
    the bending impact wave dips by less than ``tolerance`` (it shrinks with the sample spacing).
    With push-only impulses and zero restitution the sheet's bending waves die out by mass damping:
    after 0.75 s it lies flat at the push-out distance."""
    _, normal = _incline(np.radians(10.0))  # the sheet hits the tilted plane corner first
    stepper, lowest, _ = _drop(comm, SHEET, 6, Plane([0.0, 0.0, -0.03], normal), samples, steps=150)
    contacts = [r.contacts for r in stepper.history]
    assert contacts[0] == 0 and contacts[-1] > 0  # it fell, then touched
    assert min(lowest) >= -tolerance  # dense samples, not only the contact samples
    assert lowest[-1] == pytest.approx(ContactSettings().push_out, rel=1e-3)


@pytest.mark.parametrize("discretization", ["bspline2", pytest.param("bspline3", marks=pytest.mark.stress)])
def test_b_spline_sheet_dropped_on_a_plane_never_penetrates(comm, discretization):
    """The same corner-first drop with control points as the unknowns (contact rows act on them)."""
    _, normal = _incline(np.radians(10.0))
    stepper, lowest, final = _drop(comm, SHEET, 6, Plane([0.0, 0.0, -0.03], normal), 2, 150, discretization)
    assert stepper.history[0].contacts == 0 and stepper.history[-1].contacts > 0
    assert min(lowest) >= -1e-3
    assert lowest[-1] == pytest.approx(ContactSettings().push_out, rel=1e-3)


def test_cloth_dropped_on_a_sphere_never_penetrates(comm):
    """A soft 0.4 m cloth (8 x 8 patches) falls on a ball of radius 0.1 m and drapes over it."""
    cloth = Material(young=1e4, poisson=0.3, thickness=1e-3, density=200.0)
    stepper, lowest, final = _drop(comm, cloth, 8, Sphere([0.0, 0.0, -0.1], 0.1))
    assert max(r.contacts for r in stepper.history) > 50  # it wraps the ball
    # samples stay at the push-out distance; between samples (spacing s = h / 2) the ball can rise
    # by at most its sagitta s^2 / 8R
    spacing = 0.4 / 8 / 2
    assert min(lowest) >= -(spacing**2) / (8 * 0.1)
    top = final.evaluate(np.array(0.2), np.array(0.2)).x
    assert top[2] == pytest.approx(ContactSettings().push_out, abs=2e-4)  # rests on the top


def test_later_rounds_retest_only_patches_that_can_have_come_close(comm, monkeypatch):
    """Detection rounds after the first test only the patches the response moved by a quarter of
    the push-out distance or more, or that hold a contact: each such round finds what a full one finds."""
    full_detect = ContactHandler._detect
    retested = []

    def compare(self, start, end, t, dt, gap, patches=None):
        found = full_detect(self, start, end, t, dt, gap, patches)
        if patches is not None:
            every = full_detect(self, start, end, t, dt, gap)
            assert np.array_equal(np.sort(found.key), np.sort(every.key))
            retested.append(int(patches.sum()))
        return found

    monkeypatch.setattr(ContactHandler, "_detect", compare)
    cloth = Material(young=1e4, poisson=0.3, thickness=1e-3, density=200.0)
    _drop(comm, cloth, 8, Sphere([0.0, 0.0, -0.1], 0.1), steps=30)
    assert retested and min(retested) < 8 * 8  # later rounds ran, on fewer patches than all


@pytest.mark.parametrize("metric", ["jacobian", "mass"])
def test_pair_impulses_conserve_momentum_and_meet_their_rows(comm, rng, metric):
    """Self-contact rows ``n . (v_a - v_b) = 0`` on a free sheet: equal and opposite impulses, in
    both metrics (``dt^2 J + S``; ``M + S`` through its scalar block)."""
    rest = S.flat_rectangle(0.4, 0.3, 6, 5)
    model = ShellModel(rest, SHEET, comm=comm, dynamics=Dynamics(0.01))
    grid = rest.grid
    with ShellSolver(model, prefix="pair_") as solver:
        projector = ContactProjector(solver.problem)
        count = 5
        a = point_weights(
            grid, rng.integers(0, 2, count), rng.integers(0, 5, count), rng.random(count), rng.random(count)
        )
        b = point_weights(
            grid, rng.integers(4, 6, count), rng.integers(0, 5, count), rng.random(count), rng.random(count)
        )
        normal = rng.normal(size=(count, 3))
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        index = np.concatenate([a[0], b[0]], axis=1)
        coefficients = np.concatenate([a[1], -b[1]], axis=1)[:, :, None] * normal[:, None, :]
        velocity = rng.normal(size=(grid.num_nodes * 4, 3))
        projector.set_metric(solver.jacobian if metric == "jacobian" else None, 0.01)
        assert projector._scalar_active == (metric == "mass")
        projector.set_rows(index, np.concatenate([a[1], -b[1]], axis=1), normal)
        change = projector.solve(velocity, np.zeros(count))
        new = velocity + change
        projector.set_rows(a[0], a[1], normal)
        change_one_sided = projector.solve(velocity, np.zeros(count))
        rows = np.einsum("kjc,kjc->k", coefficients, new[index])
        momentum = []
        for field in (velocity, change, change_one_sided):
            closed = projector._to_closed(field)
            weighted = closed.duplicate()
            projector.mass.mult(closed, weighted)  # W t = M t for translations t
            translation = closed.duplicate()
            momentum.append([])
            for axis in range(3):
                flat = np.zeros_like(field)
                flat.reshape(-1, 4, 3)[:, 0, axis] = 1.0
                translation.array[:] = projector._to_closed(flat).array
                momentum[-1].append(weighted.dot(translation))
        projector.close()
    assert np.abs(rows).max() < 1e-6 * np.abs(velocity).max()
    # equal and opposite impulses: the change is round-off of the eps-regularized solve; one-sided
    # rows (a collider) change the momentum by O(1) of the initial value
    assert np.abs(momentum[1]).max() < 1e-5 * np.abs(momentum[0]).max()
    assert np.abs(momentum[2]).max() > 1e-2 * np.abs(momentum[0]).max()


def test_scalar_mass_metric_equals_the_vector_one(comm, rng):
    """``M + S`` factored as its scalar block gives the vector factorization's corrections, for a
    clamped sheet (all components of an edge's entries constrained) and rows in three directions."""
    rest = S.flat_rectangle(0.4, 0.3, 5, 4)
    grid = rest.grid
    clamped = [clamp(edge_nodes(grid, "xi1_min"))]
    model = ShellModel(rest, SHEET, constraints=clamped, comm=comm, dynamics=Dynamics(0.01))
    count = 6
    index, weights = point_weights(
        grid, rng.integers(0, 5, count), rng.integers(0, 4, count), rng.random(count), rng.random(count)
    )
    index, weights = np.tile(index, (3, 1)), np.tile(weights, (3, 1))
    directions = rng.normal(size=(3 * count, 3))
    velocity = rng.normal(size=(grid.num_nodes * 4, 3))
    targets = rng.normal(size=3 * count)
    changes = []
    with ShellSolver(model, prefix="scalar_") as solver:
        for scalar in (True, False):
            projector = ContactProjector(solver.problem)
            assert projector.scalar_metric
            projector.scalar_metric = scalar
            projector.set_metric()
            projector.set_rows(index, weights, directions)
            changes.append(projector.solve(velocity, targets))
            rows = np.einsum("kj,kjc,kc->k", weights, (velocity + changes[-1])[index], directions)
            projector.close()
            assert np.abs(rows - targets).max() < 1e-4 * np.abs(targets).max()  # eps-regularized least squares
    assert np.abs(changes[0]).max() > 0.0
    np.testing.assert_allclose(changes[0], changes[1], atol=1e-10 * np.abs(changes[1]).max())
    assert np.all(changes[0].reshape(*grid.node_shape, 4, 3)[0] == 0.0)  # the clamped edge stays
    # only z held on an edge: the components differ, the vector factorization is used
    held_z = [NodalConstraint(edge_nodes(grid, "xi1_min"), (0,), (2,))]
    model = ShellModel(rest, SHEET, constraints=held_z, comm=comm, dynamics=Dynamics(0.01))
    with ShellSolver(model, prefix="vector_") as solver:
        projector = ContactProjector(solver.problem)
        assert not projector.scalar_metric
        projector.close()


def test_a_contact_row_on_held_entries_only_moves_nothing(comm):
    """A contact point whose entries are all held (on a clamped edge) asks the metric for W^-1 0: no
    correction, where MUMPS refuses the sparse right-hand side without nonzeros (INFOG(1) = -22)."""
    rest = S.flat_rectangle(0.4, 0.3, 5, 4)
    grid = rest.grid
    model = ShellModel(rest, SHEET, constraints=[clamp(edge_nodes(grid, "xi1_min"))], comm=comm,
                       dynamics=Dynamics(0.01))  # fmt: skip
    m2 = grid.node_shape[1]
    index = np.array([[(0 * m2 + i2) * 4 for i2 in (1, 2, 3)]])  # the positions of nodes on xi1 = 0
    with ShellSolver(model, prefix="held_") as solver:
        projector = ContactProjector(solver.problem)
        projector.set_metric()
        projector.set_rows(index, np.ones(index.shape), np.array([[0.0, 0.0, 1.0]]))
        change = projector.solve(np.zeros((grid.num_nodes * 4, 3)), np.array([1.0]))
        projector.close()
    assert change.shape == (grid.num_nodes * 4, 3) and np.all(change == 0.0)


def test_a_refused_sparse_right_hand_side_is_solved_again_dense(comm, rng, monkeypatch):
    """Serially the metric's solves take sparse right-hand sides; where MUMPS refuses one, the same
    columns are solved as dense ones, with the same correction."""
    rest = S.flat_rectangle(0.4, 0.3, 5, 4)
    grid = rest.grid
    model = ShellModel(rest, SHEET, constraints=[clamp(edge_nodes(grid, "xi1_min"))], comm=comm,
                       dynamics=Dynamics(0.01))  # fmt: skip
    index, weights = point_weights(grid, rng.integers(0, 5, 4), rng.integers(0, 4, 4), rng.random(4), rng.random(4))
    directions, targets = rng.normal(size=(4, 3)), rng.normal(size=4)
    velocity = rng.normal(size=(grid.num_nodes * 4, 3))
    refused = []
    solve = ContactProjector._solve_columns

    def refuse_sparse(self, ksp, rhs, what):
        if rhs.getType() == "transpose":  # the sparse path: refused once, as MUMPS did (INFOG(1) = -22)
            refused.append(what)
            rhs.destroy()
            raise SolverError(f"contact projection '{self.prefix}': solving for {what} failed (refused)")
        return solve(self, ksp, rhs, what)

    changes = []
    with ShellSolver(model, prefix="refused_") as solver:
        for patch in (False, True):
            if patch:
                monkeypatch.setattr(ContactProjector, "_solve_columns", refuse_sparse)
            projector = ContactProjector(solver.problem)
            projector.set_metric()
            projector.set_rows(index, weights, directions)
            changes.append(projector.solve(velocity, targets))
            projector.close()
    assert len(refused) == (1 if comm.size == 1 else 0)  # in parallel the right-hand sides are dense
    assert np.abs(changes[0]).max() > 0 and np.abs(changes[1] - changes[0]).max() <= 1e-12 * np.abs(changes[0]).max()


def test_closest_points_match_a_dense_search(rng):
    nets = (
        rng.normal(size=(40, 4, 4, 3)) * 0.2
        + np.stack(np.meshgrid(np.linspace(0, 1, 4), np.linspace(0, 1, 4), [0.0], indexing="ij"), axis=-1)[:, :, 0, :]
    )
    points = rng.uniform([0.2, 0.2, -0.3], [0.8, 0.8, 0.3], size=(40, 3))
    uv, foot, normal, inside = project_to_patches(nets, points)
    g = np.linspace(0, 1, 401)
    uu, vv = np.meshgrid(g, g, indexing="ij")
    for k in np.flatnonzero(inside):
        from bhem_hpc.collision.bezier import evaluate

        dense = evaluate(nets[k], uu, vv).reshape(-1, 3)
        best = np.linalg.norm(dense - points[k], axis=1).min()
        assert np.linalg.norm(foot[k] - points[k]) <= best + 1e-9
        tangent_u = evaluate_many(nets[k : k + 1], uv[k : k + 1, 0], uv[k : k + 1, 1], 1, 0)[0]
        assert abs(np.dot(points[k] - foot[k], tangent_u)) < 1e-9 * (1 + np.linalg.norm(tangent_u))
    assert inside.sum() >= 10


def test_broad_phase_finds_exactly_the_overlapping_boxes(rng):
    lo_a = rng.uniform(0, 1, size=(300, 3))
    lo_b = rng.uniform(0, 1, size=(200, 3))
    boxes_a = np.stack([lo_a, lo_a + rng.uniform(0.01, 0.1, size=(300, 3))], axis=1)
    boxes_b = np.stack([lo_b, lo_b + rng.uniform(0.0, 0.3, size=(200, 3))], axis=1)
    ia, ib = overlapping_pairs(boxes_a, boxes_b)
    brute = np.all((boxes_a[:, None, 0] <= boxes_b[None, :, 1]) & (boxes_b[None, :, 0] <= boxes_a[:, None, 1]), axis=2)
    expected = set(zip(*np.nonzero(brute), strict=True))
    assert set(zip(ia.tolist(), ib.tolist(), strict=True)) == expected
    assert len(expected) > 100


def test_bad_contact_settings_are_refused():
    with pytest.raises(ValueError, match="push_out"):
        ContactSettings(push_out=0.0).validate()
    with pytest.raises(ValueError, match="metric must be one of .*got 'stiffness'"):
        ContactSettings(metric="stiffness").validate()
    grid = S.flat_rectangle(1.0, 1.0, 2, 2).grid
    for kwargs, message in [
        ({"samples_per_side": 0}, "samples_per_side"),
        ({"samples_per_side": 17}, "samples_per_side"),
        ({"self_collision": True, "self_friction": -0.1}, "self_friction"),
    ]:
        with pytest.raises(ValueError, match=message):
            ContactDetector(S.HermitePatches(grid), [], **kwargs)
    with pytest.raises(ValueError, match="friction coefficient"):
        ColliderEntry(Plane([0, 0, 0], [0, 0, 1]), -0.2)


def test_detection_split_among_ranks_is_the_serial_detection(rng):
    """Every rank tests an interleaved share of the samples; the union is the serial result."""
    rest = S.flat_rectangle(0.4, 0.4, 6, 6).transformed(np.eye(3), np.array([-0.2, -0.2, 0.0]))
    start = rest.nodal.reshape(-1, 3).copy()
    end = start.copy()
    end.reshape(7, 7, 4, 3)[:, :, 0, 2] += rng.uniform(-0.03, 0.0, size=(7, 7))
    colliders = [
        ColliderEntry(Sphere([0.0, 0.0, -0.1], 0.095)),
        ColliderEntry(Plane([0.0, 0.0, -0.02], [0.1, 0.0, 1.0]), 0.3),
    ]
    detector = ContactDetector(S.HermitePatches(rest.grid), colliders, samples_per_side=3, self_collision=True)
    serial = detector.detect(start, end, 0.0, 0.01, 1e-4)
    split = Contacts.concatenate([detector.detect(start, end, 0.0, 0.01, 1e-4, rank, 3) for rank in range(3)])
    assert len(serial) > 20
    for name in ("key", "index_a", "weights_a", "normal", "toi", "friction"):
        np.testing.assert_array_equal(getattr(split, name), getattr(serial, name))


@pytest.mark.parametrize(("discretization", "patches"), [("hermite", 24), ("hermite", 2), ("bspline2", 24),
                                                       ("bspline3", 24)])  # fmt: skip
def test_head_on_self_collision_conserves_momentum_and_keeps_the_arms_apart(comm, discretization, patches):
    """The two arms of a folded strip fly at each other (1 m/s each, plus a common drift). With 24
    patches (knot spans) along the strip the arms are far apart in the patch grid; with 2 the fold
    lies inside two neighbouring patches (the folded-patch search). On B-splines the contact rows
    act on control points, each given the velocity of its Greville point."""
    model, (arm, length, width) = hairpin_model(comm, discretization, patches)
    layout = model.discretization.patches
    before = momentum(model)
    per_side = 2 if patches > 2 else 6
    detector = ContactDetector(layout, [], samples_per_side=per_side, self_collision=True)
    u = np.linspace(0.0, 0.95 * arm, 60)
    v = np.linspace(0.0, width, 9)
    separations = []
    with ShellSolver(model, prefix="hairpin_") as solver:
        handler = ContactHandler(model, solver.problem, detector)
        stepper = TimeStepper(model, solver, contact=handler)
        for _ in range(20):
            stepper.advance()
            surface = model.state_surface()
            upper = surface.evaluate(*np.meshgrid(u, v, indexing="ij")).x
            lower = surface.evaluate(*np.meshgrid(length - u, v, indexing="ij")).x
            separations.append((upper[..., 2] - lower[..., 2]).min())
        handler.close()
        after = momentum(model)
    assert max(r.contacts for r in stepper.history) > (50 if patches > 2 else 20)
    # 4 mm of relative travel per step; between the samples the arms may dip past each other by
    # a fraction of a millimetre within the impact step, never through
    assert min(separations) > -5e-4
    assert separations[-1] > -1e-4
    np.testing.assert_allclose(after, before, atol=1e-6 * np.abs(before).max())


def _c_fold(squeeze: float, patches: int = 1):
    """A strip curled into a C within ``patches`` patch(es) along its length: the edge at xi1 = 0
    lies at z = 0, the edge at xi1 = 1 at z = 0.1 above it; ``squeeze`` lowers the upper edge's nodes.

    Returns (grid, start nodal, end nodal) as flat ``(N, 3)`` arrays.
    """
    grid = S.ParameterGrid(patches, 1, (0.0, 1.0), (0.0, 0.2))
    surface = S.from_callable(lambda a, b: np.stack([a * (1 - a), b, 0.1 * (3 * a**2 - 2 * a**3)], -1), grid)
    start = surface.nodal.copy()
    end = start.copy()
    end[-1, :, 0, 2] -= squeeze
    return grid, start.reshape(-1, 3), end.reshape(-1, 3)


@pytest.mark.parametrize("patches", [1, 2])
def test_self_contact_within_one_patch_and_its_neighbours_is_found(patches):
    """A C-fold inside one patch (and across two neighbouring patches) squeezed shut within a step.

    Reference: each sample's distance to the far part of the surface (parameter distance > 0.3
    along the strip) at 101 instants of the step, on a 241 x 9 lattice. Every sample that comes
    within the gap is detected, at a time of impact no later than the reference's first instant,
    with a normal pointing to where it started; a C that stays open, or a patch curved by 115
    degrees, gives no contact."""
    gap, dt = 2e-3, 0.01
    grid, start, end = _c_fold(0.12, patches)
    detector = ContactDetector(S.HermitePatches(grid), [], samples_per_side=4, self_collision=True)
    contacts = detector.detect(start, end, 0.0, dt, gap)
    samples = detector.samples
    sample_xi = samples.patch // grid.n2 + samples.local[:, 0]
    a, b = np.meshgrid(np.linspace(0, 1, 241), np.linspace(0, 0.2, 9), indexing="ij")
    first_touch = np.full(len(samples.patch), np.inf)
    for t in np.linspace(0.0, 1.0, 101)[::-1]:
        nodal = ((1 - t) * start + t * end).reshape(*grid.node_shape, 4, 3)
        surface = S.HermiteSurface(grid, nodal).evaluate(a.ravel(), b.ravel()).x
        points = samples.positions((1 - t) * start + t * end, np.arange(len(samples.patch)))
        far = np.abs(sample_xi[:, None] / patches - a.ravel()[None]) > 0.3
        distance = np.where(far, np.linalg.norm(points[:, None] - surface[None], axis=2), np.inf).min(axis=1)
        first_touch[distance < gap] = t
    touching = np.flatnonzero(np.isfinite(first_touch))
    assert len(touching) >= 5
    found = contacts.key % 2**40
    assert set(touching) <= set(found), "a sample that touches the far surface was not detected"
    toi = dict(zip(found, contacts.toi, strict=True))
    for k in touching:
        assert toi[k] <= first_touch[k] + 0.011
    point_a = np.einsum("kj,kjc->kc", contacts.weights_a, start[contacts.index_a])
    point_b = np.einsum("kj,kjc->kc", contacts.weights_b, start[contacts.index_b])
    assert np.all(np.einsum("kc,kc->k", contacts.normal, point_a - point_b) > 0)
    grid, start, _ = _c_fold(0.0, patches)
    assert len(detector.detect(start, start, 0.0, dt, gap)) == 0
    bent = S.from_callable(
        lambda a, b: np.stack([np.sin(a), b, 1 - np.cos(a)], -1), S.ParameterGrid(1, 1, (0.0, 2.0), (0.0, 0.5))
    ).nodal.reshape(-1, 3)
    plain = ContactDetector(S.HermitePatches(S.ParameterGrid(1, 1, (0.0, 2.0), (0.0, 0.5))), [], 4, self_collision=True)
    assert len(plain.detect(bent, bent, 0.0, dt, 0.05)) == 0
