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
from helpers import BASE

from bhem_hpc.io import read_checkpoint


def test_killed_run_leaves_readable_output(comm):
    failure = None
    if comm.rank == 0:  # one child process, started without the parent's MPI environment
        work = Path(tempfile.mkdtemp(prefix="bhem-kill-"))
        scene = work / "long.toml"
        scene.write_text(BASE.replace("steps = 6", "steps = 100000").replace("every = 2", "every = 1"))
        env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "PMI_"))}
        command = [sys.executable, "-m", "bhem_hpc.cli", "run", str(scene), "--out", str(work / "out"), "--no-progress"]
        child = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
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
        env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "PMI_"))}
        out = work / "out"
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
