"""Several bodies in one Newton solve per time step: bodies that do not interact step as each steps
alone, a spring between two free bodies conserves their total momentum (implicit Euler with the
consistent mass: internal forces sum to zero), and bodies that cannot share a solve are refused."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import CLAMPED, RUBBER, SHEET, STEEL, TwoBodySpring, momentum
from mpi4py import MPI

from bhem_hpc.bodies.petsc import StackedBlocks
from bhem_hpc.model.path import PathSettingError
from bhem_hpc.run import build_model
from bhem_hpc.scene.loader import load_scene
from bhem_hpc.solver.dynamics import PrescribedMotion, TimeStepper
from bhem_hpc.solver.model_group import ModelGroup
from bhem_hpc.solver.newton import ShellSolver
from bhem_hpc.solver.path import PathFollower
from bhem_hpc.solver.state import ShellState

SIZE = 0.2
#: tight Newton tolerances, so that one solve of two bodies and two solves of one agree closely
TIGHT = {"snes_rtol": 1e-12, "snes_stol": 0.0}


def _model(comm, tmp_path, name, discretization, material, z=0.0, x0=0.0, rest=CLAMPED, dt=0.01, time=None):
    path = tmp_path / f"{name}.toml"
    if comm.rank == 0:
        path.write_text(SHEET.format(size=SIZE, discretization=discretization, origin=[x0, 0.0, z],
                                     time=time or f"dt = {dt}\nsteps = 3", rest=rest, **material))  # fmt: skip
    comm.Barrier()
    return build_model(load_scene(path), comm)


def _held_pair(comm, tmp_path, tag=""):
    """A clamped steel Hermite sheet and a clamped rubber quadratic B-spline sheet 5 cm above it,
    hanging under gravity."""
    return [_model(comm, tmp_path, f"steel{tag}", "hermite", STEEL),
            _model(comm, tmp_path, f"rubber{tag}", "bspline2", RUBBER, z=0.05)]  # fmt: skip


def _step(models, steps, contributions=(), prefix="bodies_"):
    with ShellSolver(models, prefix, TIGHT, contributions=contributions) as solver:
        stepper = TimeStepper(models, solver)
        iterations = [stepper.advance().newton_iterations for _ in range(steps)]
    return iterations


def test_bodies_in_one_solve_step_as_each_steps_alone(comm, shared_tmp_path):
    together = _held_pair(comm, shared_tmp_path)
    iterations = _step(together, 3)
    alone = _held_pair(comm, shared_tmp_path)
    for model in alone:
        _step(model, 3, prefix="one_body_")
    for one, other in zip(together, alone, strict=True):
        start = one.x_rest.x.array
        moved = comm.allreduce(np.abs(other.x.x.array - start).max(), op=MPI.MAX)
        difference = comm.allreduce(np.abs(one.x.x.array - other.x.x.array).max(), op=MPI.MAX)
        assert moved > 1e-5  # both sag under gravity (m)
        # the solves stop at the steel's residual floor (snes_atol ~ 1e-6 N): 3e-8 of the sag measured
        assert difference <= 1e-6 * moved
        np.testing.assert_allclose(one.velocity.x.array, other.velocity.x.array, rtol=0, atol=1e-6 * moved / 0.01)
    assert all(k >= 2 for k in iterations)


@pytest.mark.parallel
def test_two_ranks_step_two_bodies_as_one_rank(comm, shared_tmp_path):
    here = _held_pair(comm, shared_tmp_path)
    _step(here, 3, prefix="ranks_")
    serial = _held_pair(MPI.COMM_SELF, shared_tmp_path, tag=f"-self-{comm.rank}")
    _step(serial, 3, prefix="self_")
    for ours, theirs in zip(here, serial, strict=True):
        moved = np.abs(theirs.state_surface().nodal - theirs.rest_surface.nodal).max()
        assert moved > 1e-5
        assert np.abs(ours.state_surface().nodal - theirs.state_surface().nodal).max() <= 1e-6 * moved


@pytest.mark.parametrize("second", ["bspline2", "bspline3"])
def test_a_spring_between_two_free_bodies_conserves_their_momentum(comm, shared_tmp_path, second):
    """Two free sheets (steel Hermite, rubber B-splines) side by side, no gravity, a stretched spring
    between their facing corners: each gains momentum, the sum stays zero (the B-spline paper's
    momentum test, with a spring for the collision)."""
    models = [_model(comm, shared_tmp_path, "left", "hermite", STEEL, rest=""),
              _model(comm, shared_tmp_path, "right", second, RUBBER, x0=SIZE + 0.05, rest="")]  # fmt: skip
    spring = TwoBodySpring(StackedBlocks(models), (SIZE, SIZE), (0.0, SIZE), 50.0, 0.01)
    _step(models, 3, [spring], prefix="sprung_")
    momenta = [momentum(m) for m in models]
    assert momenta[0][0] > 1e-4  # the spring pulled the left sheet towards +x (kg m/s)
    assert np.linalg.norm(momenta[0] + momenta[1]) <= 1e-6 * np.linalg.norm(momenta[0])


def test_a_prescribed_motion_moves_its_own_body(comm, shared_tmp_path):
    """A motion names its body: the rubber sheet's clamped edge is lifted, the steel sheet's stays."""
    models = _held_pair(comm, shared_tmp_path)
    clamp = models[1].constraints[0]
    nodes = np.asarray(clamp.nodes)
    initial = models[1].rest_surface.nodal[nodes[:, 0], nodes[:, 1]][:, list(clamp.kinds)][:, :, list(clamp.components)]
    position = (np.asarray(clamp.kinds) == 0)[None, :, None] * (np.asarray(clamp.components) == 2)[None, None, :]

    def lifted(t):
        return initial + 0.5 * t * position  # the clamped edge rises at 0.5 m/s

    with ShellSolver(models, "moved_", TIGHT) as solver:
        stepper = TimeStepper(models, solver, [PrescribedMotion(clamp, lifted, body=1)])
        stepper.advance()
        values = stepper.bc_values_at(stepper.time)
    counts = [len(m.constrained_target) for m in models]
    kept = comm.allreduce(np.abs(values[:counts[0]] - models[0].constrained_target).max(initial=0.0), op=MPI.MAX)
    lift = comm.allreduce(np.abs(values[counts[0]:] - models[1].constrained_target).max(initial=0.0), op=MPI.MAX)
    assert kept == 0.0 and lift == pytest.approx(0.5 * stepper.time, rel=1e-12)
    with pytest.raises(ValueError, match="body 2: there are 2 bodies"):
        with ShellSolver(models, "moved_bad_", TIGHT) as solver:
            TimeStepper(models, solver, [PrescribedMotion(clamp, lifted, body=2)])


def test_bodies_that_cannot_share_a_solve_are_refused(comm, shared_tmp_path):
    steel = _model(comm, shared_tmp_path, "steel", "hermite", STEEL)
    slower = _model(comm, shared_tmp_path, "slower", "hermite", STEEL, dt=0.02)
    with pytest.raises(ValueError, match="share one time step"):
        ModelGroup([steel, slower])
    with pytest.raises(ValueError, match="at least one body.s model"):
        ModelGroup([])
    with pytest.raises(ValueError, match="all be static or all be time-stepped"):
        ModelGroup([steel, _model(comm, shared_tmp_path, "static", "hermite", STEEL, time="static = true")])
    static = [_model(comm, shared_tmp_path, f"static{k}", "hermite", STEEL, time="static = true") for k in range(2)]
    with ShellSolver(static, "static_pair_") as solver, pytest.raises(PathSettingError, match="got 2 bodies"):
        PathFollower(solver)


def test_the_acceleration_of_several_bodies_weighs_each_by_its_mass(comm, shared_tmp_path):
    """Two free sheets at rest under different gravity: the first residual is each body's ``-M_b g_b``,
    so ``a_rms = sqrt((m_1 |g_1|^2 + m_2 |g_2|^2) / (m_1 + m_2))``; a step with the tolerance lets
    each fall freely."""
    gravities = ([1.0, -2.0, -9.5], [0.0, 0.0, -3.0])
    models = [_model(comm, shared_tmp_path, f"free{k}", discretization, material, x0=0.3 * k,
                     rest=f"[effects]\ngravity = {g}\n")
              for k, (discretization, material, g) in enumerate(zip(("hermite", "bspline2"), (STEEL, RUBBER),
                                                                    gravities, strict=True))]  # fmt: skip
    masses = [m["density"] * m["thickness"] * SIZE**2 for m in (STEEL, RUBBER)]
    expected = np.sqrt(sum(mass * np.dot(g, g) for mass, g in zip(masses, gravities, strict=True)) / sum(masses))
    dt = 0.01
    with ShellSolver(models, "accel_", acceleration_tolerance=1e-2) as solver:
        for model in models:
            ShellState(model).begin_step(dt)
        problem = solver.problem
        problem.state_to_vector(solver.x)
        problem.update_state(solver.x)
        problem.assemble_residual(solver.x, solver.f)
        residual = solver.acceleration.residual
        assert residual.mass == pytest.approx(sum(masses), rel=1e-12)
        assert residual.rms(solver.f) == pytest.approx(expected, rel=1e-9)
        for model in models:  # the step starts again at rest
            model.x.x.array[:] = model.x_previous.x.array
        TimeStepper(models, solver).advance()
    for model, g in zip(models, gravities, strict=True):  # each falls freely: x_1 = x_0 + dt^2 g_b
        fall = model.state_surface().nodal[..., 0, :] - model.rest_surface.nodal[..., 0, :]
        np.testing.assert_allclose(fall, np.broadcast_to(dt**2 * np.asarray(g), fall.shape), rtol=0, atol=1e-9 * dt**2)
