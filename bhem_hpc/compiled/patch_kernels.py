"""Compiled building blocks on one rational Bezier net ``(p + 1, q + 1, 4)`` (homogeneous ``(w x, w
y, w z, w)``, positive weights; see :mod:`bhem_hpc.geometry.rational_bezier`): Bernstein rows,
evaluation with first derivatives, Newton's method for a ray's crossing, halving, boxes, the
affine and straightness tests and the sampled normal's signs. Every function works in
caller-given scratch arrays (no allocation per call)."""

from __future__ import annotations

import numpy as np
from numba import njit

from bhem_hpc.geometry import rational_bezier as rb

#: Samples per side of a piece where the sign of the normal's component is tested (as the numpy search).
SIGN_SAMPLES = rb.SIGN_SAMPLES
#: The numpy searches' bounds and tolerances, which the compiled ones share.
MAX_LEVEL, MAX_PIECE, EDGE_SLACK = rb.MAX_LEVEL, rb.MAX_PIECE, rb.EDGE_SLACK
NEWTON_ITERATIONS = rb.NEWTON_ITERATIONS
#: Pieces waiting on one search's stack: a split replaces one piece by at most four, MAX_LEVEL deep.
STACK = 3 * MAX_LEVEL + 4


@njit(cache=True, error_model="numpy")
def raise_degree(t: float, values: np.ndarray, degree: int) -> None:
    """Bernstein polynomials of ``degree - 1`` at ``t`` in ``values[:degree]`` to those of ``degree``
    in ``values[:degree + 1]``, in place (a row of Piegl and Tiller's triangle, A1.3)."""
    saved = 0.0
    for k in range(degree):
        temp = values[k]
        values[k] = saved + (1.0 - t) * temp
        saved = t * temp
    values[degree] = saved


@njit(cache=True, error_model="numpy")
def bernstein(t: float, degree: int, value: np.ndarray, slope: np.ndarray) -> None:
    """Bernstein polynomials of ``degree`` at ``t`` into ``value (degree + 1,)`` and their slopes
    into ``slope (degree + 1,)`` (the triangle stopped one row early for the slopes)."""
    value[0] = 1.0
    for row in range(1, degree):
        raise_degree(t, value, row)
    if degree == 0:
        slope[0] = 0.0
        return
    for k in range(degree + 1):  # p (B_(k-1),(p-1) - B_k,(p-1))
        left = value[k - 1] if k >= 1 else 0.0
        right = value[k] if k < degree else 0.0
        slope[k] = degree * (left - right)
    raise_degree(t, value, degree)


@njit(cache=True, error_model="numpy")
def evaluate(net: np.ndarray, s: float, t: float, basis: np.ndarray, out: np.ndarray) -> None:
    """The point and its derivatives along ``s`` and ``t`` into ``out (3, 3)`` (rows), ``basis (4,
    n)`` scratch with ``n`` at least the larger degree plus one."""
    p, q = net.shape[0] - 1, net.shape[1] - 1
    bernstein(s, p, basis[0], basis[1])
    bernstein(t, q, basis[2], basis[3])
    a0 = a1 = a2 = a3 = 0.0
    s0 = s1 = s2 = s3 = 0.0
    t0 = t1 = t2 = t3 = 0.0
    # twelve scalar sums, written out: numba keeps them in registers, where a (3, 4) array would be
    # allocated on every call
    for i in range(p + 1):
        bs, dbs = basis[0, i], basis[1, i]
        for j in range(q + 1):
            bt, dbt = basis[2, j], basis[3, j]
            value, along_s, along_t = bs * bt, dbs * bt, bs * dbt
            x, y, z, w = net[i, j, 0], net[i, j, 1], net[i, j, 2], net[i, j, 3]
            a0 += value * x
            a1 += value * y
            a2 += value * z
            a3 += value * w
            s0 += along_s * x
            s1 += along_s * y
            s2 += along_s * z
            s3 += along_s * w
            t0 += along_t * x
            t1 += along_t * y
            t2 += along_t * z
            t3 += along_t * w
    px, py, pz = a0 / a3, a1 / a3, a2 / a3
    out[0, 0], out[0, 1], out[0, 2] = px, py, pz
    out[1, 0], out[1, 1], out[1, 2] = (s0 - px * s3) / a3, (s1 - py * s3) / a3, (s2 - pz * s3) / a3
    out[2, 0], out[2, 1], out[2, 2] = (t0 - px * t3) / a3, (t1 - py * t3) / a3, (t2 - pz * t3) / a3


