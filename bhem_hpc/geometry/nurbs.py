"""NURBS surfaces of any degree on non-uniform knots, numpy only.

A :class:`NurbsSurface` is a rational tensor-product B-spline
``x(u, v) = sum_ij N_i(u) M_j(v) w_ij q_ij / sum_ij N_i(u) M_j(v) w_ij`` with control points
``q (n, m, 3)`` indexed ``[i, j, xyz]``, positive weights ``w (n, m)``, degrees ``(p, q)`` and
clamped or unclamped knot vectors of lengths ``n + p + 1`` and ``m + q + 1``. Its parameter domain
is ``[knots_u[p], knots_u[n]] x [knots_v[q], knots_v[m]]``.

Every nonempty knot span pair is a rational Bezier patch: in homogeneous coordinates
``(w x, w y, w z, w)`` the B-spline basis of a span is ``N_local(t) = C @ B(t)`` with the Bernstein
polynomials ``B`` of the span's local coordinate ``t in [0, 1]`` and the span's Bezier extraction
matrix ``C`` (Borden et al. 2011), so :meth:`NurbsSurface.bezier_patches` is exact. The ray
queries of :mod:`.rational_bezier` work on those patches; closest points are in :mod:`.projection`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from bhem_hpc.geometry.affine import AffineFrame, affine_frame
from bhem_hpc.geometry.bspline import basis_functions, bernstein
from bhem_hpc.geometry.bspline import from_callable as bspline_from_callable
from bhem_hpc.geometry.grid import ParameterGrid
from bhem_hpc.geometry.surface import SurfaceError
from bhem_hpc.geometry.surface import from_callable as hermite_from_callable

#: Highest degree accepted: the Bernstein evaluation is exact far beyond, but modellers stop at 11.
MAX_DEGREE = 11


@dataclass(frozen=True)
class KnotDirection:
    """One parameter direction: degree ``p``, knots ``(n + p + 1,)`` and its nonempty spans.

    ``spans (S,)`` holds the knot indices ``k`` of the nonempty intervals ``[knots[k], knots[k+1])``
    with ``p <= k < n``; ``extraction (S, p + 1, p + 1)`` maps Bernstein polynomials on span ``s``
    to its basis functions ``k - p .. k``: ``N_local(t) = extraction[s] @ B(t)``.
    """

    degree: int
    knots: np.ndarray
    spans: np.ndarray
    extraction: np.ndarray

    @staticmethod
    def of(knots: np.ndarray, degree: int, count: int, name: str) -> KnotDirection:
        """Checked direction of ``count`` control points (``name`` appears in errors)."""
        knots = np.asarray(knots, dtype=float)
        if isinstance(degree, bool) or not isinstance(degree, int | np.integer) or not 1 <= degree <= MAX_DEGREE:
            raise SurfaceError(f"NURBS {name} degree must be an integer in [1, {MAX_DEGREE}], got {degree!r}")
        degree = int(degree)
        if count < degree + 1:
            raise SurfaceError(
                f"a degree-{degree} NURBS {name} direction needs at least {degree + 1} control points, got {count}"
            )
        if knots.shape != (count + degree + 1,):
            raise SurfaceError(
                f"NURBS {name} knot vector must have {count + degree + 1} entries (control points + degree + 1), "
                f"got shape {knots.shape}"
            )
        if not np.all(np.isfinite(knots)) or np.any(np.diff(knots) < 0.0):
            raise SurfaceError(f"NURBS {name} knots must be finite and non-decreasing, got {knots.tolist()}")
        interior = np.arange(degree, count)
        spans = interior[knots[interior + 1] > knots[interior]]
        if not len(spans):
            raise SurfaceError(f"NURBS {name} knot vector has no nonempty span in its domain: {knots.tolist()}")
        multiplicity = np.diff(np.flatnonzero(np.r_[True, np.diff(knots[degree : count + 1]) > 0, True]))
        if np.any(multiplicity[1:-1] > degree):
            raise SurfaceError(
                f"NURBS {name} knots repeat more than the degree {degree} inside the domain: {knots.tolist()}"
            )
        samples = (np.arange(degree + 1) + 0.5) / (degree + 1)  # interior points: no knot ambiguity
        inverse = np.linalg.inv(bernstein(samples, degree))
        extraction = np.empty((len(spans), degree + 1, degree + 1))
        for s, k in enumerate(spans):
            local = basis_functions(knots, degree, int(k), knots[k] + samples * (knots[k + 1] - knots[k]))
            extraction[s] = (inverse @ local).T
        return KnotDirection(degree, knots, spans, extraction)

    @property
    def domain(self) -> tuple[float, float]:
        return float(self.knots[self.degree]), float(self.knots[len(self.knots) - self.degree - 1])

    def locate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Span position ``s`` (index into :attr:`spans`) and local coordinate ``t in [0, 1]`` of
        parameters ``x``; the domain's end belongs to the last span."""
        x = np.asarray(x, dtype=float)
        lo, hi = self.domain
        if (
            np.any(~np.isfinite(x))
            or np.any(x < lo - 1e-12 * max(1.0, abs(lo)))
            or np.any(x > hi + 1e-12 * max(1.0, abs(hi)))
        ):
            raise SurfaceError(f"NURBS parameters must lie in the domain [{lo}, {hi}]")
        starts = self.knots[self.spans]
        s = np.clip(np.searchsorted(starts, x, side="right") - 1, 0, len(self.spans) - 1)
        a, b = starts[s], self.knots[self.spans[s] + 1]
        return s, np.clip((x - a) / (b - a), 0.0, 1.0)

    def basis(self, x: np.ndarray, order: int = 0) -> tuple[np.ndarray, list[np.ndarray]]:
        """First control index ``(S,)`` and the ``p + 1`` nonzero basis functions and their
        derivatives in ``x`` up to ``order``, ``order + 1`` arrays ``S + (p + 1,)``, at ``x (S,)``."""
        s, t = self.locate(x)
        width = self.knots[self.spans[s] + 1] - self.knots[self.spans[s]]
        extraction = self.extraction[s]
        values = [
            np.einsum("...ab,...b->...a", extraction, bernstein(t, self.degree, k)) / width[..., None] ** k
            for k in range(order + 1)
        ]
        return self.spans[s] - self.degree, values


