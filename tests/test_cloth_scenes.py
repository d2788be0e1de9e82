"""Real cloth: cotton held at moving corners converges in every time step without a recovery."""

from __future__ import annotations

import json
from pathlib import Path

from bhem_hpc.run import RunOptions, run_scene

HANGING = Path(__file__).resolve().parents[1] / "jobs" / "hanging.toml"


def test_hanging_cotton_converges_in_every_step_through_the_corners_stop(comm, shared_tmp_path):
    """The first 20 steps of jobs/hanging.toml: the corners move for 10 steps and stop, compressing
    the top edge in the sheet's plane (a perfectly flat sheet stays in it: nothing breaks the
    symmetry). The exact Hessian fails the first step; the projected one alone needed dt halvings
    at steps 13-16. Measured: 7.6 Newton iterations per step, none above 12."""
    out = shared_tmp_path / "hanging"
    run_scene(RunOptions(HANGING, out, steps=20, progress=False), comm)
    steps = json.loads((out / "summary.json").read_text())["steps"]
    assert len(steps) == 20
    assert sum(s["recoveries"] for s in steps) == 0
    assert sum(s["newton_iterations"] for s in steps) / len(steps) <= 10
    assert max(s["newton_iterations"] for s in steps) <= 16
