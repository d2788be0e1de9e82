"""Implicit Euler dynamics: exact discrete solutions, damping, energy decay, motions, failures."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import Dynamics, Loads, ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.dynamics import PrescribedMotion, StepFailure, TimeStepper

CLOTH = Material(young=1e4, poisson=0.3, thickness=1e-3, density=200.0)
G = 9.81


def hanging_strip(comm, patches, dt):
    """A 0.3 m x 0.05 m cloth strip clamped at xi1 = 0, under gravity, starting horizontal."""
    rest = S.flat_rectangle(0.3, 0.05, patches, 1)
    clamp = bcs.clamp(bcs.edge_nodes(rest.grid, "xi1_min"))
    return ShellModel(rest, CLOTH, Loads(gravity=(0.0, 0.0, -G)), [clamp], comm=comm, dynamics=Dynamics(dt))


def run(model, steps, motions=(), options=None):
    with ShellSolver(model, prefix="dyn_", options=options) as solver:
        stepper = TimeStepper(model, solver, motions)
        reports = [stepper.advance() for _ in range(steps)]
        energies = model.energies()
    return stepper, reports, energies


@pytest.mark.parametrize("stiffness_damping", [0.0, 0.05])
def test_free_fall_is_the_exact_implicit_euler_sequence(comm, stiffness_damping):
    rest = S.flat_rectangle(0.5, 0.3, 3, 2)
    dt, steps = 0.01, 5
    model = ShellModel(
        rest,
        CLOTH,
        Loads(gravity=(0.0, 0.0, -G)),
        comm=comm,
        dynamics=Dynamics(dt, stiffness_damping=stiffness_damping),
    )
    run(model, steps)
    final = model.state_surface()
    drop = -G * dt**2 * steps * (steps + 1) / 2  # v_k = -k g dt, x_N = sum dt v_k
    np.testing.assert_allclose(final.nodal[:, :, 0, 2], drop, rtol=1e-9)
    np.testing.assert_allclose(final.nodal[:, :, 1:], rest.nodal[:, :, 1:], atol=1e-10)
    v = model.velocity.x.array.reshape(-1, 3)
    value_blocks = model.discretization.block_kind == 0
    np.testing.assert_allclose(v[value_blocks, 2], -G * dt * steps, rtol=1e-9)


def test_mass_damping_gives_the_exact_damped_sequence(comm):
    rest = S.flat_rectangle(0.5, 0.3, 2, 2)
    dt, alpha, steps = 0.02, 3.0, 6
    model = ShellModel(rest, CLOTH, Loads(gravity=(0.0, 0.0, -G)), comm=comm, dynamics=Dynamics(dt, mass_damping=alpha))
    run(model, steps)
    v, z = 0.0, 0.0
    for _ in range(steps):
        v = (v - dt * G) / (1 + alpha * dt)
        z += dt * v
    np.testing.assert_allclose(model.state_surface().nodal[:, :, 0, 2], z, rtol=1e-9)


def test_undamped_swing_never_gains_energy(comm):
    """A strip clamped at one end falls from horizontal: implicit Euler only dissipates."""
    model = hanging_strip(comm, patches=8, dt=0.005)
    totals = []
    with ShellSolver(model, prefix="dyn_") as solver:
        stepper = TimeStepper(model, solver)
        for _ in range(15):
            stepper.advance()
            e = model.energies()
            totals.append(e["kinetic"] + e["membrane"] + e["bending"] + e["gravity"])
    assert totals[-1] < totals[0] < 0  # it fell and lost energy to numerical damping
    assert np.all(np.diff(totals) <= 1e-12 * abs(totals[0]))
    tip = model.state_surface().nodal[-1, 0, 0]
    assert tip[2] < -0.02  # it really swings (free fall would reach -0.028 m in 0.075 s)


def test_prescribed_motion_drives_a_node(comm):
    rest = S.flat_rectangle(0.4, 0.4, 4, 4)
    corner = np.array([[4, 4]])
    speed = np.array([0.0, 0.0, 0.3])
    pinned = bcs.pin(corner)
    motion = PrescribedMotion(pinned, lambda t: rest.nodal[4, 4, 0] + speed * t)
    model = ShellModel(
        rest,
        CLOTH,
        Loads(gravity=(0.0, 0.0, -G)),
        [bcs.clamp(np.array([[0, 0]])), pinned],
        comm=comm,
        dynamics=Dynamics(0.01),
    )
    stepper, reports, _ = run(model, 4, [motion])
    np.testing.assert_allclose(model.state_surface().nodal[4, 4, 0], rest.nodal[4, 4, 0] + speed * 0.04, atol=1e-14)
    assert [r.step for r in reports] == [1, 2, 3, 4] and stepper.time == pytest.approx(0.04)


def test_a_step_that_cannot_converge_stops_the_run_with_its_time(comm):
    model = hanging_strip(comm, patches=6, dt=0.2)
    before = model.x.x.array.copy()
    # neither the line-search Newton nor its trust-region recovery may take more than one iteration
    with ShellSolver(model, prefix="dyn_fail_", options={"snes_max_it": 1, "tr_snes_max_it": 1}) as solver:
        stepper = TimeStepper(model, solver, max_halvings=1)
        with pytest.raises(StepFailure, match=r"time step 1 \(t = 0.2 s\) failed after 1 halvings.*'dyn_fail_'"):
            stepper.advance()
    np.testing.assert_array_equal(model.x.x.array, before)  # never continues from a failed state


def test_a_failed_newton_step_is_recovered_by_trust_region_newton(comm):
    """Line-search Newton limited to 2 iterations fails the strip's step; the trust-region Newton
    takes over (logged and counted) and reaches the step a full Newton reaches."""
    reference = hanging_strip(comm, patches=8, dt=0.005)
    run(reference, 1)
    model = hanging_strip(comm, patches=8, dt=0.005)
    with ShellSolver(model, prefix="dyn_tr_", options={"snes_max_it": 2}) as solver:
        stepper = TimeStepper(model, solver)
        record = stepper.advance()
        counters = solver.counters()
    assert counters["trust_region_solves"] == 1 and record.trust_region_solves == 1
    assert record.dt_halvings == 0 and record.regularized_retries == 0
    difference = np.abs(model.x.x.array - reference.x.x.array).max()
    assert difference < 1e-7 * np.abs(reference.x.x.array).max()


def test_a_step_that_cannot_converge_names_the_dominant_term(comm):
    model = hanging_strip(comm, patches=8, dt=0.005)
    options = {"snes_max_it": 1, "tr_snes_max_it": 1}
    with ShellSolver(model, prefix="dyn_fail_", options=options) as solver:
        stepper = TimeStepper(model, solver, max_halvings=0)
        with pytest.raises(StepFailure, match=r"residual by term \(largest first\): (membrane|bending|inertia|gravity) "
                           r".*dominates; try a smaller dt"):  # fmt: skip
            stepper.advance()
        assert solver.counters()["trust_region_solves"] == 0


def test_the_state_begins_rolls_back_and_finishes_a_step_exactly(comm):
    """ShellState, the stepper's one writer of the state: a step's data from (x_n, v_n), the
    rollback of a failed solve, v = (x - x_n) / dt and a correction added after; read-only views."""
    from bhem_hpc.solver.state import ShellState, StateCorrection

    model, dt = hanging_strip(comm, 4, 0.01), 0.01
    state = ShellState(model)
    rng = np.random.default_rng(3)
    model.velocity.x.array[:] = rng.normal(size=model.velocity.x.array.shape)
    x_n, v_n = model.x.x.array.copy(), model.velocity.x.array.copy()
    start = state.begin_step(dt)
    assert np.array_equal(start.position, x_n) and np.array_equal(start.velocity, v_n)
    assert np.array_equal(model.x_previous.x.array, x_n) and np.array_equal(model.x.x.array, x_n + dt * v_n)
    assert np.array_equal(model.x_predicted.x.array, x_n + dt * v_n) and model.time_step.value == dt
    state.roll_back(start)
    assert np.array_equal(state.position, x_n)
    solved = x_n + 1e-3 * rng.normal(size=x_n.shape)
    model.x.x.array[:] = solved
    dv, dx = rng.normal(size=x_n.shape), 1e-4 * rng.normal(size=x_n.shape)
    state.finish_step(start, dt, StateCorrection(dv, dx))
    assert np.array_equal(state.velocity, (solved - x_n) / dt + dv) and np.array_equal(state.position, solved + dx)
    with pytest.raises(ValueError, match="read-only"):
        state.position[0] = 1.0