@njit(cache=True, error_model="numpy")
def row_normal(rows: np.ndarray) -> tuple[float, float, float]:
    """``rows[1] x rows[2]`` of a ``(3, 3)`` array: the normal ``x_s x x_t`` of an :func:`evaluate`
    output, or of a corner frame (corner, edge along s, edge along t)."""
    return (rows[1, 1] * rows[2, 2] - rows[1, 2] * rows[2, 1], rows[1, 2] * rows[2, 0] - rows[1, 0] * rows[2, 2],
            rows[1, 0] * rows[2, 1] - rows[1, 1] * rows[2, 0])  # fmt: skip


@njit(cache=True, error_model="numpy")
def quarters(net: np.ndarray, scratch: np.ndarray, out: np.ndarray, first: int) -> None:
    """The four quarters of ``net`` into ``out[first:first + 4]`` (each shaped as ``net``) in the
    order (s low, t low), (s high, t low), (s low, t high), (s high, t high); ``scratch (2, p + 1,
    q + 1, 4)``. De Casteljau at 1/2 in homogeneous coordinates: exact."""
    halves_along_s(net, scratch[0], scratch[1])
    halves_along_t(scratch[0], out[first], out[first + 2])
    halves_along_t(scratch[1], out[first + 1], out[first + 3])


@njit(cache=True, error_model="numpy")
def halves_along_s(net: np.ndarray, low: np.ndarray, high: np.ndarray) -> None:
    """The halves of ``net`` at ``s = 1/2``, written out up to cubics (the general triangle's
    loops cost ten times their arithmetic at these sizes)."""
    p = net.shape[0] - 1
    for j in range(net.shape[1]):
        for c in range(4):
            if p == 1:
                a, b = net[0, j, c], net[1, j, c]
                middle = 0.5 * (a + b)
                low[0, j, c], low[1, j, c], high[0, j, c], high[1, j, c] = a, middle, middle, b
            elif p == 2:
                a, b, d = net[0, j, c], net[1, j, c], net[2, j, c]
                ab, bd = 0.5 * (a + b), 0.5 * (b + d)
                middle = 0.5 * (ab + bd)
                low[0, j, c], low[1, j, c], low[2, j, c] = a, ab, middle
                high[0, j, c], high[1, j, c], high[2, j, c] = middle, bd, d
            elif p == 3:
                a, b, d, e = net[0, j, c], net[1, j, c], net[2, j, c], net[3, j, c]
                ab, bd, de = 0.5 * (a + b), 0.5 * (b + d), 0.5 * (d + e)
                abd, bde = 0.5 * (ab + bd), 0.5 * (bd + de)
                middle = 0.5 * (abd + bde)
                low[0, j, c], low[1, j, c], low[2, j, c], low[3, j, c] = a, ab, abd, middle
                high[0, j, c], high[1, j, c], high[2, j, c], high[3, j, c] = middle, bde, de, e
            else:
                for k in range(p + 1):
                    low[k, j, c] = high[k, j, c] = net[k, j, c]
                for r in range(1, p + 1):  # level r of the triangle: low[k] holds its k-th point for k >= r
                    for k in range(p, r - 1, -1):
                        low[k, j, c] = 0.5 * (low[k - 1, j, c] + low[k, j, c])
                    for k in range(p - r + 1):
                        high[k, j, c] = 0.5 * (high[k, j, c] + high[k + 1, j, c])


