"""The contact head-to-head page's scene variants and its gap measure: every contact job has one
contact line to replace, a variant keeps the rest of the job (its files by absolute path), and the
smallest gap of a frame is measured against the exact collider, signed."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from bhem_hpc.benchmarks.contact_page import CONTACT_WINDOWS, IPC_CONTACT, JOBS, frame_gaps, job_variant
from bhem_hpc.collision.colliders import Plane, Sphere
from bhem_hpc.scene import load_scene

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


@pytest.mark.parametrize("window", CONTACT_WINDOWS, ids=lambda w: w.job)
def test_every_contact_job_has_an_ipc_variant_that_loads_with_the_jobs_other_settings(tmp_path, window):
    source = JOBS / f"{window.job}.toml"
    shipped = load_scene(source)
    assert shipped.contact is not None and shipped.contact.method == "impulse"
    assert window.start + window.steps <= shipped.steps
    variant = tmp_path / "variant.toml"
    variant.write_text(job_variant(source.read_text(), "ipc", 1, str(source)))
    scene = load_scene(variant)
    assert scene.contact.method == "ipc" and scene.output_every == 1
    assert scene.contact.self_collision == shipped.contact.self_collision
    assert len(scene.contact.colliders) == len(shipped.contact.colliders)
    assert scene.steps == shipped.steps and scene.material == shipped.material
    impulse = job_variant(source.read_text(), "impulse", 7, str(source))
    assert IPC_CONTACT not in impulse and "\nevery = 7" in impulse


def test_a_scene_without_one_contact_line_is_refused_by_name():
    with pytest.raises(ValueError, match=r"nowhere\.toml: expected one 'contact = \.\.\.' line .*, found 0"):
        job_variant("[effects]\ngravity = [0.0, 0.0, -9.81]\n", "ipc", 1, "nowhere.toml")


def _write_frames(path, heights: list[float]) -> None:
    """A unit square of 2 x 2 quads at the given heights, one frame each (time = its index)."""
    x, y = np.meshgrid(np.linspace(0, 1, 3), np.linspace(0, 1, 3), indexing="ij")
    quads = np.array([[i * 3 + j, (i + 1) * 3 + j, (i + 1) * 3 + j + 1, i * 3 + j + 1]
                      for i in range(2) for j in range(2)])  # fmt: skip
    with h5py.File(path / "surface.h5", "w") as f:
        f["topology"] = quads
        f["parameters"] = np.stack([x.ravel(), y.ravel()], axis=1)
        for k, h in enumerate(heights):
            f[f"frames/{k}/geometry"] = np.stack([x.ravel(), y.ravel(), np.full(9, h)], axis=1)
            f[f"frames/{k}"].attrs["time"] = float(k)


def test_the_smallest_gap_is_signed_against_the_exact_colliders(tmp_path):
    _write_frames(tmp_path, [0.3, 0.1, -0.02])
    floor = Plane(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    ball = Sphere(np.array([0.5, 0.5, 2.0]), 1.0)  # its bottom 1 m above the floor: the sheet's centre 0.7 m below
    gaps = frame_gaps(tmp_path, [floor, ball], 1e-3)
    assert gaps["frames"] == 3 and gaps["self_intersecting_frames"] == 0
    assert gaps["min_signed_gap_m"] == pytest.approx(-0.02, abs=1e-12)
    assert not np.isfinite(gaps["min_mesh_gap_m"]) and gaps["mesh_collider_crossings"] == 0
