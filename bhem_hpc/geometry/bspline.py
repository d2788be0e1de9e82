"""Tensor-product B-spline surfaces of degree 2 and 3 on uniform knots, numpy only.

Each parameter direction has ``n`` uniform knot spans over its range (the :class:`ParameterGrid`'s
patches). An *open* direction has clamped ends (``p + 1`` repeated end knots; ``n + p`` control
points; the boundary curve depends on the boundary control points alone); a *periodic* direction
wraps (``n`` control points; span ``k`` uses control points ``k .. k + p`` modulo ``n``).

Every span is a polynomial patch: its basis is ``N(t) = C_k B(t)`` with the Bernstein polynomials
``B`` of degree ``p`` in the span's local coordinate ``t in [0, 1]`` and the span's *Bezier
extraction* matrix ``C_k`` ((p+1) x (p+1)). The Bezier control points of a span are therefore
exact linear maps of the control points, and a biquadratic Bezier patch is raised exactly to the
bicubic net the collision code and the renderer use (:meth:`BSplineSurface.bezier_nets`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

import numpy as np

from bhem_hpc.geometry.surface import (
    ParameterGrid,
    SurfaceError,
    SurfacePoint,
    annulus_sector_shape,
    check_regular,
    cylinder_shape,
    load_surface_file,
    rectangle_shape,
    save_surface_file,
    sphere_zone_shape,
    tensor_product_point,
    torus_shape,
)

DEGREES = (2, 3)
FILE_FORMAT = "bhem-bspline-surface"
FILE_VERSION = 1
Field = Callable[[np.ndarray, np.ndarray], np.ndarray]


def check_degree(degree: object) -> int:
    if isinstance(degree, bool) or not isinstance(degree, int | np.integer) or int(degree) not in DEGREES:
        raise SurfaceError(f"B-spline degree must be one of {DEGREES}, got {degree!r}")
    return int(degree)


def control_count(spans: int, degree: int, periodic: bool) -> int:
    """Control points along a direction of ``spans`` knot spans."""
    return spans if periodic else spans + degree


def _check_spans(grid: ParameterGrid, degree: int) -> None:
    for name, n, periodic in (("xi1", grid.n1, grid.periodic1), ("xi2", grid.n2, grid.periodic2)):
        if periodic and n < degree + 1:
            raise SurfaceError(
                f"a periodic {name} direction of a degree-{degree} B-spline needs at least {degree + 1} knot spans, "
                f"got {n}"
            )


def clamped_uniform_knots(spans: int, degree: int, lo: float, hi: float) -> np.ndarray:
    """The clamped knot vector of ``spans`` uniform spans over ``[lo, hi]``."""
    return np.concatenate([np.full(degree, lo), np.linspace(lo, hi, spans + 1), np.full(degree, hi)])


def open_knots(spans: int, degree: int) -> np.ndarray:
    """The clamped uniform knot vector in span units: ``p + 1`` zeros, ``1 .. n - 1``, ``p + 1`` times ``n``."""
    return np.concatenate([np.zeros(degree), np.arange(spans + 1, dtype=float), np.full(degree, float(spans))])


def basis_functions(knots: np.ndarray, degree: int, span: int, x: np.ndarray) -> np.ndarray:
    """The ``p + 1`` nonzero B-spline basis functions on knot interval ``span`` (Cox-de Boor).

    Args:
        knots: the knot vector; ``span`` indexes its nonempty interval ``[knots[span], knots[span + 1])``.
        x: parameters in that interval, shape ``S``.

    Returns:
        ``S + (p + 1,)``: the basis functions ``span - p .. span`` at ``x``.
    """
    x = np.asarray(x, dtype=float)
    values = np.zeros(x.shape + (degree + 1,))
    values[..., 0] = 1.0
    left = np.zeros(x.shape + (degree + 1,))
    right = np.zeros(x.shape + (degree + 1,))
    for j in range(1, degree + 1):  # The NURBS Book, algorithm A2.2
        left[..., j] = x - knots[span + 1 - j]
        right[..., j] = knots[span + j] - x
        saved = np.zeros(x.shape)
        for r in range(j):
            term = values[..., r] / (right[..., r + 1] + left[..., j - r])
            values[..., r] = saved + right[..., r + 1] * term
            saved = left[..., j - r] * term
        values[..., j] = saved
    return values


@lru_cache(maxsize=32)
def _binomials(degree: int) -> np.ndarray:
    """``(degree + 1,)``: the binomial coefficients ``C(degree, i)`` (read only)."""
    binomials = np.array([math.comb(degree, i) for i in range(degree + 1)], dtype=float)
    binomials.flags.writeable = False
    return binomials


def bernstein(t: np.ndarray, degree: int, derivative: int = 0) -> np.ndarray:
    """Bernstein polynomials of ``degree`` (or a derivative in ``t``) at ``t``: ``t.shape + (p + 1,)``.

    The ``k``-th derivative is ``p! / (p - k)! sum_j (-1)^(k - j) C(k, j) B_(i - j, p - k)``, with the
    Bernstein polynomials of degree ``p - k`` in closed form."""
    t = np.asarray(t, dtype=float)
    if derivative > degree:
        return np.zeros(t.shape + (degree + 1,))
    lower_degree = degree - derivative
    # t^m and (1 - t)^(d - m) by running products: numpy's power with an array of exponents takes
    # twice as long as the rest of this function on thousands of points
    rising, falling = np.empty(t.shape + (lower_degree + 1,)), np.empty(t.shape + (lower_degree + 1,))
    rising[..., 0] = falling[..., lower_degree] = 1.0
    complement = 1.0 - t
    for m in range(1, lower_degree + 1):
        rising[..., m] = rising[..., m - 1] * t
        falling[..., lower_degree - m] = falling[..., lower_degree - m + 1] * complement
    lower = _binomials(lower_degree) * rising * falling
    if derivative == 0:
        return lower
    out = np.zeros(t.shape + (degree + 1,))
    scale = math.factorial(degree) / math.factorial(lower_degree)
    for j in range(derivative + 1):
        out[..., j : j + lower_degree + 1] += scale * (-1) ** (derivative - j) * math.comb(derivative, j) * lower
    return out


@lru_cache(maxsize=64)
def _extraction(spans: int, degree: int, periodic: bool) -> np.ndarray:
    """Bezier extraction matrices ``(spans, p + 1, p + 1)``: ``N_local(t) = C[k] @ B(t)`` on span ``k``."""
    samples = (np.arange(degree + 1) + 0.5) / (degree + 1)  # interior points: no knot ambiguity
    inverse = np.linalg.inv(bernstein(samples, degree))  # rows: samples, columns: Bernstein index
    if periodic:
        # the cardinal B-spline on a uniform knot vector: every span alike
        knots = np.arange(-degree, degree + 2, dtype=float)
        local = basis_functions(knots, degree, degree, samples)  # (samples, p + 1)
        c = (inverse @ local).T
        return np.broadcast_to(c, (spans, degree + 1, degree + 1)).copy()
    knots = open_knots(spans, degree)
    out = np.empty((spans, degree + 1, degree + 1))
    for k in range(spans):
        local = basis_functions(knots, degree, k + degree, k + samples)
        out[k] = (inverse @ local).T
    return out


def _local_controls(spans: int, degree: int, periodic: bool) -> np.ndarray:
    """Control indices ``(spans, p + 1)`` of each span's basis functions."""
    index = np.arange(spans)[:, None] + np.arange(degree + 1)[None, :]
    return np.mod(index, spans) if periodic else index