@njit(cache=True, error_model="numpy")
def halves_along_t(net: np.ndarray, low: np.ndarray, high: np.ndarray) -> None:
    """:func:`halves_along_s` along ``t`` (written out again: numba indexes transposed views ten
    times slower than contiguous arrays)."""
    q = net.shape[1] - 1
    for i in range(net.shape[0]):
        for c in range(4):
            if q == 1:
                a, b = net[i, 0, c], net[i, 1, c]
                middle = 0.5 * (a + b)
                low[i, 0, c], low[i, 1, c], high[i, 0, c], high[i, 1, c] = a, middle, middle, b
            elif q == 2:
                a, b, d = net[i, 0, c], net[i, 1, c], net[i, 2, c]
                ab, bd = 0.5 * (a + b), 0.5 * (b + d)
                middle = 0.5 * (ab + bd)
                low[i, 0, c], low[i, 1, c], low[i, 2, c] = a, ab, middle
                high[i, 0, c], high[i, 1, c], high[i, 2, c] = middle, bd, d
            elif q == 3:
                a, b, d, e = net[i, 0, c], net[i, 1, c], net[i, 2, c], net[i, 3, c]
                ab, bd, de = 0.5 * (a + b), 0.5 * (b + d), 0.5 * (d + e)
                abd, bde = 0.5 * (ab + bd), 0.5 * (bd + de)
                middle = 0.5 * (abd + bde)
                low[i, 0, c], low[i, 1, c], low[i, 2, c], low[i, 3, c] = a, ab, abd, middle
                high[i, 0, c], high[i, 1, c], high[i, 2, c], high[i, 3, c] = middle, bde, de, e
            else:
                for k in range(q + 1):
                    low[i, k, c] = high[i, k, c] = net[i, k, c]
                for r in range(1, q + 1):
                    for k in range(q, r - 1, -1):
                        low[i, k, c] = 0.5 * (low[i, k - 1, c] + low[i, k, c])
                    for k in range(q - r + 1):
                        high[i, k, c] = 0.5 * (high[i, k, c] + high[i, k + 1, c])


@njit(cache=True, error_model="numpy")
def straight_along(net: np.ndarray, along_s: bool) -> bool:
    """Whether ``net`` is of degree 1 along ``s`` (else ``t``) with equal weights at both ends of
    each line that way: its points then move on straight lines at constant speed along that
    parameter, in every sub-piece too."""
    if (net.shape[0] if along_s else net.shape[1]) != 2:
        return False
    for k in range(net.shape[1] if along_s else net.shape[0]):
        w0, w1 = (net[0, k, 3], net[1, k, 3]) if along_s else (net[k, 0, 3], net[k, 1, 3])
        if abs(w1 - w0) > 1e-12 * w0:
            return False
    return True


@njit(cache=True, error_model="numpy")
def affine_frame(net: np.ndarray, tolerance: float, frame: np.ndarray) -> bool:
    """Whether ``net`` is an affine map of its parameters within ``tolerance`` [m] (equal weights,
    control points where the corners' affine map puts them), with its corner ``(0, 0)`` and the
    edges to the corners ``(1, 0)`` and ``(0, 1)`` in ``frame (3, 3)`` (rows), always set."""
    p, q = net.shape[0] - 1, net.shape[1] - 1
    w00 = net[0, 0, 3]
    for c in range(3):
        frame[0, c] = net[0, 0, c] / w00
        frame[1, c] = net[p, 0, c] / net[p, 0, 3] - frame[0, c]
        frame[2, c] = net[0, q, c] / net[0, q, 3] - frame[0, c]
    for i in range(p + 1):
        for j in range(q + 1):
            w = net[i, j, 3]
            if abs(w - w00) > 1e-12 * w00:
                return False
            fraction_s = i / p if p > 0 else 0.0
            fraction_t = j / q if q > 0 else 0.0
            for c in range(3):
                affine = frame[0, c] + fraction_s * frame[1, c] + fraction_t * frame[2, c]
                if abs(net[i, j, c] / w - affine) > tolerance:
                    return False
    return True


@njit(cache=True, error_model="numpy")
def sample_table(degree: int) -> np.ndarray:
    """``(2, G, degree + 1)``: the Bernstein values and slopes of ``degree`` at the centres of
    ``G = SIGN_SAMPLES`` cells of the unit interval."""
    table = np.empty((2, SIGN_SAMPLES, degree + 1))
    for a in range(SIGN_SAMPLES):
        bernstein((a + 0.5) / SIGN_SAMPLES, degree, table[0, a], table[1, a])
    return table


@njit(cache=True, error_model="numpy")
def model_size(nets: np.ndarray) -> float:
    """The largest side of the box of the Cartesian control points of ``nets (P, p+1, q+1, 4)``."""
    low, high = np.full(3, np.inf), np.full(3, -np.inf)
    for n in range(nets.shape[0]):
        for i in range(nets.shape[1]):
            for j in range(nets.shape[2]):
                for c in range(3):
                    x = nets[n, i, j, c] / nets[n, i, j, 3]
                    low[c], high[c] = min(low[c], x), max(high[c], x)
    return max(high[0] - low[0], high[1] - low[1], high[2] - low[2])


