"""The README's summary is generated from the docs pages' rows and kept in step with them."""

from __future__ import annotations

import json

import pytest
from helpers import REPO

from bhem_hpc.studies.summary import BEGIN, END, SummaryError, summary_markdown, update_readme


def test_readme_summary_is_the_one_generated_from_docs():
    readme = (REPO / "README.md").read_text()
    block = readme[readme.index(BEGIN) : readme.index(END) + len(END)]
    assert block == summary_markdown(REPO / "docs")


def test_summary_reports_the_rows_it_is_given(shared_tmp_path, comm):
    docs = shared_tmp_path / "docs"
    if comm.rank == 0:
        for name in ("plate", "buckling", "drape", "wrinkle", "cantilever"):
            folder = docs / "studies" / "ranks-1" / name
            folder.mkdir(parents=True)
            (folder / f"{name}.csv").write_text(
                "study,value,reference,error,wall_s,dofs\n"
                f"{name},1,1,0.5,0.25,100\n{name},1,1,0.004,1.5,400\n{name},1,1,0.002,7.0,900\n"
            )
        newton = {"patches": 30, "dofs": 11532, "newton_iteration_s": 0.125, "factor_s": 0.0625}
        scene = {"scene": "jobs/ball.toml", "sample_points": 10, "step_s": 0.5, "collision_fraction": 0.05, "dofs": 9,
                 "warmup": 70, "steps": 5}  # fmt: skip
        rows = {"newton": [newton], "scenes": [scene], "rays": [{"patches": 10, "speedup": 9.25}]}
        (docs / "performance.json").write_text(json.dumps(rows))
    comm.Barrier()
    text = summary_markdown(docs)
    assert text.count("1 % error in 1.5 s (400 DoFs); best 2.0e-03") == 5  # the fastest row within 1 %
    assert "30 x 30 sheet (11532 DoFs): 0.125 s, of which MUMPS LDL^T factorization 0.0625 s" in text
    assert "`ball`: 0.5 s per time step in contact (steps 71-75), collision 5.0 % of it" in text
    assert "9.2x the rays per second" in text
    readme = shared_tmp_path / f"README-{comm.rank}.md"
    readme.write_text(f"intro\n{BEGIN}\nold figures\n{END}\nrest\n")
    update_readme(readme, docs)
    assert readme.read_text() == f"intro\n{text}\nrest\n"
    readme.write_text("no markers\n")
    with pytest.raises(SummaryError, match="summary markers are missing"):
        update_readme(readme, docs)
    comm.Barrier()
    if comm.rank == 0:
        (docs / "performance.json").unlink()
    comm.Barrier()
    with pytest.raises(SummaryError, match="performance.json does not exist"):
        summary_markdown(docs)
