"""The contact head-to-head page's scene variants and its gap measure: every contact job has contact
tables to replace (a body's inline ones too), a variant keeps the rest of the job (its files by
absolute path), and the smallest gap of a frame is measured against the exact collider, signed, over
every body's series."""

from __future__ import annotations

import re
import tomllib

import h5py
import numpy as np
import pytest

from bhem_hpc.benchmarks.contact_page import CONTACT_WINDOWS, IPC_CONTACT, JOBS, frame_gaps, job_bodies, job_variant
from bhem_hpc.collision.colliders import Plane, Sphere

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


@pytest.mark.parametrize("window", CONTACT_WINDOWS, ids=lambda w: w.label)
def test_every_contact_job_has_variants_by_both_methods_that_load_with_the_jobs_other_settings(tmp_path, window):
    source = JOBS / f"{window.job}.toml"
    shipped = job_bodies(source)
    for method in ("impulse", "ipc"):
        variant = tmp_path / f"{method}.toml"
        variant.write_text(job_variant(source.read_text(), method, 7, str(source), window.impulse_contact,
                                       window.ipc_hessian, window.ipc_contact))  # fmt: skip
        bodies = job_bodies(variant)
        assert len(bodies) == len(shipped)
        for scene, original in zip(bodies, shipped, strict=True):
            assert original.contact is not None
            assert original.contact.method == ("impulse" if window.impulse_contact is None else "ipc")
            assert window.start + window.steps <= original.steps
            assert scene.contact.method == method and scene.output_every == 7
            if method == "ipc":  # IPC's step test at IPC's tolerance, the adaptive stiffness unless the window sets one
                assert scene.contact.velocity_tolerance == "auto"
                contact = tomllib.loads(window.ipc_contact)["contact"]
                assert scene.contact.barrier_stiffness == contact.get("barrier_stiffness")
            if method == "ipc" and window.ipc_hessian is not None:
                assert scene.hessian == window.ipc_hessian != original.hessian
            else:
                assert scene.hessian == original.hessian
            assert scene.contact.self_collision == original.contact.self_collision
            assert len(scene.contact.colliders) == len(original.contact.colliders)
            assert scene.steps == original.steps and scene.material == original.material


def test_every_window_and_method_runs_in_directories_of_its_own_and_has_a_label_of_its_own():
    from bhem_hpc.benchmarks.contact_page import run_name

    names = [run_name(w, method) for w in CONTACT_WINDOWS for method in w.methods]
    assert len(set(names)) == len(names) and all(re.fullmatch(r"[0-9A-Za-z.-]+", name) for name in names)
    labels = [(w.label, w.start, method) for w in CONTACT_WINDOWS for method in w.methods]
    assert len(set(labels)) == len(labels)
    stiff = [w for w in CONTACT_WINDOWS if w.variant]
    assert [run_name(w, "ipc") for w in stiff] == ["needles-1.7e4-N-m-ipc-240"]


def test_a_scene_without_a_contact_table_is_refused_by_name():
    with pytest.raises(ValueError, match=r"nowhere\.toml: expected a 'contact = \{ \.\.\. \}' table .*, found none"):
        job_variant("[effects]\ngravity = [0.0, 0.0, -9.81]\n", "ipc", 1, "nowhere.toml")


def test_inline_contact_tables_of_every_body_are_replaced():
    text = ('[[bodies]]\neffects = { gravity = [0.0, 0.0, -9.81], contact = { push_out = 2.0e-4 }, friction = 0.3 }\n'
            '[[bodies]]\neffects = { contact = {push_out=1e-4}, damping = { mass = 1.0 } }\n[solver]\n'
            'hessian = "trust_region"   # a comment\n')
    variant = job_variant(text, "ipc", 1, "pile.toml")
    assert variant.count(IPC_CONTACT) == 2 and "push_out" not in variant
    assert 'friction = 0.3 }' in variant and "damping = { mass = 1.0 } }" in variant
    assert 'hessian = "trust_region"   # a comment' in variant
    assert 'hessian = "projected"   # a comment' in job_variant(text, "ipc", 1, "pile.toml", ipc_hessian="projected")


@pytest.mark.parametrize("solver", ["", "[solver]\nlinear = \"direct\"\n"])
def test_the_ipc_hessian_of_a_window_is_set_with_or_without_a_solver_table(tmp_path, solver):
    text = f'[effects]\ncontact = {{ push_out = 1e-4 }}\n{solver}[[colliders]]\ntype = "plane"\n'
    variant = job_variant(text, "ipc", 1, "can.toml", ipc_hessian="trust_region")
    assert variant.count('hessian = "trust_region"') == 1
    assert tomllib.loads(variant)["solver"]["hessian"] == "trust_region"
    assert job_variant(text, "impulse", 1, "can.toml", ipc_hessian="trust_region").count("hessian") == 0


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