@njit(cache=True, error_model="numpy")
def normal_component_range(net: np.ndarray, direction: np.ndarray, table_s: np.ndarray, table_t: np.ndarray,
                           rows: np.ndarray) -> tuple[float, float]:  # fmt: skip
    """Smallest and largest component along ``direction (3,)`` of the normal ``x_s x x_t`` over the
    centres of a ``SIGN_SAMPLES^2`` grid of ``net``'s parameter square, each over the largest
    normal there (as :func:`bhem_hpc.geometry.rational_bezier._piece_normal_components`), from the
    :func:`sample_tables` ``table_s, table_t``; ``rows (2, G, q + 1, 4)`` scratch."""
    p, q = net.shape[0] - 1, net.shape[1] - 1
    for a in range(SIGN_SAMPLES):  # the sums over i first: values and slopes along s
        for j in range(q + 1):
            for c in range(4):
                value = slope = 0.0
                for i in range(p + 1):
                    value += table_s[0, a, i] * net[i, j, c]
                    slope += table_s[1, a, i] * net[i, j, c]
                rows[0, a, j, c], rows[1, a, j, c] = value, slope
    low, high, size = np.inf, -np.inf, 0.0
    for a in range(SIGN_SAMPLES):
        for b in range(SIGN_SAMPLES):
            v0 = v1 = v2 = v3 = s0 = s1 = s2 = s3 = t0 = t1 = t2 = t3 = 0.0  # homogeneous sums
            for j in range(q + 1):
                bt, dbt = table_t[0, b, j], table_t[1, b, j]
                v0 += bt * rows[0, a, j, 0]
                v1 += bt * rows[0, a, j, 1]
                v2 += bt * rows[0, a, j, 2]
                v3 += bt * rows[0, a, j, 3]
                s0 += bt * rows[1, a, j, 0]
                s1 += bt * rows[1, a, j, 1]
                s2 += bt * rows[1, a, j, 2]
                s3 += bt * rows[1, a, j, 3]
                t0 += dbt * rows[0, a, j, 0]
                t1 += dbt * rows[0, a, j, 1]
                t2 += dbt * rows[0, a, j, 2]
                t3 += dbt * rows[0, a, j, 3]
            # x_s x x_t = (w P_s - w_s P) x (w P_t - w_t P) / w^4: one division
            sx, sy, sz = v3 * s0 - s3 * v0, v3 * s1 - s3 * v1, v3 * s2 - s3 * v2
            tx, ty, tz = v3 * t0 - t3 * v0, v3 * t1 - t3 * v1, v3 * t2 - t3 * v2
            scale = 1.0 / (v3 * v3 * v3 * v3)
            nx, ny, nz = (sy * tz - sz * ty) * scale, (sz * tx - sx * tz) * scale, (sx * ty - sy * tx) * scale
            size = max(size, np.sqrt(nx * nx + ny * ny + nz * nz))
            component = nx * direction[0] + ny * direction[1] + nz * direction[2]
            low, high = min(low, component), max(high, component)
    scale = size if size > 0.0 else 1.0
    return low / scale, high / scale


@njit(cache=True, error_model="numpy")
def cartesian_box(net: np.ndarray, low: np.ndarray, high: np.ndarray) -> None:
    """The box ``low, high (3,)`` of ``net``'s Cartesian control points (it holds the patch)."""
    for c in range(3):
        low[c], high[c] = np.inf, -np.inf
    for i in range(net.shape[0]):
        for j in range(net.shape[1]):
            for c in range(3):
                x = net[i, j, c] / net[i, j, 3]
                low[c], high[c] = min(low[c], x), max(high[c], x)


