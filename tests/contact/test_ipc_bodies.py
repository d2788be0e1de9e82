"""IPC's barrier between bodies in one Newton solve: two SEM solids meeting head-on, a solid
dropped onto a held cotton cloth. Every accepted state is free of intersections (ipc-toolkit's test
on the bodies' collision meshes), the solids keep their momentum through the collision, the barrier's
gradient is the slope of the stacked potential on every rank count, and two ranks give the serial
states."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from bhem_hpc.bodies.petsc import StackedBlocks
from bhem_hpc.bodies.run import bodies_barrier, make_body
from bhem_hpc.geometry import nurbs
from bhem_hpc.io.cad import write_parts
from bhem_hpc.run import make_solver
from bhem_hpc.scene.loader import load_any_scene
from bhem_hpc.solver.dynamics import TimeStepper, body_state
from bhem_hpc.solver.state import StackedState

#: Two rubber blocks 4 mm apart along x, each moving towards the other at 0.5 m/s (no gravity).
BLOCKS = """
[time]
dt = 0.005
steps = 1
[solver]
acceleration_tolerance = 1e-7
options = {{ snes_atol = 1e-10 }}
[[bodies]]
name = "left"
type = "solid"
file = "left.igs"
material = {{ density = 1000.0, young = 2.0e5, poisson = 0.45 }}
sem = {{ degree = 2, lines_per_side = 8, alpha = 0.4 }}
effects = {{ contact = {{ method = "ipc" }} }}
initial = {{ velocity = [0.5, 0.0, 0.0] }}
[[bodies]]
name = "right"
type = "solid"
file = "right.igs"
material = {{ density = 1000.0, young = 2.0e5, poisson = 0.45 }}
sem = {{ degree = 2, lines_per_side = 8, alpha = 0.4 }}
effects = {{ contact = {{ method = "ipc" }} }}
initial = {{ velocity = [{right_speed}, 0.0, 0.0] }}
"""

#: A 0.4 m cotton cloth held at its corners and a light rubber toy block 5 mm above it.
TOY = """
[time]
dt = 0.01
steps = 1
[[bodies]]
name = "cloth"
surface = { kind = "rectangle", size = [0.4, 0.4], patches = [6, 6], origin = [-0.2, -0.2, 0.0] }
material = { young = 2.0e6, poisson = 0.243, thickness = 3.18e-4, density = 472.6 }
effects = { gravity = [0.0, 0.0, -9.81], damping = { mass = 1.0 }, contact = { method = "ipc", collision_cells = 3 } }
[[bodies.constraints]]
type = "fix"
corners = ["min_min", "max_min", "min_max", "max_max"]
kinds = ["x"]
[[bodies]]
name = "toy"
type = "solid"
file = "toy.igs"
material = { density = 100.0, young = 1.0e5, poisson = 0.45 }
sem = { degree = 2, lines_per_side = 8, alpha = 0.4 }
effects = { gravity = [0.0, 0.0, -9.81], contact = { method = "ipc", collision_cells = 6 } }
"""


def _scene(comm, folder: Path, text: str, models: dict[str, list]) -> Path:
    if comm.rank == 0:
        for name, parts in models.items():
            write_parts(folder / name, parts)
        (folder / "scene.toml").write_text(text)
    comm.Barrier()
    return folder / "scene.toml"


class _Run:
    """A scene's bodies, IPC barrier, solver and stepper, as ``bhem-hpc run`` makes them."""

    def __init__(self, path: Path, comm: MPI.Comm):
        scene = load_any_scene(path)
        self.bodies = [make_body(n, k, b, comm) for k, (n, b) in enumerate(zip(scene.names, scene.bodies, strict=True))]
        self.models = [body.model for body in self.bodies]
        self.barrier = bodies_barrier(self.bodies, StackedBlocks(self.models), scene, path)
        self.solver = make_solver(self.models, scene.first, path, [self.barrier])
        state = StackedState([body_state(m) for m in self.models])
        self.stepper = TimeStepper(self.models, self.solver, [], state=state)

    def positions(self) -> np.ndarray:
        return np.concatenate([m.open_positions for m in self.models])

    def intersects(self) -> bool:
        vertices = self.barrier._vertices(self.positions())
        return bool(self.barrier._ipctk.has_intersections(self.barrier.mesh, vertices))


