"""Contact by impulses on SEM solids: the solid's rational Bezier nets and sample rows reproduce its
NURBS parts, the narrow phase projects onto and sweeps rational patches exactly, a rubber block
lands on a plane without crossing it (frictionless: its horizontal momentum kept to round-off;
with friction: slowed, never turned back), two blocks collide keeping their total momentum, a block
lands on a cloth with neither crossing the other, two ranks give the serial numbers, and bad
scenes are refused before anything is written."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import write_scene
from mpi4py import MPI

from bhem_hpc.bodies.run import bodies_contact, make_body
from bhem_hpc.contact.closest_points import _time_of_impact, evaluate_points, project_to_patches
from bhem_hpc.contact.solid_surface import SolidContactSurface, elevation_matrix
from bhem_hpc.errors import InputError
from bhem_hpc.geometry import nurbs
from bhem_hpc.io.cad import write_parts
from bhem_hpc.run import RunOptions, make_solver, run_scene
from bhem_hpc.scene import SceneError
from bhem_hpc.scene.loader import load_any_scene
from bhem_hpc.solver.dynamics import TimeStepper, body_state
from bhem_hpc.solver.state import StackedState

PUSH_OUT = 1e-4
BLOCK = """
[[bodies]]
name = "{name}"
type = "solid"
file = "block.igs"
offset = {offset}
material = {{ density = 1100.0, young = 2.0e6, poisson = 0.45 }}
sem = {{ degree = 2, lines_per_side = 10, sparsity = 0.3 }}
effects = {{ {gravity}friction = {friction}, contact = {{ method = "impulse", push_out = 1e-4 }} }}
initial = {{ velocity = {velocity} }}
"""
PLANE = """
[[colliders]]
type = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
"""
CLOTH = """
[[bodies]]
name = "cloth"
surface = { kind = "rectangle", size = [0.6, 0.6], patches = [10, 10], origin = [-0.3, -0.3, 0.0] }
material = { young = 1.0e5, poisson = 0.3, thickness = 1.0e-3, density = 200.0 }
effects = { gravity = [0.0, 0.0, -9.81], damping = { mass = 1.0 }, contact = { method = "impulse", push_out = 1e-4 } }
[[bodies.constraints]]
type = "fix"
corners = ["min_min", "max_min", "min_max", "max_max"]
kinds = ["x"]
"""


def _time(dt: float, steps: int) -> str:
    return f"[time]\ndt = {dt}\nsteps = {steps}\n[output]\nevery = {steps}\n"


def _block(name="block", offset=(0.0, 0.0, 0.13), velocity=(0.5, 0.0, -1.0), friction=0.0, gravity=True) -> str:
    return BLOCK.format(name=name, offset=list(offset), velocity=list(velocity), friction=friction,
                        gravity="gravity = [0.0, 0.0, -9.81], " if gravity else "")  # fmt: skip


@pytest.fixture
def block_file(comm, shared_tmp_path):
    """A 0.2 m cube of six biquadratic faces centred at the origin, as IGES."""
    path = shared_tmp_path / "block.igs"
    if comm.rank == 0:
        write_parts(path, nurbs.box_faces([-0.1, -0.1, -0.1], [0.1, 0.1, 0.1], degree=2))
    comm.Barrier()
    return path


class Run:
    """A scene's bodies stepped by the library, its impulse contact handler attached."""

    def __init__(self, path, comm):
        scene = load_any_scene(path)
        self.bodies = [make_body(n, k, b, comm) for k, (n, b) in enumerate(zip(scene.names, scene.bodies, strict=True))]
        self.models = [body.model for body in self.bodies]
        self.solver = make_solver(self.models, scene.first, path, [])
        self.handler = bodies_contact(self.bodies, self.solver, scene)
        self.stepper = TimeStepper(self.models, self.solver, [], contact=self.handler,
                                   state=StackedState([body_state(m) for m in self.models]))  # fmt: skip

    def entries(self, body: int) -> np.ndarray:
        return self.handler.entries.surfaces[body].open_to_entries(self.stepper.state.states[body].position)

    def close(self):
        self.handler.close()
        self.solver.close()


def _solid_momentum(model) -> np.ndarray:
    """``1^T M v`` per component: the SEM solid's linear momentum [kg m/s]."""
    masses = np.asarray(model.solid.mass_scalar.sum(axis=0)).ravel()
    return masses @ model.velocity.reshape(-1, 3)