@njit(cache=True, error_model="numpy")
def ray_newton(net: np.ndarray, s: float, t: float, tau: float, origin: np.ndarray, direction: np.ndarray,  # noqa: PLR0913
               tolerance: float, iterations: int, basis: np.ndarray,
               point: np.ndarray) -> tuple[bool, float, float, float]:  # fmt: skip
    """Newton's method for ``x(s, t) = origin + tau direction`` from ``(s, t, tau)`` (as
    :func:`bhem_hpc.geometry.rational_bezier._ray_newton`): whether it converged within
    ``iterations`` (the residual's length at most ``tolerance``), and the last ``s, t, tau``;
    ``point (3, 3)`` holds the surface's point and derivatives there."""
    for _ in range(iterations):
        evaluate(net, s, t, basis, point)
        r0 = point[0, 0] - origin[0] - tau * direction[0]
        r1 = point[0, 1] - origin[1] - tau * direction[1]
        r2 = point[0, 2] - origin[2] - tau * direction[2]
        if np.sqrt(r0 * r0 + r1 * r1 + r2 * r2) <= tolerance:
            return True, s, t, tau
        # the columns x_s, x_t, -direction; Cramer's rule
        a0, a1, a2 = point[1, 0], point[1, 1], point[1, 2]
        b0, b1, b2 = point[2, 0], point[2, 1], point[2, 2]
        c0, c1, c2 = -direction[0], -direction[1], -direction[2]
        det = a0 * (b1 * c2 - b2 * c1) - b0 * (a1 * c2 - a2 * c1) + c0 * (a1 * b2 - a2 * b1)
        if abs(det) <= 1e-300:
            return False, s, t, tau
        ds = (r0 * (b1 * c2 - b2 * c1) - b0 * (r1 * c2 - r2 * c1) + c0 * (r1 * b2 - r2 * b1)) / det
        dt = (a0 * (r1 * c2 - r2 * c1) - r0 * (a1 * c2 - a2 * c1) + c0 * (a1 * r2 - a2 * r1)) / det
        dtau = (a0 * (b1 * r2 - b2 * r1) - b0 * (a1 * r2 - a2 * r1) + r0 * (a1 * b2 - a2 * b1)) / det
        s, t, tau = s - ds, t - dt, tau - dtau
        if not (-0.5 < s < 1.5 and -0.5 < t < 1.5):
            return False, s, t, tau
    return False, s, t, tau


#: The quarters' boxes in the local parameters of their parent, in the order of
#: :func:`quarters`: ``(s0, s1, t0, t1)``.
QUARTERS = np.array([(0.0, 0.5, 0.0, 0.5), (0.5, 1.0, 0.0, 0.5), (0.0, 0.5, 0.5, 1.0), (0.5, 1.0, 0.5, 1.0)])


@njit(cache=True, error_model="numpy")
def quarter_rects(rect: np.ndarray, level: int, rects: np.ndarray, levels: np.ndarray, first: int) -> None:
    """The parameter rectangles (s0, s1, t0, t1) of the quarters of the piece on ``rect`` at
    ``level`` into ``rects[first:first + 4]`` and their level into ``levels[first:first + 4]``, in the
    order of :func:`quarters` (``rect`` may be the row ``rects[first]``: read before written over)."""
    s0, s1, t0, t1 = rect[0], rect[1], rect[2], rect[3]
    width_s, width_t = s1 - s0, t1 - t0
    for k in range(4):
        rects[first + k, 0] = s0 + QUARTERS[k, 0] * width_s
        rects[first + k, 1] = s0 + QUARTERS[k, 1] * width_s
        rects[first + k, 2] = t0 + QUARTERS[k, 2] * width_t
        rects[first + k, 3] = t0 + QUARTERS[k, 3] * width_t
        levels[first + k] = level + 1


@njit(cache=True, error_model="numpy")
def push_quarters(piece, rect, level, scratch, stack, rects, levels, top) -> int:
    """Push the quarters of ``piece`` (on ``rect``, at ``level``) onto the stack at ``top``; the new top."""
    quarters(piece, scratch, stack, top)  # the piece was popped from top: read before written over
    quarter_rects(rect, level, rects, levels, top)
    return top + 4


@njit(cache=True, error_model="numpy")
def _push_halves(rect, level, along_s, scratch, stack, rects, levels, top) -> int:
    """Push the halves along ``s`` (else ``t``) of the piece at ``top`` (on ``rect``, at ``level``,
    just popped) onto the stack; the new top."""
    if along_s:
        halves_along_s(stack[top], scratch[0], scratch[1])
    else:
        halves_along_t(stack[top], scratch[0], scratch[1])
    stack[top], stack[top + 1] = scratch[0], scratch[1]
    middle = 0.5 * (rect[0] + rect[1]) if along_s else 0.5 * (rect[2] + rect[3])
    for k in range(2):
        rects[top + k] = rect
        levels[top + k] = level + 1
    if along_s:
        rects[top, 1] = rects[top + 1, 0] = middle
    else:
        rects[top, 3] = rects[top + 1, 2] = middle
    return top + 2


@njit(cache=True, error_model="numpy")
def split_onto_stack(piece, rect, level, large_s, large_t, scratch, stack, rects, levels, top) -> int:
    """Split the piece just popped from ``top`` along the directions in which it is large (both when
    neither is); the new top."""
    if large_s != large_t:
        return _push_halves(rect, level, large_s, scratch, stack, rects, levels, top)
    return push_quarters(piece, rect, level, scratch, stack, rects, levels, top)
