"""A solid's state as ParaView files (VTK XML, float64): its NURBS parts tessellated as one
quadrilateral surface, and its quadrature points with their Cauchy stresses; as one state
(:func:`write_solid_files`) or a time series (:class:`SolidTimeSeries`, which also writes each
frame's deformed model as IGES, read back by :func:`read_solid_frame`). Serial writers, numpy
only; the arrays come from the solid (:class:`~bhem_hpc.solids.sem.ShapeMatchingSolid`)."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from bhem_hpc.errors import InputError
from bhem_hpc.geometry.nurbs import NurbsSurface
from bhem_hpc.geometry.surface import SurfaceError
from bhem_hpc.io.cad import read_parts, write_parts
from bhem_hpc.io.vtu import VTK_VERTEX, write_pvd, write_vtu

#: A part's tessellation: its parameter lines in ``[0, 1]`` of its domain, ``(u lines, v lines)``.
PartGrid = tuple[np.ndarray, np.ndarray]


def part_grids(parts: Sequence[NurbsSurface], samples: int | Sequence[PartGrid]) -> list[PartGrid]:
    """Each part's parameter lines: ``samples`` equally spaced per side, or the grids given."""
    if isinstance(samples, int | np.integer):
        lines = np.linspace(0.0, 1.0, int(samples))
        return [(lines, lines)] * len(parts)
    if len(samples) != len(parts):
        raise ValueError(f"{len(samples)} tessellation grids for {len(parts)} parts")
    return [(np.asarray(u, dtype=float), np.asarray(v, dtype=float)) for u, v in samples]


def tessellate_parts(parts: Sequence[NurbsSurface], samples: int | Sequence[PartGrid] = 9):
    """Every part on a parameter grid (``samples x samples`` points, or each part's own grid of
    :func:`part_grids`): points ``(P, 3)``, quadrilaterals ``(M, 4)`` (counter-clockwise about
    ``x_u x x_v``), unit normals ``(P, 3)`` and each point's part index ``(P,)``."""
    points, quads, normals, part = [], [], [], []
    start = 0
    for k, (surface, (lines_u, lines_v)) in enumerate(zip(parts, part_grids(parts, samples), strict=True)):
        (u0, u1), (v0, v1) = surface.u.domain, surface.v.domain
        u, v = (a.ravel() for a in np.meshgrid(u0 + lines_u * (u1 - u0), v0 + lines_v * (v1 - v0), indexing="ij"))
        count_v = len(lines_v)
        corner = (np.arange(len(lines_u) - 1)[:, None] * count_v + np.arange(count_v - 1)[None, :]).ravel()
        point, x_u, x_v = surface.evaluate(u, v)
        normal = np.cross(x_u, x_v)
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        normals.append(np.divide(normal, length, out=np.zeros_like(normal), where=length > 0))  # poles: 0
        quads.append(np.stack([corner, corner + count_v, corner + count_v + 1, corner + 1], axis=1) + start)
        points.append(point)
        part.append(np.full(len(u), float(k)))
        start += len(u)
    return np.concatenate(points), np.concatenate(quads), np.concatenate(normals), np.concatenate(part)


def write_solid_files(
    directory: str | Path,
    parts: Sequence[NurbsSurface],
    rest_parts: Sequence[NurbsSurface],
    positions: np.ndarray,
    stresses: np.ndarray,
    volumes: np.ndarray,
    stem: str = "solid",
    samples: int | Sequence[PartGrid] = 9,
) -> tuple[Path, Path]:
    """Write ``<stem>_boundary.vtu`` (the parts tessellated, with ``normal``, ``displacement`` from
    ``rest_parts`` and ``part``) and ``<stem>_points.vtu`` (the quadrature points at ``positions
    (Q, 3)`` with their Cauchy ``stress (Q, 3, 3)`` [Pa], its ``von_mises`` [Pa] and their
    reference ``volume (Q,)`` [m^3]) into ``directory``; returns both paths."""
    directory = Path(directory)
    points, quads, normals, part = tessellate_parts(parts, samples)
    rest, _, _, _ = tessellate_parts(rest_parts, samples)
    boundary = write_vtu(
        directory / f"{stem}_boundary.vtu",
        points,
        quads,
        {"normal": normals, "displacement": points - rest, "part": part},
    )
    stresses = np.asarray(stresses, dtype=float)
    deviator = stresses - np.trace(stresses, axis1=1, axis2=2)[:, None, None] * np.eye(3) / 3.0
    von_mises = np.sqrt(1.5 * np.einsum("kij,kij->k", deviator, deviator))
    cloud = write_vtu(
        directory / f"{stem}_points.vtu",
        np.asarray(positions, dtype=float),
        np.arange(len(positions))[:, None],
        {"stress": stresses.reshape(-1, 9), "von_mises": von_mises, "volume": np.asarray(volumes, dtype=float)},
        normals=None,
        cell_type=VTK_VERTEX,
    )
    return boundary, cloud