@lru_cache(maxsize=64)
def _knot_extraction(knots: tuple[float, ...], degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Bezier extraction matrices ``(spans, p + 1, p + 1)`` and local control indices ``(spans,
    p + 1)`` of a clamped knot vector (its nonempty spans in order; interior knots may repeat)."""
    knots_array = np.asarray(knots)
    samples = (np.arange(degree + 1) + 0.5) / (degree + 1)
    inverse = np.linalg.inv(bernstein(samples, degree))
    starts = np.arange(degree, len(knots) - degree - 1)
    starts = starts[knots_array[starts + 1] > knots_array[starts]]
    out = np.empty((len(starts), degree + 1, degree + 1))
    for s, k in enumerate(starts):
        a, b = knots_array[k], knots_array[k + 1]
        out[s] = (inverse @ basis_functions(knots_array, degree, int(k), a + samples * (b - a))).T
    return out, (starts - degree)[:, None] + np.arange(degree + 1)[None, :]


#: Per direction the knot vector of a surface whose knot spans are not all of one length, or whose
#: interior knots repeat (None: uniform): its spans are still the grid's uniform ones in the
#: surface's parameters, each mapped affinely onto its knot interval.
Knots = tuple[np.ndarray | None, np.ndarray | None]


def span_extraction(grid: ParameterGrid, degree: int, axis: int,
               knots: Knots | None = None) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """Extraction matrices, local control indices and span width of one direction."""
    spans, periodic, h = (grid.n1, grid.periodic1, grid.h1) if axis == 0 else (grid.n2, grid.periodic2, grid.h2)
    if knots is not None and knots[axis] is not None:
        return (*_knot_extraction(tuple(float(k) for k in knots[axis]), degree), h)
    return _extraction(spans, degree, periodic), _local_controls(spans, degree, periodic), h


def bezier_extraction(control: np.ndarray, first: tuple, second: tuple) -> np.ndarray:
    """The Bezier nets ``(n1, n2, p + 1, p + 1, d)`` of every span of data ``control (c1, c2, d)``
    per control point, given each direction's :func:`span_extraction` (extraction matrices, local
    controls, ...): ``P[p1, p2] = C1[p1]^T control[local1[p1]][:, local2[p2]] C2[p2]``."""
    (c1, local1, *_), (c2, local2, *_) = first, second
    patches = control[local1[:, None, :, None], local2[None, :, None, :]]  # (n1, n2, p+1, p+1, d)
    return np.einsum("aik,abijc,bjl->abklc", c1, patches, c2)


def point_weights(
    grid: ParameterGrid,
    degree: int,
    p1: np.ndarray,
    p2: np.ndarray,
    t1: np.ndarray,
    t2: np.ndarray,
    d1: int = 0,
    d2: int = 0,
    knots: Knots | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Linear map from control points to points (or parametric derivatives ``d^(d1+d2) x /
    dxi1^d1 dxi2^d2``): ``x = sum_j weights[..., j] control.reshape(-1, 3)[index[..., j]]``.

    Args:
        p1, p2: span indices, shape ``S``; t1, t2: local coordinates in [0, 1], shape ``S``.
        knots: non-uniform knot vectors (:data:`Knots`), or None.

    Returns:
        ``(index, weights)`` of shape ``S + ((p + 1)^2,)``, index ``i1 * c2 + i2``.
    """
    p1, p2, t1, t2 = np.broadcast_arrays(np.asarray(p1), np.asarray(p2), np.asarray(t1, float), np.asarray(t2, float))
    c1, local1, h1 = span_extraction(grid, degree, 0, knots)
    c2, local2, h2 = span_extraction(grid, degree, 1, knots)
    n1 = np.einsum("...ij,...j->...i", c1[p1], bernstein(t1, degree, d1)) / h1**d1  # S + (p + 1,)
    n2 = np.einsum("...ij,...j->...i", c2[p2], bernstein(t2, degree, d2)) / h2**d2
    columns = control_count(grid.n2, degree, grid.periodic2) if knots is None or knots[1] is None else (
        len(knots[1]) - degree - 1)
    index = local1[p1][..., :, None] * columns + local2[p2][..., None, :]
    weights = n1[..., :, None] * n2[..., None, :]
    return index.reshape(p1.shape + (-1,)), weights.reshape(p1.shape + (-1,))


