"""Cubic Hermite basis functions in one parameter (numpy only).

The bicubic Hermite patch of the paper (eqs. 14-15, Appendix A) is the tensor product of two
cubic Hermite interpolants. Everything here works in *local* patch coordinates theta in [0, 1];
scaling to parametric units (a patch of width h) is done by the caller.

Local DOF order in one parameter: ``(value at 0, derivative at 0, value at 1, derivative at 1)``,
derivatives taken with respect to theta.
"""

from __future__ import annotations

import numpy as np

# Hermite -> Bezier control points, one parameter: b = HERMITE_TO_BEZIER @ (v0, t0, v1, t1).
HERMITE_TO_BEZIER = np.array(
    [
        [1.0, 0.0, 0.0, 0.0],
        [1.0, 1.0 / 3.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, -1.0 / 3.0],
        [0.0, 0.0, 1.0, 0.0],
    ]
)


def basis(theta: np.ndarray, derivative: int = 0) -> np.ndarray:
    """Cubic Hermite basis functions (or their theta-derivatives) at ``theta``.

    Args:
        theta: local coordinates, any shape ``S``.
        derivative: 0, 1 or 2.

    Returns:
        Array of shape ``S + (4,)`` in the local DOF order (v0, t0, v1, t1).
    """
    t = np.asarray(theta, dtype=float)
    if derivative == 0:
        cols = (2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t, -2 * t**3 + 3 * t**2, t**3 - t**2)
    elif derivative == 1:
        cols = (6 * t**2 - 6 * t, 3 * t**2 - 4 * t + 1, -6 * t**2 + 6 * t, 3 * t**2 - 2 * t)
    elif derivative == 2:
        cols = (12 * t - 6, 6 * t - 4, -12 * t + 6, 6 * t - 2)
    else:
        raise ValueError(f"Hermite basis derivative order must be 0, 1 or 2, got {derivative!r}")
    return np.stack(cols, axis=-1)


def gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre points and weights on [0, 1] (``n`` points, exact to degree 2n-1)."""
    points, weights = np.polynomial.legendre.leggauss(n)
    return 0.5 * (points + 1.0), 0.5 * weights