def _momentum(model) -> np.ndarray:
    """A solid's linear momentum [kg m/s] (its consistent mass times its control points' velocities)."""
    return np.asarray(model.solid.mass_scalar.sum(axis=0)).ravel() @ model.velocity.reshape(-1, 3)


def test_two_solids_meet_without_crossing_and_keep_their_momentum(comm, shared_tmp_path):
    """Blocks of 1000 and 1500 kg/m^3 worth of speed (0.5 and -0.75 m/s) close a 4 mm gap; the
    barrier stops them with their meshes apart (above 0, below dhat) and pushes them back in the
    first three steps: the total momentum stays what it was within 1e-6 of one block's (the solves'
    residual floor), and the left block moves backwards at the end, apart from the other."""
    models = {"left.igs": nurbs.box_faces([-0.102, -0.05, -0.05], [-0.002, 0.05, 0.05], degree=2),
              "right.igs": nurbs.box_faces([0.002, -0.05, -0.05], [0.102, 0.05, 0.05], degree=2)}  # fmt: skip
    run = _Run(_scene(comm, shared_tmp_path, BLOCKS.format(right_speed=-0.75), models), comm)
    start = sum(_momentum(m) for m in run.models)
    scale = np.abs(_momentum(run.models[0])).max()
    distances = []
    with run.solver:
        for _ in range(6):
            run.stepper.advance()
            assert not run.intersects()
            distances.append(run.barrier.min_distance(run.positions()))
            np.testing.assert_allclose(sum(_momentum(m) for m in run.models), start, atol=1e-6 * scale)
    assert 0.0 < min(distances) < run.barrier.dhat < distances[-1]
    assert _momentum(run.models[0])[0] < 0.0  # the left block bounced back


@pytest.mark.parametrize("friction", [0.0, 0.4])
def test_the_barriers_gradient_is_the_slope_of_the_stacked_potential(comm, shared_tmp_path, rng, friction):
    """A shell and a solid within dhat of each other: the stacked residual is the central
    difference of the stacked incremental potential along a random direction (1e-5), on every rank
    count (the barrier's vertices gathered from the rank that holds each); with friction 0.4 on
    both, lagged at this state for a step of 10 ms, as well."""
    toy = nurbs.box_faces([-0.04, -0.04, 3e-4], [0.04, 0.04, 0.08], degree=2)
    text = TOY.replace("contact = { method", f"friction = {friction}, contact = {{ method")
    run = _Run(_scene(comm, shared_tmp_path, text, {"toy.igs": toy}), comm)
    with run.solver:
        problem = run.solver.problem
        x, f = problem.jacobian.createVecs()
        problem.state_to_vector(x)
        problem.bc_values = x.array_r[problem.bc_local].copy()
        problem.update_state(x)
        problem.begin_step(0.0, 0.01)
        assert (run.barrier.friction is not None and run.barrier.friction.active) == (friction > 0)
        assert problem.comm.allreduce(run.barrier.energy(problem.contribution_state())) > 0.0
        problem.assemble_residual(x, f)
        direction = x.duplicate()
        sizes = comm.allgather(x.getLocalSize())
        whole = comm.bcast(rng.normal(size=sum(sizes)))
        direction.array[:] = 1e-3 * whole[sum(sizes[: comm.rank]) : sum(sizes[: comm.rank + 1])]
        direction.array[problem.bc_local] = 0.0
        bound = problem.max_step(direction)
        h = 1e-3 * bound
        energies = []
        for sign in (1.0, -1.0):
            trial = x.copy()
            trial.axpy(sign * h, direction)
            problem.update_state(trial)
            energies.append(problem.potential_energy())
        slope = (energies[0] - energies[1]) / (2 * h)
        assert slope == pytest.approx(f.dot(direction), rel=1e-5)


def _toy_run(comm, folder: Path, steps: int) -> tuple[list[float], list[float], np.ndarray]:
    """The toy's lowest control point and the meshes' distance after each step, and its control
    points at the end ``(n_q, 3)`` (on every rank)."""
    toy = nurbs.box_faces([-0.05, -0.05, 0.005], [0.05, 0.05, 0.1], degree=2)
    run = _Run(_scene(comm, folder, TOY, {"toy.igs": toy}), comm)
    heights, distances = [], []
    with run.solver:
        for _ in range(steps):
            assert run.stepper.advance().dt_halvings == 0
            assert not run.intersects()
            distances.append(run.barrier.min_distance(run.positions()))
            heights.append(float(run.models[1].open_positions[:, 2].min()))
    return heights, distances, run.models[1].open_positions.copy()