class BSplinePatches:
    """The knot spans of a B-spline surface as linear maps of its control points (contact's patch layout)."""

    def __init__(self, grid: ParameterGrid, degree: int):
        self.grid = grid
        self.degree = check_degree(degree)
        self.control_shape = BSplineSurface.control_shape_of(grid, self.degree)

    @property
    def num_entries(self) -> int:
        return self.control_shape[0] * self.control_shape[1]

    def point_entries(
        self, p1: np.ndarray, p2: np.ndarray, t1: np.ndarray, t2: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(index, weights)``, shape ``S + ((p + 1)^2,)`` each, of the points: :func:`point_weights`."""
        return point_weights(self.grid, self.degree, p1, p2, t1, t2)

    def patch_entries(self) -> np.ndarray:
        """``(n1 * n2, (p + 1)^2)`` the control points that determine each span (order ``p1 * n2 + p2``)."""
        p1, p2 = (a.ravel() for a in np.meshgrid(np.arange(self.grid.n1), np.arange(self.grid.n2), indexing="ij"))
        return point_weights(self.grid, self.degree, p1, p2, 0.5, 0.5)[0]

    def bezier_nets(self, entries: np.ndarray) -> np.ndarray:
        """Bicubic Bezier nets ``(n1 * n2, 4, 4, 3)`` of control points ``(N, 3)`` (positions or velocities)."""
        return BSplineSurface(self.grid, self.degree, np.asarray(entries).reshape(*self.control_shape, 3)).bezier_nets()


#: Exact degree elevation of a quadratic Bezier curve to a cubic one: ``Q = ELEVATE @ P``.
ELEVATE = np.array([[1.0, 0.0, 0.0], [1 / 3, 2 / 3, 0.0], [0.0, 2 / 3, 1 / 3], [0.0, 0.0, 1.0]])


class BSplineSurface:
    """A tensor-product B-spline surface of degree 2 (C1) or 3 (C2) on a uniform knot grid.

    Args:
        grid: the knot spans (``n1 x n2`` patches) and which directions are periodic.
        degree: 2 or 3, in both directions.
        control: control points ``(c1, c2, 3)``, ``c = n + p`` in an open direction, ``n`` in a
            periodic one.
    """

    def __init__(self, grid: ParameterGrid, degree: int, control: np.ndarray):
        self.degree = check_degree(degree)
        _check_spans(grid, self.degree)
        control = np.asarray(control, dtype=float)
        shape = self._expected_control_shape(grid, self.degree)
        if control.shape != (*shape, 3):
            raise SurfaceError(f"control points must have shape {(*shape, 3)}, got {control.shape}")
        if not np.all(np.isfinite(control)):
            raise SurfaceError("control points contain NaN/Inf")
        self.grid = grid
        self.control = control

    @staticmethod
    def control_shape_of(grid: ParameterGrid, degree: int) -> tuple[int, int]:
        """Control points ``(c1, c2)`` of a degree-``degree`` surface on ``grid``."""
        return (
            control_count(grid.n1, degree, grid.periodic1),
            control_count(grid.n2, degree, grid.periodic2),
        )

    def _expected_control_shape(self, grid: ParameterGrid, degree: int) -> tuple[int, int]:
        return self.control_shape_of(grid, degree)

    @property
    def node_shape(self) -> tuple[int, int]:
        """The nodes that carry data: the control points ``(c1, c2)``."""
        return self.control.shape[:2]

    #: Kinds of data per node: the control point's position only.
    kind_count = 1

    @property
    def discretization(self) -> str:
        """The discretization whose DOFs are this surface's control points."""
        return f"bspline{self.degree}"

    @property
    def nodal(self) -> np.ndarray:
        """The control points as nodal data ``(c1, c2, 1, 3)`` (kind 0 = the position)."""
        return self.control[:, :, None, :]

    def with_nodal(self, nodal: np.ndarray) -> BSplineSurface:
        """The surface with other control points, given as nodal data ``(c1, c2, 1, 3)``."""
        return BSplineSurface(self.grid, self.degree, np.asarray(nodal)[:, :, 0, :])

    def check_regular(self, quadrature_points: int = 4, name: str = "surface") -> None:
        """Raise :class:`SurfaceError` if ``|a1 x a2|`` vanishes at a Gauss point of any span."""
        check_regular(self, quadrature_points, name)

    def model_parameters(self, xi1: np.ndarray, xi2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The parameters of the model the surface was made from (the same: its knots are uniform)."""
        return np.asarray(xi1, dtype=float), np.asarray(xi2, dtype=float)

    def surface_parameters(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The inverse of :meth:`model_parameters` (the same)."""
        return np.asarray(u, dtype=float), np.asarray(v, dtype=float)

    def nurbs(self, name: str = "shell"):
        """The same surface as a NURBS part (clamped uniform knots, weights 1), for writing the model
        back; periodic directions are refused."""
        from bhem_hpc.geometry.nurbs import NurbsSurface  # the CAD geometry loads for CAD output only

        if self.grid.periodic1 or self.grid.periodic2:
            raise SurfaceError("a periodic B-spline surface has no clamped NURBS form here")
        knots = [clamped_uniform_knots(n, self.degree, lo, hi) for n, (lo, hi) in
                 ((self.grid.n1, self.grid.xi1_range), (self.grid.n2, self.grid.xi2_range))]  # fmt: skip
        return NurbsSurface((self.degree, self.degree), *knots, self.control, None, name)

    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> BSplineSurface:
        """The surface moved rigidly: ``x -> R x + t`` (control points transform alike)."""
        rotation = np.asarray(rotation, float)
        return BSplineSurface(self.grid, self.degree, self.control @ rotation.T + np.asarray(translation, float))

    # -- evaluation ---------------------------------------------------------------------------
    def _direction(self, axis: int) -> tuple[np.ndarray, np.ndarray, float]:
        return span_extraction(self.grid, self.degree, axis)

    def point_weights(
        self, p1: np.ndarray, p2: np.ndarray, t1: np.ndarray, t2: np.ndarray, d1: int = 0, d2: int = 0
    ) -> tuple[np.ndarray, np.ndarray]:
        """See :func:`point_weights`."""
        return point_weights(self.grid, self.degree, p1, p2, t1, t2, d1, d2)

    def evaluate(self, xi1: np.ndarray, xi2: np.ndarray) -> SurfacePoint:
        """Position and first and second parametric derivatives at parameters of shape ``S``: each
        point's span's control points contracted with its B-spline basis in each parameter (the span's
        extraction of the Bernstein basis; no other span's)."""
        located = self.grid.locate(xi1, xi2)
        p1, p2, t1, t2 = (np.ravel(a) for a in located)
        (c1, local1, h1), (c2, local2, h2) = self._direction(0), self._direction(1)
        basis1, basis2 = (np.stack([np.einsum("kij,kj->ki", c[p], bernstein(t, self.degree, d)) / h**d
                                    for d in range(3)], axis=1)
                          for c, p, t, h in ((c1, p1, t1, h1), (c2, p2, t2, h2)))  # fmt: skip
        control = self.control[local1[p1][:, :, None], local2[p2][:, None, :]]  # (K, p + 1, p + 1, 3)
        return tensor_product_point(control, basis1, basis2, located[0].shape)

    # -- Bezier form ----------------------------------------------------------------------------
    def bezier_control_points(self) -> np.ndarray:
        """Exact Bezier control nets of every span, ``(n1, n2, p + 1, p + 1, 3)`` indexed
        ``[p1, p2, k1, k2, component]``; the span is ``sum_k1,k2 B_k1(t1) B_k2(t2) P[k1, k2]``."""
        return bezier_extraction(self.control, self._direction(0), self._direction(1))

    def bezier_nets(self) -> np.ndarray:
        """Bicubic Bezier nets ``(n1 * n2, 4, 4, 3)`` (order ``p1 * n2 + p2``), degree-elevated
        exactly from biquadratic spans: what the collision code and the ray tracer take."""
        nets = self.bezier_control_points()
        if self.degree == 2:
            nets = np.einsum("ki,abijc,lj->abklc", ELEVATE, nets, ELEVATE)
        return nets.reshape(-1, 4, 4, 3)

    def tessellate(self, density: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Quad mesh sampling every span on a ``(density+1)^2`` grid: ``(points, quads, parameters)``."""
        g = self.grid
        m1, m2 = g.n1 * density + 1, g.n2 * density + 1
        a, b = np.meshgrid(np.linspace(*g.xi1_range, m1), np.linspace(*g.xi2_range, m2), indexing="ij")
        points = self.evaluate(a, b).x.reshape(-1, 3)
        ids = np.arange(m1 * m2).reshape(m1, m2)
        quads = np.stack([ids[:-1, :-1], ids[1:, :-1], ids[1:, 1:], ids[:-1, 1:]], axis=-1).reshape(-1, 4)
        return points, quads, np.stack([a.ravel(), b.ravel()], axis=1)

    # -- files ----------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the surface as a ``.npz`` file (format ``bhem-bspline-surface``)."""
        save_surface_file(
            path, FILE_FORMAT, FILE_VERSION, self.grid, degree=np.array(self.degree), control=self.control
        )

    @classmethod
    def load(cls, path: str | Path) -> BSplineSurface:
        """Read a file written by :meth:`save`; errors name the file and the key."""
        keys = ("degree", "control")
        grid, arrays = load_surface_file(path, FILE_FORMAT, FILE_VERSION, keys, "B-spline surface file")
        degree = np.asarray(arrays["degree"])
        if degree.shape != () or degree.dtype.kind not in "iu":
            raise SurfaceError(f"{path}: key 'degree' must be an integer, got {degree.tolist()!r}")
        try:
            return cls(grid, int(degree), arrays["control"])
        except (SurfaceError, ValueError, TypeError) as exc:
            raise SurfaceError(f"{path}: key 'control' or 'degree': {exc}") from exc


# ---------------------------------------------------------------------------------------------
# Constructors: interpolation at the Greville abscissae
# ---------------------------------------------------------------------------------------------
def greville(spans: int, degree: int, periodic: bool, lo: float, hi: float) -> np.ndarray:
    """Greville abscissae (the averages of each basis function's inner knots), in parameters."""
    h = (hi - lo) / spans
    if periodic:  # control i carries the basis on spans i - p .. i: its centre, wrapped into [lo, hi)
        return lo + np.mod(h * (np.arange(spans) - (degree - 1) / 2.0), hi - lo)
    knots = open_knots(spans, degree)
    index = np.arange(spans + degree)[:, None] + np.arange(1, degree + 1)[None, :]
    return lo + h * knots[index].mean(axis=1)


def collocation(spans: int, degree: int, periodic: bool, lo: float, hi: float) -> np.ndarray:
    """The matrix ``A[i, j] = N_j(greville_i)`` of one direction."""
    grid = ParameterGrid(spans, 1, (lo, hi), (0.0, 1.0), periodic, False)
    points = greville(spans, degree, periodic, lo, hi)
    span, _, t, _ = grid.locate(points, np.zeros_like(points))
    values = np.einsum("kij,kj->ki", _extraction(spans, degree, periodic)[span], bernstein(t, degree))
    count = control_count(spans, degree, periodic)
    matrix = np.zeros((len(points), count))
    np.add.at(matrix, (np.arange(len(points))[:, None], _local_controls(spans, degree, periodic)[span]), values)
    return matrix


def from_callable(position: Field, grid: ParameterGrid, *, degree: int) -> BSplineSurface:
    """The B-spline surface interpolating ``x(xi1, xi2)`` at the tensor Greville points of ``grid``.

    Args:
        position: vectorized callable mapping two arrays of shape ``S`` to ``S + (3,)``.
        degree: 2 or 3.
    """
    degree = check_degree(degree)
    _check_spans(grid, degree)
    g1 = greville(grid.n1, degree, grid.periodic1, *grid.xi1_range)
    g2 = greville(grid.n2, degree, grid.periodic2, *grid.xi2_range)
    a1 = collocation(grid.n1, degree, grid.periodic1, *grid.xi1_range)
    a2 = collocation(grid.n2, degree, grid.periodic2, *grid.xi2_range)
    values = np.asarray(position(*np.meshgrid(g1, g2, indexing="ij")), dtype=float)  # (c1, c2, 3)
    return BSplineSurface(grid, degree, interpolate_at_greville(a1, a2, values))


def interpolate_at_greville(a1: np.ndarray, a2: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Control points ``(c1, c2, 3)`` whose spline takes ``values (c1, c2, 3)`` at the tensor
    Greville points: ``A1 P A2^T = X`` with the 1-D collocation matrices, direction by direction."""
    control = np.linalg.solve(a1, values.reshape(len(a1), -1)).reshape(values.shape)
    control = np.linalg.solve(a2, control.transpose(1, 0, 2).reshape(len(a2), -1))
    return control.reshape(len(a2), len(a1), 3).transpose(1, 0, 2)


def flat_rectangle(
    length1: float,
    length2: float,
    n1: int,
    n2: int,
    *,
    degree: int,
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> BSplineSurface:
    """A flat ``length1 x length2`` sheet (:func:`~bhem_hpc.geometry.surface.rectangle_shape`)."""
    grid, position = rectangle_shape(length1, length2, n1, n2, origin)
    return from_callable(position, grid, degree=degree)


def cylinder(
    radius: float,
    length: float,
    n_along: int,
    n_around: int,
    *,
    degree: int,
    closed: bool = True,
    angle: float = 2 * math.pi,
    seam_angle: float = 0.0,
) -> BSplineSurface:
    """A cylinder about the z axis (:func:`~bhem_hpc.geometry.surface.cylinder_shape`), periodic when ``closed``."""
    grid, position = cylinder_shape(radius, length, n_along, n_around, closed, angle, seam_angle)
    return from_callable(position, grid, degree=degree)


def sphere_zone(
    radius: float, polar_min: float, polar_max: float, n_polar: int, n_azimuth: int, *, degree: int,
    azimuth: tuple[float, float] = (0.0, 2 * math.pi), closed: bool | None = None,
) -> BSplineSurface:  # fmt: skip
    """Zone or sector of a sphere (:func:`~bhem_hpc.geometry.surface.sphere_zone_shape`)."""
    grid, position = sphere_zone_shape(radius, polar_min, polar_max, n_polar, n_azimuth, azimuth, closed)
    return from_callable(position, grid, degree=degree)


def annulus_sector(
    r_inner: float, r_outer: float, angle_min: float, angle_max: float, n_radial: int, n_angular: int, *,
    degree: int, closed: bool | None = None,
) -> BSplineSurface:  # fmt: skip
    """Flat annulus sector (:func:`~bhem_hpc.geometry.surface.annulus_sector_shape`); a full turn is
    closed unless ``closed=False`` (a slit annulus)."""
    grid, position = annulus_sector_shape(r_inner, r_outer, angle_min, angle_max, n_radial, n_angular, closed)
    return from_callable(position, grid, degree=degree)


def torus(major_radius: float, minor_radius: float, n_major: int, n_minor: int, *, degree: int) -> BSplineSurface:
    """Torus about z, closed in both parameters (:func:`~bhem_hpc.geometry.surface.torus_shape`)."""
    grid, position = torus_shape(major_radius, minor_radius, n_major, n_minor)
    return from_callable(position, grid, degree=degree)


#: The surface kinds a scene or a file can name, by their discretization.
DISCRETIZATIONS = ("hermite", "bspline2", "bspline3")
#: Gauss points per direction by discretization: the BHEM paper's 4 x 4 for bicubic patches, and the
#: standard p + 1 points of a degree-p spline (3 x 3 for quadratic B-splines, as the B-spline paper).
DEFAULT_QUADRATURE = {"hermite": 4, "bspline2": 3, "bspline3": 4, "nurbs2": 3, "nurbs3": 4}


def surface_from_nodal(discretization: str, grid: ParameterGrid, nodal: np.ndarray,
                       weights: np.ndarray | None = None, knots: Knots | None = None):  # fmt: skip
    """The surface of nodal data ``(m1, m2, kinds, 3)`` (``surface.nodal``) for a discretization name
    (``nurbs2``, ``nurbs3``: with the control points' ``weights`` and the part's own ``knots``)."""
    from bhem_hpc.geometry.rational_bspline import RationalBSplineSurface
    from bhem_hpc.geometry.surface import HermiteSurface

    if discretization == "hermite":
        return HermiteSurface(grid, nodal)
    if discretization in ("nurbs2", "nurbs3") and weights is not None:
        return RationalBSplineSurface(grid, int(discretization[-1]), np.asarray(nodal)[:, :, 0], weights, knots)
    if discretization in DISCRETIZATIONS:
        return BSplineSurface(grid, int(discretization[-1]), np.asarray(nodal)[:, :, 0])
    raise SurfaceError(f"discretization {discretization!r} does not exist; expected one of {DISCRETIZATIONS}")
