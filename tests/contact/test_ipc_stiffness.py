"""IPC's adaptive barrier stiffness: kappa doubles after a Newton iterate whose closest pair is nearer
than its threshold and nearer than the last iterate's, up to its limit, never otherwise; a scene
whose shell is pressed onto a floor grows it, records it, and a restart goes on with the grown one."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import RUBBER, SHEET, hairpin_model, write_scene

from bhem_hpc.contact.ipc_contribution import STIFFNESS_GROWTH_DISTANCE
from bhem_hpc.contact.ipc_setup import shell_barrier
from bhem_hpc.io import read_checkpoint
from bhem_hpc.run import RunOptions, run_scene
from bhem_hpc.solver.contributions import ContributionState, IterationAdapted

DHAT = 1e-3


def _hairpin_before_a_wall(comm):
    """A B-spline hairpin (its control points translate the surface exactly) and a wall 0.1 mm ahead
    of its collision mesh's front; ``state(gap)`` moves the hairpin along x so that its closest
    collision vertex is ``gap`` [m] from the wall."""
    from bhem_hpc.collision.colliders import Plane

    model, _ = hairpin_model(comm, "bspline2", 8)
    positions = model.x.x.array.reshape(-1, 3).copy()
    probe = shell_barrier(model, [], DHAT, 10.0, 2, 200.0, 1e-3)
    front = probe._vertices(positions)[: probe.num_points, 0].max()
    wall = front + 1e-4
    plane = Plane(np.array([wall, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0]))

    def state(gap: float) -> ContributionState:
        return ContributionState(positions + np.array([1e-4 - gap, 0.0, 0.0]), 1.0, np.zeros((0, 3)))

    return model, plane, state


def test_the_stiffness_doubles_only_while_the_closest_pair_closes_in_below_its_threshold(comm):
    model, plane, state = _hairpin_before_a_wall(comm)
    barrier = shell_barrier(model, [plane], DHAT, 10.0, 2, 200.0, 1e-3)
    assert isinstance(barrier, IterationAdapted)
    assert not barrier.adapt(state(0.5 * barrier.growth_distance))  # a given stiffness stays fixed
    barrier.allow_stiffness_growth(80.0)
    barrier.begin_step(state(1e-4), 0.0, 1e-3)
    threshold = barrier.growth_distance
    rest = barrier.mesh.rest_positions[: barrier.num_points]
    diagonal = np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))
    assert threshold == pytest.approx(STIFFNESS_GROWTH_DISTANCE * diagonal, rel=1e-12)
    before = barrier.energy(state(0.8 * threshold))
    # (gap, stiffness after the iterate): beyond the threshold, closing in from beyond it, closing
    # in within it, opening, closing in twice more (the limit reached), closing in at the limit
    expected = [(1e-4, 10.0), (0.9 * threshold, 10.0), (0.8 * threshold, 20.0), (0.85 * threshold, 20.0),
                (0.5 * threshold, 40.0), (0.4 * threshold, 80.0), (0.3 * threshold, 80.0)]  # fmt: skip
    for gap, stiffness in expected:
        previous = barrier.stiffness
        assert barrier.adapt(state(gap)) == (stiffness != previous)
        assert barrier.stiffness == stiffness
    assert barrier.stiffness_doublings == 3
    after = barrier.energy(state(0.8 * threshold))  # collective; rank 0's: kappa times the barrier sum
    if comm.rank == 0:
        assert after == pytest.approx(8.0 * before, rel=1e-12) and before > 0
    restarted = shell_barrier(model, [plane], DHAT, 10.0, 2, 200.0, 1e-3)
    restarted.restore({"another_contributions_parameter": 1.0})  # names it does not know are ignored
    assert restarted.stiffness == 10.0
    restarted.restore(barrier.parameters())
    assert restarted.stiffness == 80.0


#: A rubber sheet 5 mm above a floor, pressed onto it by 10 MPa (``rest`` of :data:`SHEET`): with the
#: stiffness at the top of ipc-toolkit's range its collision mesh would sink to about 1e-9 m of it.
PRESSED = """
[effects]
gravity = [0.0, 0.0, -9.81]
area_loads = [{ force = [0.0, 0.0, -1.0e7] }]
contact = { method = "ipc", dhat = 1e-3 }
[[colliders]]
type = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
"""


def test_a_pressed_sheet_grows_the_stiffness_and_a_restart_goes_on_with_it(comm, shared_tmp_path):
    text = SHEET.format(size=0.2, discretization="hermite", origin=[0.0, 0.0, 0.005], time="dt = 0.005\nsteps = 6",
                        rest=PRESSED, **RUBBER)  # fmt: skip
    path = write_scene(comm, shared_tmp_path / "pressed.toml", text)
    whole, split = shared_tmp_path / "whole", shared_tmp_path / "split"
    summary = run_scene(RunOptions(path, whole, progress=False), comm)
    contact = summary["contact"]
    assert contact["stiffness_doublings"] >= 1 and sum(s["recoveries"] for s in summary["steps"]) == 0
    grown = contact["barrier_stiffness_start"] * 2.0 ** contact["stiffness_doublings"]
    assert contact["barrier_stiffness"] == pytest.approx(min(grown, contact["barrier_stiffness_limit"]), rel=1e-12)
    run_scene(RunOptions(path, split, steps=3, progress=False), comm)
    continued = run_scene(RunOptions(path, split, restart=split, progress=False), comm)
    assert continued["contact"]["barrier_stiffness"] == contact["barrier_stiffness"]
    if comm.rank == 0:
        ours, attrs = read_checkpoint(split / "checkpoint.h5")
        theirs, _ = read_checkpoint(whole / "checkpoint.h5")
        assert attrs["adapted_ipc_barrier_stiffness"] == contact["barrier_stiffness"]
        np.testing.assert_allclose(ours["position_dofs"], theirs["position_dofs"], rtol=0, atol=1e-12)