def test_a_toy_dropped_on_a_held_cloth_rests_on_it(comm, shared_tmp_path):
    """The toy (0.1 kg) lands on the cotton cloth (0.024 kg, held at its corners) in its second
    step and sinks with it into a pocket no deeper than the cloth's stretch allows, its mesh never
    crossing the cloth's: it is 0.22 m/s^2 * t^2 / 2 short of free fall after 0.2 s."""
    heights, distances, _ = _toy_run(comm, shared_tmp_path, 20)
    assert 0.0 < min(distances) < 1e-3
    free_fall = 0.005 - 0.5 * 9.81 * 0.2**2
    assert heights[-1] > free_fall + 0.1


@pytest.mark.parallel
def test_two_ranks_drop_the_toy_as_one_does(comm, shared_tmp_path):
    """The toy on the cloth for 8 steps (it lands in the second) on this process's ranks and
    serially on each: the toy's control points within 1e-5 of its motion (both solves stop at the
    acceleration tolerance, not at round-off)."""
    heights, _, parallel = _toy_run(comm, shared_tmp_path, 8)
    folder = shared_tmp_path / f"serial_{comm.rank}"
    folder.mkdir()
    serial_heights, _, serial = _toy_run(MPI.COMM_SELF, folder, 8)
    moved = abs(serial_heights[-1] - 0.005)
    assert moved > 0.01
    np.testing.assert_allclose(parallel, serial, atol=1e-5 * moved)


def test_bodies_in_contact_by_two_methods_or_overlapping_are_refused(comm, shared_tmp_path):
    """A shell in contact by impulses beside a solid (which meets others by IPC only) is refused
    naming both bodies and the key; two solids that overlap at the start are refused before the
    run's output, naming both."""
    from bhem_hpc.errors import RunError
    from bhem_hpc.run import RunOptions, run_scene
    from bhem_hpc.scene import SceneError

    toy = nurbs.box_faces([-0.05, -0.05, 0.005], [0.05, 0.05, 0.1], degree=2)
    impulse = TOY.replace('contact = { method = "ipc", collision_cells = 3 }', "contact = true")
    path = _scene(comm, shared_tmp_path, impulse, {"toy.igs": toy})
    with pytest.raises(SceneError, match=r"body 'toy' \(bodies\[1\]\): key 'effects.contact.method' is 'ipc' but "
                                         r"body 'cloth' \(bodies\[0\]\) has 'impulse'"):  # fmt: skip
        load_any_scene(path)
    overlapping = {"left.igs": nurbs.box_faces([-0.1, -0.05, -0.05], [0.01, 0.05, 0.05], degree=2),
                   "right.igs": nurbs.box_faces([0.0, -0.05, -0.05], [0.1, 0.05, 0.05], degree=2)}  # fmt: skip
    path = _scene(comm, shared_tmp_path, BLOCKS.format(right_speed=0.0), overlapping)
    with pytest.raises(RunError, match=r"the bodies in contact \(left, right\) start in contact .*intersects"):
        run_scene(RunOptions(path, shared_tmp_path / "out", progress=False), comm)
    assert not (shared_tmp_path / "out").exists()


def test_bhem_hpc_run_meets_the_bodies_by_ipc(comm, shared_tmp_path):
    """The scene run as `bhem-hpc run` runs it: the summary names the barrier (its dhat, 1e-3 of the
    bodies' bounding box, and every body in contact) and every step converges without recovery."""
    from bhem_hpc.run import RunOptions, run_scene

    toy = nurbs.box_faces([-0.05, -0.05, 0.005], [0.05, 0.05, 0.1], degree=2)
    path = _scene(comm, shared_tmp_path, TOY.replace("steps = 1", "steps = 6"), {"toy.igs": toy})
    summary = run_scene(RunOptions(path, shared_tmp_path / "out", progress=False), comm)
    contact = summary["contact"]
    assert contact["method"] == "ipc" and contact["bodies"] == ["cloth", "toy"]
    assert contact["dhat_m"] == pytest.approx(1e-3 * np.linalg.norm([0.4, 0.4, 0.1]), rel=1e-2)
    assert summary["status"] == "completed" and sum(s["recoveries"] for s in summary["steps"]) == 0
