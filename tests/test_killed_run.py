"""A run killed mid-way leaves a readable time series of every completed step and a valid checkpoint."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import pytest
from helpers import BASE

from bhem_hpc.io import read_checkpoint

pytestmark = pytest.mark.serial_child  # every test checks serial child processes


def _child_env() -> dict[str, str]:
    """The environment of a child run: without the parent's MPI (a child is a singleton)."""
    return {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "PMI_"))}


def _run_command(scene: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "bhem_hpc.cli", "run", str(scene), "--out", str(out), "--no-progress"]


def test_killed_run_leaves_readable_output(comm):
    failure = None
    if comm.rank == 0:  # one child process, started without the parent's MPI environment
        work = Path(tempfile.mkdtemp(prefix="bhem-kill-"))
        scene = work / "long.toml"
        scene.write_text(BASE.replace("steps = 6", "steps = 100000").replace("every = 2", "every = 1"))
        env = _child_env()
        child = subprocess.Popen(
            _run_command(scene, work / "out"), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
        )
        deadline = time.monotonic() + 120
        xdmf = work / "out" / "surface.xdmf"
        frames = 0
        while time.monotonic() < deadline and frames < 6 and child.poll() is None:
            time.sleep(0.2)
            if xdmf.exists():
                frames = len(ET.parse(xdmf).getroot().findall(".//Grid[@GridType='Uniform']"))
        child.send_signal(signal.SIGKILL)
        child.wait()
        try:
            assert frames >= 6, child.stderr.read().decode()[-2000:]
            root = ET.parse(xdmf).getroot()
            grids = root.findall(".//Grid[@GridType='Uniform']")
            with h5py.File(work / "out" / "surface.h5", "r") as f:
                for k in range(len(grids)):
                    assert f[f"frames/{k}/geometry"].shape[1] == 3
            arrays, attrs = read_checkpoint(work / "out" / "checkpoint.h5")
            assert attrs["step"] >= len(grids) - 2 and arrays["position_dofs"].shape == (4, 3, 4, 3)
        except AssertionError as exc:
            failure = str(exc)
    failure = comm.bcast(failure)
    assert failure is None, failure


def test_a_full_disk_ends_the_run_cleanly_with_its_last_frames_readable(comm):
    """The output files may not grow past 150 kB (RLIMIT_FSIZE, the way a full disk fails a
    write, without root): exit code 2 and one error line, no crash; the summary says failed; the
    XDMF lists only complete frames, the last of which reads back, and the checkpoint is whole."""
    import json

    from bhem_hpc.io import read_frame

    failure = None
    if comm.rank == 0:
        work = Path(tempfile.mkdtemp(prefix="bhem-full-"))
        scene = work / "long.toml"
        scene.write_text(BASE.replace("steps = 6", "steps = 400").replace("every = 2", "every = 1"))
        code = (  # the limit after MPI_Init: MPI's own shared-memory files must not hit it
            "import resource, signal, sys\nfrom mpi4py import MPI\n"
            "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
            "resource.setrlimit(resource.RLIMIT_FSIZE, (150_000, 150_000))\n"
            "from bhem_hpc import cli\nsys.exit(cli.main(sys.argv[1:]))\n"
        )
        env = _child_env()
        out = work / "out"
        # one step without the limit first: the forms' JIT cache (a clean checkout has none) is
        # written in files the limit would cut
        subprocess.run(
            [*_run_command(scene, work / "warm"), "--steps", "1"], env=env, capture_output=True, timeout=300, check=True
        )
        command = [sys.executable, "-c", code, "run", str(scene), "--out", str(out), "--no-progress"]
        child = subprocess.run(command, env=env, capture_output=True, timeout=300)
        try:
            errors = [line for line in child.stderr.decode().splitlines() if line.startswith("bhem-hpc: error:")]
            assert child.returncode == 2 and len(errors) == 1, child.stderr.decode()[-3000:]
            assert "Traceback" not in child.stderr.decode(), child.stderr.decode()[-3000:]
            assert "frame at t = " in errors[0] and "not written (File too large)" in errors[0]
            summary = json.loads((out / "summary.json").read_text())
            assert summary["status"] == "failed" and 5 < len(summary["steps"]) < 400
            listed = ET.parse(out / "surface.xdmf").getroot().findall(".//Grid[@GridType='Uniform']")
            last_time = float(listed[-1].find("Time").get("Value"))
            surface, time = read_frame(out / "surface.h5")
            assert time == last_time and surface.nodal.shape == (4, 3, 4, 3)
            _, attrs = read_checkpoint(out / "checkpoint.h5")
            assert attrs["time"] == last_time
            assert not list(out.glob("*.tmp"))
        except AssertionError as exc:
            failure = str(exc)
    failure = comm.bcast(failure)
    assert failure is None, failure


