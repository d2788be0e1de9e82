"""Whether a run's output ever intersects itself: every frame's output meshes (the tessellated
surfaces a run writes, as ParaView shows them) of every body, tested together with ipc-toolkit's
intersection test and measured by the smallest distance between non-adjacent triangles (numpy,
h5py and ipctk; serial).

A shell crossing itself or another body shows as triangles that intersect in some frame. A crossing
completed between two frames (a sheet that passed wholly through another) does not: the test sees
frames, not the motion between them. Analytic colliders are not part of the meshes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from bhem_hpc.contact.ipc import minimum_distance
from bhem_hpc.errors import InputError
from bhem_hpc.io.run_directory import run_series


@dataclass(frozen=True)
class FrameAudit:
    """One frame of a run's output.

    Attributes:
        index: the frame's index in its series.
        time: its time (a static run: its load factor or arc length).
        intersecting: whether its meshes (all bodies together) intersect.
        min_distance: the smallest distance [m] between non-adjacent triangles closer than the
            audit's ``within`` (``inf`` if none are).
    """

    index: int
    time: float
    intersecting: bool
    min_distance: float


def _quads_to_triangles(quads: np.ndarray) -> np.ndarray:
    quads = np.asarray(quads, dtype=np.int32)
    return np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])


def read_frames(directory: Path) -> tuple[np.ndarray, list[tuple[np.ndarray, float]]]:
    """The output meshes of the run in ``directory`` (its one series, or each body's of a run of
    several bodies, stacked): triangles ``(T, 3)`` and, per frame, its vertices ``(V, 3)`` [m] and time.

    Raises:
        InputError: ``directory`` holds no readable series, or series of different frame counts.
    """
    handles = []
    try:
        for path in run_series(directory):
            try:
                handles.append(h5py.File(path, "r"))
            except OSError as exc:
                raise InputError(f"{path}: not a readable surface series ({exc})") from None
        counts = {len(h["frames"]) for h in handles}
        if len(counts) != 1:
            raise InputError(f"{directory}: its bodies' series hold different numbers of frames ({sorted(counts)})")
        triangles, start = [], 0
        for h in handles:
            triangles.append(_quads_to_triangles(h["topology"][...]) + start)
            start += len(h["parameters"])
        frames = [(np.concatenate([h[f"frames/{k}/geometry"][...] for h in handles]),
                   float(handles[0][f"frames/{k}"].attrs["time"])) for k in range(counts.pop())]  # fmt: skip
        return np.concatenate(triangles), frames
    finally:
        for h in handles:
            h.close()


def audit_frames(faces: np.ndarray, frames: list[tuple[np.ndarray, float]], within: float) -> list[FrameAudit]:
    """Every frame of :func:`read_frames`' ``faces`` and ``frames``, distances measured up to ``within`` [m]."""
    import ipctk  # loaded for audits only

    _check_within(within)
    edges = ipctk.edges(faces)
    audits = []
    for k, (vertices, time) in enumerate(frames):
        mesh = ipctk.CollisionMesh(np.asfortranarray(vertices), edges, faces)
        distance = minimum_distance(mesh, vertices, within)
        audits.append(FrameAudit(k, time, bool(ipctk.has_intersections(mesh, vertices)), distance))
    return audits


def audit_run(directory: Path, within: float) -> list[FrameAudit]:
    """Every frame of the run in ``directory`` (:func:`read_frames`, :func:`audit_frames`).

    Raises:
        InputError: ``within`` is not a positive distance, ``directory`` holds no readable series, or
            series of different frame counts.
    """
    _check_within(within)  # before the files are read
    return audit_frames(*read_frames(directory), within)


def _check_within(within: float) -> None:
    if not (np.isfinite(within) and within > 0):
        raise InputError(f"--within must be a positive distance, got {within!r}")