def test_the_smallest_gap_of_a_run_of_several_bodies_is_over_every_bodys_series(tmp_path):
    from bhem_hpc.io.run_directory import MANIFEST

    for name, heights in (("upper", [0.3, 0.2]), ("lower", [0.1, -0.03])):
        (tmp_path / name).mkdir()
        _write_frames(tmp_path / name, heights)
    (tmp_path / MANIFEST).write_text('{"bodies": ["upper", "lower"]}')
    floor = Plane(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    gaps = frame_gaps(tmp_path, [floor], 0.5)  # distances between the sheets measured up to 0.5 m
    assert gaps["frames"] == 2 and gaps["self_intersecting_frames"] == 0
    assert gaps["min_signed_gap_m"] == pytest.approx(-0.03, abs=1e-12)
    assert gaps["min_self_distance_m"] == pytest.approx(0.2, abs=1e-12)  # the sheets 0.2 m apart in the first frame


def test_the_page_lists_the_windows_it_timed_and_a_method_only_where_its_window_names_it():
    from bhem_hpc.benchmarks.contact_page import contact_markdown

    can = [w for w in CONTACT_WINDOWS if w.job == "crushed-can"]
    assert [w.methods for w in can] == [("impulse", "ipc"), ("impulse",)]
    assert can[1].timed_steps == (can[1].start + 1, can[1].start + can[1].steps)
    rows = [{"job": "crushed-can", "method": "impulse", "window": list(can[1].timed_steps), "status": "failed: stopped",
             "steps": 0}]  # fmt: skip
    page = contact_markdown(rows, "bhem-hpc contact-page", "a test")
    assert f"- crushed-can: steps {can[1].timed_steps[0]}–{can[1].timed_steps[1]}, {can[1].phase}." in page
    assert f"steps {can[0].timed_steps[0]}–" not in page


def test_the_page_runs_each_window_by_the_methods_it_names_and_writes_their_rows(tmp_path, monkeypatch):
    import json

    from bhem_hpc.benchmarks import contact_page

    def fake_run(window, method, runs, timeout):
        return {"job": window.job, "method": method, "window": list(window.timed_steps), "status": "completed",
                "steps": 0, "gap": float("inf")}  # fmt: skip

    monkeypatch.setattr(contact_page, "run_window", fake_run)
    can = tuple(w for w in CONTACT_WINDOWS if w.job == "crushed-can")
    page = contact_page.write_contact_page(tmp_path / "docs", tmp_path / "runs", can, 1.0, "bhem-hpc contact-page",
                                           "a test")  # fmt: skip
    rows = json.loads((tmp_path / "docs" / "contact-comparison.json").read_text())
    first, second = can[0].timed_steps[0], can[1].timed_steps[0]
    assert [(r["method"], r["window"][0]) for r in rows] == [("impulse", first), ("ipc", first), ("impulse", second)]
    assert rows[0]["gap"] is None  # not-a-number figures are written as null
    assert page.read_text().count("- crushed-can: steps") == 2


def test_a_window_runs_again_and_only_runs_of_the_same_newton_iterations_count_for_its_seconds(tmp_path, monkeypatch):
    """The later runs of a window go to directories of their own; one whose steps took other Newton
    iterations (another computation) is left out of the median; the page shows the median and the range."""
    import json

    from bhem_hpc.benchmarks import contact_page

    window = CONTACT_WINDOWS[0]
    first, last = window.timed_steps
    iterations = {"ball-ipc-70-window-2": 5, "ball-ipc-70-window-3": 6}
    ran = []

    def fake_run(scene, out, steps, timeout, restart=None):
        ran.append(out.name)
        out.mkdir()
        rows = [{"step": step, "newton_iterations": iterations[out.name], "wall_s": 2.0}
                for step in range(window.start + 1, last + 1)]  # fmt: skip
        (out / "steps.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")
        return "completed"

    monkeypatch.setattr(contact_page, "_run", fake_run)
    records = [{"step": step, "newton_iterations": 5, "wall_s": 1.0} for step in range(first, last + 1)]
    seconds = contact_page._repeated_step_seconds(window, tmp_path / "scene.toml", tmp_path / "ball-ipc-70",
                                                  tmp_path / "warm", records, 1.0)  # fmt: skip
    assert ran == ["ball-ipc-70-window-2", "ball-ipc-70-window-3"][: contact_page.WINDOW_RUNS - 1]
    assert seconds == [2.0]
    row = {"step_s": 1.5, "step_s_runs": [1.0, *seconds]}
    assert contact_page._seconds(row) == "1.5 (1–2)"
    assert contact_page._seconds({"step_s": 1.25}) == "1.25"
