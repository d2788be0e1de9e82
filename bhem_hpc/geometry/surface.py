"""Parametric bicubic Hermite surfaces (numpy only; no dolfinx, PETSc or MPI).

A :class:`HermiteSurface` stores nodal data on a uniform ``n1 x n2`` grid of patches over a
rectangle of parameter space (paper §4.1, Fig. 6). Each node carries four vectors in R^3,
the *parametric* derivatives

    kind 0: x,   kind 1: dx/dxi1,   kind 2: dx/dxi2,   kind 3: d2x/dxi1 dxi2.

The nodal array has shape ``(m1, m2, 4, 3)`` indexed ``[i1, i2, kind, component]`` where
``m_a = n_a`` if the surface is periodic (closed) in xi_a and ``n_a + 1`` otherwise: a closed
direction stores each seam node once (paper §4.2).

This module is the single source of geometry for the solver's initial/rest state, for output,
for collision and for rendering. Conversion to the finite element's reference-cell DOFs happens
in :mod:`bhem_hpc.discretization` and nowhere else.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from bhem_hpc.geometry import hermite
from bhem_hpc.geometry.grid import (  # re-exported: the surfaces' grid and files
    ParameterGrid,
    SurfaceError,
    load_surface_file,
    save_surface_file,
)

KIND_NAMES = ("x", "d1", "d2", "d12")
FILE_FORMAT = "bhem-hermite-surface"
FILE_VERSION = 1


@dataclass(frozen=True)
class SurfacePoint:
    """Geometry at a set of parameters; each array has shape ``S + (3,)``."""

    x: np.ndarray
    a1: np.ndarray
    a2: np.ndarray
    a11: np.ndarray
    a12: np.ndarray
    a22: np.ndarray

    @staticmethod
    def of(derivative: Callable[[int, int], np.ndarray]) -> SurfacePoint:
        """The point from ``derivative(d1, d2)``, the parametric derivative ``d^(d1+d2) x / dxi1^d1 dxi2^d2``."""
        return SurfacePoint(
            x=derivative(0, 0),
            a1=derivative(1, 0),
            a2=derivative(0, 1),
            a11=derivative(2, 0),
            a12=derivative(1, 1),
            a22=derivative(0, 2),
        )

    @functools.cached_property
    def normal(self) -> np.ndarray:
        n = np.cross(self.a1, self.a2)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)


def tensor_product_point(coefficients: np.ndarray, basis1: np.ndarray, basis2: np.ndarray,
                         shape: tuple[int, ...]) -> SurfacePoint:  # fmt: skip
    """The point and its first and second derivatives from tensor-product ``coefficients (K, a, b, 3)``
    of ``K`` points and the one-parameter bases ``basis1 (K, 3, a)``, ``basis2 (K, 3, b)`` (values,
    first and second derivatives, in the parameters the derivatives are wanted in): arrays of
    ``shape + (3,)``. Two batched products, the first parameter first (numpy's three-operand einsum,
    one per derivative, took 2.5 times as long: an output frame of a 30 x 30 patch sheet
    evaluates 14,641 points)."""
    count, a, b, _ = coefficients.shape
    along1 = np.matmul(basis1, coefficients.reshape(count, a, 3 * b))  # [point, d1, (b, component)]
    along1 = along1.reshape(count, 3, b, 3).transpose(0, 2, 1, 3).reshape(count, b, 9)  # [point, b, (d1, component)]
    both = np.matmul(basis2, along1).reshape(count, 3, 3, 3)  # [point, d2, d1, component]
    return SurfacePoint.of(lambda d1, d2: both[:, d2, d1].reshape(*shape, 3))


class HermiteSurface:
    """A C1 surface made of bicubic Hermite patches.

    Args:
        grid: the parameter grid.
        nodal: array of shape ``(m1, m2, 4, 3)`` indexed ``[i1, i2, kind, component]``
            (see module docstring); copied.
    """

    def __init__(self, grid: ParameterGrid, nodal: np.ndarray):
        nodal = np.array(nodal, dtype=float)
        expected = (*grid.node_shape, 4, 3)
        if nodal.shape != expected:
            raise SurfaceError(f"nodal data has shape {nodal.shape}, expected {expected} for {grid}")
        if not np.all(np.isfinite(nodal)):
            where = np.argwhere(~np.isfinite(nodal))[0]
            raise SurfaceError(
                f"nodal data contains NaN/Inf: value {nodal[tuple(where)]!r} at node ({where[0]}, {where[1]}), "
                f"kind {KIND_NAMES[where[2]]}, component {where[3]}"
            )
        self.grid = grid
        self.nodal = nodal

    # -- evaluation ---------------------------------------------------------------------------
    def patch_coefficients(self, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
        """Hermite coefficients of patches in local (theta) units.

        Returns:
            Array of shape ``S + (4, 4, 3)`` indexed ``[..., a, b, component]`` where ``a`` and
            ``b`` run over the one-parameter local DOFs (v0, t0, v1, t1) in xi1 and xi2.
        """
        g = self.grid
        p1 = np.asarray(p1)
        p2 = np.asarray(p2)
        coeffs = np.empty(p1.shape + (4, 4, 3))
        for c1 in (0, 1):
            for c2 in (0, 1):
                i1, i2 = g.wrap_node(p1 + c1, p2 + c2)
                node = self.nodal[i1, i2]  # S + (4, 3)
                coeffs[..., 2 * c1, 2 * c2, :] = node[..., 0, :]
                coeffs[..., 2 * c1 + 1, 2 * c2, :] = g.h1 * node[..., 1, :]
                coeffs[..., 2 * c1, 2 * c2 + 1, :] = g.h2 * node[..., 2, :]
                coeffs[..., 2 * c1 + 1, 2 * c2 + 1, :] = g.h1 * g.h2 * node[..., 3, :]
        return coeffs

    def evaluate(self, xi1: np.ndarray, xi2: np.ndarray) -> SurfacePoint:
        """Position and first and second parametric derivatives at parameters ``(xi1, xi2)``."""
        g = self.grid
        p1, p2, t1, t2 = g.locate(xi1, xi2)
        basis1 = np.stack([hermite.basis(t1, d).reshape(-1, 4) / g.h1**d for d in range(3)], axis=1)
        basis2 = np.stack([hermite.basis(t2, d).reshape(-1, 4) / g.h2**d for d in range(3)], axis=1)
        return tensor_product_point(self.patch_coefficients(p1, p2).reshape(-1, 4, 4, 3), basis1, basis2, p1.shape)

    def point_weights(
        self, p1: np.ndarray, p2: np.ndarray, t1: np.ndarray, t2: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Linear map from nodal data to points: ``x = sum_j weights[..., j] nodal_flat[index[..., j]]``.

        Args:
            p1, p2: patch indices, shape ``S``; t1, t2: local coordinates in [0, 1], shape ``S``.

        Returns:
            ``(index, weights)`` of shape ``S + (16,)``: rows of ``nodal.reshape(-1, 3)``
            (flat ``(i1 * m2 + i2) * 4 + kind``) and the parametric Hermite basis values. The
            same map takes nodal velocities to point velocities (it is linear and fixed).
        """
        return point_weights(self.grid, p1, p2, t1, t2)

    def bezier_control_points(self) -> np.ndarray:
        """Exact Bezier control nets of all patches.

        Returns:
            Array of shape ``(n1, n2, 4, 4, 3)`` indexed ``[p1, p2, k1, k2, component]``; the
            patch is ``sum_k1,k2 B3_k1(theta1) B3_k2(theta2) P[k1, k2]``.
        """
        g = self.grid
        p1, p2 = np.meshgrid(np.arange(g.n1), np.arange(g.n2), indexing="ij")
        coeffs = self.patch_coefficients(p1, p2).reshape(g.n1, g.n2, 16, 3)
        # P[k, l] = sum_ab C[k, a] C[l, b] coeffs[a, b]: one (16, 16) matrix product per patch
        # (the three-operand einsum was ten times slower; contact detection calls this every round)
        c = hermite.HERMITE_TO_BEZIER
        return np.matmul(np.kron(c, c), coeffs).reshape(g.n1, g.n2, 4, 4, 3)

    def nurbs(self, name: str = "shell"):
        """The same surface, exactly, as a bicubic NURBS part (weights 1, every interior node a knot
        of multiplicity 3: the patches' Bezier nets side by side), for writing the model back."""
        from bhem_hpc.geometry.nurbs import NurbsSurface  # the CAD geometry loads for CAD output only

        g, nets = self.grid, self.bezier_control_points()
        control = np.empty((3 * g.n1 + 1, 3 * g.n2 + 1, 3))
        for k in range(4):
            for m in range(4):
                control[k : 3 * g.n1 + k : 3, m : 3 * g.n2 + m : 3] = nets[:, :, k, m]
        knots = [np.r_[lo, np.repeat(np.linspace(lo, hi, n + 1), 3), hi]
                 for n, (lo, hi) in ((g.n1, g.xi1_range), (g.n2, g.xi2_range))]  # fmt: skip
        return NurbsSurface((3, 3), *knots, control, None, name)

    def tessellate(self, density: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Quad mesh sampling every patch on a ``(density+1)^2`` grid (shared edges merged).

        Returns:
            ``(points, quads, params)``: points ``(P, 3)``, quads ``(Q, 4)`` (counter-clockwise
            in parameter space), params ``(P, 2)``.
        """
        if int(density) < 1:
            raise SurfaceError(f"tessellation density must be >= 1, got {density!r}")
        g = self.grid
        s1 = g.n1 * density + (0 if g.periodic1 else 1)
        s2 = g.n2 * density + (0 if g.periodic2 else 1)
        xi1 = g.xi1_range[0] + g.h1 / density * np.arange(s1)
        xi2 = g.xi2_range[0] + g.h2 / density * np.arange(s2)
        x1, x2 = np.meshgrid(xi1, xi2, indexing="ij")
        points = self.evaluate(x1, x2).x.reshape(-1, 3)
        i, j = np.meshgrid(np.arange(g.n1 * density), np.arange(g.n2 * density), indexing="ij")
        i, j = i.ravel(), j.ravel()

        def vid(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            return np.mod(a, s1) * s2 + np.mod(b, s2)

        quads = np.stack([vid(i, j), vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1)], axis=1)
        return points, quads, np.stack([x1.ravel(), x2.ravel()], axis=1)

    # -- checks --------------------------------------------------------------------------------
    def check_regular(self, quadrature_points: int = 4, name: str = "surface") -> None:
        """Raise :class:`SurfaceError` if ``|a1 x a2|`` vanishes at a Gauss point of any patch."""
        check_regular(self, quadrature_points, name)

    @property
    def node_shape(self) -> tuple[int, int]:
        """The nodes that carry data, ``(m1, m2)`` (distinct nodes)."""
        return self.grid.node_shape

    #: Kinds of nodal data per node: x, d1, d2, d12.
    kind_count = 4
    #: The discretization whose DOFs are this surface's data.
    discretization = "hermite"

    def model_parameters(self, xi1: np.ndarray, xi2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The parameters of the model the surface was made from (the same)."""
        return np.asarray(xi1, dtype=float), np.asarray(xi2, dtype=float)

    def surface_parameters(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The inverse of :meth:`model_parameters` (the same)."""
        return np.asarray(u, dtype=float), np.asarray(v, dtype=float)

    def bezier_nets(self) -> np.ndarray:
        """Exact bicubic Bezier nets ``(n1 * n2, 4, 4, 3)`` of every patch (order ``p1 * n2 + p2``)."""
        return self.bezier_control_points().reshape(-1, 4, 4, 3)

    def with_nodal(self, nodal: np.ndarray) -> HermiteSurface:
        """The surface on the same grid with other nodal data ``(m1, m2, 4, 3)``."""
        return HermiteSurface(self.grid, nodal)

    # -- transformations -----------------------------------------------------------------------
    def transformed(self, rotation: np.ndarray, translation: np.ndarray) -> HermiteSurface:
        """The rigidly (or linearly) moved surface ``x -> R x + t``."""
        nodal = np.einsum("ij,...j->...i", np.asarray(rotation, float), self.nodal)
        nodal[:, :, 0, :] += np.asarray(translation, float)
        return HermiteSurface(self.grid, nodal)

    # -- files ---------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the surface as a ``.npz`` nodal data file (format in README.md)."""
        save_surface_file(path, FILE_FORMAT, FILE_VERSION, self.grid, nodal=self.nodal)

    @classmethod
    def load(cls, path: str | Path) -> HermiteSurface:
        """Read a nodal data file written by :meth:`save`; errors name the file and key."""
        grid, arrays = load_surface_file(path, FILE_FORMAT, FILE_VERSION, ("nodal",), "nodal data file")
        try:
            return cls(grid, arrays["nodal"])
        except (SurfaceError, ValueError, TypeError) as exc:
            raise SurfaceError(f"{path}: {exc}") from exc


# ---------------------------------------------------------------------------------------------
# Constructors
# ---------------------------------------------------------------------------------------------
Field = Callable[[np.ndarray, np.ndarray], np.ndarray]


def check_regular(surface, quadrature_points: int = 4, name: str = "surface") -> None:
    """Raise :class:`SurfaceError` if ``|a1 x a2|`` of ``surface`` (any surface with ``grid`` and
    ``evaluate``) vanishes at a Gauss point of any patch."""
    g = surface.grid
    q, _ = hermite.gauss_legendre(quadrature_points)
    p1, p2, t1, t2 = np.meshgrid(np.arange(g.n1), np.arange(g.n2), q, q, indexing="ij")
    xi1 = g.xi1_range[0] + (p1 + t1) * g.h1
    xi2 = g.xi2_range[0] + (p2 + t2) * g.h2
    pt = surface.evaluate(xi1, xi2)
    area = np.linalg.norm(np.cross(pt.a1, pt.a2), axis=-1)
    scale = np.linalg.norm(pt.a1, axis=-1) * np.linalg.norm(pt.a2, axis=-1)
    bad = ~(area > 1e-10 * np.maximum(scale, np.finfo(float).tiny))
    if np.any(bad):
        k = tuple(np.argwhere(bad)[0])
        raise SurfaceError(
            f"{name} is degenerate: |a1 x a2| = {area[k]:.3e} at quadrature point "
            f"(xi1, xi2) = ({xi1[k]:.6g}, {xi2[k]:.6g}) of patch ({k[0]}, {k[1]})"
        )


def point_weights(
    grid: ParameterGrid, p1: np.ndarray, p2: np.ndarray, t1: np.ndarray, t2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """See :meth:`HermiteSurface.point_weights` (this form needs only the grid)."""
    p1, p2, t1, t2 = np.broadcast_arrays(np.asarray(p1), np.asarray(p2), np.asarray(t1, float), np.asarray(t2, float))
    b1, b2 = hermite.basis(t1), hermite.basis(t2)  # S + (4,): (v0, t0, v1, t1)
    m2 = grid.node_shape[1]
    index = np.empty(p1.shape + (16,), dtype=np.int64)
    weights = np.empty(p1.shape + (16,))
    scale = (1.0, grid.h1, grid.h2, grid.h1 * grid.h2)  # parametric derivative -> local theta units
    j = 0
    for c1 in (0, 1):
        for c2 in (0, 1):
            i1, i2 = grid.wrap_node(p1 + c1, p2 + c2)
            base = (i1 * m2 + i2) * 4
            for kind, (a, b) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1))):
                index[..., j] = base + kind
                weights[..., j] = scale[kind] * b1[..., 2 * c1 + a] * b2[..., 2 * c2 + b]
                j += 1
    return index, weights


