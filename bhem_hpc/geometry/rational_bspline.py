"""Rational B-spline (NURBS) shell surfaces of degree 2 and 3 on uniform knots, numpy only.

``x(xi) = sum_i w_i N_i(xi) q_i / W(xi)`` with ``W = sum_i w_i N_i``: the B-spline basis ``N`` of
:mod:`.bspline` (uniform knot spans, clamped or periodic), control points ``q (c1, c2, 3)`` and
fixed positive weights ``w (c1, c2)``. With the weights fixed, a point, and every parametric
derivative of it, is still a *linear* map of the control points (the rational basis
``R_i = w_i N_i / W`` and its quotient-rule derivatives), so the control points are the unknowns as
for polynomial B-splines; the homogeneous field ``Y = W x = sum_i N_i (w_i q_i)`` is a polynomial
B-spline, what the shell discretization assembles (:mod:`bhem_hpc.discretization.rational`).

CAD parts (:class:`~bhem_hpc.geometry.nurbs.NurbsSurface`) on knots that lie on a uniform lattice,
each interior knot once, are carried over exactly by knot insertion (:func:`on_uniform_knots`):
circular arcs, cylinders, spheres and tori from revolutions, and the uniform parts modellers write.
"""

from __future__ import annotations

import math

import numpy as np

from bhem_hpc.geometry.bspline import BSplinePatches, BSplineSurface, point_weights
from bhem_hpc.geometry.grid import ParameterGrid
from bhem_hpc.geometry.nurbs import NurbsSurface
from bhem_hpc.geometry.surface import SurfaceError

#: The finest uniform knot lattice searched for a part's knots (spans per direction).
MAX_LATTICE = 512
#: A knot lies on the lattice when within this fraction of the parameter range of a lattice point.
LATTICE_TOLERANCE = 1e-9