def _nearest_projection(points: np.ndarray, nets: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each point's closest point over all ``nets``: ``(foot, unit normal, inside the patch, distance)``."""
    point, patch = np.divmod(np.arange(len(points) * len(nets)), len(nets))
    _, foot, normal, inside = project_to_patches(nets[patch], points[point])
    distance = np.linalg.norm(points[point] - foot, axis=1)
    nearest = np.full(len(points), np.inf)
    np.minimum.at(nearest, point, distance)
    closest = np.flatnonzero(distance == nearest[point])
    closest = closest[np.unique(point[closest], return_index=True)[1]]
    return foot[closest], normal[closest], inside[closest], distance[closest]


def _depth_inside(points: np.ndarray, nets: np.ndarray, centre: np.ndarray) -> float:
    """How far ``points`` reach into a convex solid of patches ``nets`` about ``centre`` [m] (negative:
    the nearest point's distance outside). A point's closest point on the solid lies inside one of
    its patches when the point is inside (a convex body); it is inside where the centre lies on its
    side of the tangent plane there."""
    foot, normal, inside, distance = _nearest_projection(points, nets)
    offset = np.einsum("kc,kc->k", points - foot, normal) * np.sign(np.einsum("kc,kc->k", centre - foot, normal))
    # (a closest point on a patch's edge: the point is outside, that far)
    return float(np.max(np.where(inside, offset, -distance)))


def _depth_below(points: np.ndarray, nets: np.ndarray) -> float:
    """How far ``points`` lie below a sheet of patches ``nets`` that faces up [m] (negative: the
    nearest point's height above it), over the points whose closest point is inside a patch."""
    foot, normal, inside, _ = _nearest_projection(points, nets)
    height = np.einsum("kc,kc->k", points - foot, normal * np.sign(normal[:, 2:]))
    return float(np.max(-height[inside]))


def test_rational_nets_and_sample_rows_reproduce_the_parts():
    rng = np.random.default_rng(3)
    parts = [nurbs.sphere(0.3, (0.1, 0.0, 0.2)), nurbs.torus(0.5, 0.1), *nurbs.box_faces([1, 0, 0], [1.3, 0.2, 0.25])]
    surface = SolidContactSurface(parts, 2)
    control = np.concatenate([p.control.reshape(-1, 3) for p in parts])
    nets, first, worst = surface.nets(control), 0, 0.0
    for part in parts:
        boxes = part.bezier_patches.boxes
        for k, box in enumerate(boxes):
            s, t = rng.random(6), rng.random(6)
            exact = part.evaluate(box[0] + s * (box[1] - box[0]), box[2] + t * (box[3] - box[2]))[0]
            on_net = evaluate_points(np.repeat(nets[first + k][None], 6, axis=0), s, t)
            index, weights = surface.point_entries(np.full(6, first + k), np.stack([s, t], axis=1))
            by_rows = np.einsum("nk,nkc->nc", weights, control[index])
            worst = max(worst, np.abs(on_net - exact).max(), np.abs(by_rows - exact).max())
        first += len(boxes)
    assert first == surface.num_patches
    assert worst < 1e-14
    samples = surface.samples
    points = samples.positions(control, np.arange(len(samples.patch)))
    assert np.abs(np.linalg.norm(points[: np.count_nonzero(samples.index[:, 0] < 45)] - [0.1, 0.0, 0.2], axis=1)
                  - 0.3).max() < 1e-14  # fmt: skip
    # degree elevation keeps the polynomial: x^2 on [0, 1] from degree 2 to 3
    np.testing.assert_allclose(elevation_matrix(2) @ np.array([0.0, 0.0, 1.0]), [0.0, 0.0, 1 / 3, 1.0], atol=1e-15)
    with pytest.raises(InputError, match=r"degrees \(4, 1\): impulse contact takes parts of degree at most 3"):
        knots = np.r_[np.zeros(5), np.ones(5)]
        SolidContactSurface([nurbs.NurbsSurface((4, 1), knots, [0, 0, 1, 1], rng.random((5, 2, 3)))], 2)


def test_points_project_onto_and_cross_rational_patches_where_they_are():
    sphere = nurbs.sphere(0.3, (0.1, 0.0, 0.2))
    surface = SolidContactSurface([sphere], 2)
    nets = surface.nets(sphere.control.reshape(-1, 3))
    rng = np.random.default_rng(5)
    patch, uv = rng.integers(0, len(nets), 300), 0.1 + 0.8 * rng.random((300, 2))
    foot = evaluate_points(nets[patch], uv[:, 0], uv[:, 1])
    radial = (foot - [0.1, 0.0, 0.2]) / 0.3
    found_uv, found_foot, normal, inside = project_to_patches(nets[patch], foot + 0.04 * radial)
    assert inside.all()
    np.testing.assert_allclose(found_foot, foot, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.einsum("kc,kc->k", normal, radial)), 1.0, atol=1e-12)
    # a point crossing the patch at half the step, found by CCD on the weighted offsets
    for k in range(5):
        hit = _time_of_impact(nets[patch[k]], nets[patch[k]], foot[k] + 0.05 * radial[k], foot[k] - 0.05 * radial[k],
                              1.0, 1e-7)  # fmt: skip
        assert hit is not None and abs(hit[0] - 0.5) < 1e-5
        np.testing.assert_allclose(hit[1:], uv[k], atol=1e-5)
        assert _time_of_impact(nets[patch[k]], nets[patch[k]], foot[k] + 0.05 * radial[k], foot[k] + 0.01 * radial[k],
                               1.0, 1e-7) is None  # fmt: skip


