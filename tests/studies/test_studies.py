"""Accuracy-versus-cost studies: the framework (default suite) and the full studies (`study` marker)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from bhem_hpc.studies.report import run_study
from bhem_hpc.studies.study import StudyError


@pytest.fixture
def out(shared_tmp_path):
    return shared_tmp_path / "plate"


def test_study_writes_csv_table_and_plot(comm, out):
    rows = run_study("plate", out, comm, limit=3)
    assert [r["patches"] for r in rows] == [2, 4, 8]
    comm.Barrier()
    with open(out / "plate.csv") as f:
        written = list(csv.DictReader(f))
    assert len(written) == 3 and float(written[2]["error"]) < float(written[0]["error"])
    assert "| simply_supported | hermite | 8 | 4 | exact | ldlt |" in (out / "plate.md").read_text()
    assert (out / "plate.png").stat().st_size > 5000
    with pytest.raises(StudyError, match="exists and is not empty"):
        run_study("plate", out, comm, limit=1)
    known = r"\['buckling', 'cantilever', 'drape', 'plate', 'wrinkle'\]"
    with pytest.raises(StudyError, match=rf"study 'shell' does not exist; known: {known}"):
        run_study("shell", out.parent / "other", comm)


@pytest.mark.study
def test_plate_study_converges(comm, out):
    rows = run_study("plate", out, comm)
    for support, min_rate, final in (("simply_supported", 3.5, 1e-6), ("clamped", 2.0, 1e-5)):
        series = [
            r
            for r in rows
            if r["support"] == support
            and r["discretization"] == "hermite"
            and r["quadrature"] == 4
            and r["hessian"] == "exact"
            and r["factorization"] == "ldlt"
        ]
        patches = np.array([r["patches"] for r in series], dtype=float)
        errors = np.array([r["error"] for r in series])
        rates = np.log(errors[1:-1] / errors[2:]) / np.log(patches[2:] / patches[1:-1])
        assert np.all(rates >= min_rate), (support, rates)
        assert errors[-1] < final
    # the knobs that must not change the answer: pseudo Hessian and LU reproduce the exact LDL^T value
    for support in ("simply_supported", "clamped"):
        hermite = [r for r in rows if r["discretization"] == "hermite"]
        same = [r["value"] for r in hermite if r["support"] == support and r["patches"] == 16 and r["quadrature"] == 4]
        assert np.ptp(same) < 1e-9 * np.mean(same)
    # B-splines: the centre deflection converges at 2 (p - 1) until the tabulated clamped value's
    # six digits (a few 1e-6) are reached
    for degree in (2, 3):
        for support in ("simply_supported", "clamped"):
            method = (f"bspline{degree}", support, 3 if degree == 2 else 4)
            series = [r for r in rows if (r["discretization"], r["support"], r["quadrature"]) == method]
            spans = np.array([r["patches"] for r in series], dtype=float)
            errors = np.array([r["error"] for r in series])
            rates = np.log(errors[:-1] / errors[1:]) / np.log(spans[1:] / spans[:-1])
            resolved = errors[1:] > 2e-5
            assert np.all(rates[resolved] >= 0.9 * 2 * (degree - 1)), (degree, support, rates)
            assert errors[-1] < (2e-3 if degree == 2 else 2e-6), (degree, support, errors)
    # the reduced rule: the clamped plate converges at close to rate 2 on the finer spans, and
    # both plates stay within 3.5 x of the 3 x 3 Gauss error at 48 spans
    for support in ("simply_supported", "clamped"):
        reduced = {r["patches"]: r["error"] for r in rows if r["quadrature"] == "reduced" and r["support"] == support}
        full = {
            r["patches"]: r["error"] for r in rows
            if r["discretization"] == "bspline2" and r["quadrature"] == 3 and r["support"] == support
        }  # fmt: skip
        assert reduced[48] < 3.5 * full[48], (support, reduced, full)
        if support == "clamped":
            assert np.log(reduced[24] / reduced[48]) / np.log(2) > 1.7, reduced


@pytest.mark.study
def test_cantilever_study_tracks_the_master_curve(comm, out):
    all_rows = run_study("cantilever", out.parent / "cantilever", comm)
    rows = [r for r in all_rows if r["discretization"] == "hermite"]
    finest = [r for r in rows if r["patches"] == 32 and r["hessian"] == "exact"]
    assert len(finest) == 8 and max(r["error"] for r in finest) < 0.005  # all Gamma* within 0.5 %
    # the B-spline strips track the master curve within 1 % at 32 spans (every Gamma*)
    for degree in (2, 3):
        splines = [r for r in all_rows if r["discretization"] == f"bspline{degree}" and r["patches"] == 32]
        for rule in {r["quadrature"] for r in splines}:  # 3 x 3 Gauss and reduced for degree 2
            same = [r for r in splines if r["quadrature"] == rule]
            assert len(same) == 8 and max(r["error"] for r in same) < 0.01, (degree, rule)
    exact = [r for r in rows if r["hessian"] == "exact" and r["newton_rtol"] == 1e-9]
    for gamma in {r["gamma"] for r in rows}:
        by_patches = {r["patches"]: r["error"] for r in exact if r["gamma"] == gamma}
        assert by_patches[32] <= by_patches[8] + 1e-6  # refinement does not make it worse
    # a looser Newton tolerance: 1e-6 changes nothing visible, 1e-3 may stop early
    for r in rows:
        if r["newton_rtol"] == 1e-6:
            twin = next(e for e in exact if e["gamma"] == r["gamma"] and e["patches"] == r["patches"])
            assert abs(r["value"] / twin["value"] - 1) < 1e-5


def test_cheapest_configuration_per_tolerance():
    from bhem_hpc.studies.report import cheapest

    rows = [{"error": 2e-2, "wall_s": 0.1}, {"error": 5e-3, "wall_s": 0.3}, {"error": 4e-4, "wall_s": 0.2}]
    assert cheapest(rows, 1e-2)["wall_s"] == 0.2 and cheapest(rows, 1e-3)["error"] == 4e-4
    assert cheapest(rows, 1e-4) is None


def test_lateral_buckling_reference():
    """The Michell-Prandtl constant by shooting equals the tabulated 12.85 (Timoshenko & Gere)."""
    from bhem_hpc.studies.references import lateral_buckling_constant, lateral_buckling_gamma

    assert lateral_buckling_constant() == pytest.approx(12.85, abs=0.005)
    assert lateral_buckling_gamma(0.0) == pytest.approx(12 * 12.8538 / np.sqrt(72), rel=1e-4)


def test_buckling_threshold_of_a_narrow_plate(comm):
    """A 1 m x 2 cm plate hanging on edge (40 patches) buckles laterally within 2 % of beam theory
    (the difference is mostly the plate's width, see the study)."""
    from bhem_hpc.studies.buckling import run_buckling

    row = run_buckling({"aspect": 0.02, "patches_per_m": 40, "poisson": 0.0}, comm)
    assert row["error"] < 0.02, row


@pytest.mark.study
def test_buckling_study_approaches_beam_theory(comm, out):
    rows = run_study("buckling", out.parent / "buckling", comm)
    nu0 = [r for r in rows if r["poisson"] == 0.0 and r["discretization"] == "hermite"]
    narrow = {r["patches_per_m"]: r for r in nu0 if r["aspect"] == 0.02}
    assert narrow[40]["error"] < 0.02
    # the plate's threshold grows linearly with w / L; extrapolated to w / L -> 0 it is the beam's
    fine = sorted((r["aspect"], r["value"] / r["reference"]) for r in nu0 if r["patches_per_m"] == 40)
    slope, intercept = np.polyfit([a for a, _ in fine[:3]], [v for _, v in fine[:3]], 1)
    assert abs(intercept - 1) < 0.01, (slope, intercept)
    for aspect in {r["aspect"] for r in nu0}:
        by = {r["patches_per_m"]: r["value"] for r in nu0 if r["aspect"] == aspect}
        assert abs(by[40] / by[20] - 1) < 0.01  # converged in the resolution
    # wider plates are stiffer near the clamp: the threshold rises with the aspect ratio
    finest = sorted((r["aspect"], r["value"]) for r in nu0 if r["patches_per_m"] == 40)
    assert all(b[1] >= a[1] * (1 - 2e-3) for a, b in zip(finest, finest[1:], strict=False))
    # the splines at 40 spans per metre find the Hermite threshold: cubic within 0.5 %, quadratic
    # with 3 x 3 Gauss within 3 %
    hermite = dict(finest)
    for method, bound in ((("bspline3", 4), 5e-3), (("bspline2", 3), 3e-2)):
        for r in rows:
            if (r["discretization"], r["quadrature"]) == method and r["patches_per_m"] == 40:
                assert abs(r["value"] / hermite[r["aspect"]] - 1) < bound, (method, r)


@pytest.mark.study
def test_drape_study_converges_to_the_finest_rest_shape(comm, out):
    all_rows = run_study("drape", out.parent / "drape", comm)
    rows = [r for r in all_rows if r["discretization"] == "hermite"]
    exact = {r["patches"]: r for r in rows if r["hessian"] == "exact" and r["dt"] == 0.01}
    errors = [exact[n]["error"] for n in (4, 8, 12, 16)]
    assert all(b < a for a, b in zip(errors, errors[1:], strict=False)), errors
    assert errors[-1] < 2e-3
    # the pseudo Hessian and a larger dt reach the same rest shape, to what the stopping criterion
    # (every node slower than 1 mm/s) leaves
    for r in rows:
        if r["hessian"] == "pseudo" or r["dt"] != 0.01:
            twin = exact[r["patches"]]
            assert abs(r["value"] / twin["value"] - 1) < 5e-3, (r, twin["value"])
    # every spline method at 24 spans drapes within 2 % of the side of the Hermite reference
    splines = [r for r in all_rows if r["discretization"] != "hermite" and r["patches"] == 24]
    assert len(splines) == 3 and max(r["error"] for r in splines) < 2e-2, splines


@pytest.mark.study
def test_wrinkle_study_converges_to_the_measured_amplitude(comm, out):
    from bhem_hpc.studies.wrinkle import WRINKLE_MEASURED

    all_rows = run_study("wrinkle", out.parent / "wrinkle", comm)
    rows = [r for r in all_rows if r["discretization"] == "hermite"]
    exact = {r["patches"]: r for r in rows if r["hessian"] == "exact" and r["quadrature"] == 4 and r["dt"] == 0.01}
    # the paper's Fig. 17: the amplitude grows with the resolution and settles near the measured
    # 0.35 mm from 30 x 30 patches on
    assert exact[5]["value"] < exact[15]["value"] < exact[30]["value"]
    assert abs(exact[40]["value"] / exact[30]["value"] - 1) < 0.03
    assert exact[40]["error"] < 0.1
    # the small outermost half-waves by the free edges come and go
    # with the threshold (10 % of the peak) and the slow rearrangement near the grips
    assert abs(exact[30]["wrinkles"] - exact[40]["wrinkles"]) <= 1
    # the pseudo Hessian and a larger dt reach the same wrinkles at 20 x 20
    for r in rows:
        if r["hessian"] == "pseudo" or r["dt"] != 0.01:
            assert abs(r["value"] / exact[20]["value"] - 1) < 0.02, (r, exact[20]["value"])
    # 3 x 3 Gauss under-integrates the bicubic energy: its amplitude differs, less so on the finer mesh
    reduced = {r["patches"]: r for r in rows if r["quadrature"] == 3}
    assert abs(reduced[30]["value"] / exact[30]["value"] - 1) < abs(reduced[20]["value"] / exact[20]["value"] - 1)
    # the splines wrinkle too, their amplitude rising with the spans
    for method in (("bspline2", 3), ("bspline2", "reduced"), ("bspline3", 4)):
        by = sorted((r["patches"], r["value"]) for r in all_rows if (r["discretization"], r["quadrature"]) == method)
        assert by[0][1] > 0.2 * WRINKLE_MEASURED and by[-1][1] > by[0][1], (method, by)


def test_stretched_sheet_wrinkles_at_10_patches(comm, out):
    """The wrinkle study's first rows (default suite): the pull buckles the flat sheet into
    wrinkles across the width; at 10 x 10 the amplitude is below the converged ~0.34 mm (paper
    Fig. 13c: 'several shallow wrinkles'). The shapes figure is drawn."""
    from bhem_hpc.studies.wrinkle import WRINKLE_MEASURED

    rows = run_study("wrinkle", out.parent / "wrinkle", comm, limit=2)
    coarse = rows[1]
    assert coarse["patches"] == 10
    assert 0.6 * WRINKLE_MEASURED < coarse["value"] < 0.8 * WRINKLE_MEASURED, coarse
    assert coarse["wrinkles"] == 7
    assert coarse["steps"] < 100
    assert rows[0]["value"] < coarse["value"]
    if comm.rank == 0:
        assert (out.parent / "wrinkle" / "wrinkle-shapes.png").stat().st_size > 10_000


def test_accuracy_cost_page_sets_rank_counts_side_by_side(comm, out):
    """The docs page from a serial and a 2-rank run's rows: cheapest configurations over both, and
    a table of each configuration's value and time per rank count."""
    import shutil

    from bhem_hpc.studies.report import _accuracy_cost_markdown, read_rows

    docs = out.parent / "docs"
    rows = run_study("plate", docs / "studies" / "ranks-1" / "plate", comm, limit=2)
    if comm.rank == 0:
        (docs / "studies" / "ranks-2").mkdir()
        shutil.copytree(docs / "studies" / "ranks-1" / "plate", docs / "studies" / "ranks-2" / "plate")
        path = docs / "studies" / "ranks-2" / "plate" / "plate.csv"
        back = read_rows(path)
        assert [r["value"] for r in back] == [r["value"] for r in rows]  # numbers survive the CSV
        assert back[0]["patches"] == 2 and back[0]["support"] == "simply_supported"
        path.write_text(path.read_text().replace(",1,", ",2,", 1))  # first row: the 2-rank run's
        page = _accuracy_cost_markdown(docs)
        assert "on 1 and 2 rank(s)" in page
        table = page[page.index("Rank counts") :]
        first = rows[0]
        assert f"| {first['value']:.6g} | {first['value']:.6g} |" in table
        assert "studies/ranks-1/plate/plate.csv" in page and "studies/ranks-2/plate/plate.csv" in page
        assert "## `cantilever`" not in page  # studies without rows are left out
