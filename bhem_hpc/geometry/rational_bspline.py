"""Rational B-spline (NURBS) shell surfaces of degree 2 and 3 on a uniform grid of spans, numpy only.

``x(xi) = sum_i w_i N_i(xi) q_i / W(xi)`` with ``W = sum_i w_i N_i``: the B-spline basis ``N`` of
:mod:`.bspline` (uniform knot spans, clamped or periodic), control points ``q (c1, c2, 3)`` and
fixed positive weights ``w (c1, c2)``. With the weights fixed, a point, and every parametric
derivative of it, is still a *linear* map of the control points (the rational basis
``R_i = w_i N_i / W`` and its quotient-rule derivatives), so the control points are the unknowns as
for polynomial B-splines; the homogeneous field ``Y = W x = sum_i N_i (w_i q_i)`` is a polynomial
B-spline, what the shell discretization assembles (:mod:`bhem_hpc.discretization.rational`).

CAD parts (:class:`~bhem_hpc.geometry.nurbs.NurbsSurface`), each interior knot once, are carried
over exactly by knot insertion (:func:`on_uniform_knots`): onto the uniform lattice of their knots
where they have one (circular arcs, cylinders, spheres and tori from revolutions, the uniform parts
modellers write), else on their own knots, the shell's uniform spans mapped onto the knot intervals.
"""

from __future__ import annotations

import math

import numpy as np

from bhem_hpc.geometry.bspline import (
    BSplinePatches,
    BSplineSurface,
    Knots,
    bezier_extraction,
    check_degree,
    clamped_uniform_knots,
    point_weights,
    span_extraction,
)
from bhem_hpc.geometry.grid import ParameterGrid
from bhem_hpc.geometry.nurbs import NurbsSurface
from bhem_hpc.geometry.surface import SurfaceError, SurfacePoint

#: The finest uniform knot lattice searched for a part's knots (spans per direction).
MAX_LATTICE = 512
#: A knot lies on the lattice when within this fraction of the parameter range of a lattice point.
LATTICE_TOLERANCE = 1e-9