@pytest.mark.parametrize("friction", [0.0, 0.3])
def test_a_rubber_block_lands_on_a_plane_by_impulses(comm, shared_tmp_path, block_file, friction):
    path = write_scene(comm, shared_tmp_path / "drop.toml", _time(0.005, 16) + _block(friction=friction) + PLANE)
    run = Run(path, comm)
    try:
        (model,) = run.models
        samples = run.handler.entries.surfaces[0].samples
        every = np.arange(len(samples.patch))
        lowest, speeds, contacts = [], [], 0
        for _ in range(16):
            run.stepper.advance()
            lowest.append(samples.positions(run.entries(0), every)[:, 2].min())
            speeds.append(_solid_momentum(model) / model.solid.mass)
            contacts += run.handler.history[-1].contacts
    finally:
        run.close()
    speeds = np.array(speeds)
    assert contacts > 50
    # lands at step 6 (0.03 m at 1 m/s and more); then rests on the push-out distance, never below it
    assert min(lowest) >= 0.5 * PUSH_OUT and lowest[5] < 2 * PUSH_OUT
    assert speeds[5, 2] > -1.2 and speeds[-1, 2] > -0.5  # the fall stopped (it rebounds: rubber)
    if friction == 0.0:
        np.testing.assert_allclose(speeds[:, :2], [[0.5, 0.0]] * 16, atol=1e-10)
    else:
        assert np.all(np.diff(speeds[:, 0]) <= 1e-12) and 0.0 <= speeds[-1, 0] < 0.45


def test_two_blocks_colliding_by_impulses_keep_their_momentum(comm, shared_tmp_path, block_file):
    text = (_time(0.005, 10) + _block("left", (-0.12, 0.0, 0.0), (1.0, 0.0, 0.0), gravity=False)
            + _block("right", (0.12, 0.02, 0.03), (-1.0, 0.0, 0.0), gravity=False))  # fmt: skip
    run = Run(write_scene(comm, shared_tmp_path / "pair.toml", text), comm)
    try:
        start = sum(_solid_momentum(m) for m in run.models)
        scale = sum(np.abs(_solid_momentum(m)).max() for m in run.models)
        left, right = run.handler.entries.surfaces
        depth = -np.inf
        for _ in range(10):
            run.stepper.advance()
            for a, b in ((0, 1), (1, 0)):
                samples, entries = run.handler.entries.surfaces[a].samples, run.entries(b)
                points = samples.positions(run.entries(a), np.arange(len(samples.patch)))
                nets = run.handler.entries.surfaces[b].nets(entries)
                depth = max(depth, _depth_inside(points, nets, entries.mean(axis=0)))
        contacts = sum(report.contacts for report in run.handler.history)
        end = sum(_solid_momentum(m) for m in run.models)
        velocities = [_solid_momentum(m)[0] / m.solid.mass for m in run.models]
    finally:
        run.close()
    assert contacts > 20
    assert depth < -0.5 * PUSH_OUT  # every sample stayed outside the other block
    np.testing.assert_allclose(end, start, atol=1e-10 * scale)
    assert velocities[0] < 0.9 and velocities[1] > -0.9  # the blocks met and pushed each other
    assert right.num_patches == left.num_patches == 6