class PatchLayout(Protocol):
    """A surface's patches as linear maps of its flat entries ``(N, 3)`` (what contact detection uses).

    ``grid`` gives the patch topology (``n1 x n2`` patches, periodic directions); a point of patch
    ``(p1, p2)`` at local coordinates ``(t1, t2)`` is ``sum_j weights[j] entries[index[j]]``.
    """

    grid: ParameterGrid

    @property
    def num_entries(self) -> int: ...

    def point_entries(
        self, p1: np.ndarray, p2: np.ndarray, t1: np.ndarray, t2: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]: ...

    def patch_entries(self) -> np.ndarray: ...

    def bezier_nets(self, entries: np.ndarray) -> np.ndarray: ...


class HermitePatches:
    """The patches of a Hermite surface as linear maps of its flat entries ``nodal.reshape(-1, 3)``.

    What contact detection needs of a discretization's patches: the patch grid, the entries and
    weights of a point, the entries that move each patch, and the exact Bezier nets.
    """

    def __init__(self, grid: ParameterGrid):
        self.grid = grid

    @property
    def num_entries(self) -> int:
        return 4 * self.grid.num_nodes

    def point_entries(
        self, p1: np.ndarray, p2: np.ndarray, t1: np.ndarray, t2: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(index, weights)``, shape ``S + (16,)`` each, of the points: see :func:`point_weights`."""
        return point_weights(self.grid, p1, p2, t1, t2)

    def patch_entries(self) -> np.ndarray:
        """``(n1 * n2, 16)`` the entries that determine each patch (order ``p1 * n2 + p2``)."""
        p1, p2 = (a.ravel() for a in np.meshgrid(np.arange(self.grid.n1), np.arange(self.grid.n2), indexing="ij"))
        return point_weights(self.grid, p1, p2, 0.0, 0.0)[0]

    def bezier_nets(self, entries: np.ndarray) -> np.ndarray:
        """Exact Bezier nets ``(n1 * n2, 4, 4, 3)`` of entries ``(N, 3)`` (positions or velocities)."""
        nodal = np.asarray(entries).reshape(*self.grid.node_shape, 4, 3)
        return HermiteSurface(self.grid, nodal).bezier_control_points().reshape(-1, 4, 4, 3)


def from_callable(
    position: Field,
    grid: ParameterGrid,
    derivatives: tuple[Field, Field, Field] | None = None,
) -> HermiteSurface:
    """Interpolate ``x(xi1, xi2)`` at the nodes of ``grid``.

    Args:
        position: vectorized callable mapping two arrays of shape ``S`` to ``S + (3,)``.
        derivatives: optional callables for dx/dxi1, dx/dxi2 and d2x/dxi1dxi2 (same signature).
            When absent they are computed numerically: by complex step if ``position`` accepts
            complex input, otherwise by Richardson-extrapolated central differences.
    """
    xi1, xi2 = grid.node_parameters()
    nodal = np.empty((*xi1.shape, 4, 3))
    nodal[:, :, 0] = position(xi1, xi2)
    if derivatives is not None:
        for k, f in enumerate(derivatives, start=1):
            nodal[:, :, k] = f(xi1, xi2)
    else:
        scale = (grid.h1, grid.h2)
        nodal[:, :, 1], nodal[:, :, 2], nodal[:, :, 3] = numerical_derivatives(position, xi1, xi2, scale)
    return HermiteSurface(grid, nodal)


def _richardson(estimate: Callable[[float], np.ndarray], h0: float, levels: int = 7) -> np.ndarray:
    """Extrapolate an even-in-h difference quotient to h -> 0; pick per entry the best level."""
    rows = [[estimate(h0)]]
    best = rows[0][0]
    best_err = np.full(best.shape, np.inf)
    for i in range(1, levels):
        row = [estimate(h0 / 2**i)]
        factor = 4.0
        for j in range(1, i + 1):
            row.append(row[j - 1] + (row[j - 1] - rows[i - 1][j - 1]) / (factor - 1.0))
            factor *= 4.0
            err = np.maximum(np.abs(row[j] - row[j - 1]), np.abs(row[j] - rows[i - 1][j - 1]))
            better = err < best_err
            best = np.where(better, row[j], best)
            best_err = np.where(better, err, best_err)
        rows.append(row)
    return best


def numerical_derivatives(
    position: Field, xi1: np.ndarray, xi2: np.ndarray, scale: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """dx/dxi1, dx/dxi2 and d2x/dxi1dxi2 of ``position`` at ``(xi1, xi2)``, shapes ``S + (3,)``."""
    h1, h2 = 0.1 * scale[0], 0.1 * scale[1]
    try:
        probe = np.asarray(position(xi1 + 1e-30j, xi2), dtype=complex)
        complex_ok = np.all(np.isfinite(probe)) and np.any(probe.imag != 0.0)
    except (TypeError, ValueError):
        complex_ok = False
    if complex_ok:
        tiny = 1e-30

        def d1(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            return np.imag(position(a + tiny * 1j, b)) / tiny

        def d2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            return np.imag(position(a, b + tiny * 1j)) / tiny

        x1 = d1(xi1, xi2)
        x2 = d2(xi1, xi2)
        x12 = _richardson(lambda h: (d1(xi1, xi2 + h) - d1(xi1, xi2 - h)) / (2 * h), h2)
        return x1, x2, x12
    x1 = _richardson(lambda h: (position(xi1 + h, xi2) - position(xi1 - h, xi2)) / (2 * h), h1)
    x2 = _richardson(lambda h: (position(xi1, xi2 + h) - position(xi1, xi2 - h)) / (2 * h), h2)

    def mixed(h: float) -> np.ndarray:
        k = h * h2 / h1
        return (
            position(xi1 + h, xi2 + k)
            - position(xi1 + h, xi2 - k)
            - position(xi1 - h, xi2 + k)
            + position(xi1 - h, xi2 - k)
        ) / (4 * h * k)

    return x1, x2, _richardson(mixed, h1)


def _stack(*components: np.ndarray) -> np.ndarray:
    shape = np.broadcast(*components).shape
    return np.stack([np.broadcast_to(c, shape) for c in components], axis=-1)


# The shapes: each a parameter grid and its map x(xi1, xi2); the Hermite constructors below and the
# B-spline ones (:mod:`bhem_hpc.geometry.bspline`) build their surfaces from the same definitions.
Shape = tuple[ParameterGrid, Field]


def rectangle_shape(
    length1: float, length2: float, n1: int, n2: int, origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> Shape:
    """A flat ``length1 x length2`` sheet in the plane z = origin[2]; xi = in-plane coordinates."""
    grid = ParameterGrid(n1, n2, (0.0, float(length1)), (0.0, float(length2)))
    o = np.asarray(origin, float)
    zero = np.zeros(())
    return grid, lambda a, b: _stack(a + o[0], b + o[1], zero * a + o[2])


def cylinder_shape(
    radius: float, length: float, n_along: int, n_around: int, closed: bool, angle: float, seam_angle: float = 0.0
) -> Shape:
    """Cylinder about the z axis; xi1 = z in [0, length], xi2 = polar angle from ``seam_angle``
    (periodic when ``closed``, which needs ``angle == 2*pi``)."""
    if closed and not math.isclose(angle, 2 * math.pi):
        raise SurfaceError(f"a closed cylinder needs angle = 2*pi, got {angle!r}")
    grid = ParameterGrid(n_along, n_around, (0.0, float(length)), (seam_angle, seam_angle + angle), False, closed)
    r = float(radius)
    return grid, lambda z, p: _stack(r * np.cos(p), r * np.sin(p), z)


def _turn(name: str, low: float, high: float, closed: bool | None) -> bool:
    """Whether an angle range ``[low, high]`` is closed (periodic): by default when it is a full turn;
    ``closed=False`` on a full turn cuts it along one line (a slit with two separate edges)."""
    full = math.isclose(high - low, 2 * math.pi)
    if not 0 < high - low <= 2 * math.pi + 1e-12:
        raise SurfaceError(f"{name} needs an angle range of (0, 2*pi], got [{low!r}, {high!r}]")
    if closed and not full:
        raise SurfaceError(f"a closed {name} needs a full turn (angle range 2*pi), got [{low!r}, {high!r}]")
    return full if closed is None else bool(closed)


def sphere_zone_shape(
    radius: float, polar_min: float, polar_max: float, n_polar: int, n_azimuth: int,
    azimuth: tuple[float, float] = (0.0, 2 * math.pi), closed: bool | None = None,
) -> Shape:  # fmt: skip
    """Zone of a sphere between two polar angles (radians from +z) and two azimuths.

    xi1 = polar angle, xi2 = azimuth in ``azimuth`` (default a full turn, closed; an open sector
    otherwise, or with ``closed=False`` a full turn cut along one meridian). A zone touching a pole
    is degenerate (a1 x a2 = 0 there) and is rejected; use e.g. ``polar_min = 0.1`` for a hemisphere
    with a hole.
    """
    if not 0.0 < polar_min < polar_max < math.pi:
        raise SurfaceError(
            f"sphere zone needs 0 < polar_min < polar_max < pi (a pole is a degenerate parameter point), "
            f"got polar_min={polar_min!r}, polar_max={polar_max!r}"
        )
    low, high = (float(a) for a in azimuth)
    periodic = _turn("sphere zone", low, high, closed)
    grid = ParameterGrid(n_polar, n_azimuth, (float(polar_min), float(polar_max)), (low, high), False, periodic)
    r = float(radius)
    return grid, lambda t, p: _stack(r * np.sin(t) * np.cos(p), r * np.sin(t) * np.sin(p), r * np.cos(t))


def annulus_sector_shape(
    r_inner: float, r_outer: float, angle_min: float, angle_max: float, n_radial: int, n_angular: int,
    closed: bool | None = None,
) -> Shape:  # fmt: skip
    """Flat annulus sector in the z = 0 plane; xi1 = radius, xi2 = angle (periodic for a full turn
    unless ``closed=False``, which leaves a slit: two separate edges along the ray at ``angle_min``)."""
    closed = _turn("annulus sector", float(angle_min), float(angle_max), closed)
    if not (0 < r_inner < r_outer):
        raise SurfaceError(f"annulus sector needs 0 < r_inner < r_outer, got {r_inner!r}, {r_outer!r}")
    grid = ParameterGrid(n_radial, n_angular, (float(r_inner), float(r_outer)), (angle_min, angle_max), False, closed)
    return grid, lambda r, p: _stack(r * np.cos(p), r * np.sin(p), 0 * r)


def torus_shape(major_radius: float, minor_radius: float, n_major: int, n_minor: int) -> Shape:
    """Torus about z, closed in both parameters; xi1 = angle around z, xi2 = angle around the tube."""
    big, small = float(major_radius), float(minor_radius)
    if not (0 < small < big):
        raise SurfaceError(f"torus needs 0 < minor_radius < major_radius, got {small!r}, {big!r}")
    grid = ParameterGrid(n_major, n_minor, (0.0, 2 * math.pi), (0.0, 2 * math.pi), True, True)

    def position(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        ring = big + small * np.cos(v)
        return _stack(ring * np.cos(u), ring * np.sin(u), small * np.sin(v))

    return grid, position


def flat_rectangle(
    length1: float, length2: float, n1: int, n2: int, *, origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> HermiteSurface:
    """A flat ``length1 x length2`` sheet in the plane z = origin[2]; xi = in-plane coordinates."""
    grid, position = rectangle_shape(length1, length2, n1, n2, origin)
    zero = np.zeros(())
    one = np.ones(())
    return from_callable(
        position,
        grid,
        (
            lambda a, b: _stack(one + 0 * a, zero * a, zero * a),
            lambda a, b: _stack(zero * a, one + 0 * a, zero * a),
            lambda a, b: _stack(zero * a, zero * a, zero * a),
        ),
    )


def cylinder(
    radius: float,
    length: float,
    n_along: int,
    n_around: int,
    *,
    closed: bool = True,
    angle: float = 2 * math.pi,
    seam_angle: float = 0.0,
) -> HermiteSurface:
    """Cylinder about the z axis (:func:`cylinder_shape`): seam DOFs identified when ``closed``."""
    grid, position = cylinder_shape(radius, length, n_along, n_around, closed, angle, seam_angle)
    r = float(radius)
    zero = np.zeros(())
    return from_callable(
        position,
        grid,
        (
            lambda z, p: _stack(zero * z, zero * z, 1.0 + 0 * z),
            lambda z, p: _stack(-r * np.sin(p), r * np.cos(p), zero * z),
            lambda z, p: _stack(zero * z, zero * z, zero * z),
        ),
    )


def sphere_zone(
    radius: float, polar_min: float, polar_max: float, n_polar: int, n_azimuth: int, *,
    azimuth: tuple[float, float] = (0.0, 2 * math.pi), closed: bool | None = None,
) -> HermiteSurface:  # fmt: skip
    """Zone or sector of a sphere (:func:`sphere_zone_shape`), checked to be regular."""
    grid, position = sphere_zone_shape(radius, polar_min, polar_max, n_polar, n_azimuth, azimuth, closed)
    r = float(radius)
    surface = from_callable(
        position,
        grid,
        (
            lambda t, p: _stack(r * np.cos(t) * np.cos(p), r * np.cos(t) * np.sin(p), -r * np.sin(t)),
            lambda t, p: _stack(-r * np.sin(t) * np.sin(p), r * np.sin(t) * np.cos(p), 0 * t),
            lambda t, p: _stack(-r * np.cos(t) * np.sin(p), r * np.cos(t) * np.cos(p), 0 * t),
        ),
    )
    surface.check_regular(name="sphere zone")
    return surface


def annulus_sector(
    r_inner: float, r_outer: float, angle_min: float, angle_max: float, n_radial: int, n_angular: int, *,
    closed: bool | None = None,
) -> HermiteSurface:  # fmt: skip
    """Flat annulus sector (:func:`annulus_sector_shape`); a full turn is closed (periodic in xi2)
    unless ``closed=False`` (a slit annulus)."""
    grid, position = annulus_sector_shape(r_inner, r_outer, angle_min, angle_max, n_radial, n_angular, closed)
    return from_callable(
        position,
        grid,
        (
            lambda r, p: _stack(np.cos(p) + 0 * r, np.sin(p) + 0 * r, 0 * r),
            lambda r, p: _stack(-r * np.sin(p), r * np.cos(p), 0 * r),
            lambda r, p: _stack(-np.sin(p) + 0 * r, np.cos(p) + 0 * r, 0 * r),
        ),
    )


def torus(major_radius: float, minor_radius: float, n_major: int, n_minor: int) -> HermiteSurface:
    """Torus about z (:func:`torus_shape`), derivatives from the map."""
    grid, position = torus_shape(major_radius, minor_radius, n_major, n_minor)
    return from_callable(position, grid)
