"""Ray-cast volume quadrature of a solid bounded by NURBS parts (SEM paper §6.3): numpy, the parts'
Bezier extraction, the lines' crossings and the points compiled (:mod:`bhem_hpc.compiled`).

The solid's integral ``int f dV`` becomes, over the bounding box, an integral over the box's face
across ``axis`` of line integrals along ``axis`` (Khosravifard and Hematiyan 2010): lines through
the centres of a grid of cells that tiles that face carry the outer midpoint rule; each line's
inside intervals carry Gauss-Legendre rules of ``order`` points per segment no longer than the
cell's side. Inside is where the winding number of the crossings is nonzero: the CSG union of
overlapping closed parts, whatever they are made of (a part may be one closed surface or one face
of a closed shell). A line whose crossings do not return to winding zero has passed through a gap
of the model (or grazed a fold closer than the crossing search separates); it carries no points,
and :attr:`VolumeQuadrature.open_lines` reports it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from bhem_hpc.compiled.extraction import bezier_nets_by_degree
from bhem_hpc.compiled.line_crossings import raw_crossings
from bhem_hpc.compiled.volume_points import merged_crossings, volume_points
from bhem_hpc.geometry.nurbs import NurbsSurface
from bhem_hpc.geometry.rational_bezier import DUPLICATE_DISTANCE
from bhem_hpc.geometry.surface import SurfaceError

#: Largest share of the lines with inside intervals that may be open before the model is refused.
OPEN_LINE_SHARE = 0.01


@dataclass(frozen=True)
class VolumeQuadrature:
    """Points ``(Q, 3)`` and weights ``(Q,)`` of a volume rule, with what the ray casting saw.

    ``lines`` is the number of lines cast, ``open_lines`` the coordinates ``(L, 2)`` across the axis
    of lines whose crossings did not close, ``seconds`` the wall time per stage.
    """

    points: np.ndarray
    weights: np.ndarray
    axis: int
    spacing: float
    lines: int
    open_lines: np.ndarray
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def volume(self) -> float:
        return float(self.weights.sum())

    def integrate(self, values: np.ndarray) -> np.ndarray:
        """``sum_k weights[k] values[k, ...]`` for values ``(Q, ...)`` at the points."""
        return np.tensordot(self.weights, values, axes=(0, 0))


def model_bounds(parts: Sequence[NurbsSurface]) -> tuple[np.ndarray, np.ndarray]:
    """Box ``(3,), (3,)`` of all control points (it holds every part: the weights are positive)."""
    points = np.concatenate([part.control.reshape(-1, 3) for part in parts])
    return points.min(axis=0), points.max(axis=0)


def _line_grid(lo: np.ndarray, hi: np.ndarray, axis: int, lines_per_side: int):
    """Segment length along the lines (the box's longest side over ``lines_per_side``), the cell
    area, and the lines' coordinates across ``axis``: cell centres of a grid that tiles the box's
    face exactly, with cells no wider than the segment length."""
    # in Python floats: numpy's calls cost more than their arithmetic on three numbers
    low, high = lo.tolist(), hi.tolist()
    spacing = max(b - a for a, b in zip(low, high, strict=True)) / lines_per_side  # the longest side sets it
    widths, centres = [], []
    for a in range(3):
        if a != axis:
            extent = max(high[a] - low[a], 1e-300)
            count = max(1, math.ceil(extent / spacing - 1e-9))
            widths.append(extent / count)
            centres.append(low[a] + widths[-1] * (np.arange(count) + 0.5))
    return spacing, widths[0] * widths[1], centres


@lru_cache(maxsize=16)
def _gauss_legendre(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights ``(order,)`` of the Gauss-Legendre rule on [-1, 1] (read only; numpy
    builds them by an eigenvalue solve, a fifth of a small model's quadrature)."""
    nodes, weights = np.polynomial.legendre.leggauss(order)
    nodes.flags.writeable = weights.flags.writeable = False
    return nodes, weights


def ray_cast_quadrature(
    parts: Sequence[NurbsSurface], lines_per_side: int, order: int = 2, axis: int = 0, name: str = "model"
) -> VolumeQuadrature:
    """Volume rule of the solid bounded by ``parts`` from lines along ``axis``.

    Args:
        parts: the model's NURBS parts (any orientation that is consistent per closed shell: the
            winding rule counts both orientations as inside).
        lines_per_side: the resolution: the bounding box's longest side over the cells' width
            (and the longest segment along a line).
        order: Gauss-Legendre points per segment of an inside interval.
        name: the model's name in errors.

    Raises:
        SurfaceError: the lines found no inside, or more than :data:`OPEN_LINE_SHARE` of them
            passed through gaps (the message says where).
    """
    if isinstance(lines_per_side, bool) or not isinstance(lines_per_side, int) or lines_per_side < 1:
        raise SurfaceError(f"{name}: lines per side must be a positive integer, got {lines_per_side!r}")
    if isinstance(order, bool) or not isinstance(order, int) or not 1 <= order <= 16:
        raise SurfaceError(f"{name}: quadrature order must be an integer in [1, 16], got {order!r}")
    seconds = {}
    clock = time.perf_counter()
    lo, hi = model_bounds(parts)
    spacing, cell_area, (first, second) = _line_grid(lo, hi, axis, lines_per_side)
    lines = len(first) * len(second)
    # one search per patch degree for all parts (a part's crossings met again on another part's
    # seam are merged below, as crossings found twice within a part are)
    crossings = [raw_crossings(nets, axis, first, second) for nets, _ in bezier_nets_by_degree(parts)]
    positions, lines = np.concatenate([c[0] for c in crossings]), np.concatenate([c[1] for c in crossings])
    line, position, direction = merged_crossings(lines[:, 0], positions[:, 0], lines[:, 1],
                                                 DUPLICATE_DISTANCE * float(np.max(hi - lo)))  # fmt: skip
    seconds["crossings"] = time.perf_counter() - clock
    clock = time.perf_counter()
    nodes, node_weights = _gauss_legendre(order)
    points, weights, open_mask, crossed, intervals = volume_points(
        line, position, direction, first, second, axis, spacing, cell_area, nodes, node_weights)
    open_lines = np.stack(
        [first[np.flatnonzero(open_mask) // len(second)], second[np.flatnonzero(open_mask) % len(second)]], axis=1
    )
    if len(open_lines) > OPEN_LINE_SHARE * crossed:
        where = ", ".join(f"({a:.4g}, {b:.4g})" for a, b in open_lines[:3])
        raise SurfaceError(
            f"{name}: {len(open_lines)} of {crossed} lines along {'xyz'[axis]} found no closed inside "
            f"(gaps between parts or inconsistently oriented parts), e.g. through {where}"
        )
    if not intervals:
        raise SurfaceError(f"{name}: no line along {'xyz'[axis]} found an inside; the parts enclose no volume")
    seconds["points"] = time.perf_counter() - clock
    return VolumeQuadrature(points, weights, axis, spacing, lines, open_lines, seconds)