class SolidState(Protocol):
    """What a frame of a solid holds (:class:`~bhem_hpc.solids.model.SolidFrame`)."""

    parts: list[NurbsSurface]
    positions: np.ndarray
    stresses: np.ndarray
    volumes: np.ndarray


class SolidTimeSeries:
    """A solid's frames that ParaView plays as an animation: ``<name>_frames/frame_<k>_boundary.vtu``
    and ``frame_<k>_points.vtu`` (:func:`write_solid_files`), listed by ``<name>.pvd`` (the
    boundaries) and ``<name>_points.pvd`` (the quadrature points), rewritten after every frame.

    Args:
        path: the series' name (its suffix is dropped: ``body/surface.xdmf`` writes ``body/surface.pvd``).
        rest_parts: the parts at rest (displacements are from them).
        samples: tessellation points per part side, or each part's grid (:func:`part_grids`).
        continue_at: continue the series there: its frames up to that time are kept, later ones
            (written after the checkpoint being continued) removed.
    """

    def __init__(self, path: str | Path, rest_parts: Sequence[NurbsSurface], samples: int | Sequence[PartGrid] = 9,
                 continue_at: float | None = None):  # fmt: skip
        path = Path(path)
        self.pvd_path = path.with_suffix(".pvd")
        self.points_pvd_path = path.with_name(path.stem + "_points.pvd")
        self.folder = path.with_name(path.stem + "_frames")
        self.rest_parts, self.samples = list(rest_parts), samples
        self.times: list[float] = []
        if continue_at is not None:
            self._continue(continue_at)
        self.folder.mkdir(exist_ok=True)

    def _continue(self, until: float) -> None:
        if not self.pvd_path.is_file():
            raise InputError(f"{self.pvd_path} does not exist: there is no series to continue")
        listed = pvd_times(self.pvd_path)
        tolerance = 1e-9 * max(abs(until), 1e-300)
        self.times = [t for t in listed if t <= until + tolerance]
        for stale in [*self.folder.glob("frame_*.vtu"), *self.folder.glob("frame_*.igs")]:
            index = re.match(r"frame_(\d+)[_.]", stale.name)
            if index is not None and int(index.group(1)) >= len(self.times):
                stale.unlink()

    def write(self, time: float, state: SolidState) -> None:
        """Append a frame of ``state`` at ``time`` and list it."""
        write_solid_files(self.folder, state.parts, self.rest_parts, state.positions, state.stresses, state.volumes,
                          stem=f"frame_{len(self.times):06d}", samples=self.samples)  # fmt: skip
        write_parts(self.model_file(len(self.times)), state.parts)
        self.times.append(float(time))
        write_pvd(self.pvd_path, self.frame_files())
        points = [(t, file.replace("_boundary.vtu", "_points.vtu")) for t, file in self.frame_files()]
        write_pvd(self.points_pvd_path, points)

    def model_file(self, frame: int) -> Path:
        """The deformed model of frame ``frame`` as IGES (its parts, exact: it opens in a modeller and
        ``bhem-hpc render`` draws it)."""
        return self.folder / f"frame_{frame:06d}.igs"

    def frame_files(self) -> list[tuple[float, str]]:
        """``(time, boundary file relative to the series' folder)`` of every frame written."""
        return [(t, f"{self.folder.name}/frame_{k:06d}_boundary.vtu") for k, t in enumerate(self.times)]

    def close(self) -> None:
        """Every frame is complete once written: nothing is held open."""


def pvd_times(pvd: Path) -> list[float]:
    """The times of the frames a ParaView collection lists, in its order."""
    return [float(d.get("timestep")) for d in ET.parse(pvd).getroot().iter("DataSet")]


@dataclass(frozen=True)
class SolidParts:
    """A solid's frame as its NURBS parts (what the ray tracer draws of a solid)."""

    parts: list[NurbsSurface]


def read_solid_frame(pvd: str | Path, frame: int = -1) -> tuple[SolidParts, float]:
    """The parts and time of frame ``frame`` (negative: from the end) of the solid series listed by
    ``pvd`` (``<body>/surface.pvd``), from its IGES file.

    Raises:
        InputError: no such series or frame, or an unreadable model file.
    """
    pvd = Path(pvd)
    try:
        times = pvd_times(pvd)
    except (OSError, ET.ParseError, TypeError, ValueError) as exc:
        raise InputError(f"{pvd}: not a readable series of a solid ({exc})") from None
    if not -len(times) <= frame < len(times):
        raise InputError(f"{pvd}: frame {frame} does not exist (the series has {len(times)} frames)")
    index = frame % len(times)
    path = pvd.with_name(pvd.stem + "_frames") / f"frame_{index:06d}.igs"
    try:
        return SolidParts(read_parts(path)), times[index]
    except (OSError, SurfaceError) as exc:
        raise InputError(f"{path}: the model of frame {index} cannot be read ({exc})") from None
