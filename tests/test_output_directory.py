"""Output that is never lost or mixed: --force replaces a directory only when the new run writes,
never through links; failed runs say so; restarts continue the same series to the scene's end."""

from __future__ import annotations

import json
import os
from pathlib import Path

import h5py
import numpy as np
import pytest
from helpers import BASE, frame_times

from bhem_hpc.io import read_checkpoint
from bhem_hpc.run import RunError, RunOptions, run_scene


def write(comm, path: Path, text: str) -> Path:
    if comm.rank == 0:
        path.write_text(text)
    comm.Barrier()
    return path


def files(directory: Path) -> dict[str, bytes]:
    """Every file under ``directory``, by relative path."""
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def run(scene: Path, out: Path, comm, **options) -> dict:
    return run_scene(RunOptions(scene, out, progress=False, **options), comm)


def test_a_restart_in_its_own_directory_continues_the_series_to_the_scenes_end(comm, shared_tmp_path):
    scene = write(comm, shared_tmp_path / "scene.toml", BASE)
    full = run(scene, shared_tmp_path / "full", comm)
    out = shared_tmp_path / "run"
    run(scene, out, comm, steps=3)
    assert frame_times(out) == pytest.approx([0.0, 0.02, 0.03])
    continued = run(scene, out, comm, restart=out)  # no --steps: the 3 steps left to the scene's end
    assert continued["status"] == "completed"
    assert [row["step"] for row in continued["steps"]] == [1, 2, 3, 4, 5, 6]
    assert frame_times(out) == pytest.approx([0.0, 0.02, 0.03, 0.04, 0.06])
    ours, attrs = read_checkpoint(out / "checkpoint.h5")
    reference, _ = read_checkpoint(shared_tmp_path / "full" / "checkpoint.h5")
    assert attrs["step"] == 6 and full["time"] == pytest.approx(0.06)
    scale = np.abs(reference["position_dofs"]).max()
    assert np.abs(ours["position_dofs"] - reference["position_dofs"]).max() <= 1e-12 * scale
    with pytest.raises(RunError, match="the checkpoint is at step 6, the scene's last .*pass --steps"):
        run(scene, out, comm, restart=out)
    # into another directory: the series starts with the restart frame
    run(scene, shared_tmp_path / "more", comm, restart=out, steps=2)
    assert frame_times(shared_tmp_path / "more") == pytest.approx([0.06, 0.08])


def test_a_force_rerun_that_fails_before_writing_leaves_the_old_result(comm, shared_tmp_path):
    scene = write(comm, shared_tmp_path / "scene.toml", BASE)
    out = shared_tmp_path / "out"
    run(scene, out, comm, steps=2)
    before = files(out)
    bad = write(comm, shared_tmp_path / "bad.toml", BASE + '\n[solver]\noptions = { snes_type = "nosuch" }\n')
    with pytest.raises(Exception, match="nosuch|SNES|86"):
        run(bad, out, comm, steps=2, force=True)
    assert files(out) == before


def test_a_static_run_replacing_a_dynamic_one_leaves_only_its_own_files(comm, shared_tmp_path):
    scene = write(comm, shared_tmp_path / "scene.toml", BASE)
    static = (
        BASE.replace("dt = 0.01\nsteps = 6", "static = true")
        .replace("damping = { mass = 0.5 }\n", "")
        .replace('corners = ["min_min"]', 'edge = "xi1_min"')
        .split('[[constraints]]\ntype = "fix"')[0]
    )
    static_scene = write(comm, shared_tmp_path / "static.toml", static)
    out = shared_tmp_path / "out"
    run(scene, out, comm, steps=2)
    summary = run(static_scene, out, comm, force=True)
    assert summary["status"] == "completed" and summary["static"]
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [".bhem-run", "scene.toml", "surface.xdmf", "surface.h5", "surface.pvd", "surface_frames", "checkpoint.h5",
         "summary.json", "last.png", "path.csv", "path.png", "steps.jsonl"]
    )
    _, attrs = read_checkpoint(out / "checkpoint.h5")
    assert attrs["static"] and attrs["step"] == 1  # the static run's own checkpoint
    assert frame_times(out) == [0.0, 1.0]  # the start and the load level
    assert (out / "scene.toml").read_text() == static


def test_force_never_writes_through_a_symbolic_link(comm, shared_tmp_path):
    scene = write(comm, shared_tmp_path / "scene.toml", BASE)
    out = shared_tmp_path / "out"
    run(scene, out, comm, steps=1)
    target = shared_tmp_path / "precious.h5"
    if comm.rank == 0:
        target.write_bytes(b"keep")
        (out / "surface.h5").unlink()
        os.symlink(target, out / "surface.h5")
    comm.Barrier()
    with pytest.raises(RunError, match=r"surface.h5 is a symbolic link"):
        run(scene, out, comm, restart=out, steps=1)  # continuing in place refuses links
    run(scene, out, comm, steps=1, force=True)
    assert target.read_bytes() == b"keep"
    assert not (out / "surface.h5").is_symlink()
    assert not list(shared_tmp_path.glob(".out.replaced-*"))  # the old directory is gone


