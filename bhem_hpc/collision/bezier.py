"""Bicubic Bezier nets: conversion from Hermite nodal data, evaluation, splitting, bounds.

A net has shape ``(4, 4, 3)`` indexed ``[i, j, xyz]``: control point ``p_ij`` of
``x(u, v) = sum_ij B_i(u) B_j(v) p_ij`` (paper eq. 22) with local parameters ``u, v in [0, 1]``.
"""

from __future__ import annotations

import numpy as np

from bhem_hpc.geometry.surface import HermiteSurface, ParameterGrid


def control_nets(grid: ParameterGrid, nodal: np.ndarray) -> np.ndarray:
    """Exact Bezier nets of every patch, ``(n1 * n2, 4, 4, 3)`` in patch order ``p1 * n2 + p2``.

    ``nodal`` is Hermite nodal data ``(m1, m2, 4, 3)``: positions, or velocities (the map is linear,
    so velocities of control points come out the same way).
    """
    return HermiteSurface(grid, nodal).bezier_control_points().reshape(-1, 4, 4, 3)


def _bernstein(t: np.ndarray, derivative: int = 0) -> np.ndarray:
    """Cubic Bernstein polynomials (or their first or second derivatives) at ``t``: shape ``t.shape + (4,)``."""
    t = np.asarray(t, dtype=float)
    s = 1.0 - t
    out = np.empty(t.shape + (4,))  # filled column by column: np.stack costs more than the arithmetic
    if derivative == 0:
        out[..., 0], out[..., 1], out[..., 2], out[..., 3] = s**3, 3 * t * s**2, 3 * t**2 * s, t**3
    elif derivative == 1:
        out[..., 0], out[..., 1], out[..., 2], out[..., 3] = (
            -3 * s**2,
            3 * s**2 - 6 * t * s,
            6 * t * s - 3 * t**2,
            3 * t**2,
        )
    elif derivative == 2:
        out[..., 0], out[..., 1], out[..., 2], out[..., 3] = 6 * s, 6 * t - 12 * s, 6 * s - 12 * t, 6 * t
    else:
        raise ValueError(f"Bernstein derivative order must be 0, 1 or 2, got {derivative!r}")
    return out


def evaluate(net: np.ndarray, u: np.ndarray, v: np.ndarray, du: int = 0, dv: int = 0) -> np.ndarray:
    """Point (or first partial derivative) of a net at local parameters; shape ``S + (3,)``."""
    return np.einsum("...i,...j,ijc->...c", _bernstein(u, du), _bernstein(v, dv), net)


def evaluate_many(nets: np.ndarray, u: np.ndarray, v: np.ndarray, du: int = 0, dv: int = 0) -> np.ndarray:
    """One point (or partial derivative) per net: nets ``(N, 4, 4, C)``, ``u, v (N,)`` -> ``(N, C)``
    (``C = 3``: points; ``C = 4``: homogeneous coordinates of a rational net)."""
    components = nets.shape[-1]
    # two batched matrix products: several times faster than one three-operand einsum
    along_u = np.matmul(_bernstein(u, du)[:, None, :], nets.reshape(len(nets), 4, 4 * components))
    return np.matmul(_bernstein(v, dv)[:, None, :], along_u.reshape(-1, 4, components))[:, 0]


def _split_curves(points: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """de Casteljau on axis 0 of ``(4, ...)`` control polygons: the two halves at ``t``."""
    p = points
    a = (1 - t) * p[:-1] + t * p[1:]
    b = (1 - t) * a[:-1] + t * a[1:]
    c = (1 - t) * b[:-1] + t * b[1:]
    left = np.stack([p[0], a[0], b[0], c[0]])
    right = np.stack([c[0], b[1], a[2], p[3]])
    return left, right


def split_u(net: np.ndarray, u: float) -> tuple[np.ndarray, np.ndarray]:
    """The nets of ``[0, u]`` and ``[u, 1]`` in the first parameter (exact)."""
    return _split_curves(net, u)


def split_v(net: np.ndarray, v: float) -> tuple[np.ndarray, np.ndarray]:
    """The nets of ``[0, v]`` and ``[v, 1]`` in the second parameter (exact)."""
    left, right = _split_curves(np.swapaxes(net, 0, 1), v)
    return np.swapaxes(left, 0, 1), np.swapaxes(right, 0, 1)


def subpatch(net: np.ndarray, u0: float, u1: float, v0: float, v1: float) -> np.ndarray:
    """The net of the sub-rectangle ``[u0, u1] x [v0, v1]`` (exact, by two splits per direction)."""
    if not (0.0 <= u0 < u1 <= 1.0 and 0.0 <= v0 < v1 <= 1.0):
        raise ValueError(f"sub-rectangle [{u0}, {u1}] x [{v0}, {v1}] is not inside [0, 1]^2")
    out = net
    if u1 < 1.0:
        out = split_u(out, u1)[0]
    if u0 > 0.0:
        out = split_u(out, u0 / u1)[1]
    if v1 < 1.0:
        out = split_v(out, v1)[0]
    if v0 > 0.0:
        out = split_v(out, v0 / v1)[1]
    return out


def _restriction_matrices(t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """``(N, 4, 4)`` matrices taking a cubic's Bezier control points to those of its piece on
    ``[t0, t1]`` (de Casteljau applied to the identity: split at t1, keep the left part, split that
    at t0 / t1, keep the right part; a split at 1 or 0 keeps the curve exactly)."""
    points = np.broadcast_to(np.eye(4), (len(t0), 4, 4))
    for t, keep_right in ((t1, False), (t0 / t1, True)):
        t = t[:, None]
        a = (1 - t[:, None]) * points[:, :-1] + t[:, None] * points[:, 1:]
        b = (1 - t[:, None]) * a[:, :-1] + t[:, None] * a[:, 1:]
        c = (1 - t[:, None]) * b[:, :-1] + t[:, None] * b[:, 1:]
        if keep_right:
            points = np.stack([c[:, 0], b[:, 1], a[:, 2], points[:, 3]], axis=1)
        else:
            points = np.stack([points[:, 0], a[:, 0], b[:, 0], c[:, 0]], axis=1)
    return points


def subpatch_many(nets: np.ndarray, u0: np.ndarray, u1: np.ndarray, v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """:func:`subpatch` of ``nets (N, 4, 4, 3)``, one sub-rectangle each (``(N,)`` bounds, u0 < u1)."""
    count = len(nets)
    along_u = np.matmul(_restriction_matrices(u0, u1), nets.reshape(count, 4, 12)).reshape(count, 4, 4, 3)
    return np.matmul(_restriction_matrices(v0, v1)[:, None], along_u)


def bounds_many(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-row minimum and maximum of ``(N, 2^k, 3)`` points, ``(N, 3)`` each (pairwise halving:
    much faster than a strided ``min(axis=1)``)."""
    lo = hi = points
    while lo.shape[1] > 1:
        half = lo.shape[1] // 2
        lo = np.minimum(lo[:, :half], lo[:, half:])
        hi = np.maximum(hi[:, :half], hi[:, half:])
    return lo[:, 0], hi[:, 0]


def aabb(net: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds of the control points (they contain the patch), ``(3,)`` each."""
    points = np.asarray(net).reshape(-1, 3)
    return points.min(axis=0), points.max(axis=0)
