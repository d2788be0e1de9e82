"""The cloth comparison page: its cases' scenes, the wrinkle count and one small run of it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bhem_hpc.geometry import surface as S
from bhem_hpc.scene import load_scene
from bhem_hpc.studies.cloth_page import (
    WRINKLE_AMPLITUDE,
    ClothCase,
    cloth_cases,
    count_wrinkles,
    write_cloth_comparison,
)


def test_a_case_rewrites_the_jobs_resolution_discretization_quadrature_and_material(shared_tmp_path, comm):
    case = ClothCase("hanging", "bspline2", 12, "reduced", "fbw")
    scene = load_scene_text(shared_tmp_path, comm, case.scene_text())
    assert (scene.surface.grid.n1, scene.surface.grid.n2) == (12, 12)
    assert scene.surface.discretization == "bspline2" and scene.quadrature == "reduced"
    assert scene.material.membrane == "fbw" and scene.material.shear_ratio == 1.0
    assert scene.material.young == 2e6 and scene.steps == 200
    sweep = load_scene_text(shared_tmp_path, comm, ClothCase("locking-cotton", "hermite", 6, young=2e4).scene_text())
    assert sweep.material.young == 2e4 and sweep.material.bending == "none"


def write_scene(directory, comm, text):
    """``text`` as ``directory/scene.toml`` (written on rank 0, seen by every rank)."""
    path = directory / "scene.toml"
    if comm.rank == 0:
        path.write_text(text)
    comm.Barrier()
    return path


def load_scene_text(directory, comm, text):
    return load_scene(write_scene(directory, comm, text))


def test_the_paper_matrix_of_cases():
    cases = cloth_cases()
    names = {c.name for c in cases}
    assert "hanging-hermite-25" in names and "hanging-bspline2-75-reduced" in names
    assert "drape-cotton-bspline3-125" in names and "hanging-bspline2-75-fbw" in names
    assert "locking-cotton-hermite-25-Y20000" in names
    assert len(names) == len(cases)


@pytest.mark.parametrize("wrinkles", [0, 3, 7])
def test_wrinkles_are_counted_along_the_line(wrinkles):
    """A hanging sheet (in the x-y plane) with ``wrinkles`` sine waves of 2 mm in z across its line
    at y = 0.85 and a sag of 5 cm: the sag is fitted away, the waves counted."""
    rest = S.flat_rectangle(1.0, 1.0, 40, 40)
    nodal = rest.nodal.copy()
    x = nodal[..., 0, 0]
    # waves over the counted span [0.05, 0.95]: z = A sin(2 pi k (x - 0.05) / 0.9) + sag
    phase = 2 * np.pi * wrinkles * (x - 0.05) / 0.9
    nodal[..., 0, 2] = 2e-3 * np.sin(phase) + 0.05 * (x - 0.5) ** 2
    nodal[..., 1, 2] = 2e-3 * np.cos(phase) * 2 * np.pi * wrinkles / 0.9 + 0.1 * (x - 0.5)
    nodal[..., 3, 2] = 0.0
    counted = count_wrinkles(rest.with_nodal(nodal), "hanging")
    assert abs(counted - wrinkles) <= (1 if wrinkles else 0)
    assert WRINKLE_AMPLITUDE < 2e-3


def test_a_small_page_is_written_with_its_figures(shared_tmp_path, comm):
    cases = [ClothCase("hanging", "hermite", 6), ClothCase("hanging", "bspline2", 8, "reduced")]
    whole = frozenset({"hanging-hermite-6"})  # 200 steps: the job's 2 s at 10 ms
    page = write_cloth_comparison(shared_tmp_path / "docs", shared_tmp_path / "runs", 3, cases, comm, whole=whole)
    comm.Barrier()
    rows = json.loads((shared_tmp_path / "docs" / "cloth-comparison.json").read_text())
    assert [r["case"] for r in rows] == ["hanging-hermite-6", "hanging-bspline2-8-reduced"]
    assert [(r["steps"], r["whole"]) for r in rows] == [(200, True), (3, False)]
    assert all(r["status"] == "completed" and r["step_s"] > 0 for r in rows)
    assert all(0 < r["newton_per_step"] <= r["newton_max"] and r["quality"][0] == "wrinkles" for r in rows)
    text = page.read_text()
    assert "| hanging-hermite-6 | adaptive | 588 |" in text and "| 200* |" in text and "(hanging-hermite-6)" in text
    assert (shared_tmp_path / "docs" / "cloth-comparison.png").stat().st_size > 0


def test_the_shear_jobs_edges_move_until_a_tenth_of_a_second_then_hold(shared_tmp_path, comm):
    from pathlib import Path

    from bhem_hpc.scene import SceneError

    jobs = Path(__file__).resolve().parents[2] / "jobs"
    scene = load_scene(jobs / "shear.toml")
    motion = scene.constraints[0].motion
    initial = np.zeros((1, 1, 3))
    np.testing.assert_allclose(motion.values(0.05, initial)[0, 0], [-0.025, 0.0, 0.0])
    np.testing.assert_allclose(motion.values(0.5, initial)[0, 0], [-0.05, 0.0, 0.0])
    text = (jobs / "shear.toml").read_text().replace("until = 0.1 }", "until = -1.0 }", 1)
    with pytest.raises(SceneError, match=r"until' must be a number > 0"):
        load_scene_text(shared_tmp_path, comm, text)
