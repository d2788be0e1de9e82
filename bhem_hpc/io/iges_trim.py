"""Trimmed surfaces in IGES files (numpy only): entity 144 and the curves that bound it.

A trimmed surface (144) points to its surface (128), to the curve on the surface that bounds it
outside (142; none: the surface's own boundary) and to those that cut holes in it. Each curve on
a surface gives its curve in the surface's parameter space (``BPTR``): a rational B-spline curve
(126), a line (110) or a composite curve (102) of those. Such a curve is sampled into a closed
polygon in the parameters (:data:`SAMPLES_PER_SPAN` points per knot span, the ends of consecutive
pieces shared): the loops a trimmed shell takes (:mod:`bhem_hpc.geometry.trim`). A curve on a
surface that has only its model-space curve, or a curve entity of another type, is refused with
its file and entity named.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bhem_hpc.geometry.nurbs import KnotDirection
from bhem_hpc.geometry.surface import SurfaceError
from bhem_hpc.geometry.trim import close_loop
from bhem_hpc.io.cad import iges_numbers

#: Points sampled on each knot span of a parameter-space B-spline curve (a trimmed shell's loops
#: follow the curve within its chords' sagitta).
SAMPLES_PER_SPAN = 24
#: Curves a composite curve may chain (bounds the walk through pointers).
MAX_COMPOSITE = 10_000


def _bspline_curve(values: np.ndarray, where: str) -> np.ndarray:
    """Points ``(n, 2)`` along a rational B-spline curve (126) in a surface's parameters."""
    try:
        count, degree = int(values[0]) + 1, int(values[1])
        at = 6
        knots = values[at : at + count + degree + 1]
        at += count + degree + 1
        weights = values[at : at + count]
        at += count
        control = values[at : at + 3 * count].reshape(count, 3)
        at += 3 * count
        start, end = values[at], values[at + 1]
    except (IndexError, ValueError) as error:
        raise SurfaceError(f"{where}: entity 126 parameters are malformed ({error})") from None
    direction = KnotDirection.of(knots, degree, count, "trim curve")
    breaks = np.unique(np.clip(knots, start, end))
    t = np.unique(np.concatenate([np.linspace(a, b, SAMPLES_PER_SPAN + 1) for a, b in zip(breaks[:-1], breaks[1:],
                                                                                         strict=True)]))  # fmt: skip
    first, basis = direction.basis(t)
    index = first[:, None] + np.arange(degree + 1)
    weighted = basis[0] * weights[index]
    points = np.einsum("sa,sab->sb", weighted, control[index, :2]) / weighted.sum(axis=1)[:, None]
    return points


def _curve(entities, pointer: int, where: str, depth: int = 0) -> np.ndarray:
    """Points ``(n, 2)`` along the parameter-space curve at ``pointer`` (126, 110 or 102)."""
    if pointer not in entities:
        raise SurfaceError(f"{where}: points to D{pointer}, which is not in the file")
    kind, _, _, fields, _ = entities[pointer]
    at = f"{where}: D{pointer}"
    if kind == 126:
        return _bspline_curve(iges_numbers(fields), at)
    if kind == 110:
        values = iges_numbers(fields)
        return np.array([values[0:2], values[3:5]])
    if kind == 102 and depth == 0:
        values = iges_numbers(fields)
        count = int(values[0])
        if not 1 <= count <= MAX_COMPOSITE or len(values) < count + 1:
            raise SurfaceError(f"{at}: a composite curve (102) of {count} curves, with {len(values) - 1} pointers")
        pieces = [_curve(entities, int(p), where, depth + 1) for p in values[1 : count + 1]]
        return np.concatenate([pieces[0]] + [piece[1:] for piece in pieces[1:]])
    raise SurfaceError(f"{at}: a trim curve in the surface's parameters must be a B-spline curve (126), a line (110) "
                       f"or a composite curve (102) of them, got entity {kind}")  # fmt: skip


def _loop(entities, pointer: int, where: str) -> np.ndarray:
    """The closed polygon ``(n, 2)`` (its first point repeated at its end) of the curve on a
    surface (142) at ``pointer``."""
    kind, _, _, fields, _ = entities.get(pointer, (None, 0, "", [], ""))
    if kind != 142:
        raise SurfaceError(f"{where}: D{pointer} is not a curve on a surface (entity 142), got {kind}")
    values = iges_numbers(fields)
    parameter_curve = int(values[2]) if len(values) > 2 else 0
    if not parameter_curve:
        raise SurfaceError(f"{where}: the curve on the surface D{pointer} has no curve in the surface's parameters "
                           "(only its model-space curve); export trims with their parameter-space curves")  # fmt: skip
    return close_loop(_curve(entities, parameter_curve, f"{where}: D{pointer}"))


def trimmed_surfaces(entities, path: Path) -> dict[int, tuple[int, np.ndarray | None, list[np.ndarray]]]:
    """Every trimmed surface (144) of a file's ``entities`` (as :func:`bhem_hpc.io.cad._iges_entities`
    reads them): ``{its directory pointer: (its surface's pointer, its outer loop or None: the
    surface's own boundary, its holes' loops)}``."""
    out = {}
    for pointer, (kind, _, _, fields, _) in entities.items():
        if kind != 144:
            continue
        where = f"{path}: trimmed surface D{pointer}"
        values = iges_numbers(fields)
        try:
            surface, outer_given, holes, outer = int(values[0]), int(values[1]), int(values[2]), int(values[3])
            inner = [int(v) for v in values[4 : 4 + holes]]
        except (IndexError, ValueError) as error:
            raise SurfaceError(f"{where}: entity 144 parameters are malformed ({error})") from None
        if entities.get(surface, (None,))[0] != 128:
            raise SurfaceError(f"{where}: its surface D{surface} is not a rational B-spline surface (entity 128)")
        out[pointer] = (surface, _loop(entities, outer, where) if outer_given else None,
                        [_loop(entities, p, where) for p in inner])  # fmt: skip
    return out