def _timeless(row: dict) -> dict:
    """A step record without its wall times (which no two runs share)."""
    return {k: v for k, v in row.items() if not (k.endswith("_s") or k == "wall_s")}


def _killed_and_restarted(scene: Path, out: Path, kill_after_rows: list[int], table: str, env: dict) -> None:
    """Run ``scene`` into ``out``, SIGKILL it once ``out/table`` has each count of rows in turn
    (restarting in place after each kill), then let the last restart finish."""
    run = _run_command(scene, out)
    for k, rows in enumerate(kill_after_rows):
        command = run + (["--restart", str(out)] if k else [])
        child = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and child.poll() is None:
            path = out / table
            if path.exists() and path.read_text().count("\n") >= rows:
                break
            time.sleep(0.01)
        child.send_signal(signal.SIGKILL)
        child.wait()
        assert (out / "checkpoint.h5").exists(), child.stderr.read().decode()[-2000:]
    finished = subprocess.run(run + ["--restart", str(out)], env=env, capture_output=True, timeout=600)
    assert finished.returncode == 0, finished.stderr.decode()[-3000:]


def test_a_run_killed_at_any_moment_and_restarted_in_place_has_the_records_of_one_that_was_not(comm):
    """Dynamic: SIGKILL at three moments (whatever the run was doing), each time restarted in place:
    summary.json's step records, steps.jsonl and probes.csv equal an uninterrupted run's (the
    restart is bit-exact, so do the records but for their wall times)."""
    import csv
    import json

    failure = None
    if comm.rank == 0:
        work = Path(tempfile.mkdtemp(prefix="bhem-records-"))
        scene = work / "s.toml"
        scene.write_text(BASE.replace("steps = 6", "steps = 40").replace("every = 2", "every = 3")
                         + '\n[[probes]]\nname = "tip"\nat = [0.4, 0.3]\n')  # fmt: skip
        env = _child_env()
        reference = subprocess.run(_run_command(scene, work / "whole"), env=env, capture_output=True, timeout=600)
        try:
            assert reference.returncode == 0, reference.stderr.decode()[-3000:]
            _killed_and_restarted(scene, work / "killed", [5, 17, 29], "steps.jsonl", env)
            summaries = [json.loads((work / d / "summary.json").read_text()) for d in ("whole", "killed")]
            lines = [(work / d / "steps.jsonl").read_text().splitlines() for d in ("whole", "killed")]
            records = [[_timeless(json.loads(line)) for line in text] for text in lines]
            assert [r["step"] for r in records[1]] == list(range(1, 41))
            assert records[1] == records[0]
            assert [_timeless(r) for r in summaries[1]["steps"]] == records[0]
            assert summaries[1]["status"] == "completed"
            probes = [list(csv.DictReader(open(work / d / "probes.csv"))) for d in ("whole", "killed")]
            assert len(probes[0]) == 41 and probes[1] == probes[0]
        except AssertionError as exc:
            failure = str(exc)
    failure = comm.bcast(failure)
    assert failure is None, failure


def test_a_path_killed_at_any_moment_and_restarted_in_place_has_every_row(comm):
    """Static (the shallow arch's arc length): SIGKILL twice, restarted in place: path.csv and the
    step records equal an uninterrupted path's."""
    import csv
    import json

    from helpers import REPO

    failure = None
    if comm.rank == 0:
        work = Path(tempfile.mkdtemp(prefix="bhem-path-records-"))
        scene = REPO / "jobs" / "shallow-arch.toml"
        env = _child_env()
        reference = subprocess.run(_run_command(scene, work / "whole"), env=env, capture_output=True, timeout=600)
        try:
            assert reference.returncode == 0, reference.stderr.decode()[-3000:]
            _killed_and_restarted(scene, work / "killed", [6, 15], "path.csv", env)
            table = [list(csv.DictReader(open(work / d / "path.csv"))) for d in ("whole", "killed")]
            assert len(table[0]) > 16 and table[1] == table[0]
            steps = [json.loads((work / d / "summary.json").read_text())["steps"] for d in ("whole", "killed")]
            assert [_timeless(r) for r in steps[1]] == [_timeless(r) for r in steps[0]]
        except AssertionError as exc:
            failure = str(exc)
    failure = comm.bcast(failure)
    assert failure is None, failure
