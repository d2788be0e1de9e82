"""The path-following page: every static job runs and stays within its reference's tolerance."""

from __future__ import annotations

import pytest

from bhem_hpc.studies.path_page import CASES, write_path_following

#: Largest error per job (the page's measure): arch and strip by their theories' approximations
#: ((pi e / L)^2; the bow's w0 / w), the panel by 8 x 8 against 16 x 16 patches, the rotation roll-up
#: by the patches, the moment one by the bending measure's (h kappa)^2 coupling.
BOUNDS = {
    "shallow-arch": 2e-3, "compressed-strip": 2e-3, "cylindrical-panel": 2e-3, "roll-up": 2e-4,
    "moment-roll-up": 1.5e-3,
}  # fmt: skip


@pytest.mark.study
def test_the_path_page_runs_every_job_within_its_bounds(comm, shared_tmp_path):
    page = write_path_following(shared_tmp_path / "docs", shared_tmp_path / "runs", comm)
    if comm.rank != 0:
        return
    rows = [line.split(" | ") for line in page.read_text().splitlines() if line.startswith("| ") and "---" not in line]
    assert len(rows) == len(CASES) + 1  # the header and one row per job
    for case, row in zip(CASES, rows[1:], strict=True):
        assert float(row[6]) < BOUNDS[case.job], (case.job, row)
        assert (shared_tmp_path / "docs" / f"path-{case.job}.png").stat().st_size > 10_000
    assert rows[1][4].count("limit at") == 2  # the arch's two limit points
