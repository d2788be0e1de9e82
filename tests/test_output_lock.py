"""One writer per output directory, and --force that replaces only a run's own files: real
processes, real signals, the shipped SLURM script with stand-ins for srun and scontrol."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from helpers import BASE, REPO, message_lines

pytestmark = pytest.mark.serial_child  # every test checks serial child processes

#: The child processes run without the parent's MPI environment (one rank each).
ENV = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "PMI_"))}


def _run(scene: Path, out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "bhem_hpc.cli", "run", str(scene), "--out", str(out), "--no-progress", *extra]


def _serial(comm, check) -> None:
    """Run ``check`` on rank 0 only (its processes are its own) and fail on every rank alike."""
    failure = None
    if comm.rank == 0:
        try:
            check(Path(tempfile.mkdtemp(prefix="bhem-lock-")))
        except AssertionError as exc:
            failure = str(exc) or repr(exc)
    failure = comm.bcast(failure)
    assert failure is None, failure


def _wait_for(path: Path, child: subprocess.Popen, seconds: float = 120) -> None:
    deadline = time.monotonic() + seconds
    while not path.exists() and child.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    assert path.exists(), f"{path} never appeared (child exit {child.poll()})"


def test_a_second_run_into_a_directory_being_written_is_refused_and_the_first_is_unharmed(comm):
    def check(work: Path) -> None:
        scene = work / "long.toml"
        scene.write_text(BASE.replace("steps = 6", "steps = 600"))  # still running when the others try
        out = work / "out"
        first = subprocess.Popen(_run(scene, out), env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        _wait_for(out / "surface.xdmf", first)
        for extra in ((), ("--force",)):
            second = subprocess.run(_run(scene, out, *extra), env=ENV, capture_output=True, text=True, timeout=300)
            assert second.returncode == 2, second.stderr[-2000:]
            lines = message_lines(second.stderr)
            assert len(lines) == 1 and "is being written by another run (process" in lines[0], second.stderr
            assert f"process {first.pid} on this host" in lines[0]
        assert first.wait(timeout=600) == 0, first.stderr.read().decode()[-2000:]
        summary = json.loads((out / "summary.json").read_text())
        assert summary["status"] == "completed" and len(summary["steps"]) == 600
        assert not (work / ".out.lock").exists()  # released at the end

    _serial(comm, check)


def test_the_lock_of_a_killed_run_is_stale_and_a_restart_takes_it(comm):
    def check(work: Path) -> None:
        scene = work / "long.toml"
        scene.write_text(BASE.replace("steps = 6", "steps = 100000"))
        out = work / "out"
        child = subprocess.Popen(_run(scene, out), env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        _wait_for(out / "checkpoint.h5", child)
        child.send_signal(signal.SIGKILL)
        child.wait()
        assert (work / ".out.lock").exists()  # a killed process frees nothing
        again = subprocess.run(_run(scene, out, "--restart", str(out), "--steps", "2"), env=ENV,
                               capture_output=True, text=True, timeout=300)  # fmt: skip
        assert again.returncode == 0, again.stderr[-2000:]
        assert not (work / ".out.lock").exists()

    _serial(comm, check)


def test_force_refuses_a_directory_holding_files_it_did_not_write(comm):
    def check(work: Path) -> None:
        scene = work / "s.toml"
        scene.write_text(BASE)
        out = work / "out"
        assert subprocess.run(_run(scene, out, "--steps", "1"), env=ENV, capture_output=True).returncode == 0
        (out / "notes.txt").write_text("mine")
        (out / "sub").mkdir()
        (out / "sub" / "data.csv").write_text("1,2")
        forced = subprocess.run(_run(scene, out, "--force"), env=ENV, capture_output=True, text=True, timeout=300)
        assert forced.returncode == 2, forced.stderr[-2000:]
        assert "holds files bhem-hpc did not write (notes.txt, sub/)" in forced.stderr
        assert (out / "notes.txt").read_text() == "mine" and (out / "sub" / "data.csv").read_text() == "1,2"
        # the scene's own folder as --out: the scene file is not the run's, so it is kept
        inside = subprocess.run(_run(scene, work, "--force"), env=ENV, capture_output=True, text=True, timeout=300)
        assert inside.returncode == 2 and "s.toml" in inside.stderr and scene.read_text() == BASE
        # a run's own output alone is replaced
        (out / "notes.txt").unlink()
        (out / "sub" / "data.csv").unlink()
        (out / "sub").rmdir()
        replaced = subprocess.run(_run(scene, out, "--force", "--steps", "1"), env=ENV, capture_output=True, text=True)
        assert replaced.returncode == 0, replaced.stderr[-2000:]

    _serial(comm, check)


def test_the_slurm_script_never_forces(comm):
    """A folder without a checkpoint or a completed summary (here a user's thesis beside nothing of
    a run) is left as it is: the script does not call srun with --force, it says what to do."""

    def check(work: Path) -> None:
        bin_dir = work / "bin"
        bin_dir.mkdir()
        (bin_dir / "scontrol").write_text(f'#!/bin/sh\necho "JobId=1 Command={REPO}/jobs/slurm.sbatch Other=x"\n')
        (bin_dir / "srun").write_text(f'#!/bin/sh\necho "$@" > {work}/srun-args\n')
        for tool in ("scontrol", "srun"):
            (bin_dir / tool).chmod(0o755)
        scene = work / "s.toml"
        scene.write_text(BASE)
        data = work / "data"
        data.mkdir()
        (data / "thesis.tex").write_text("\\chapter{Results}")
        env = ENV | {"PATH": f"{bin_dir}:{os.environ['PATH']}", "SLURM_JOB_ID": "1", "SLURM_NTASKS": "1"}
        done = subprocess.run(["bash", str(REPO / "jobs" / "slurm.sbatch"), str(scene), str(data)], env=env,
                              capture_output=True, text=True, timeout=60)  # fmt: skip
        log = (work / "data.log").read_text()
        assert done.returncode == 2, log
        assert "holds no checkpoint to continue from" in log and "--force" in log
        assert (data / "thesis.tex").read_text() == "\\chapter{Results}"
        assert not (work / "srun-args").exists()
        # an empty folder (a job that stopped before writing anything) simply starts
        (data / "thesis.tex").unlink()
        done = subprocess.run(["bash", str(REPO / "jobs" / "slurm.sbatch"), str(scene), str(data)], env=env,
                              capture_output=True, text=True, timeout=60)  # fmt: skip
        assert done.returncode == 0, (work / "data.log").read_text()
        assert "--force" not in (work / "srun-args").read_text()

    _serial(comm, check)


def _terminated(scene: Path, out: Path, message: str, after_s: float) -> tuple[dict, dict]:
    """Run ``scene`` into ``out`` and SIGTERM it ``after_s`` after its first checkpoint: its exit
    code is 2 and its one error line holds ``message``. Returns its summary and checkpoint attributes."""
    from bhem_hpc.io import read_checkpoint

    child = subprocess.Popen(_run(scene, out), env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _wait_for(out / "checkpoint.h5", child)
    time.sleep(after_s)
    child.send_signal(signal.SIGTERM)
    _, err = child.communicate(timeout=120)
    assert child.returncode == 2, err[-2000:]
    assert len(message_lines(err)) == 1 and message in err, err
    return json.loads((out / "summary.json").read_text()), read_checkpoint(out / "checkpoint.h5")[1]


def test_sigterm_ends_a_run_at_a_step_boundary_with_its_state_written(comm):
    """``kill`` (or ``timeout``) during a run: status ``interrupted``, every step recorded, the last
    step written as a frame and a checkpoint, and a restart in place continues from it."""
    from bhem_hpc.io import read_frame

    def check(work: Path) -> None:
        scene = work / "long.toml"
        scene.write_text(BASE.replace("steps = 6", "steps = 100000"))
        out = work / "out"
        summary, attrs = _terminated(scene, out, "stopped by SIGTERM after step", 1.0)
        assert summary["status"] == "interrupted" and len(summary["steps"]) == attrs["step"] > 0
        _, last_time = read_frame(out / "surface.h5", -1)
        assert last_time == attrs["time"]
        assert not (work / ".out.lock").exists()
        again = subprocess.run(_run(scene, out, "--restart", str(out), "--steps", "2"), env=ENV,
                               capture_output=True, text=True, timeout=300)  # fmt: skip
        assert again.returncode == 0, again.stderr[-2000:]
        assert len(json.loads((out / "summary.json").read_text())["steps"]) == attrs["step"] + 2

    _serial(comm, check)


def test_sigterm_ends_a_static_path_after_a_point_with_its_rows_and_plot(comm):
    """The same for a path (the cylindrical panel's arc length): ``interrupted`` after a converged
    point whose frame, checkpoint and path.csv row are written, and path.png drawn."""

    def check(work: Path) -> None:
        out = work / "out"
        panel = REPO / "jobs" / "cylindrical-panel.toml"
        summary, attrs = _terminated(panel, out, "stopped by SIGTERM after path point", 0.5)
        rows = (out / "path.csv").read_text().splitlines()
        assert summary["status"] == "interrupted" and len(summary["steps"]) == attrs["step"] + 1 == len(rows) - 1
        assert (out / "path.png").stat().st_size > 10_000

    _serial(comm, check)
