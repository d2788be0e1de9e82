"""``bhem-hpc states``: a recorded job compares equal with a second run of it, and a changed state,
iteration count or missing job fails the comparison; bad arguments are refused by name."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import BASE, REPO

from bhem_hpc.benchmarks import reference_states as rs


def _state(job: str, scale: float = 1.0, iterations: int = 7) -> rs.JobState:
    rng = np.random.default_rng(3)
    arrays = {"position_dofs": scale * rng.standard_normal((4, 4, 4, 3)),
              "velocity_dofs": rng.standard_normal((4, 4, 4, 3))}  # fmt: skip
    return rs.JobState(job, 3, "completed", iterations, arrays)


def test_a_record_read_back_compares_equal_and_a_perturbed_state_fails(tmp_path):
    path = tmp_path / "states.npz"
    rs.save_states(path, [_state("a"), _state("b")])
    loaded = rs.load_states(path)
    assert set(loaded) == {"a", "b"}
    np.testing.assert_array_equal(loaded["a"].arrays["position_dofs"], _state("a").arrays["position_dofs"])
    lines = rs.compare_states(loaded, [_state("a"), _state("b")], 1e-12)
    assert all(line.startswith("ok") for line in lines), lines
    assert "relative difference 0.000e+00" in lines[0]
    perturbed = _state("a", scale=1.0 + 1e-9)
    difference = rs.state_difference(loaded["a"], perturbed)
    assert difference == pytest.approx(1e-9, rel=1e-3)  # the largest change over the largest magnitude
    assert rs.compare_states(loaded, [perturbed], 1e-12)[0].startswith("FAIL")
    assert rs.compare_states(loaded, [perturbed], 1e-8)[0].startswith("ok")
    assert rs.compare_states(loaded, [_state("a", iterations=8)], 1e-8)[0].startswith("FAIL")
    assert rs.compare_states(loaded, [_state("c")], 1e-8)[0] == "FAIL c: not in the reference file"


def test_a_small_job_run_twice_gives_the_same_state(shared_tmp_path, comm):
    """Serially bit for bit; on 2 ranks within round-off (parallel MUMPS and MPI's reductions do not
    fix the order of their sums: 2.7e-15 seen)."""
    jobs = shared_tmp_path / "jobs"
    if comm.rank == 0:
        jobs.mkdir()
        (jobs / "small.toml").write_text(BASE)
    comm.Barrier()
    [scene] = rs.job_files(["small"], jobs)
    first = rs.run_job(scene, shared_tmp_path / "runs", 2, comm)
    second = rs.run_job(scene, shared_tmp_path / "again", 2, comm)
    if comm.rank == 0:
        assert first.steps == 2 and first.status == "completed" and first.newton_iterations > 0
        assert set(first.arrays) == set(rs.STATE_ARRAYS)
        assert rs.state_difference(first, second) <= (0.0 if comm.size == 1 else 1e-12)
        assert np.abs(first.arrays["velocity_dofs"]).max() > 1e-3  # it moved


def test_a_job_of_several_bodies_is_recorded_by_each_bodys_last_frame(shared_tmp_path, comm):
    """A scene of several bodies is recorded by each body's last frame."""
    jobs = shared_tmp_path / "jobs"
    if comm.rank == 0:
        jobs.mkdir()
        (jobs / "pair.toml").write_text((REPO / "jobs" / "hanging-pair.toml").read_text())
    comm.Barrier()
    [scene] = rs.job_files(["pair"], jobs)
    first = rs.run_job(scene, shared_tmp_path / "runs", 2, comm)
    second = rs.run_job(scene, shared_tmp_path / "again", 2, comm)
    if comm.rank == 0:
        assert set(first.arrays) == {"cotton_position_nodal", "rubber_position_nodal"} and first.steps == 2
        # serially bit for bit; on 2 ranks the energy trust region's runs differ beyond round-off
        # (drape-cotton, one body: 2.6e-10 after 2 steps)
        assert rs.state_difference(first, second) <= (0.0 if comm.size == 1 else 1e-9)


def test_bad_arguments_are_refused_by_name(tmp_path):
    with pytest.raises(rs.ReferenceError, match="exactly one of --record FILE and --compare FILE"):
        rs.reference_states(None, None, None, 3, tmp_path, 1e-12)
    with pytest.raises(rs.ReferenceError, match="--steps must be >= 1, got 0"):
        rs.reference_states(tmp_path / "a.npz", None, None, 0, tmp_path, 1e-12)
    with pytest.raises(rs.ReferenceError, match="--tolerance must be >= 0, got nan"):
        rs.reference_states(tmp_path / "a.npz", None, None, 3, tmp_path, float("nan"))
    with pytest.raises(rs.ReferenceError, match="no such job in .*: nonesuch.toml"):
        rs.job_files(["nonesuch"])
    (tmp_path / "junk.npz").write_text("not numpy")
    with pytest.raises(rs.ReferenceError, match="junk.npz: not a reference-state file"):
        rs.reference_states(None, tmp_path / "junk.npz", None, 3, tmp_path, 1e-12)