def rational_point_weights(grid: ParameterGrid, degree: int, weights: np.ndarray, p1, p2, t1, t2, d1: int = 0,
                           d2: int = 0) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The rational counterpart of :func:`~bhem_hpc.geometry.bspline.point_weights`: ``(index,
    values)`` of shape ``S + ((p + 1)^2,)`` with ``d^(d1+d2) x / dxi1^d1 dxi2^d2 = sum_j values[..., j]
    control.reshape(-1, 3)[index[..., j]]`` for ``d1 + d2 <= 2``, ``weights (c1, c2)``.

    The quotient rule on ``W x = Y``: ``R = w N / W``; ``R_a = (w N_a - R W_a) / W``;
    ``R_ab = (w N_ab - R_a W_b - R_b W_a - R W_ab) / W``.
    """
    if d1 + d2 > 2:
        raise SurfaceError(f"rational derivatives up to order 2, got ({d1}, {d2})")
    flat_weights = np.asarray(weights, dtype=float).ravel()

    def homogeneous(a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        index, values = point_weights(grid, degree, p1, p2, t1, t2, a, b)
        weighted = values * flat_weights[index]
        return index, weighted, weighted.sum(axis=-1, keepdims=True)

    index, n0, w0 = homogeneous(0, 0)
    r0 = n0 / w0
    if (d1, d2) == (0, 0):
        return index, r0
    first = {}
    for a, b in ((1, 0), (0, 1)):
        if (d1, d2) == (a, b) or d1 + d2 == 2:
            _, n_a, w_a = homogeneous(a, b)
            first[a, b] = ((n_a - r0 * w_a) / w0, w_a)
    if d1 + d2 == 1:
        return index, first[d1, d2][0]
    _, n_ab, w_ab = homogeneous(d1, d2)
    (r_1, w_1), (r_2, w_2) = first[1, 0], first[0, 1]
    if (d1, d2) == (1, 1):
        return index, (n_ab - r_1 * w_2 - r_2 * w_1 - r0 * w_ab) / w0
    r_a, w_a = (r_1, w_1) if d1 == 2 else (r_2, w_2)
    return index, (n_ab - 2.0 * r_a * w_a - r0 * w_ab) / w0


class RationalBSplinePatches(BSplinePatches):
    """The knot spans of a rational B-spline surface as linear maps of its control points.

    Points and their weights are rational (:func:`rational_point_weights`); a rational span has no
    polynomial Bezier net, so :meth:`bezier_nets` refuses: the collision queries that need one
    (the impulse response's continuous collision detection) do not run on rational shells.
    """

    def __init__(self, grid: ParameterGrid, degree: int, weights: np.ndarray):
        super().__init__(grid, degree)
        self.weights = np.asarray(weights, dtype=float)

    def point_entries(self, p1, p2, t1, t2) -> tuple[np.ndarray, np.ndarray]:
        """``(index, values)``, shape ``S + ((p + 1)^2,)`` each: the rational basis at the points."""
        return rational_point_weights(self.grid, self.degree, self.weights, p1, p2, t1, t2)

    def bezier_nets(self, entries: np.ndarray) -> np.ndarray:
        raise SurfaceError("a rational B-spline span has no polynomial Bezier net: contact between steps "
                           "(method 'impulse') needs polynomial patches; rational shells take 'ipc'")  # fmt: skip


class RationalBSplineSurface(BSplineSurface):
    """A rational tensor-product B-spline surface of degree 2 or 3 on a uniform knot grid.

    Args:
        grid, degree, control: as :class:`~bhem_hpc.geometry.bspline.BSplineSurface`.
        weights: ``(c1, c2)`` positive, finite weights of the control points (fixed: they are
            geometry of the parametrization, not unknowns).
    """

    def __init__(self, grid: ParameterGrid, degree: int, control: np.ndarray, weights: np.ndarray):
        super().__init__(grid, degree, control)
        weights = np.asarray(weights, dtype=float)
        if weights.shape != self.control.shape[:2]:
            raise SurfaceError(f"weights must have shape {self.control.shape[:2]}, got {weights.shape}")
        if not np.all(np.isfinite(weights)) or np.any(weights <= 0.0):
            i, j = np.argwhere(~(np.isfinite(weights) & (weights > 0.0)))[0]
            raise SurfaceError(f"weights must be positive and finite, got {weights[i, j]!r} at control point "
                               f"({i}, {j})")  # fmt: skip
        self.weights = weights

    @property
    def discretization(self) -> str:
        """The discretization whose DOFs are this surface's control points (with its weights)."""
        return f"nurbs{self.degree}"

    def with_nodal(self, nodal: np.ndarray) -> RationalBSplineSurface:
        """The surface with other control points ``(c1, c2, 1, 3)`` and the same weights."""
        return RationalBSplineSurface(self.grid, self.degree, np.asarray(nodal)[:, :, 0, :], self.weights)

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> RationalBSplineSurface:
        """The surface moved rigidly (control points transform alike; the weights stay)."""
        moved = super().transformed(rotation, translation)
        return RationalBSplineSurface(self.grid, self.degree, moved.control, self.weights)

    def point_weights(self, p1, p2, t1, t2, d1: int = 0, d2: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """See :func:`rational_point_weights`."""
        return rational_point_weights(self.grid, self.degree, self.weights, p1, p2, t1, t2, d1, d2)

    def bezier_control_points(self) -> np.ndarray:
        raise SurfaceError("a rational B-spline surface has no polynomial Bezier nets (see homogeneous_nets)")

    def homogeneous_nets(self) -> np.ndarray:
        """Exact rational Bezier nets ``(n1, n2, p + 1, p + 1, 4)`` of every span: ``(w x, w y, w z, w)``."""
        homogeneous = BSplineSurface(self.grid, self.degree, self.control * self.weights[..., None])
        weight = BSplineSurface(self.grid, self.degree, np.repeat(self.weights[..., None], 3, axis=2))
        return np.concatenate([homogeneous.bezier_control_points(), weight.bezier_control_points()[..., :1]], axis=-1)

    def nurbs(self, name: str = "shell") -> NurbsSurface:
        """The same surface as a :class:`NurbsSurface` (clamped directions only): for the ray tracer
        and for writing the model back."""
        if self.grid.periodic1 or self.grid.periodic2:
            raise SurfaceError("a periodic rational B-spline surface has no clamped NURBS form here")
        knots = [_clamped_knots(n, self.degree, lo, hi) for n, (lo, hi) in
                 ((self.grid.n1, self.grid.xi1_range), (self.grid.n2, self.grid.xi2_range))]  # fmt: skip
        return NurbsSurface((self.degree, self.degree), *knots, self.control, self.weights, name)

    def save(self, path) -> None:
        raise SurfaceError("rational B-spline surfaces are written as NURBS parts (IGES or .3dm), not as .npz")


def _clamped_knots(spans: int, degree: int, lo: float, hi: float) -> np.ndarray:
    inner = np.linspace(lo, hi, spans + 1)
    return np.concatenate([np.full(degree, lo), inner, np.full(degree, hi)])


def insert_knot(knots: np.ndarray, degree: int, homogeneous: np.ndarray, value: float) -> tuple[np.ndarray, np.ndarray]:
    """Boehm's knot insertion along the first axis: ``(knots', homogeneous')`` describing the same
    curves (or surface rows) with ``value`` inserted once; ``homogeneous (n, ..., 4)``."""
    k = int(np.searchsorted(knots, value, side="right") - 1)
    out = np.empty((homogeneous.shape[0] + 1, *homogeneous.shape[1:]))
    out[: k - degree + 1] = homogeneous[: k - degree + 1]
    out[k + 1 :] = homogeneous[k:]
    for i in range(k - degree + 1, k + 1):
        alpha = (value - knots[i]) / (knots[i + degree] - knots[i])
        out[i] = alpha * homogeneous[i] + (1.0 - alpha) * homogeneous[i - 1]
    return np.insert(knots, k + 1, value), out


def _elevated(knots: np.ndarray, degree: int, homogeneous: np.ndarray, target: int, name: str,
              where: str) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A direction of one span (a Bezier curve, as a ruled part's straight direction) raised exactly
    from ``degree`` to ``target`` along the first axis of ``homogeneous (degree + 1, ..., 4)``."""
    if degree == target:
        return knots, homogeneous
    if len(homogeneous) != degree + 1:
        raise SurfaceError(f"{where}: the {name} direction has degree {degree} and several spans; a rational shell "
                           f"patch has one degree ({target}) in both directions")  # fmt: skip
    for r in range(degree, target):  # Q_i = i / (r + 1) P_(i-1) + (1 - i / (r + 1)) P_i
        ratio = (np.arange(r + 2) / (r + 1)).reshape(-1, *([1] * (homogeneous.ndim - 1)))
        padded = np.concatenate([homogeneous[:1] * 0.0, homogeneous, homogeneous[:1] * 0.0])
        homogeneous = ratio * padded[:-1] + (1.0 - ratio) * padded[1:]
    lo, hi = float(knots[0]), float(knots[-1])
    return np.r_[np.full(target + 1, lo), np.full(target + 1, hi)], homogeneous


def _lattice(knots: np.ndarray, degree: int, name: str, where: str) -> tuple[int, float, float]:
    """``(spans, lo, hi)``: the coarsest uniform lattice holding every interior knot of a clamped
    direction, each interior knot appearing once."""
    lo, hi = float(knots[degree]), float(knots[-degree - 1])
    if np.any(knots[: degree + 1] != lo) or np.any(knots[-degree - 1 :] != hi):
        raise SurfaceError(f"{where}: the {name} knots are not clamped (degree + 1 equal end knots): "
                           f"{knots.tolist()}")  # fmt: skip
    interior = knots[degree + 1 : -degree - 1]
    values, counts = np.unique(interior, return_counts=True)
    if np.any(counts > 1):
        raise SurfaceError(f"{where}: the {name} knot {values[counts > 1][0]!r} repeats {counts[counts > 1][0]} "
                           f"times; a shell patch needs each interior knot once (the part is not C{degree - 1} "
                           "there: split it at that knot into parts)")  # fmt: skip
    relative = (values - lo) / (hi - lo)
    for spans in range(1, MAX_LATTICE + 1):
        if np.all(np.abs(relative * spans - np.rint(relative * spans)) <= LATTICE_TOLERANCE * spans):
            return spans, lo, hi
    raise SurfaceError(f"{where}: the {name} knots {values.tolist()} lie on no uniform lattice of at most "
                       f"{MAX_LATTICE} spans: rational shell patches need uniform knot spans")  # fmt: skip


def on_uniform_knots(part: NurbsSurface, spans: tuple[int, int], degree: int | None = None) -> RationalBSplineSurface:
    """The part, exactly, as a rational B-spline of ``degree`` (default: its higher degree) on
    uniform knot spans: the coarsest lattice holding its knots, refined uniformly (by knot
    insertion) to at least ``spans`` per direction (a multiple of the lattice). A direction of a
    lower degree is raised exactly where it is one span (a ruled part's straight direction, an arc).

    Raises:
        SurfaceError: naming the part: a degree other than 2 or 3, a lower-degree direction of
            several spans, knots that are not clamped, repeat inside the domain, or lie on no
            uniform lattice.
    """
    p = max(part.degrees) if degree is None else degree
    if p not in (2, 3) or p < max(part.degrees):
        raise SurfaceError(f"{part.name}: a rational shell patch has degree 2 or 3; the part has degrees "
                           f"{part.degrees}")  # fmt: skip
    homogeneous = part.homogeneous
    directions = []
    for axis, (direction, name, wanted) in enumerate(((part.u, "u", spans[0]), (part.v, "v", spans[1]))):
        moved = np.moveaxis(homogeneous, axis, 0)
        knots, moved = _elevated(direction.knots, direction.degree, moved, p, name, part.name)
        lattice, lo, hi = _lattice(knots, p, name, part.name)
        count = lattice * math.ceil(int(wanted) / lattice)
        for value in lo + (hi - lo) * np.arange(1, count) / count:
            if not np.any(np.abs(knots - value) <= LATTICE_TOLERANCE * (hi - lo)):
                knots, moved = insert_knot(knots, p, moved, value)
        homogeneous = np.moveaxis(moved, 0, axis)
        directions.append((count, (lo, hi)))
    (n1, range1), (n2, range2) = directions
    grid = ParameterGrid(n1, n2, range1, range2, False, False)
    weights = homogeneous[..., 3]
    return RationalBSplineSurface(grid, p, homogeneous[..., :3] / weights[..., None], weights)


def _kinks(knots: np.ndarray, degree: int) -> list[int]:
    """The last index of each interior knot repeated ``degree`` times (where the part is only C0)."""
    values, first, counts = np.unique(knots[degree + 1 : -degree - 1], return_index=True, return_counts=True)
    return [int(degree + 1 + f + c - 1) for f, c in zip(first, counts, strict=True) if c >= degree]


def _split_direction(knots: np.ndarray, degree: int, homogeneous: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The pieces ``(knots, homogeneous)`` of one direction (the first axis) between its C0 knots: a
    knot ``t`` repeated ``p`` times ending at index ``s`` ends a piece at control point ``s - p``
    (the curve passes through it), which the next piece starts with; each piece's knots are clamped
    by one more ``t``."""
    pieces, prefix, first_knot, first_control = [], knots[:0], 0, 0
    for s in _kinks(knots, degree):
        t = knots[s]
        pieces.append((np.r_[prefix, knots[first_knot : s + 1], t], homogeneous[first_control : s - degree + 1]))
        prefix, first_knot, first_control = np.array([t]), s - degree + 1, s - degree
    return [*pieces, (np.r_[prefix, knots[first_knot:]], homogeneous[first_control:])]


def split_at_kinks(part: NurbsSurface) -> list[list[NurbsSurface]]:
    """The part cut along its interior knots of multiplicity equal to the degree (where it is only
    C0, as a circle's quarter points): pieces ``[i][j]`` along u and v, each the same surface over
    its knot box, neighbours sharing their edge's control points and weights exactly."""
    p, q = part.degrees
    rows = _split_direction(part.u.knots, p, part.homogeneous)
    pieces = []
    for i, (knots_u, row) in enumerate(rows):
        columns = _split_direction(part.v.knots, q, np.moveaxis(row, 1, 0))
        pieces.append([NurbsSurface((p, q), knots_u, knots_v, np.moveaxis(block, 0, 1)[..., :3]
                                    / np.moveaxis(block, 0, 1)[..., 3:], np.moveaxis(block, 0, 1)[..., 3],
                                    f"{part.name} piece {i} {j}")
                       for j, (knots_v, block) in enumerate(columns)])  # fmt: skip
    return pieces
