"""``bhem-hpc bench --scaling``: cases, speedups, the page, and one real run through mpirun."""

from __future__ import annotations

import csv
import os
import subprocess
import sys

import pytest

from bhem_hpc.benchmarks.scaling import ScalingError, scaling_cases, scaling_markdown, speedups
from bhem_hpc.blas import blas_label, openblas_core


def test_strong_and_weak_cases():
    cases = scaling_cases([2, 1], [30, 100], ["direct", "iterative"], weak=50)
    strong = [(c.ranks, c.patches, c.linear) for c in cases if c.kind == "strong"]
    assert strong[:2] == [(1, 30, "direct"), (2, 30, "direct")] and len(strong) == 8
    weak = [(c.ranks, c.patches) for c in cases if c.kind == "weak" and c.linear == "iterative"]
    assert weak == [(1, 50), (2, 71)]  # patches grow as sqrt(ranks): DoFs per rank stay about equal
    for bad in (dict(ranks=[0], sizes=[10]), dict(ranks=[1], sizes=[]), dict(ranks=[1], sizes=[10], weak=0),
                dict(ranks=[1], sizes=[10], fresh=[0])):  # fmt: skip
        with pytest.raises(ScalingError):
            scaling_cases(bad["ranks"], bad["sizes"], ["direct"], bad.get("weak"), fresh=bad.get("fresh"))
    fresh = [c for c in scaling_cases([1, 2], [30], ["iterative"], None, fresh=[30]) if c.kind == "fresh"]
    assert [(c.ranks, c.patches, c.linear, c.factorization) for c in fresh] == [(1, 30, "direct", "fresh")]


def row(ranks, patches, linear, step_s, memory=1.0, status="ok"):
    return {"kind": "strong", "ranks": ranks, "patches": patches, "linear": linear, "dofs": 12 * (patches + 1) ** 2,
            "status": status, "step_s": step_s, "newton_per_step": 4.0, "newton_iteration_s": step_s / 4,
            "assembly_per_iteration_s": step_s / 8, "solve_per_iteration_s": step_s / 8, "krylov_per_solve": 5.0,
            "refactorizations_per_step": 0.5, "peak_memory_per_rank_gb": memory, "error": ""}  # fmt: skip


def test_speedups_and_the_page():
    failed = row(1, 290, "direct", 0.0, status="failed") | {"error": "killed"}
    rows = [row(1, 100, "iterative", 2.0), row(2, 100, "iterative", 1.0, 0.5), row(1, 100, "direct", 6.0, 2.0),
            row(2, 100, "direct", 5.0, 1.5), failed]  # fmt: skip
    assert speedups(rows) == {(100, 2, "iterative"): 2.0, (100, 2, "direct"): 1.2}
    page = scaling_markdown(rows, {"command": "bhem-hpc bench --scaling", "host": "h", "cores": 2, "scene": "s.toml",
                                   "steps": 3, "warmup": 1}, "scaling/scaling.png")  # fmt: skip
    assert "- 100 x 100 patches, iterative: 2 ranks 2.00x faster per step than 1" in page
    assert "the iterative path's step takes 0.33x the time of MUMPS' (3.00x as fast), 0.50x its memory" in page
    # MUMPS' 1-rank step: 6 s, of which 4 Newton iterations x 0.75 s of linear solve
    assert "memory per rank; a linear solve that took no time would make MUMPS' step 2.00x as fast" in page
    assert "| failed: killed |" in page and "![scaling](scaling/scaling.png)" in page
    assert "factorization at every Newton iteration" not in page


def test_the_page_compares_both_paths_with_a_factorization_per_newton_iteration():
    fresh = row(1, 200, "direct", 120.0, 3.0) | {"kind": "fresh", "factorization": "fresh"}
    rows = [row(1, 200, "iterative", 6.0), row(1, 200, "direct", 8.0, 3.0), fresh]
    page = scaling_markdown(rows, {"command": "c", "host": "h", "cores": 2, "scene": "s.toml", "steps": 3,
                                   "warmup": 1}, "scaling.png")  # fmt: skip
    assert "| fresh | 1 | 200 | 484812 | direct, factored every iteration | 120 |" in page
    assert ("- 200 x 200 patches: MUMPS factoring at every Newton iteration 120 s / step; the iterative path "
            "6 s / step (20.00x as fast); MUMPS keeping its factorizations 8 s / step (15.00x as fast)") in page
    assert speedups(rows) == {}  # one rank only: the fresh case is no rank count of its own


@pytest.mark.serial_child
def test_the_command_runs_every_case_in_its_own_mpi_job(comm, shared_tmp_path):
    if comm.rank == 0:
        out = shared_tmp_path / "scaling"
        env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "PMI_"))}
        command = [sys.executable, "-m", "bhem_hpc.cli", "bench", "--scaling", "--patches", "6", "--ranks", "1", "2",
                   "--steps", "2", "--dt", "0.002", "0.008", "--fresh", "6", "--out", str(out),
                   "--docs", str(shared_tmp_path / "docs")]  # fmt: skip
        done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=600)
        assert done.returncode == 0, done.stderr
        with (out / "scaling.csv").open() as f:
            rows = list(csv.DictReader(f))
        assert [(r["kind"], r["ranks"], r["linear"], r["status"]) for r in rows] == [
            ("strong", "1", "direct", "ok"), ("strong", "2", "direct", "ok"), ("strong", "1", "iterative", "ok"),
            ("strong", "2", "iterative", "ok"), ("dt", "1", "iterative", "ok"), ("dt", "1", "iterative", "ok"),
            ("fresh", "1", "direct", "ok"),
        ]  # fmt: skip
        *_, fresh = rows  # a factorization at every Newton iteration: as many as Newton iterations
        assert fresh["factorization"] == "fresh" and float(fresh["refactorizations_per_step"]) == float(
            fresh["newton_per_step"])
        assert rows[0]["factorization"] == "reuse" and float(rows[0]["refactorizations_per_step"]) < float(
            rows[0]["newton_per_step"])
        # a longer time step: less inertia in the step matrix, more Krylov iterations
        short, long = rows[-3:-1]
        assert float(short["dt"]) == 0.002 and float(long["mass_dominance"]) < float(short["mass_dominance"]) / 15
        assert all(int(r["dofs"]) == 12 * 7 * 7 and float(r["step_s"]) > 0 for r in rows)
        assert all(float(r["krylov_per_solve"]) > 0 for r in rows if r["linear"] == "iterative")
        assert all(float(r["peak_memory_per_rank_gb"]) > 0.01 for r in rows)
        assert {r["blas"] for r in rows} == {openblas_core()}  # the ranks run the kernels this process chose
        page = (shared_tmp_path / "docs" / "scaling.md").read_text()
        assert "## Krylov iterations against the time step" in page
        assert "- 6 x 6 patches: MUMPS factoring at every Newton iteration" in page
        assert f"BLAS: {blas_label(openblas_core())})" in page
        assert page.startswith("# Scaling") and (shared_tmp_path / "docs" / "scaling" / "scaling.png").stat().st_size
    comm.Barrier()
