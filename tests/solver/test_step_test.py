"""Newton's stop on its step (``solver.velocity_tolerance``, IPC's test): the measure, its "auto"
tolerance, the cotton drape's time steps with the energy trust region and the hanging cotton's with
line-search Newton against the same steps solved to the acceleration tolerance alone, and bad values."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import REPO

from bhem_hpc.errors import RunError
from bhem_hpc.run import RunOptions, build_model, make_solver, prescribed_motions, run_scene
from bhem_hpc.scene.loader import load_scene
from bhem_hpc.scene.table import SceneError
from bhem_hpc.solver.dynamics import TimeStepper
from bhem_hpc.solver.state import ShellState
from bhem_hpc.solver.step_test import StepVelocityTest, auto_velocity_tolerance


def test_a_step_passes_when_no_block_moves_more_than_the_tolerance_times_dt(comm, rng):
    """The largest block over all ranks decides; dt = 0 (no step begun) never passes."""
    blocks = rng.uniform(-1e-4, 1e-4, size=(50, 3))
    blocks[7] = [3e-4, 4e-4, 0.0] if comm.rank == comm.size - 1 else blocks[7]  # 5e-4 m on the last rank
    test = StepVelocityTest(tolerance=0.1, comm=comm)
    assert not test.passes(blocks)
    test.dt = 5e-3
    assert test.passes(blocks)  # 5e-4 <= 0.1 * 5e-3
    test.dt = 4.9e-3
    assert not test.passes(blocks)
    assert auto_velocity_tolerance(0.5) == pytest.approx(5e-3)
    # rational B-splines' open blocks are W times a point's motion: a weight of 0.8 makes 5e-4 a 6.25e-4
    weighted = StepVelocityTest(tolerance=0.1, comm=comm, dt=5e-3, block_weights=np.full(50, 0.8))
    assert not weighted.passes(blocks)
    weighted.dt = 6.25e-3
    assert weighted.passes(blocks)


def run_steps(comm, job: str, steps: int, solver_keys: dict, patches: int = 10):
    """``steps`` time steps of ``job`` at ``patches`` x ``patches``: the Newton iterations of each, the
    final position (raw DOFs, gathered: the same layout on any number of ranks) and the solver's
    step test (None without one)."""
    scene = load_scene(REPO / "jobs" / f"{job}.toml", {"surface": {"patches": [patches, patches]},
                                                       "solver": solver_keys})  # fmt: skip
    model = build_model(scene, comm)
    with make_solver(model, scene, scene.path) as solver:
        stepper = TimeStepper(model, solver, prescribed_motions(scene), max_halvings=0)
        iterations = [stepper.advance().newton_iterations for _ in range(steps)]
        return iterations, ShellState(model).raw_position(), solver.problem.step_velocity_test


@pytest.mark.parametrize("job, steps", [("drape-cotton", 8), ("hanging", 8)])
def test_the_step_test_ends_cotton_steps_sooner_within_its_tolerance(comm, job, steps):
    """Cotton at 10 x 10 Hermite patches, the drape with the energy trust region, the hanging sheet
    with line-search Newton (adaptive Hessian): with ``velocity_tolerance = "auto"`` (1.41e-2 m/s for
    the 1 m sheet) the steps take fewer Newton iterations in all than with the acceleration
    tolerance alone, and the state after them is within the tolerance's reach of that one's
    (each step may leave ``tolerance * dt`` to correct)."""
    tight, tight_state, none = run_steps(comm, job, steps, {"velocity_tolerance": None})
    loose, loose_state, test = run_steps(comm, job, steps, {"velocity_tolerance": "auto"})
    assert none is None and test.tolerance == pytest.approx(1e-2 * np.sqrt(2.0))
    assert sum(loose) < sum(tight)
    reach = steps * test.tolerance * 0.01
    assert np.abs(loose_state - tight_state).max() <= reach


@pytest.mark.parametrize("value, message", [
    ("fast", r"key 'solver.velocity_tolerance' must be a speed in \[1e-09, 1000\] \[m/s\] or \"auto\", got 'fast'"),
    (-1.0, r"key 'solver.velocity_tolerance' must be a speed .* got -1.0"),
    (True, r"key 'solver.velocity_tolerance' must be a speed .* got True"),
])  # fmt: skip
def test_a_bad_velocity_tolerance_is_refused_by_key_and_value(value, message):
    with pytest.raises(SceneError, match=message):
        load_scene(REPO / "jobs" / "drape-cotton.toml", {"solver": {"velocity_tolerance": value}})


def test_a_static_scene_refuses_a_velocity_tolerance():
    with pytest.raises(SceneError, match=r"key 'solver.velocity_tolerance' must be absent: a static scene has no "
                                         r"velocities, got 'auto'"):
        load_scene(REPO / "jobs" / "cylindrical-panel.toml", {"solver": {"velocity_tolerance": "auto"}})


def test_several_bodies_refuse_a_velocity_tolerance(comm):
    scene = load_scene(REPO / "jobs" / "drape-cotton.toml", {"solver": {"velocity_tolerance": "auto"},
                                                             "surface": {"patches": [4, 4]}})  # fmt: skip
    models = [build_model(scene, comm), build_model(scene, comm)]
    with pytest.raises(RunError, match=r"key 'solver.velocity_tolerance' = 'auto' applies to a scene of one shell"):
        make_solver(models, scene, scene.path)


def test_a_run_records_the_tolerance_it_used(comm, shared_tmp_path):
    """summary.json holds the resolved tolerance ("auto" -> 1e-2 of the 1 m sheet's diagonal per
    second); without the key it has none."""
    text = (REPO / "jobs" / "drape-cotton.toml").read_text().replace("patches = [25, 25]", "patches = [4, 4]")
    for name, keep in (("auto", True), ("none", False)):
        path = shared_tmp_path / f"drape-{name}.toml"
        if comm.rank == 0:
            path.write_text(text if keep else text.replace('velocity_tolerance = "auto"', ""))
        comm.Barrier()
        summary = run_scene(RunOptions(path, shared_tmp_path / f"run-{name}", steps=1, progress=False), comm)
        if keep:
            assert summary["velocity_tolerance_m_s"] == pytest.approx(1e-2 * np.sqrt(2.0), rel=1e-12)
        else:
            assert "velocity_tolerance_m_s" not in summary
