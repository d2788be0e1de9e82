"""A solid's state as ParaView files (VTK XML, float64): its NURBS parts tessellated as one
quadrilateral surface, and its quadrature points with their Cauchy stresses. Serial writers,
numpy only; the arrays come from the solid (:class:`~bhem_hpc.solids.sem.ShapeMatchingSolid`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bhem_hpc.geometry.nurbs import NurbsSurface
from bhem_hpc.io.vtu import VTK_VERTEX, write_vtu


def tessellate_parts(parts: Sequence[NurbsSurface], samples: int = 9):
    """Every part on a ``samples x samples`` parameter grid: points ``(P, 3)``, quadrilaterals
    ``(M, 4)`` (counter-clockwise about ``x_u x x_v``), unit normals ``(P, 3)`` and each point's
    part index ``(P,)``."""
    grid = np.linspace(0.0, 1.0, samples)
    u, v = (a.ravel() for a in np.meshgrid(grid, grid, indexing="ij"))
    cell = np.arange(samples - 1)
    corner = (cell[:, None] * samples + cell[None, :]).ravel()  # (i, j) -> i * samples + j
    local_quads = np.stack([corner, corner + samples, corner + samples + 1, corner + 1], axis=1)
    points, quads, normals, part = [], [], [], []
    for k, surface in enumerate(parts):
        point, x_u, x_v = surface.evaluate(u, v)
        normal = np.cross(x_u, x_v)
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        normals.append(np.divide(normal, length, out=np.zeros_like(normal), where=length > 0))  # poles: 0
        quads.append(local_quads + k * len(u))
        points.append(point)
        part.append(np.full(len(u), float(k)))
    return np.concatenate(points), np.concatenate(quads), np.concatenate(normals), np.concatenate(part)


def write_solid_files(
    directory: str | Path,
    parts: Sequence[NurbsSurface],
    rest_parts: Sequence[NurbsSurface],
    positions: np.ndarray,
    stresses: np.ndarray,
    volumes: np.ndarray,
    stem: str = "solid",
    samples: int = 9,
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
