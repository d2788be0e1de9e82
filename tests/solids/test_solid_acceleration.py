"""The acceleration stopping test of a solid: its lumped masses are positive and add up to its mass
where the consistent mass's row sums are negative (the toy castle's overlapping parts), and the
shipped toy dropped onto a cotton cloth by IPC lands without a recovery."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import REPO

from bhem_hpc.io.cad import read_parts
from bhem_hpc.run import RunOptions, run_scene
from bhem_hpc.solids.acceleration import lumped_masses
from bhem_hpc.solids.sem import ShapeMatchingSolid, SolidMaterial, SolidOptions


def test_lumped_masses_are_positive_where_row_sums_are_not():
    toy = ShapeMatchingSolid(read_parts(REPO / "jobs" / "models" / "toy.igs"), SolidMaterial(150.0, 2.0e5, 0.4),
                             SolidOptions(degree=2, lines_per_side=16, sparsity=0.3), name="toy")  # fmt: skip
    row_sums = np.asarray(toy.mass_scalar.sum(axis=1)).ravel()
    assert np.count_nonzero(row_sums < 0) > 50  # measured: 70 of 258
    lumped = lumped_masses(toy.mass_scalar)
    assert lumped.min() > 1e-3 * lumped.mean()
    assert lumped.sum() == pytest.approx(toy.mass, rel=1e-12)
    # proportional to the consistent mass's diagonal
    np.testing.assert_allclose(lumped / toy.mass_scalar.diagonal(), toy.mass / toy.mass_scalar.diagonal().sum())


def test_the_shipped_toy_lands_on_the_cotton_cloth_without_a_recovery(comm, shared_tmp_path):
    out = shared_tmp_path / "toy"
    summary = run_scene(RunOptions(REPO / "jobs" / "toy-on-cloth.toml", out, steps=6, progress=False), comm)
    assert summary["status"] == "completed"
    if comm.rank == 0:
        steps = [json.loads(line) for line in (out / "steps.jsonl").read_text().splitlines()]
        # it lands in the fourth step (the barrier active), each step in a few Newton iterations
        assert [s["recoveries"] + s["dt_halvings"] for s in steps] == [0] * 6
        assert max(s["newton_iterations"] for s in steps) <= 20
