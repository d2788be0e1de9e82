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
