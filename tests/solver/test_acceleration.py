"""The acceleration residual ``a_rms = sqrt(r^T M^-1 r / m)`` and Newton's stop at
``solver.acceleration_tolerance``."""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import pytest
from helpers import REPO
from mpi4py import MPI

from bhem_hpc.run import build_model, prescribed_motions
from bhem_hpc.scene.loader import load_scene
from bhem_hpc.scene.table import SceneError
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.acceleration import AccelerationResidual, certainly_above
from bhem_hpc.solver.dynamics import TimeStepper
from bhem_hpc.solver.state import ShellState

FREE_SHEET = """
[surface]
kind = "rectangle"
size = [0.7, 0.4]
patches = [5, 3]
discretization = "{discretization}"
[material]
young = 2.0e6
poisson = 0.243
thickness = 3.18e-4
density = 472.6
[time]
dt = 0.01
steps = 1
[effects]
gravity = [1.0, -2.0, -9.5]
"""


GRAVITY = np.array([1.0, -2.0, -9.5])


@contextmanager
def free_sheet_at_rest(comm, folder, discretization: str, extra: str = ""):
    """A solver on a free sheet at rest (``extra``: more scene text), with ``solver.f`` its first time
    step's residual: the gravity load ``-M g`` alone (no strain, no inertia at the inertial prediction)."""
    path = folder / f"free-{discretization}.toml"
    if comm.rank == 0:
        path.write_text(FREE_SHEET.format(discretization=discretization) + extra)
    comm.barrier()
    scene = load_scene(path)
    model = build_model(scene, comm)
    with ShellSolver(model, prefix=f"acc_{discretization}_", acceleration_tolerance=1.0) as solver:
        ShellState(model).begin_step(scene.dt)
        problem = solver.problem
        problem.state_to_vector(solver.x)
        problem.update_state(solver.x)
        problem.assemble_residual(solver.x, solver.f)
        yield solver


@pytest.mark.parametrize("discretization", ["hermite", "bspline2", "bspline3"])
def test_a_uniform_acceleration_field_measures_its_magnitude(comm, shared_tmp_path, discretization):
    """A free sheet at rest: ``a_rms`` of its gravity load is ``|g|`` on every discretization, its
    derivative and control-point DOFs included; a residual scaled by 3 measures 3 |g|."""
    with free_sheet_at_rest(comm, shared_tmp_path, discretization) as solver:
        residual = solver.acceleration.residual
        assert residual.rms(solver.f) == pytest.approx(np.linalg.norm(GRAVITY), rel=1e-9)
        solver.f.scale(3.0)
        assert residual.rms(solver.f) == pytest.approx(3 * np.linalg.norm(GRAVITY), rel=1e-9)
        assert residual.mass == pytest.approx(472.6 * 3.18e-4 * 0.7 * 0.4, rel=1e-12)


HELD_CORNERS = '\n[[constraints]]\ntype = "pin"\ncorners = ["min_max", "max_max"]\n'


@pytest.mark.parametrize("held", ["", HELD_CORNERS])
@pytest.mark.parametrize("discretization", ["hermite", "bspline2", "bspline3"])
def test_the_bound_that_spares_the_mass_solve_is_below_the_measure(comm, shared_tmp_path, discretization, held):
    """``|r|^2 / ||M||_inf <= r^T M^-1 r`` on seeded residuals, smooth (gravity's, 0.3 to 1 of it on
    these sheets) and rough ones, with and without held corners (the held rows of ``M``, made the
    identity, stay out of the bound); the stopping test solves only where the bound passes."""
    with free_sheet_at_rest(comm, shared_tmp_path, discretization, held) as solver:
        residual, g = solver.acceleration.residual, np.linalg.norm(GRAVITY)
        bound = np.sqrt(residual.lower_bound_squared(solver.f.array_r) / residual.mass)
        assert 0.3 * g < bound <= g * (1 + 1e-12)
        assert certainly_above(residual, solver.f, 0.25 * g) and not certainly_above(residual, solver.f, g)
        rng = np.random.default_rng(20261204 + comm.rank)
        for _ in range(5):
            solver.f.array[:] = rng.normal(size=solver.f.getLocalSize())
            bound = residual.lower_bound_squared(solver.f.array_r)
            assert 0.0 < bound <= residual.mass_norm_squared(solver.f.array_r) * (1 + 1e-12)


def cotton_steps(comm, job: str, patches: int, steps: int, tolerance: float | None, prefix: str):
    """``steps`` time steps of a cotton job at ``patches`` x ``patches``: Newton iterations per step,
    the final open DOFs and the final ``a_rms`` [m/s^2]."""
    scene = load_scene(REPO / "jobs" / job, {"surface": {"patches": [patches, patches]}})
    model = build_model(scene, comm)
    with ShellSolver(model, prefix=prefix, options=scene.petsc_options, acceleration_tolerance=tolerance) as solver:
        stepper = TimeStepper(model, solver, prescribed_motions(scene), max_halvings=0)
        iterations = [stepper.advance().newton_iterations for _ in range(steps)]
        problem = solver.problem
        problem.state_to_vector(solver.x)
        problem.update_state(solver.x)
        problem.assemble_residual(solver.x, solver.f)
        rows = (problem.bc_rows, problem.bc_local)
        with AccelerationResidual(model, problem.prolongation, *rows, prefix + "check_") as measure:
            acceleration = measure.rms(solver.f)
        return iterations, model.x.x.array.copy(), acceleration


@pytest.mark.parametrize(("job", "hessian"), [("hanging.toml", "adaptive"), ("drape-cotton.toml", "trust_region")])
def test_time_steps_stop_at_the_acceleration_tolerance(comm, job, hessian):
    """Cotton at 8 x 8 patches, 4 steps, through line-search Newton (hanging, adaptive Hessian) and the
    energy trust region (drape): with a tolerance of 1e-2 m/s^2 every step stops below it, in no more
    iterations than at the jobs' relative tolerances, and the DOFs stay within 1e-4 of theirs
    (positions in m, Hermite derivatives dimensionless; measured: hanging 1.1e-7, drape 3.1e-5, where
    compression makes the stiffness indefinite and a_rms dt^2 = 1e-6 m a step no bound)."""
    tight, x_tight, a_tight = cotton_steps(comm, job, 8, 4, None, f"tight_{hessian}_")
    loose, x_loose, a_loose = cotton_steps(comm, job, 8, 4, 1e-2, f"loose_{hessian}_")
    assert a_loose <= 1e-2 and a_tight < 1e-3
    assert all(a <= b for a, b in zip(loose, tight, strict=True)) and sum(loose) < sum(tight)
    difference = np.abs(x_loose - x_tight).reshape(-1, 3)  # open DOFs, positions and derivatives
    assert comm.allreduce(float(difference.max(initial=0.0)), op=MPI.MAX) < 1e-4


@pytest.mark.parametrize(("job", "value", "expected"), [
    ("shallow-arch.toml", 1e-2, "absent: a static scene has no accelerations"),
    ("drape-cotton.toml", -1.0, r"a number in \[1e-12, 1e\+06\]"),
    ("drape-cotton.toml", "fast", r"a number in \[1e-12, 1e\+06\]"),
])  # fmt: skip
def test_an_acceleration_tolerance_that_does_not_apply_is_refused(job, value, expected):
    with pytest.raises(SceneError, match=rf"{job}: .*'solver.acceleration_tolerance'.*{expected}"):
        load_scene(REPO / "jobs" / job, {"solver": {"acceleration_tolerance": value}})
