"""Whether a run's output ever intersects itself: every frame's output meshes (the tessellated
surfaces a run writes, as ParaView shows them) of every body, tested together with ipc-toolkit's
intersection test and measured by the smallest distance between non-adjacent triangles (numpy,
h5py and ipctk; serial).

A shell crossing itself or another body shows as triangles that intersect in some frame. A crossing
completed between two frames (a sheet that passed wholly through another) does not: the test sees
frames, not the motion between them. Analytic colliders are not part of the meshes. A solid's
frames are its boundary ``.vtu`` files (its parts tessellated); its parts overlap and meet along
their edges by design (a modeller's parts), so a solid is tested against the other bodies only,
never against itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree

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


@dataclass(frozen=True)
class RunMeshes:
    """The output meshes of a run, every body's stacked.

    Attributes:
        faces: triangles ``(T, 3)``.
        frames: per frame, its vertices ``(V, 3)`` [m] and time.
        groups: ``(V,)`` a group per vertex; only vertices of different groups can meet (a vertex
            of a shell is a group of its own, a solid's vertices are one group).
    """

    faces: np.ndarray
    frames: list[tuple[np.ndarray, float]]
    groups: np.ndarray


def _shell_series(path: Path) -> tuple[np.ndarray, list[tuple[np.ndarray, float]]]:
    """A shell's output meshes: triangles and per frame vertices and time, from its ``surface.h5``."""
    try:
        with h5py.File(path, "r") as h:
            faces = _quads_to_triangles(h["topology"][...])
            frames = [(h[f"frames/{k}/geometry"][...], float(h[f"frames/{k}"].attrs["time"]))
                      for k in range(len(h["frames"]))]  # fmt: skip
    except OSError as exc:
        raise InputError(f"{path}: not a readable surface series ({exc})") from None
    return faces, frames


def _solid_series(path: Path) -> tuple[np.ndarray, list[tuple[np.ndarray, float]]]:
    """A solid's output meshes: each frame's boundary ``.vtu`` (its parts tessellated, quadrilaterals)."""
    from bhem_hpc.io.solid_output import pvd_times
    from bhem_hpc.io.vtu import read_vtu

    try:
        times = pvd_times(path)
    except (OSError, ElementTree.ParseError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: not a readable series of a solid ({exc})") from None
    faces, frames = np.zeros((0, 3), np.int32), []
    for k, time in enumerate(times):
        boundary = path.with_name(path.stem + "_frames") / f"frame_{k:06d}_boundary.vtu"
        try:
            points, quads = read_vtu(boundary)
        except (OSError, ValueError) as exc:
            raise InputError(f"{boundary}: not a readable boundary mesh of a solid ({exc})") from None
        faces = _quads_to_triangles(quads)
        frames.append((points, time))
    return faces, frames


def read_frames(directory: Path) -> RunMeshes:
    """The output meshes of the run in ``directory`` (its one series, or each body's of a run of
    several bodies, stacked).

    Raises:
        InputError: ``directory`` holds no readable series, or series of different frame counts.
    """
    triangles, frames, groups, start = [], [], [], 0
    for path in run_series(directory):
        faces, series = _solid_series(path) if path.suffix == ".pvd" else _shell_series(path)
        count = len(series[0][0]) if series else 0
        triangles.append(faces + start)
        frames.append(series)
        # a shell's vertices each a group of their own (it may cross itself); a solid's one group
        groups.append(np.full(count, -1 - len(groups)) if path.suffix == ".pvd" else start + np.arange(count))
        start += count
    counts = {len(series) for series in frames}
    if len(counts) != 1:
        raise InputError(f"{directory}: its bodies' series hold different numbers of frames ({sorted(counts)})")
    stacked = [(np.concatenate([series[k][0] for series in frames]), frames[0][k][1]) for k in range(counts.pop())]
    every = np.concatenate(groups)
    return RunMeshes(np.concatenate(triangles).astype(np.int32), stacked, (every - every.min()).astype(np.int32))


def audit_frames(meshes: RunMeshes, within: float) -> list[FrameAudit]:
    """Every frame of a run's output ``meshes`` (:func:`read_frames`), distances measured up to ``within`` [m]."""
    import ipctk  # loaded for audits only

    _check_within(within)
    faces = meshes.faces
    edges = ipctk.edges(faces)
    audits = []
    for k, (vertices, time) in enumerate(meshes.frames):
        mesh = ipctk.CollisionMesh(np.asfortranarray(vertices), edges, faces)
        mesh.can_collide = ipctk.make_vertex_patches_filter(meshes.groups)
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
    return audit_frames(read_frames(directory), within)


def _check_within(within: float) -> None:
    if not (np.isfinite(within) and within > 0):
        raise InputError(f"--within must be a positive distance, got {within!r}")
