"""The linked rubber bands (``jobs/linked-bands.toml``, a case impulses between steps cannot do):
by IPC the pulled band catches the held one and both stretch, and no output frame has the bands
crossing each other (ipc-toolkit's test on the output meshes)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from bhem_hpc.benchmarks.contact_page import JOBS
from bhem_hpc.contact.audit import audit_run
from bhem_hpc.run import RunOptions, run_scene

#: Steps to t = 0.12 s: the bands catch at about t = 0.085 s, the pull goes on 1.75 cm more.
STEPS = 60


def _extent(out, body: str) -> np.ndarray:
    """The x extent [m] of ``body``'s output mesh in each frame."""
    with h5py.File(out / body / "surface.h5", "r") as f:
        return np.array([np.ptp(f[f"frames/{k}/geometry"][:, 0]) for k in range(len(f["frames"]))])


def test_linked_bands_catch_and_stretch_without_crossing(comm, shared_tmp_path):
    """Rest: both bands 0.1 m across, the pulled one's near side 1 cm inside the held one. The pulled
    band's far side moves 6 cm (the band first stretches behind it); its near side meets the held band
    and stretches it along the pull by more than 1 cm (measured 1.39 cm); no frame of 13 intersects,
    no dt is halved, and the bands come within dhat of each other."""
    out = shared_tmp_path / "bands"
    summary = run_scene(RunOptions(JOBS / "linked-bands.toml", out, steps=STEPS, progress=False), comm)
    records = summary["steps"]
    assert summary["status"] == "completed" and len(records) == STEPS
    assert sum(r["dt_halvings"] for r in records) == 0
    if comm.rank != 0:
        return
    held = _extent(out, "held")
    assert held[0] == pytest.approx(0.1, abs=1e-6)
    assert held[-1] > 0.11
    audits = audit_run(out, 1e-3)
    assert len(audits) == STEPS // 5 + 1
    assert not any(a.intersecting for a in audits)
    assert 0.0 < min(a.min_distance for a in audits) < summary["contact"]["dhat_m"]
