"""The interfaces page: every case runs by both methods and the page's rows show what it measures."""

from __future__ import annotations

import json

import pytest

from bhem_hpc.studies.interfaces_page import write_interfaces_page


@pytest.mark.rank_free
def test_the_interfaces_page_measures_both_methods_on_every_case(tmp_path):
    """At one penalty factor and 2 steps of the hood: shared edges have no gap and fewer unknowns,
    the patch test's departure by shared edges is the one patch's and the penalty's 100 times it,
    and every row is written."""
    page = write_interfaces_page(tmp_path / "docs", tmp_path / "runs", "test", factors=(1e3,), hood_steps=2,
                                 roof_spans=(6,))  # fmt: skip
    record = json.loads((tmp_path / "docs" / "interfaces.json").read_text())
    static = {(r["case"], r["discretization"], r["method"]): r for r in record["static"]}
    assert len(static) == 8 and not any(r["failure"] for r in static.values())
    for (case, discretization, method), row in static.items():
        if method == "shared":
            coupled = static[(case, discretization, "coupled")]
            assert row["gap_m"] < 1e-13 < coupled["gap_m"] and row["unknowns"] < coupled["unknowns"]
            assert abs(row["difference"]) < 3e-4 and abs(coupled["difference"]) < 3e-4
    departures = {(p["discretization"], p["method"]): p["departure"] for p in record["patch_test"]}
    for discretization in ("bspline3", "hermite"):
        assert departures[(discretization, "shared")] == pytest.approx(departures[(discretization, "one patch")],
                                                                       rel=1e-3)  # fmt: skip
        assert departures[(discretization, "coupled")] > 50 * departures[(discretization, "shared")]
    assert [h["status"] for h in record["hood"]] == ["completed", "completed"]
    # exact rational patches: at 6 x 6 spans the exact and the interpolated cubic cylinder lie within
    # 1e-2 of the reference (measured 9.2e-3 and 7.8e-3); joined rational patches give one patch's values
    roof = {r["discretization"]: abs(r["error"]) for r in record["rational"]["roof_convergence"]}
    assert roof["nurbs3"] < 1e-2 and roof["bspline3"] < 1e-2 and set(roof) == {"nurbs2", "nurbs3", "bspline3"}, roof
    joined = record["rational"]["joined"]
    assert len(joined) == 6 and all(not r["failure"] and abs(r["difference"]) < 1e-3 for r in joined), joined
    text = page.read_text()
    assert text.count("\n| bspline3 | shared | 1e+03 |") == 2 and (tmp_path / "docs" / "interfaces.png").exists()