def test_a_run_that_fails_while_stepping_says_so(comm, shared_tmp_path):
    # one Newton iteration, in line-search Newton and in its trust-region recovery, cannot reach 1e-14
    options = "{ snes_max_it = 1, tr_snes_max_it = 1, snes_rtol = 1e-14, snes_atol = 1e-300 }"
    failing = BASE + f"\n[solver]\noptions = {options}\n"
    scene = write(comm, shared_tmp_path / "failing.toml", failing)
    out = shared_tmp_path / "out"
    with pytest.raises(RunError):
        run(scene, out, comm)
    # rank 0 records the failure without a collective (a rank that failed alone must not wait for
    # the others), so the other ranks may get here first
    comm.Barrier()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["error"]
    assert summary["steps"] == []  # no step completed
    assert frame_times(out) == [0.0]


def _forge(path: Path, how: str) -> None:
    """Damage a checkpoint the ways a user or a full disk would."""
    if how == "truncated":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif how == "garbage":
        path.write_bytes(b"\x89not hdf5 at all" * 10)
    else:
        with h5py.File(path, "r+") as f:
            if how == "foreign":  # another program's HDF5 file
                for name in list(f):
                    del f[name]
                f.attrs.clear()
                f["data"] = np.arange(3)
            elif how == "nan":
                f["velocity_dofs"][0, ...] = np.nan
            elif how == "shape":
                del f["position_dofs"]
                f["position_dofs"] = np.zeros((2, 3))
            elif how == "clock":
                f.attrs["step"] = "many"


@pytest.mark.parametrize(
    ("how", "message"),
    [
        ("truncated", "not a readable checkpoint"),
        ("garbage", "not a readable checkpoint"),
        ("foreign", "different scene or resolution"),
        ("nan", "non-finite"),
        ("shape", "position and velocity DOFs have shapes"),
        ("clock", "'time' and 'step' attributes"),
    ],
)
def test_a_damaged_checkpoint_is_refused_before_anything_is_written(comm, shared_tmp_path, how, message):
    scene = write(comm, shared_tmp_path / "scene.toml", BASE)
    first = shared_tmp_path / "first"
    run(scene, first, comm, steps=2)
    if comm.rank == 0:
        _forge(first / "checkpoint.h5", how)
    comm.Barrier()
    with pytest.raises(RunError, match=message) as error:
        run(scene, shared_tmp_path / "second", comm, restart=first)
    assert str(first) in str(error.value)
    assert not (shared_tmp_path / "second").exists()


def test_force_into_the_scenes_own_folder_keeps_the_scene(comm, shared_tmp_path):
    """The folder holding the scene file is replaced; the scene is read first and written back."""
    folder = shared_tmp_path / "job"
    if comm.rank == 0:
        folder.mkdir()
    scene = write(comm, folder / "scene.toml", BASE)
    summary = run(scene, folder, comm, steps=1, force=True)
    assert summary["status"] == "completed"
    assert (folder / "scene.toml").read_text() == BASE


def test_misspelled_petsc_options_are_reported(comm, shared_tmp_path):
    """PETSc's "options left": a misspelled scene option is named in summary.json; options PETSc
    reads only at the first factorization (MUMPS' ICNTL) count as used."""
    options = '\n[solver]\noptions = { snes_rtoll = 1e-3, snes_rtol = 1e-8, mat_mumps_icntl_14 = 50 }\n'
    scene = write(comm, shared_tmp_path / "scene.toml", BASE + options)
    summary = run(scene, shared_tmp_path / "out", comm, steps=1)
    assert summary["unused_petsc_options"] == ["bhem_snes_rtoll"]
    assert json.loads((shared_tmp_path / "out" / "summary.json").read_text())["unused_petsc_options"] == [
        "bhem_snes_rtoll"
    ]


def test_a_running_summary_shows_the_step_records_up_to_each_checkpoint(comm, shared_tmp_path, monkeypatch):
    """With the rewrite interval at 0 s, summary.json is rewritten at every checkpoint (every 2
    steps here) with the records so far (a restart reads them from steps.jsonl)."""
    import bhem_hpc.run as R
    from bhem_hpc.io.run_summary import RunSummary

    monkeypatch.setattr(R, "SUMMARY_EVERY_S", 0.0)
    written = []
    original = RunSummary.write

    def spy(summary: RunSummary, out: Path) -> None:
        written.append((summary.status, len(summary.steps)))
        original(summary, out)

    monkeypatch.setattr(RunSummary, "write", spy)
    scene = write(comm, shared_tmp_path / "scene.toml", BASE)
    run(scene, shared_tmp_path / "out", comm)
    if comm.rank == 0:
        assert written == [("running", 0), ("running", 2), ("running", 4), ("running", 6), ("completed", 6)]