def test_a_block_lands_on_a_cloth_by_impulses_and_neither_crosses(comm, shared_tmp_path, block_file):
    text = _time(0.005, 24) + CLOTH + _block(offset=(0.0, 0.0, 0.11), velocity=(0.0, 0.0, -0.5))
    run = Run(write_scene(comm, shared_tmp_path / "cloth.toml", text), comm)
    try:
        cloth_model, block_model = run.models
        surfaces = run.handler.entries.surfaces
        into_block, below_cloth = -np.inf, -np.inf
        for _ in range(24):
            run.stepper.advance()
            cloth, block = cloth_model.state_surface(), run.entries(1)
            cloth_samples = run.handler.detector.detectors[0].samples
            points = cloth_samples.positions(run.entries(0), np.arange(len(cloth_samples.patch)))
            into_block = max(into_block, _depth_inside(points, surfaces[1].nets(block), block.mean(axis=0)))
            points = surfaces[1].samples.positions(block, np.arange(len(surfaces[1].samples.patch)))
            below_cloth = max(below_cloth, _depth_below(points, cloth.bezier_nets()))
        between = sum(report.contacts for report in run.handler.history)
        sag = -cloth_samples.positions(run.entries(0), np.arange(len(cloth_samples.patch)))[:, 2].min()
        bottom = surfaces[1].samples.positions(run.entries(1), np.arange(len(surfaces[1].samples.patch)))[:, 2].min()
    finally:
        run.close()
    assert between > 100
    # no sample of either crossed the other (each rests at the push-out distance or beyond)
    assert into_block < -0.4 * PUSH_OUT and below_cloth < -0.4 * PUSH_OUT
    assert sag > 0.02  # the block pushed the cloth down ...
    assert -sag < bottom < -sag + 0.01  # ... and sinks with it, lying in its pocket


def test_a_run_of_a_block_landing_by_impulses_restarts_where_it_stopped(comm, shared_tmp_path, block_file):
    from bhem_hpc.io import read_checkpoint

    path = write_scene(comm, shared_tmp_path / "land.toml", _time(0.005, 10) + _block(friction=0.3) + PLANE)
    whole, split = shared_tmp_path / "whole", shared_tmp_path / "split"
    summary = run_scene(RunOptions(path, whole, progress=False), comm)
    run_scene(RunOptions(path, split, steps=7, progress=False), comm)
    run_scene(RunOptions(path, split, restart=split, progress=False), comm)
    assert sum(step["contacts"] for step in summary["steps"]) > 50  # steps 6-10 in contact, 7 the restart
    np.testing.assert_array_equal(read_checkpoint(split / "checkpoint.h5")[0]["position_dofs"],
                                  read_checkpoint(whole / "checkpoint.h5")[0]["position_dofs"])  # fmt: skip


@pytest.mark.parallel
def test_two_ranks_give_the_serial_numbers_of_a_block_on_a_cloth(comm, shared_tmp_path, block_file):
    text = _time(0.005, 14) + CLOTH + _block(offset=(0.0, 0.0, 0.11), velocity=(0.0, 0.0, -0.5))
    path = write_scene(comm, shared_tmp_path / "ranks.toml", text)
    states = []
    for communicator in (comm, MPI.COMM_SELF):
        run = Run(path, communicator)
        try:
            for _ in range(14):
                run.stepper.advance()
            assert sum(report.contacts for report in run.handler.history) > 0
            states.append(run.entries(1).copy())
        finally:
            run.close()
    moved = 0.07
    np.testing.assert_allclose(states[0], states[1], atol=1e-7 * moved)


@pytest.mark.parametrize(
    ("scene", "message"),
    [
        (lambda: _time(0.005, 2) + _block(offset=(0.0, 0.0, 0.05)) + PLANE,
         r"body 'block': key 'effects.contact.method' = 'impulse': 21 of its 54 boundary samples start inside "
         r"colliders\[0\], the deepest at \[.*\] m, 0.05 m deep"),
        (lambda: _time(0.005, 2) + CLOTH + _block(offset=(0.0, 0.0, 0.05)),
         r"body 'cloth' \(bodies\[0\]\) and body 'block' \(bodies\[1\]\) overlap at the start near \[.*\]: key "
         r"'offset' or 'surface' of one of them must place them apart"),
        (lambda: _time(0.005, 2) + _block().replace('push_out = 1e-4', 'push_out = 1e-4, metric = "stiff"') + PLANE,
         r"body 'block' \(bodies\[0\]\): key 'effects.contact.metric' must be one of \('mass', 'jacobian'\)"),
        (lambda: _time(0.005, 2) + _block().replace("friction = 0.0", "friction = 0.0, static_friction = 0.5")
         + PLANE, r"body 'block' \(bodies\[0\]\): key 'effects.static_friction' = 0.5: impulses have one Coulomb "
         r"coefficient"),
    ],
)  # fmt: skip
def test_bad_impulse_scenes_of_solids_are_refused_before_anything_is_written(comm, shared_tmp_path, block_file, scene,
                                                                               message):  # fmt: skip
    path = write_scene(comm, shared_tmp_path / "bad.toml", scene())
    with pytest.raises(SceneError, match=message):
        run_scene(RunOptions(path, shared_tmp_path / "out", progress=False), comm)
    assert not (shared_tmp_path / "out").exists()