@dataclass(frozen=True)
class RationalBezierPatches:
    """The rational Bezier patches of one surface: homogeneous nets and their parameter boxes.

    ``nets (P, p + 1, q + 1, 4)`` holds ``(w x, w y, w z, w)`` indexed ``[patch, i, j, xyzw]`` of
    ``x(s, t) = sum_ij B_i(s) B_j(t) nets[..., :3] / sum_ij B_i(s) B_j(t) nets[..., 3]``, local
    ``s, t in [0, 1]``; ``boxes (P, 4)`` is each patch's ``(u0, u1, v0, v1)`` in the surface's parameters.
    """

    nets: np.ndarray
    boxes: np.ndarray


class NurbsSurface:
    """A checked NURBS surface (see the module docstring for the index order)."""

    def __init__(
        self,
        degrees: tuple[int, int],
        knots_u: np.ndarray,
        knots_v: np.ndarray,
        control: np.ndarray,
        weights: np.ndarray | None = None,
        name: str = "NURBS surface",
    ):
        control = np.asarray(control, dtype=float)
        if control.ndim != 3 or control.shape[2] != 3:
            raise SurfaceError(f"{name}: control points must have shape (n, m, 3), got {control.shape}")
        if not np.all(np.isfinite(control)):
            raise SurfaceError(f"{name}: control points must be finite")
        weights = np.ones(control.shape[:2]) if weights is None else np.asarray(weights, dtype=float)
        if weights.shape != control.shape[:2]:
            raise SurfaceError(f"{name}: weights must have shape {control.shape[:2]}, got {weights.shape}")
        if not np.all(np.isfinite(weights)) or np.any(weights <= 0.0):
            i, j = np.argwhere(~(np.isfinite(weights) & (weights > 0.0)))[0]
            raise SurfaceError(
                f"{name}: weights must be positive and finite, got {weights[i, j]!r} at control point ({i}, {j})"
            )
        self.name = name
        self.u = KnotDirection.of(knots_u, degrees[0], control.shape[0], f"{name} u")
        self.v = KnotDirection.of(knots_v, degrees[1], control.shape[1], f"{name} v")
        self.control = control
        self.weights = weights

    @property
    def degrees(self) -> tuple[int, int]:
        return self.u.degree, self.v.degree

    @property
    def homogeneous(self) -> np.ndarray:
        """``(n, m, 4)``: ``(w x, w y, w z, w)``."""
        return np.concatenate([self.control * self.weights[..., None], self.weights[..., None]], axis=2)

    def with_name(self, name: str) -> NurbsSurface:
        return NurbsSurface(self.degrees, self.u.knots, self.v.knots, self.control, self.weights, name)

    def with_control(self, control: np.ndarray) -> NurbsSurface:
        """The same knots and weights with other control points ``(n, m, 3)`` (a deformed part)."""
        return NurbsSurface(self.degrees, self.u.knots, self.v.knots, control, self.weights, self.name)

    def _homogeneous_derivatives(self, u: np.ndarray, v: np.ndarray, order: int) -> dict[tuple[int, int], np.ndarray]:
        """``{(a, b): d^(a+b) A / du^a dv^b}`` ``(S, 4)`` of the homogeneous map for ``a + b <= order``."""
        first_u, basis_u = self.u.basis(u, order)
        first_v, basis_v = self.v.basis(v, order)
        rows = first_u[:, None] + np.arange(self.u.degree + 1)
        cols = first_v[:, None] + np.arange(self.v.degree + 1)
        local = self.homogeneous[rows[:, :, None], cols[:, None, :]]  # (S, p + 1, q + 1, 4)
        along_v = [np.einsum("sb,sabc->sac", basis_v[b], local) for b in range(order + 1)]
        return {
            (a, b): np.einsum("sa,sac->sc", basis_u[a], along_v[b])
            for a in range(order + 1)
            for b in range(order + 1 - a)
        }

    def evaluate(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points and first partial derivatives at parameters ``u, v (S,)``: three ``(S, 3)`` arrays."""
        u, v = np.atleast_1d(np.asarray(u, dtype=float)), np.atleast_1d(np.asarray(v, dtype=float))
        a = self._homogeneous_derivatives(u, v, 1)
        weight = a[0, 0][:, 3:]
        point = a[0, 0][:, :3] / weight
        # quotient rule: x = A / W, x_u = (A_u - x W_u) / W
        return (
            point,
            (a[1, 0][:, :3] - point * a[1, 0][:, 3:]) / weight,
            (a[0, 1][:, :3] - point * a[0, 1][:, 3:]) / weight,
        )

    def second_derivatives(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, ...]:
        """``x, x_u, x_v, x_uu, x_uv, x_vv`` at ``u, v (S,)``, each ``(S, 3)``."""
        u, v = np.atleast_1d(np.asarray(u, dtype=float)), np.atleast_1d(np.asarray(v, dtype=float))
        a = self._homogeneous_derivatives(u, v, 2)
        weight = a[0, 0][:, 3:]
        x = a[0, 0][:, :3] / weight
        x_u = (a[1, 0][:, :3] - x * a[1, 0][:, 3:]) / weight
        x_v = (a[0, 1][:, :3] - x * a[0, 1][:, 3:]) / weight
        # differentiate A = W x twice: A_uv = W_uv x + W_u x_v + W_v x_u + W x_uv
        x_uu = (a[2, 0][:, :3] - a[2, 0][:, 3:] * x - 2.0 * a[1, 0][:, 3:] * x_u) / weight
        x_uv = (a[1, 1][:, :3] - a[1, 1][:, 3:] * x - a[1, 0][:, 3:] * x_v - a[0, 1][:, 3:] * x_u) / weight
        x_vv = (a[0, 2][:, :3] - a[0, 2][:, 3:] * x - 2.0 * a[0, 1][:, 3:] * x_v) / weight
        return x, x_u, x_v, x_uu, x_uv, x_vv

    def basis_matrix(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rational basis ``phi_ij`` at ``u, v (S,)``: control indices ``(S, (p+1)(q+1))`` into
        the flattened ``(n * m)`` control points and their values (rows sum to 1): ``x = phi q``."""
        u, v = np.atleast_1d(np.asarray(u, dtype=float)), np.atleast_1d(np.asarray(v, dtype=float))
        (first_u, (basis_u,)), (first_v, (basis_v,)) = self.u.basis(u), self.v.basis(v)
        rows = first_u[:, None] + np.arange(self.u.degree + 1)
        cols = first_v[:, None] + np.arange(self.v.degree + 1)
        weighted = basis_u[:, :, None] * basis_v[:, None, :] * self.weights[rows[:, :, None], cols[:, None, :]]
        values = weighted / weighted.sum(axis=(1, 2), keepdims=True)
        index = rows[:, :, None] * self.control.shape[1] + cols[:, None, :]
        return index.reshape(len(u), -1), values.reshape(len(u), -1)

    @cached_property
    def flat_frame(self) -> AffineFrame | None:
        """The surface's frame where it is an affine map of its parameters (a flat face; a ray
        leaving it never meets it again), else ``None`` (:func:`~bhem_hpc.geometry.affine.affine_frame`)."""
        domains = (self.u.domain, self.v.domain)
        return affine_frame(self.degrees, (self.u.knots, self.v.knots), domains, self.control, self.weights)

    @cached_property
    def bezier_patches(self) -> RationalBezierPatches:
        """Exact rational Bezier extraction, patches in order ``span_u * S_v + span_v``."""
        (p, q), u, v = self.degrees, self.u, self.v
        if _bezier_knots(u) and _bezier_knots(v):  # one Bezier patch: its B-splines are the Bernstein polynomials
            box = np.array([[u.knots[p], u.knots[p + 1], v.knots[q], v.knots[q + 1]]])
            return RationalBezierPatches(self.homogeneous[None], box)
        count_u, count_v = len(u.spans), len(v.spans)
        boxes = np.empty((count_u, count_v, 4))
        boxes[..., 0], boxes[..., 1] = u.knots[u.spans][:, None], u.knots[u.spans + 1][:, None]
        boxes[..., 2], boxes[..., 3] = v.knots[v.spans], v.knots[v.spans + 1]
        boxes = boxes.reshape(-1, 4)
        rows = (u.spans - p)[:, None] + np.arange(p + 1)  # (S_u, p + 1): the control rows of each u span
        cols = (v.spans - q)[:, None] + np.arange(q + 1)
        local = self.homogeneous[rows[:, None, :, None], cols[None, :, None, :]]  # [a, b, i, j, c]
        # nets[a, b, k, l] = sum_ij E_u[a, i, k] E_v[b, j, l] local[a, b, i, j]: two batched products
        # over all spans, the u sums (batched over a), then the v sums (batched over b). B-splines of
        # degree 0 and 1 are the Bernstein polynomials on every span: that direction has no product
        if p > 1:
            by_u = local.transpose(0, 2, 1, 3, 4).reshape(count_u, p + 1, -1)
            summed = np.matmul(u.extraction.transpose(0, 2, 1), by_u)
            local = summed.reshape(count_u, p + 1, count_v, q + 1, 4).transpose(0, 2, 1, 3, 4)
        if q > 1:
            by_v = local.transpose(1, 3, 0, 2, 4).reshape(count_v, q + 1, -1)
            summed = np.matmul(v.extraction.transpose(0, 2, 1), by_v)
            local = summed.reshape(count_v, q + 1, count_u, p + 1, 4).transpose(2, 0, 3, 1, 4)
        nets = np.ascontiguousarray(local).reshape(count_u * count_v, p + 1, q + 1, 4)
        return RationalBezierPatches(nets, boxes)


def _bezier_knots(direction: KnotDirection) -> bool:
    """Whether ``direction`` has ``p + 1`` control points on clamped knots ``(a,) * (p + 1) + (b,) *
    (p + 1)``: one span whose B-splines are the Bernstein polynomials (unclamped knots have one span
    of other polynomials)."""
    p, knots = direction.degree, direction.knots
    # knots are nondecreasing: a run is constant where its ends are equal
    return len(knots) == 2 * p + 2 and knots[0] == knots[p] and knots[p + 1] == knots[-1]


def _insert_knot(homogeneous: np.ndarray, knots: np.ndarray, degree: int,
                 value: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Boehm's insertion of ``value`` once into the first direction of ``homogeneous (n, m, 4)``
    (degree ``degree``, ``knots (n + degree + 1,)``): ``(n + 1, m, 4)`` points and the new knots."""
    span = int(np.searchsorted(knots, value, side="right")) - 1
    first = span - degree + 1  # the points span - degree + 1 .. span are blends of two old ones
    blend = (value - knots[first : span + 1]) / (knots[first + degree : span + degree + 1] - knots[first : span + 1])
    middle = blend[:, None, None] * homogeneous[first : span + 1] + (1.0 - blend[:, None, None]) * homogeneous[
        first - 1 : span
    ]
    points = np.concatenate([homogeneous[:first], middle, homogeneous[span:]])
    return points, np.insert(knots, span + 1, value)


def insert_knots(surface: NurbsSurface, u_values: Sequence[float] = (), v_values: Sequence[float] = ()) -> NurbsSurface:
    """The same surface with the knots ``u_values`` and ``v_values`` inserted (each once, strictly
    inside the domain): one more control row per ``u`` knot and column per ``v`` knot, the shape
    unchanged to round-off (Boehm's algorithm in homogeneous coordinates)."""
    homogeneous = surface.homogeneous
    knots = {"u": surface.u.knots, "v": surface.v.knots}
    for axis, direction, values in ((0, surface.u, u_values), (1, surface.v, v_values)):
        low, high = direction.domain
        for value in values:
            if not low < value < high:
                raise SurfaceError(f"{surface.name}: a knot to insert must lie inside ({low}, {high}), got {value!r}")
            moved = np.moveaxis(homogeneous, axis, 0)
            points, knots["uv"[axis]] = _insert_knot(moved, knots["uv"[axis]], direction.degree, float(value))
            homogeneous = np.moveaxis(points, 0, axis)
    weights = homogeneous[..., 3]
    return NurbsSurface(surface.degrees, knots["u"], knots["v"], homogeneous[..., :3] / weights[..., None], weights,
                        surface.name)  # fmt: skip


def _span_midpoints(direction: KnotDirection, count: int) -> list[float]:
    """``count`` knots that halve the widest spans of ``direction`` in turn (a span once halved
    counts as two of half its width)."""
    edges = list(np.unique(direction.knots[direction.spans[0] : direction.spans[-1] + 2]))
    values = []
    for _ in range(count):
        k = int(np.argmax(np.diff(edges)))
        values.append(0.5 * (edges[k] + edges[k + 1]))
        edges.insert(k + 1, values[-1])
    return values


def refine(surface: NurbsSurface, extra: tuple[int, int]) -> NurbsSurface:
    """The same surface with ``extra = (rows, columns)`` more control points, by knots inserted at
    the middles of its widest spans (:func:`insert_knots`)."""
    return insert_knots(surface, _span_midpoints(surface.u, extra[0]), _span_midpoints(surface.v, extra[1]))


def span_lattice(direction: KnotDirection, per_side: int) -> np.ndarray:
    """``per_side`` equal steps per nonempty knot span of a direction, in its parameters, both ends of
    its domain included (a closed part samples its seam twice): :func:`knot_aligned_grid`'s lines."""
    low, high = direction.domain
    return low + knot_aligned_grid(direction, per_side * len(direction.spans)) * (high - low)


def knot_aligned_grid(axis: KnotDirection, cells: int) -> np.ndarray:
    """Parameters in [0, 1] (of ``axis.domain``) for at least ``cells`` cells: every distinct knot
    inside the domain, each knot span cut into ``ceil(cells / spans)`` equal cells."""
    low, high = axis.domain
    knots = np.unique(np.clip(np.asarray(axis.knots, dtype=float), low, high))
    breaks = (knots - low) / (high - low)
    per_span = max(1, -(-int(cells) // (len(breaks) - 1)))
    inner = [np.linspace(a, b, per_span + 1)[:-1] for a, b in zip(breaks[:-1], breaks[1:], strict=True)]
    return np.concatenate([*inner, [1.0]])


def bezier_nets_by_degree(parts: Sequence[NurbsSurface]) -> list[tuple[np.ndarray, np.ndarray]]:
    """The parts' rational Bezier nets in one array per degree (one ray search each) with the part
    of each patch: ``[(nets (P, p + 1, q + 1, 4), part (P,)), ...]``."""
    by_degree: dict[tuple[int, int], list[tuple[np.ndarray, int]]] = {}
    for k, part in enumerate(parts):
        by_degree.setdefault(part.degrees, []).append((part.bezier_patches.nets, k))
    return [(np.concatenate([nets for nets, _ in group]), np.concatenate([np.full(len(nets), k) for nets, k in group]))
            for group in by_degree.values()]  # fmt: skip


# ---- exact shapes ----------------------------------------------------------------------------

_CIRCLE_KNOTS = np.array([0, 0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 4], dtype=float) / 4.0
_HALF_CIRCLE_KNOTS = np.array([0, 0, 0, 1, 1, 2, 2, 2], dtype=float) / 2.0


def _circle(count: int) -> tuple[np.ndarray, np.ndarray]:
    """Control points ``(count, 2)`` and weights of the unit circle (9 points) or the half circle
    from angle -pi/2 to pi/2 (5 points), quarter arcs of weight ``cos(pi / 4)`` at their corners."""
    angles = -0.5 * math.pi + 0.25 * math.pi * np.arange(count) if count == 5 else 0.25 * math.pi * np.arange(count)
    corner = np.arange(count) % 2 == 1
    radius = np.where(corner, math.sqrt(2.0), 1.0)
    points = radius[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return np.round(points, 15), np.where(corner, math.sqrt(0.5), 1.0)


def revolve(
    profile: np.ndarray, profile_weights: np.ndarray, profile_knots: np.ndarray, profile_degree: int, name: str
) -> NurbsSurface:
    """The exact surface of revolution about the z axis of a rational profile ``(m, 2)`` of
    ``(radius, z)`` points: ``u`` goes round (9 control points), ``v`` along the profile."""
    circle, circle_weights = _circle(9)
    control = np.empty((9, len(profile), 3))
    control[..., 0] = circle[:, None, 0] * profile[None, :, 0]
    control[..., 1] = circle[:, None, 1] * profile[None, :, 0]
    control[..., 2] = profile[None, :, 1]
    weights = circle_weights[:, None] * profile_weights[None, :]
    return NurbsSurface((2, profile_degree), _CIRCLE_KNOTS, profile_knots, control, weights, name)


def sphere(radius: float, center=(0.0, 0.0, 0.0)) -> NurbsSurface:
    """The exact NURBS sphere (degree 2 x 2, 9 x 5 control points; outward normal ``x_u x x_v``)."""
    half, weights = _circle(5)
    surface = revolve(radius * half, weights, _HALF_CIRCLE_KNOTS, 2, "sphere")
    return surface.with_control(surface.control + np.asarray(center, dtype=float))


def torus(major_radius: float, minor_radius: float) -> NurbsSurface:
    """The exact NURBS torus about the z axis (degree 2 x 2, 9 x 9 control points)."""
    circle, weights = _circle(9)
    profile = np.stack([major_radius + minor_radius * circle[:, 0], minor_radius * circle[:, 1]], axis=1)
    return revolve(profile, weights, _CIRCLE_KNOTS, 2, "torus")


def pipe_bend(bend_radius: float, pipe_radius: float, azimuth_range: tuple[float, float]) -> NurbsSurface:
    """A pipe bend: the torus of ``bend_radius`` about the z axis and tube radius ``pipe_radius``
    over ``azimuth_range`` (less than pi), as a modeller revolves it: ``u`` round the tube (a
    rational circle of 9 control points, only C0 at its quarter points), ``v`` along the bend."""
    circle, weights = _circle(9)
    profile = np.stack([bend_radius + pipe_radius * circle[:, 0], pipe_radius * circle[:, 1]], axis=1)
    return revolve_by(profile, weights, _CIRCLE_KNOTS, 2, azimuth_range, "pipe bend")


def cylinder_panel(radius: float, z_range: tuple[float, float], angle_range: tuple[float, float],
                   name: str = "cylinder panel") -> NurbsSurface:
    """The exact panel ``(R cos a, R sin a, z)`` of a cylinder about the z axis, ``u = z`` over
    ``z_range`` (degree 1) and ``v in [0, 1]`` along the arc over ``angle_range`` (one rational
    quadratic segment, less than pi: its middle control point at ``R / cos(h)``, weight ``cos(h)``,
    ``h`` half the arc's angle)."""
    arc, weights = _one_segment_arc(angle_range, name)
    control = np.empty((2, 3, 3))
    control[..., :2] = radius * arc
    control[..., 2] = np.array(z_range)[:, None]
    knots = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]
    return NurbsSurface((1, 2), [z_range[0], z_range[0], z_range[1], z_range[1]], knots, control,
                        np.tile(weights, (2, 1)), name)  # fmt: skip


def _one_segment_arc(angles: tuple[float, float], name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(cos, sin)`` control points ``(3, 2)`` and weights of the unit arc over ``angles`` (one
    rational quadratic segment, less than pi)."""
    half = 0.5 * (angles[1] - angles[0])
    if not 0.0 < half < 0.5 * math.pi:
        raise SurfaceError(f"{name}: a one-segment arc spans more than 0 and less than pi, got {angles}")
    middle = np.array([angles[0], angles[0] + half, angles[1]])
    radii = np.array([1.0, 1.0 / math.cos(half), 1.0])
    return radii[:, None] * np.stack([np.cos(middle), np.sin(middle)], 1), np.array([1.0, math.cos(half), 1.0])


def revolved_arc_panel(centre: tuple[float, float], radius: float, polar_range: tuple[float, float],
                       azimuth_range: tuple[float, float], name: str = "revolved arc") -> NurbsSurface:
    """The exact panel swept by the circular arc of ``radius`` about ``centre = (r, z)`` over polar
    angles ``polar_range`` (from +z: the point ``(r + radius sin t, z + radius cos t)``) revolved
    about the z axis over ``azimuth_range``: a sphere zone (centre (0, 0)) or a torus patch.
    Degree 2 x 2, ``u`` along the arc, ``v`` about the axis, both over [0, 1]."""
    polar, weights = _one_segment_arc(polar_range, name)
    profile = np.stack([centre[0] + radius * polar[:, 1], centre[1] + radius * polar[:, 0]], axis=1)
    return revolve_by(profile, weights, np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0]), 2, azimuth_range, name)


def revolve_by(profile: np.ndarray, profile_weights: np.ndarray, profile_knots: np.ndarray, profile_degree: int,
               azimuth_range: tuple[float, float], name: str) -> NurbsSurface:
    """The exact surface of revolution about the z axis of a rational profile ``(m, 2)`` of
    ``(radius, z)`` points over ``azimuth_range`` (less than pi: one rational quadratic segment):
    ``u`` along the profile, ``v`` about the axis over [0, 1]."""
    around, around_weights = _one_segment_arc(azimuth_range, name)
    control = np.empty((len(profile), 3, 3))
    control[..., 0] = profile[:, None, 0] * around[None, :, 0]
    control[..., 1] = profile[:, None, 0] * around[None, :, 1]
    control[..., 2] = profile[:, None, 1]
    weights = np.asarray(profile_weights)[:, None] * around_weights[None, :]
    return NurbsSurface((profile_degree, 2), profile_knots, [0.0, 0.0, 0.0, 1.0, 1.0, 1.0], control, weights, name)


def beam_faces(lo, hi, sections: int, degree: int = 1, spans: tuple[int, int] = (1, 1)) -> list[NurbsSurface]:
    """An axis-aligned box cut into ``sections`` along x: its four long sides as ``sections`` parts
    each, and its two ends (``4 sections + 2`` parts, unconnected, outward normals), each part of
    ``degree`` with ``spans`` knot spans as :func:`box_faces` (the sides' first direction runs along
    the cut when the face's first parameter does)."""
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    cuts = np.linspace(lo[0], hi[0], sections + 1)
    parts = []
    for k in range(sections):
        piece = box_faces([cuts[k], lo[1], lo[2]], [cuts[k + 1], hi[1], hi[2]], degree, spans)
        parts += [face.with_name(f"{face.name} section {k}") for face in piece[2:]]  # the four sides
    whole = box_faces(lo, hi, degree, spans)
    return parts + whole[:2]


def _flat_knots(degree: int, spans: int) -> tuple[np.ndarray, np.ndarray]:
    """A clamped uniform knot vector on [0, 1] and its Greville abscissae (control points there
    make the parametrization linear)."""
    knots = np.r_[np.zeros(degree), np.linspace(0.0, 1.0, spans + 1), np.ones(degree)]
    count = spans + degree
    greville = np.array([knots[i + 1 : i + degree + 1].mean() for i in range(count)])
    return knots, greville


def box_faces(lo, hi, degree: int = 1, spans: tuple[int, int] = (1, 1)) -> list[NurbsSurface]:
    """The six faces of an axis-aligned box as flat NURBS parts (-x, +x, -y, +y, -z, +z), normals
    ``x_u x x_v`` outward: of ``degree`` in both directions with ``spans`` uniform knot spans, the
    control points on the Greville abscissae (bilinear with four control points by default)."""
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    (knots_u, greville_u), (knots_v, greville_v) = (_flat_knots(degree, n) for n in spans)
    faces = []
    for axis in range(3):
        a, b = (axis + 1) % 3, (axis + 2) % 3
        for side, level in ((-1, lo[axis]), (1, hi[axis])):
            first, second = (a, b) if side > 0 else (b, a)  # right-handed (first, second, outward)
            control = np.empty((len(greville_u), len(greville_v), 3))
            control[..., axis] = level
            control[..., first] = (lo[first] + greville_u * (hi[first] - lo[first]))[:, None]
            control[..., second] = (lo[second] + greville_v * (hi[second] - lo[second]))[None, :]
            faces.append(NurbsSurface((degree, degree), knots_u, knots_v, control,
                                      name=f"box face {'-+'[side > 0]}{'xyz'[axis]}"))  # fmt: skip
    return faces


def shell_surface(part: NurbsSurface, patches: tuple[int, int], discretization: str):
    """A shell discretization's surface of a NURBS part over its parameter domain, ``patches`` knot
    spans of one width each (uniform, as the shells' discretizations are): Hermite nodal data from
    the part's exact derivatives at the grid's nodes, or a B-spline of degree 2 or 3 interpolating
    it at the Greville points. Exact where the part lies in the chosen space (a B-spline part of
    that degree on those uniform knots); otherwise an approximation (:func:`shell_fit_error`)."""
    grid = ParameterGrid(int(patches[0]), int(patches[1]), part.u.domain, part.v.domain, False, False)

    def derivative(order: int):
        def evaluate(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            values = part.second_derivatives(np.ravel(u), np.ravel(v))[order]
            return values.reshape(*np.shape(u), 3)

        return evaluate

    if discretization == "hermite":
        return hermite_from_callable(derivative(0), grid, (derivative(1), derivative(2), derivative(4)))
    return bspline_from_callable(derivative(0), grid, degree=int(discretization[-1]))


def shell_fit_error(part: NurbsSurface, shell, samples: int = 4) -> float:
    """The largest distance [m] between a part and its shell surface (:func:`shell_surface`) at
    ``samples`` points per span side of the shell's grid."""
    grid = shell.grid
    u = np.linspace(*grid.xi1_range, grid.n1 * samples + 1)
    v = np.linspace(*grid.xi2_range, grid.n2 * samples + 1)
    uu, vv = (a.ravel() for a in np.meshgrid(u, v, indexing="ij"))
    return float(np.linalg.norm(shell.evaluate(uu, vv).x - part.evaluate(*shell.model_parameters(uu, vv))[0],
                                axis=1).max())  # fmt: skip


def graph_parts(height, x_range: tuple[float, float], y_range: tuple[float, float], splits: tuple[int, int],
                spans: tuple[int, int] = (2, 2), degree: int = 3) -> list[NurbsSurface]:  # fmt: skip
    """The surface ``z = height(x, y)`` over a rectangle as ``splits[0] x splits[1]`` B-spline parts
    (part ``i * splits[1] + j`` the ``i``-th along x and ``j``-th along y), each of ``degree`` with
    ``spans`` uniform knot spans on [0, 1] and its control points on the graph above the Greville
    abscissae: neighbours share their edge curves exactly (their boundary control points are the
    same), their slopes across an edge nearly (as parts modelled separately meet)."""
    (knots_u, greville_u), (knots_v, greville_v) = (_flat_knots(degree, n) for n in spans)
    xs, ys = (np.linspace(*r, n + 1) for r, n in ((x_range, splits[0]), (y_range, splits[1])))
    parts = []
    for i in range(splits[0]):
        for j in range(splits[1]):
            x = xs[i] + greville_u * (xs[i + 1] - xs[i])
            y = ys[j] + greville_v * (ys[j + 1] - ys[j])
            gx, gy = np.meshgrid(x, y, indexing="ij")
            control = np.stack([gx, gy, height(gx, gy)], axis=-1)
            parts.append(NurbsSurface((degree, degree), knots_u, knots_v, control, name=f"part {i} {j}"))
    return parts
