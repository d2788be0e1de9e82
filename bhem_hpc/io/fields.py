"""Pointwise fields of a deformed surface for output (numpy only): curvature, energy densities."""

from __future__ import annotations

import numpy as np

from bhem_hpc.geometry.surface import SurfacePoint
from bhem_hpc.model.material import Material


def fundamental_forms(point: SurfacePoint) -> tuple[np.ndarray, np.ndarray]:
    """First and second fundamental forms ``(a, b)``, each of shape ``S + (2, 2)``."""
    a1, a2, n = point.a1, point.a2, point.normal
    a = np.empty(a1.shape[:-1] + (2, 2))
    b = np.empty_like(a)
    a[..., 0, 0], a[..., 1, 1] = np.einsum("...c,...c->...", a1, a1), np.einsum("...c,...c->...", a2, a2)
    a[..., 0, 1] = a[..., 1, 0] = np.einsum("...c,...c->...", a1, a2)
    b[..., 0, 0], b[..., 1, 1] = np.einsum("...c,...c->...", point.a11, n), np.einsum("...c,...c->...", point.a22, n)
    b[..., 0, 1] = b[..., 1, 0] = np.einsum("...c,...c->...", point.a12, n)
    return a, b


def inverse_2x2(m: np.ndarray) -> np.ndarray:
    """The inverses of matrices ``m`` of shape ``S + (2, 2)`` by their adjugates: numpy's batched
    ``inv`` calls LAPACK once per matrix, about 70 microseconds each (4.7 s for one output frame's
    metrics of a 30 x 30 patch sheet, measured), the closed form a vector operation."""
    det = m[..., 0, 0] * m[..., 1, 1] - m[..., 0, 1] * m[..., 1, 0]
    adjugate = np.stack([np.stack([m[..., 1, 1], -m[..., 0, 1]], -1), np.stack([-m[..., 1, 0], m[..., 0, 0]], -1)], -2)
    return adjugate / det[..., None, None]


def _trace_of_product(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """``tr(left right)`` of matrices ``S + (2, 2)`` (without the products' off-diagonal entries)."""
    return np.einsum("...ij,...ji->...", left, right)


def mean_curvature(point: SurfacePoint, forms: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """``H = tr(a^-1 b) / 2`` (sign follows the normal a1 x a2), shape ``S``; ``forms``: the point's
    :func:`fundamental_forms` where the caller has them."""
    a, b = fundamental_forms(point) if forms is None else forms
    return 0.5 * _trace_of_product(inverse_2x2(a), b)


class RestMetric:
    """What the energy densities need of the rest surface at a set of points: the inverse of its
    first fundamental form and both forms, each ``S + (2, 2)`` (an output series computes them once)."""

    def __init__(self, rest: SurfacePoint):
        self.first, self.second = fundamental_forms(rest)
        self.inverse = inverse_2x2(self.first)


def energy_densities(rest: RestMetric, current: SurfacePoint, material: Material,
                     forms: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Membrane and bending energy per unit rest area (paper eqs. 7-8), each of shape ``S``, from the
    rest surface's metric at the points; ``forms``: the current points' :func:`fundamental_forms`
    where the caller has them."""
    a, b = fundamental_forms(current) if forms is None else forms
    nu, young = material.poisson, material.young
    lmbda, mu = young * nu / (1 - nu**2), young / (2 * (1 + nu))
    inverse = rest.inverse

    def svk(strain: np.ndarray) -> np.ndarray:
        mixed = np.matmul(inverse, strain)
        return 0.5 * lmbda * np.trace(mixed, axis1=-2, axis2=-1) ** 2 + mu * _trace_of_product(mixed, mixed)

    h = material.thickness
    return h * svk(0.5 * (a - rest.first)), h**3 / 3 * svk(0.5 * (b - rest.second))
