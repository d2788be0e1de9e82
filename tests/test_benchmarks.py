"""Benchmark pages: the equal-accuracy selection from the plate study's rows, the page's tables and
claims, and the time steps of the benchmark sheet."""

from __future__ import annotations

import csv

from bhem_hpc.benchmarks import performance, timing
from bhem_hpc.studies.registry import STUDIES


def _plate_rows() -> list[dict]:
    rows = []
    for discretization, quadrature, errors in (
        ("hermite", 4, {4: 3e-3, 8: 8e-5}),
        ("bspline2", 3, {8: 5e-2, 16: 8e-3, 32: 1.1e-3}),
        ("bspline2", "reduced", {8: 4e-2, 16: 9e-3}),
        ("bspline3", 4, {4: 2e-2, 8: 9e-4}),
    ):
        for patches, error in errors.items():
            method = {"discretization": discretization, "quadrature": quadrature}
            rows.append({"support": "clamped", **method, "patches": patches, "hessian": "exact",
                         "factorization": "ldlt", "error": error})  # fmt: skip
    # a row that must not count: another support
    rows.append({**rows[0], "support": "simply_supported", "patches": 2, "error": 1e-9})
    return rows


def test_equal_accuracy_takes_the_fewest_spans_that_reach_each_target(shared_tmp_path, comm, monkeypatch):
    plate = shared_tmp_path / "docs" / "studies" / "ranks-1" / "plate"
    if comm.rank == 0:
        plate.mkdir(parents=True)
        with open(plate / "plate.csv", "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=STUDIES["plate"].columns, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(_plate_rows())
    comm.Barrier()
    calls = []

    def fake_benchmark(spans, comm, discretization, quadrature):
        calls.append((discretization, quadrature, spans))
        return {"patches": spans}

    monkeypatch.setattr(performance, "benchmark", fake_benchmark)
    monkeypatch.setattr(performance, "sheet_step_benchmark", lambda *args, **kwargs: {"step_s": 1.0})
    rows = performance.equal_accuracy_benchmarks(shared_tmp_path / "docs", comm)
    assert calls == [
        ("hermite", None, 4), ("bspline2", None, 16), ("bspline2", "reduced", 16), ("bspline3", None, 8),
        ("hermite", None, 8), ("bspline3", None, 8),
    ]  # fmt: skip
    assert [r["plate_target"] for r in rows] == [1e-2] * 4 + [1e-3] * 2
    assert rows[1]["plate_error"] == 8e-3


def test_performance_page_states_the_paper_claims_at_equal_dofs():
    def row(discretization, quadrature, patches, nnz, jacobian):
        return {"discretization": discretization, "quadrature": quadrature, "patches": patches, "dofs": 1452,
                "nnz": nnz, "membrane_points": 900, "bending_points": 400, "assemble_jacobian_s": jacobian,
                "factor_s": 0.01, "newton_iteration_s": 0.02 * nnz / 1e5, "step_s": 0.1 * nnz / 1e5,
                "newton_per_step": 3.0}  # fmt: skip

    rows = [
        row("hermite", 4, 10, 1e5, 0.01),
        row("bspline2", 3, 20, 2e5, 0.04),
        row("bspline2", "reduced", 20, 2e5, 0.03),
    ]
    lines = performance._discretization_table(rows, [{**rows[0], "plate_target": 0.01, "plate_error": 3e-3}])
    text = "\n".join(lines)
    assert "| bspline2 reduced | 20 | 1452 | 138 | 900 / 400 | 0.0300 |" in text
    assert "nonzeros per DoF 138 against 69" in text and "Newton iteration 2.00 x" in text
    assert "Jacobian in 0.75 x the time of 3 x 3 Gauss" in text
    assert "| 0.01 | 3.00e-03 |" in text


def test_contact_scenes_are_timed_where_their_contact_page_windows_start():
    """Every contact job of the paper's Table 2 is timed after its window's untimed steps (in contact),
    and the table names the steps it timed."""
    from bhem_hpc.benchmarks.contact_page import CONTACT_WINDOWS, METHODS

    windows = {w.job: w.start for w in CONTACT_WINDOWS if w.methods == METHODS}
    warmups = {job: warmup for job, *_, warmup in performance.PAPER_TABLE_2}
    for job in ("ball", "needles", "mesh-obstacle", "crushed-can", "mandrel"):
        assert warmups[job] == windows[job]
    row = {"label": "Needles (Fig. 4)", "scene": "jobs/needles.toml", "warmup": 240, "dofs": 11532, "nnz": 1.19e6,
           "sample_points": 3771, "step_s": 2.5, "collision_per_step_s": 2.3, "detection_per_step_s": 2.1,
           "self_collision": True, "paper": (1.15e4, 1.19e6, "3.6k", 2, 5.05, 26.66, "yes")}  # fmt: skip
    text = "\n".join(performance._scene_table([row], 5))
    assert "| Needles (Fig. 4) (`needles`) | 241–245 | 11532 / 1.15e+04 |" in text


def test_sheet_time_steps_are_timed(comm):
    row = timing.sheet_step_benchmark(3, "bspline2", "reduced", steps=2, comm=comm)
    assert row["step_s"] > 0 and row["newton_per_step"] >= 1