def rational_point_weights(grid: ParameterGrid, degree: int, weights: np.ndarray, p1, p2, t1, t2, d1: int = 0,
                           d2: int = 0, knots: Knots | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
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
        index, values = point_weights(grid, degree, p1, p2, t1, t2, a, b, knots)
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

    def __init__(self, grid: ParameterGrid, degree: int, weights: np.ndarray, knots: Knots | None = None):
        super().__init__(grid, degree)
        self.weights = np.asarray(weights, dtype=float)
        self.knots = knots
        self.control_shape = control_shape(grid, self.degree, knots)

    def point_entries(self, p1, p2, t1, t2) -> tuple[np.ndarray, np.ndarray]:
        """``(index, values)``, shape ``S + ((p + 1)^2,)`` each: the rational basis at the points."""
        return rational_point_weights(self.grid, self.degree, self.weights, p1, p2, t1, t2, knots=self.knots)

    def patch_entries(self) -> np.ndarray:
        """``(n1 * n2, (p + 1)^2)`` the control points that determine each span."""
        p1, p2 = (a.ravel() for a in np.meshgrid(np.arange(self.grid.n1), np.arange(self.grid.n2), indexing="ij"))
        return point_weights(self.grid, self.degree, p1, p2, 0.5, 0.5, knots=self.knots)[0]

    def bezier_nets(self, entries: np.ndarray) -> np.ndarray:
        raise SurfaceError("a rational B-spline span has no polynomial Bezier net: contact between steps "
                           "(method 'impulse') needs polynomial patches; rational shells take 'ipc'")  # fmt: skip


class RationalBSplineSurface(BSplineSurface):
    """A rational tensor-product B-spline surface of degree 2 or 3 on a uniform grid of spans.

    Args:
        grid, degree, control: as :class:`~bhem_hpc.geometry.bspline.BSplineSurface`.
        weights: ``(c1, c2)`` positive, finite weights of the control points (fixed: they are
            geometry of the parametrization, not unknowns).
        knots: per direction None (the grid's uniform knots) or the part's own clamped knot vector
            ``(n + 2 p + 1,)`` over the grid's range, each interior knot once: the surface's
            parameter ``s`` then runs over the grid's uniform spans, span ``k`` mapped affinely onto
            knot interval ``k`` (:meth:`model_parameters`). Every energy is the same in either
            parameter; the basis is the part's own.
    """

    def __init__(self, grid: ParameterGrid, degree: int, control: np.ndarray, weights: np.ndarray,
                 knots: Knots | None = None):  # fmt: skip
        self.knots = _checked_knot_pair(knots, grid, check_degree(degree))
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

    def _expected_control_shape(self, grid: ParameterGrid, degree: int) -> tuple[int, int]:
        return control_shape(grid, degree, self.knots)

    def with_nodal(self, nodal: np.ndarray) -> RationalBSplineSurface:
        """The surface with other control points ``(c1, c2, 1, 3)`` and the same weights."""
        return RationalBSplineSurface(self.grid, self.degree, np.asarray(nodal)[:, :, 0, :], self.weights, self.knots)

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> RationalBSplineSurface:
        """The surface moved rigidly (control points transform alike; the weights stay)."""
        moved = self.control @ np.asarray(rotation, float).T + np.asarray(translation, float)
        return RationalBSplineSurface(self.grid, self.degree, moved, self.weights, self.knots)

    def _direction(self, axis: int) -> tuple[np.ndarray, np.ndarray, float]:
        return span_extraction(self.grid, self.degree, axis, self.knots)

    def point_weights(self, p1, p2, t1, t2, d1: int = 0, d2: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """See :func:`rational_point_weights`."""
        return rational_point_weights(self.grid, self.degree, self.weights, p1, p2, t1, t2, d1, d2, self.knots)

    def evaluate(self, xi1: np.ndarray, xi2: np.ndarray) -> SurfacePoint:
        """Position and first and second parametric derivatives at parameters of shape ``S``, by the
        rational weights of :meth:`point_weights` (linear in the control points, the weights fixed)."""
        p1, p2, t1, t2 = self.grid.locate(xi1, xi2)
        flat = self.control.reshape(-1, 3)

        def derivative(d1: int, d2: int) -> np.ndarray:
            index, weights = self.point_weights(p1, p2, t1, t2, d1, d2)
            return np.einsum("...j,...jc->...c", weights, flat[index])

        return SurfacePoint.of(derivative)

    def homogeneous_nets(self) -> np.ndarray:
        """Exact rational Bezier nets ``(n1, n2, p + 1, p + 1, 4)`` of every span: ``(w x, w y, w z, w)``."""
        homogeneous = np.concatenate([self.control * self.weights[..., None], self.weights[..., None]], axis=-1)
        return bezier_extraction(homogeneous, self._direction(0), self._direction(1))

    def bezier_nets(self) -> np.ndarray:
        raise SurfaceError("a rational B-spline surface has no polynomial Bezier nets (see homogeneous_nets)")

    def model_parameters(self, xi1: np.ndarray, xi2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The part's own parameters of the surface's parameters (the same where the knots are uniform)."""
        return tuple(_to_knots(x, k, lo, h) for x, k, (lo, _), h in
                     zip((xi1, xi2), self.knots or (None, None), (self.grid.xi1_range, self.grid.xi2_range),
                         (self.grid.h1, self.grid.h2), strict=True))  # fmt: skip

    def surface_parameters(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The inverse of :meth:`model_parameters`: the surface's parameters of the part's own."""
        return tuple(_from_knots(x, k, lo, h) for x, k, (lo, _), h in
                     zip((u, v), self.knots or (None, None), (self.grid.xi1_range, self.grid.xi2_range),
                         (self.grid.h1, self.grid.h2), strict=True))  # fmt: skip

    def nurbs(self, name: str = "shell") -> NurbsSurface:
        """The same surface as a :class:`NurbsSurface` over its own knots (clamped directions only):
        for writing the model back."""
        if self.grid.periodic1 or self.grid.periodic2:
            raise SurfaceError("a periodic rational B-spline surface has no clamped NURBS form here")
        knots = [clamped_uniform_knots(n, self.degree, lo, hi) if own is None else own for n, (lo, hi), own in
                 zip((self.grid.n1, self.grid.n2), (self.grid.xi1_range, self.grid.xi2_range),
                     self.knots or (None, None), strict=True)]  # fmt: skip
        return NurbsSurface((self.degree, self.degree), *knots, self.control, self.weights, name)

    def save(self, path) -> None:
        raise SurfaceError("rational B-spline surfaces are written as NURBS parts (IGES or .3dm), not as .npz")


def control_shape(grid: ParameterGrid, degree: int, knots: Knots | None) -> tuple[int, int]:
    """Control points ``(c1, c2)`` on ``grid``: ``n + p`` per direction on uniform knots, as many as
    a direction's own knots have basis functions (repeated interior knots add to them)."""
    uniform = BSplineSurface.control_shape_of(grid, degree)
    return tuple(count if own is None else len(own) - degree - 1 for count, own in zip(uniform, knots or (None, None),
                                                                                        strict=True))  # fmt: skip


def _checked_knot_pair(knots: Knots | None, grid: ParameterGrid, degree: int) -> Knots | None:
    """Each direction's own knots checked (:func:`_checked_knots`); None where both are uniform."""
    if knots is None or (knots[0] is None and knots[1] is None):
        return None
    if knots[0] is not None and grid.periodic1 or knots[1] is not None and grid.periodic2:
        raise SurfaceError("a periodic direction has uniform knots: own knots are for clamped directions")
    return tuple(None if k is None else _checked_knots(k, n, degree, r, axis) for axis, (k, n, r) in
                 enumerate(zip(knots, (grid.n1, grid.n2), (grid.xi1_range, grid.xi2_range), strict=True)))  # fmt: skip


def _checked_knots(knots, spans: int, degree: int, domain: tuple[float, float], axis: int) -> np.ndarray:
    """A clamped knot vector over ``domain`` of ``spans`` nonempty spans, interior knots repeated
    fewer times than the degree (the surface at least C1)."""
    knots = np.asarray(knots, dtype=float)
    ends = np.any(knots[: degree + 1] != domain[0]) or np.any(knots[-degree - 1 :] != domain[1])
    interior = knots[degree + 1 : -degree - 1] if knots.ndim == 1 and len(knots) > 2 * degree + 2 else knots[:0]
    values, counts = np.unique(interior, return_counts=True)
    inside = np.all((values > domain[0]) & (values < domain[1]))
    if ends or not inside or len(values) + 1 != spans or np.any(counts >= degree):
        raise SurfaceError(f"knots of direction {axis + 1} must be clamped over {domain} with {spans} nonempty spans, "
                           f"interior knots repeated fewer than {degree} times, got {knots.tolist()}")  # fmt: skip
    return knots


def _to_knots(x: np.ndarray, knots: np.ndarray | None, lo: float, h: float) -> np.ndarray:
    """Parameters on uniform spans of width ``h`` from ``lo``, mapped onto the knot intervals."""
    if knots is None:
        return np.asarray(x, dtype=float)
    breaks = np.unique(knots)
    position = (np.asarray(x, dtype=float) - lo) / h
    span = np.clip(np.floor(position).astype(np.int64), 0, len(breaks) - 2)
    return breaks[span] + (position - span) * (breaks[span + 1] - breaks[span])


def _from_knots(x: np.ndarray, knots: np.ndarray | None, lo: float, h: float) -> np.ndarray:
    """The inverse of :func:`_to_knots`."""
    if knots is None:
        return np.asarray(x, dtype=float)
    breaks = np.unique(knots)
    span = np.clip(np.searchsorted(breaks, x, side="right") - 1, 0, len(breaks) - 2)
    return lo + h * (span + (np.asarray(x, dtype=float) - breaks[span]) / (breaks[span + 1] - breaks[span]))


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


def _distinct_interior(knots: np.ndarray, degree: int, name: str,
                       where: str) -> tuple[np.ndarray, np.ndarray, float, float]:  # fmt: skip
    """``(distinct interior knots, their multiplicities, lo, hi)`` of a clamped direction whose
    interior knots repeat fewer times than the degree."""
    lo, hi = float(knots[degree]), float(knots[-degree - 1])
    if np.any(knots[: degree + 1] != lo) or np.any(knots[-degree - 1 :] != hi):
        raise SurfaceError(f"{where}: the {name} knots are not clamped (degree + 1 equal end knots): "
                           f"{knots.tolist()}")  # fmt: skip
    values, counts = np.unique(knots[degree + 1 : -degree - 1], return_counts=True)
    if np.any(counts >= degree):
        raise SurfaceError(f"{where}: the {name} knot {values[counts >= degree][0]!r} repeats "
                           f"{counts[counts >= degree][0]} times: the part is only C0 there, where an exact patch "
                           "needs C1; cut it there (split_at_kinks, as cad_shell does), or take a polynomial "
                           "discretization, which interpolates it")  # fmt: skip
    return values, counts, lo, hi


def _lattice(values: np.ndarray, lo: float, hi: float) -> int | None:
    """The coarsest uniform lattice (spans over [lo, hi], at most :data:`MAX_LATTICE`) holding every
    interior knot, or None."""
    relative = (values - lo) / (hi - lo)
    for spans in range(1, MAX_LATTICE + 1):
        if np.all(np.abs(relative * spans - np.rint(relative * spans)) <= LATTICE_TOLERANCE * spans):
            return spans
    return None


def _refined(knots: np.ndarray, degree: int, homogeneous: np.ndarray, wanted: int, name: str,
             where: str) -> tuple[np.ndarray | None, int, tuple[float, float], np.ndarray]:  # fmt: skip
    """One direction refined by knot insertion to at least ``wanted`` spans: onto the uniform
    lattice of its knots where that lattice is at most twice as fine as needed (then ``knots`` is
    None: the uniform knots), else by cutting each of its spans into equal parts (its own knots)."""
    values, counts, lo, hi = _distinct_interior(knots, degree, name, where)
    existing = len(values) + 1
    lattice = _lattice(values, lo, hi) if np.all(counts == 1) else None  # repeated knots: its own
    if lattice is not None and lattice * math.ceil(wanted / lattice) <= 2 * max(wanted, existing):
        count = lattice * math.ceil(wanted / lattice)
        new = [v for v in lo + (hi - lo) * np.arange(1, count) / count
               if not np.any(np.abs(knots - v) <= LATTICE_TOLERANCE * (hi - lo))]  # fmt: skip
        uniform = True
    else:
        parts = math.ceil(wanted / existing)
        breaks = np.r_[lo, values, hi]
        new = [a + (b - a) * k / parts for a, b in zip(breaks[:-1], breaks[1:], strict=True) for k in range(1, parts)]
        count, uniform = existing * parts, False
    for value in new:
        knots, homogeneous = insert_knot(knots, degree, homogeneous, value)
    return None if uniform else knots, count, (lo, hi), homogeneous


def on_uniform_knots(part: NurbsSurface, spans: tuple[int, int], degree: int | None = None) -> RationalBSplineSurface:
    """The part, exactly, as a rational B-spline of ``degree`` (default: its higher degree, at least
    2: a bilinear part, as a modeller's planar face, is raised) on a uniform grid of at least
    ``spans`` knot spans per direction (knot insertion; unclamped knots are clamped first): on the
    uniform lattice of its knots where it has a fine enough one (circles, revolutions, most
    modellers' uniform parts), else (or where interior knots repeat) on its own knots, each span cut
    into equal parts, the grid's uniform spans mapped onto them (:class:`RationalBSplineSurface`'s
    ``knots``). A direction of a lower degree is raised exactly where it is one span (a ruled part's
    straight direction, an arc).

    Raises:
        SurfaceError: naming the part: a degree other than 2 or 3, a lower-degree direction of
            several spans, an interior knot repeated as often as the degree (only C0 there).
    """
    p = max(2, *part.degrees) if degree is None else degree
    if p not in (2, 3) or p < max(part.degrees):
        raise SurfaceError(f"{part.name}: an exact (rational) shell patch has degree 2 or 3; the part has degrees "
                           f"{part.degrees}: a polynomial discretization interpolates it")  # fmt: skip
    part = clamped(part)
    homogeneous = part.homogeneous
    directions = []
    for axis, (direction, name, wanted) in enumerate(((part.u, "u", spans[0]), (part.v, "v", spans[1]))):
        moved = np.moveaxis(homogeneous, axis, 0)
        knots, moved = _elevated(direction.knots, direction.degree, moved, p, name, part.name)
        own, count, domain, moved = _refined(knots, p, moved, int(wanted), name, part.name)
        homogeneous = np.moveaxis(moved, 0, axis)
        directions.append((own, count, domain))
    (knots1, n1, range1), (knots2, n2, range2) = directions
    grid = ParameterGrid(n1, n2, range1, range2, False, False)
    weights = homogeneous[..., 3]
    return RationalBSplineSurface(grid, p, homogeneous[..., :3] / weights[..., None], weights, (knots1, knots2))


def _clamp_start(knots: np.ndarray, degree: int, homogeneous: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An unclamped start (as a modeller's periodic parts have) clamped along the first axis: the
    domain's first knot inserted up to multiplicity ``p``, then the knots and control points
    before it dropped (a basis function's piece on the domain depends on its knots from there on)."""
    lo = knots[degree]
    while np.count_nonzero(knots[: degree + 1] == lo) < degree + 1:
        if np.count_nonzero(knots == lo) >= degree:  # the point at lo interpolated: drop what lies before
            first = int(np.flatnonzero(knots == lo)[0])
            return np.r_[lo, knots[first:]], homogeneous[first - 1 :]
        knots, homogeneous = insert_knot(knots, degree, homogeneous, lo)
    return knots, homogeneous


def clamped(part: NurbsSurface) -> NurbsSurface:
    """The part with clamped knot vectors, the same surface over its domain (unchanged if clamped)."""
    homogeneous, knots = part.homogeneous, []
    for axis, direction in enumerate((part.u, part.v)):
        moved, k = np.moveaxis(homogeneous, axis, 0), direction.knots
        k, moved = _clamp_start(k, direction.degree, moved)
        k, moved = _clamp_start(-k[::-1], direction.degree, moved[::-1])  # the end, as a start reversed
        homogeneous, knots = np.moveaxis(moved[::-1], 0, axis), [*knots, -k[::-1]]
    return NurbsSurface(part.degrees, *knots, homogeneous[..., :3] / homogeneous[..., 3:], homogeneous[..., 3],
                        part.name)  # fmt: skip


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
    part = clamped(part)
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


def _join_direction(pieces: list[tuple[np.ndarray, np.ndarray]], degree: int) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`_split_direction`: pieces ``(knots, homogeneous)`` along the first axis,
    each starting with the last control row of the one before, joined with the seam knots repeated
    ``p`` times (only C0 there)."""
    knots, rows = pieces[0][0][:-1], [pieces[0][1]]
    for piece_knots, homogeneous in pieces[1:]:
        knots = np.r_[knots, piece_knots[degree + 1 : -1]]
        rows.append(homogeneous[1:])
    return np.r_[knots, pieces[-1][0][-1]], np.concatenate(rows)


def join_pieces(pieces: list[list[NurbsSurface]], name: str) -> NurbsSurface:
    """One part of pieces ``[i][j]`` (:func:`split_at_kinks`'s, each clamped, of one degree;
    neighbours along u with the same v knots and the same control points on their common edge,
    and alike along v): the seams become knots of multiplicity equal to the degree. The first
    piece's control points along each seam are kept."""
    p, q = pieces[0][0].degrees
    rows = []
    for row in pieces:
        joined = _join_direction([(piece.v.knots, np.moveaxis(piece.homogeneous, 1, 0)) for piece in row], q)
        rows.append((row[0].u.knots, np.moveaxis(joined[1], 0, 1), joined[0]))
    knots_u, homogeneous = _join_direction([(k, h) for k, h, _ in rows], p)
    return NurbsSurface((p, q), knots_u, rows[0][2], homogeneous[..., :3] / homogeneous[..., 3:], homogeneous[..., 3],
                        name)  # fmt: skip
