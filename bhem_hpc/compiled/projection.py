"""Closest points on NURBS surfaces, compiled: the projection of
:func:`bhem_hpc.geometry.projection.closest_points` (the same seeds, Newton's method on the
squared distance with Gauss-Newton's Hessian where Newton's is indefinite or its step fails, the
domain's bounds as an active set, the same backtracking and stopping tests) run point by point
in one compiled loop on the surface's rational Bezier patches instead of array by array through
its B-spline basis; flat faces in the closed form of
:func:`bhem_hpc.geometry.affine.closest_on_parallelogram`, point by point."""

from __future__ import annotations

import numpy as np
from numba import njit

from bhem_hpc.compiled.patch_kernels import bernstein, raise_degree
from bhem_hpc.geometry import projection as reference
from bhem_hpc.geometry.nurbs import NurbsSurface

PROJECTION_ITERATIONS = reference.PROJECTION_ITERATIONS
CLOSE_STEP = reference.CLOSE_STEP
ROUNDOFF_STEP = reference.ROUNDOFF_STEP
BACKTRACKS = reference.BACKTRACKS
DISTANCE_ROUNDOFF = reference.DISTANCE_ROUNDOFF


@njit(cache=True, error_model="numpy")
def _second_bernstein(t: float, degree: int, curvature: np.ndarray, scratch: np.ndarray) -> None:
    """Second derivatives ``(degree + 1,)`` of the Bernstein polynomials of ``degree`` at ``t``:
    ``p (p - 1) (B_(k-2) - 2 B_(k-1) + B_k)`` of degree ``p - 2`` (``scratch (degree + 1,)``)."""
    for k in range(degree + 1):
        curvature[k] = 0.0
    if degree < 2:
        return
    lower = degree - 2
    scratch[0] = 1.0
    for row in range(1, lower + 1):
        raise_degree(t, scratch, row)
    scale = degree * (degree - 1.0)
    for k in range(lower + 1):
        curvature[k] += scale * scratch[k]
        curvature[k + 1] -= 2.0 * scale * scratch[k]
        curvature[k + 2] += scale * scratch[k]


@njit(cache=True, error_model="numpy")
def _surface_point(nets, u_breaks, v_breaks, u, v, basis, sums, out, second: bool) -> None:  # noqa: PLR0913
    """The point ``x`` and (in the surface's parameters) ``x_u, x_v`` and, with ``second``,
    ``x_uu, x_uv, x_vv`` into the rows of ``out (6, 3)``: on the patch whose span holds ``(u, v)``
    (patches in order ``span_u * S_v + span_v``, spans between the sorted ``u_breaks (S_u + 1,)``,
    ``v_breaks (S_v + 1,)``). ``basis (7, n)``, ``sums (6, 4)`` scratch."""
    span_u = min(max(np.searchsorted(u_breaks, u, side="right") - 1, 0), len(u_breaks) - 2)
    span_v = min(max(np.searchsorted(v_breaks, v, side="right") - 1, 0), len(v_breaks) - 2)
    width_u, width_v = u_breaks[span_u + 1] - u_breaks[span_u], v_breaks[span_v + 1] - v_breaks[span_v]
    s = min(max((u - u_breaks[span_u]) / width_u, 0.0), 1.0)
    t = min(max((v - v_breaks[span_v]) / width_v, 0.0), 1.0)
    net = nets[span_u * (len(v_breaks) - 1) + span_v]
    p, q = net.shape[0] - 1, net.shape[1] - 1
    bernstein(s, p, basis[0], basis[1])
    bernstein(t, q, basis[3], basis[4])
    if second:
        _second_bernstein(s, p, basis[2], basis[6])
        _second_bernstein(t, q, basis[5], basis[6])
    sums[:] = 0.0  # A, A_s, A_t, A_ss, A_st, A_tt (homogeneous)
    for i in range(p + 1):
        for j in range(q + 1):
            weights = (basis[0, i] * basis[3, j], basis[1, i] * basis[3, j], basis[0, i] * basis[4, j],
                       basis[2, i] * basis[3, j] if second else 0.0, basis[1, i] * basis[4, j],
                       basis[0, i] * basis[5, j] if second else 0.0)  # fmt: skip
            for k in range(6 if second else 3):
                for c in range(4):
                    sums[k, c] += weights[k] * net[i, j, c]
    w = sums[0, 3]
    scales = (1.0, 1.0 / width_u, 1.0 / width_v, 1.0 / width_u**2, 1.0 / (width_u * width_v), 1.0 / width_v**2)
    for c in range(3):
        x = sums[0, c] / w
        x_u = (sums[1, c] - x * sums[1, 3]) / w
        x_v = (sums[2, c] - x * sums[2, 3]) / w
        out[0, c], out[1, c], out[2, c] = x, x_u * scales[1], x_v * scales[2]
        if second:  # differentiate A = W x twice
            out[3, c] = (sums[3, c] - sums[3, 3] * x - 2.0 * sums[1, 3] * x_u) / w * scales[3]
            out[4, c] = (sums[4, c] - sums[4, 3] * x - sums[1, 3] * x_v - sums[2, 3] * x_u) / w * scales[4]
            out[5, c] = (sums[5, c] - sums[5, 3] * x - 2.0 * sums[2, 3] * x_v) / w * scales[5]


@njit(cache=True, error_model="numpy")
def _squared_distance(nets, u_breaks, v_breaks, u, v, target, basis, sums, out) -> float:
    _surface_point(nets, u_breaks, v_breaks, u, v, basis, sums, out, False)
    return (out[0, 0] - target[0]) ** 2 + (out[0, 1] - target[1]) ** 2 + (out[0, 2] - target[2]) ** 2


@njit(cache=True, error_model="numpy")
def _step(g1: float, g2: float, h11: float, h12: float, h22: float, hold_u: bool, hold_v: bool) -> tuple[float, float]:
    """:func:`bhem_hpc.geometry.projection._projection_step` for one point."""
    det = h11 * h22 - h12 * h12
    along_u, along_v = -g1 / max(h11, 1e-300), -g2 / max(h22, 1e-300)
    if det > 1e-14 * (h11 + h22) ** 2:
        du, dv = -(h22 * g1 - h12 * g2) / det, -(h11 * g2 - h12 * g1) / det
    else:  # a singular metric (a pole): a gradient step along the nonzero tangent
        du, dv = along_u, along_v
    if hold_u:
        return 0.0, along_v
    if hold_v:
        return along_u, 0.0
    return du, dv


@njit(cache=True, error_model="numpy")
def _try_steps(nets, u_breaks, v_breaks, domain, u, v, du, dv, target, distance, scales, basis, sums, out):  # noqa: PLR0913
    """The first of ``scales`` whose clamped step from ``(u, v)`` does not lengthen the squared
    ``distance``: ``(found, u, v, moved)``, ``moved`` the step's relative length, 0 where it
    shortens the distance by no more than round-off."""
    u0, u1, v0, v1 = domain[0], domain[1], domain[2], domain[3]
    for scale in scales:
        u_try, v_try = min(max(u + scale * du, u0), u1), min(max(v + scale * dv, v0), v1)
        trial = _squared_distance(nets, u_breaks, v_breaks, u_try, v_try, target, basis, sums, out)
        if trial <= distance:
            moved = abs(u_try - u) / (u1 - u0) + abs(v_try - v) / (v1 - v0)
            return True, u_try, v_try, moved if distance - trial > DISTANCE_ROUNDOFF * distance else 0.0
    return False, u, v, 0.0


@njit(cache=True, error_model="numpy")
def _project(nets, u_breaks, v_breaks, domain, points, u, v):  # noqa: C901, PLR0912, PLR0915
    """Newton's method on ``|x(u, v) - X|^2 / 2`` from ``u, v (Q,)`` (overwritten) for each of
    ``points (Q, 3)``: the steps of :func:`bhem_hpc.geometry.projection.closest_points`."""
    n = max(nets.shape[1], nets.shape[2])
    basis, sums, out = np.zeros((7, n)), np.empty((6, 4)), np.empty((6, 3))
    u0, u1, v0, v1 = domain[0], domain[1], domain[2], domain[3]
    full_step = np.ones(1)
    halvings = 0.5 ** np.arange(1.0, BACKTRACKS)
    with_full = np.concatenate((full_step, halvings))
    for k in range(len(points)):
        target = points[k]
        for _ in range(PROJECTION_ITERATIONS):
            _surface_point(nets, u_breaks, v_breaks, u[k], v[k], basis, sums, out, True)
            r0, r1, r2 = out[0, 0] - target[0], out[0, 1] - target[1], out[0, 2] - target[2]
            g1 = out[1, 0] * r0 + out[1, 1] * r1 + out[1, 2] * r2
            g2 = out[2, 0] * r0 + out[2, 1] * r1 + out[2, 2] * r2
            gauss = (out[1, 0] ** 2 + out[1, 1] ** 2 + out[1, 2] ** 2,
                     out[1, 0] * out[2, 0] + out[1, 1] * out[2, 1] + out[1, 2] * out[2, 2],
                     out[2, 0] ** 2 + out[2, 1] ** 2 + out[2, 2] ** 2)  # fmt: skip
            f11 = gauss[0] + out[3, 0] * r0 + out[3, 1] * r1 + out[3, 2] * r2
            f12 = gauss[1] + out[4, 0] * r0 + out[4, 1] * r1 + out[4, 2] * r2
            f22 = gauss[2] + out[5, 0] * r0 + out[5, 1] * r1 + out[5, 2] * r2
            newton = f11 > 0.0 and f11 * f22 - f12 * f12 > 1e-12 * (f11 + f22) ** 2
            h11, h12, h22 = (f11, f12, f22) if newton else gauss
            hold_u = (u[k] <= u0 and g1 > 0.0) or (u[k] >= u1 and g1 < 0.0)
            hold_v = (v[k] <= v0 and g2 > 0.0) or (v[k] >= v1 and g2 < 0.0)
            du, dv = _step(g1, g2, h11, h12, h22, hold_u, hold_v)
            distance = r0 * r0 + r1 * r1 + r2 * r2
            step = abs(du) / (u1 - u0) + abs(dv) / (v1 - v0)
            if newton and step <= CLOSE_STEP:  # Newton's step close to the foot: taken as it is
                u[k], v[k] = min(max(u[k] + du, u0), u1), min(max(v[k] + dv, v0), v1)
                moved = step if step > ROUNDOFF_STEP else 0.0
            else:
                found, u[k], v[k], moved = _try_steps(nets, u_breaks, v_breaks, domain, u[k], v[k], du, dv, target,
                                                      distance, full_step, basis, sums, out)  # fmt: skip
                if not found and -(g1 * du + g2 * dv) > DISTANCE_ROUNDOFF * distance:
                    found, u[k], v[k], moved = _try_steps(nets, u_breaks, v_breaks, domain, u[k], v[k], du, dv,
                                                          target, distance, halvings, basis, sums, out)  # fmt: skip
                    if not found and newton:  # Gauss-Newton's model where Newton's fails
                        du, dv = _step(g1, g2, gauss[0], gauss[1], gauss[2], hold_u, hold_v)
                        found, u[k], v[k], moved = _try_steps(
                            nets, u_breaks, v_breaks, domain, u[k], v[k], du, dv, target, distance, with_full, basis,
                            sums, out)  # fmt: skip
            if moved <= 1e-14:
                break


@njit(cache=True, error_model="numpy")
def _feet(nets, u_breaks, v_breaks, u, v) -> np.ndarray:
    """The surface's points ``(Q, 3)`` at ``u, v (Q,)``."""
    n = max(nets.shape[1], nets.shape[2])
    basis, sums, out = np.zeros((7, n)), np.empty((6, 4)), np.empty((6, 3))
    feet = np.empty((len(u), 3))
    for k in range(len(u)):
        _surface_point(nets, u_breaks, v_breaks, u[k], v[k], basis, sums, out, False)
        feet[k] = out[0]
    return feet


@njit(cache=True, error_model="numpy")
def _parallelogram_feet(points: np.ndarray, origin: np.ndarray, a: np.ndarray, b: np.ndarray):
    """:func:`bhem_hpc.geometry.affine.closest_on_parallelogram` point by point: scaled parameters
    ``(Q, 2)`` and points ``(Q, 3)`` of the closest points of ``origin + u a + v b``, ``u, v`` in [0, 1]."""
    aa, ab, bb = a @ a, a @ b, b @ b
    determinant = aa * bb - ab * ab
    scaled, feet = np.empty((len(points), 2)), np.empty((len(points), 3))
    candidates = np.empty((5, 2))
    for k in range(len(points)):
        ra = rb = 0.0
        for c in range(3):
            ra += (points[k, c] - origin[c]) * a[c]
            rb += (points[k, c] - origin[c]) * b[c]
        candidates[0, 0], candidates[0, 1] = (bb * ra - ab * rb) / determinant, (aa * rb - ab * ra) / determinant
        for edge, fixed in enumerate((0.0, 1.0)):  # one parameter on the edge, the other clamped
            candidates[1 + 2 * edge, 0] = fixed
            candidates[1 + 2 * edge, 1] = min(max((rb - fixed * ab) / bb, 0.0), 1.0)
            candidates[2 + 2 * edge, 0] = min(max((ra - fixed * ab) / aa, 0.0), 1.0)
            candidates[2 + 2 * edge, 1] = fixed
        inside = 0.0 <= candidates[0, 0] <= 1.0 and 0.0 <= candidates[0, 1] <= 1.0
        best, best_squared = -1, np.inf
        for j in range(0 if inside else 1, 5):  # the projection first where it lies inside
            squared = 0.0
            for c in range(3):
                squared += (origin[c] + candidates[j, 0] * a[c] + candidates[j, 1] * b[c] - points[k, c]) ** 2
            if squared < best_squared:
                best, best_squared = j, squared
        scaled[k, 0], scaled[k, 1] = candidates[best, 0], candidates[best, 1]
        for c in range(3):
            feet[k, c] = origin[c] + candidates[best, 0] * a[c] + candidates[best, 1] * b[c]
    return scaled, feet


def closest_points(surface: NurbsSurface, points: np.ndarray, seeds_per_side: int = 8):
    """:func:`bhem_hpc.geometry.projection.closest_points`, compiled: parameters ``(Q, 2)``,
    surface points ``(Q, 3)`` and distances ``(Q,)`` of the closest points to ``points (Q, 3)``."""
    points = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 3))
    (u0, u1), (v0, v1) = surface.u.domain, surface.v.domain
    if surface.flat_frame is not None:  # a flat face: in closed form
        frame = surface.flat_frame
        scaled, x = _parallelogram_feet(points, *(np.ascontiguousarray(v, dtype=float) for v in frame))
        parameters = np.stack([u0 + scaled[:, 0] * (u1 - u0), v0 + scaled[:, 1] * (v1 - v0)], axis=1)
        return parameters, x, np.linalg.norm(x - points, axis=1)
    u, v = reference.nearest_seeds(surface, points, seeds_per_side)
    nets = np.ascontiguousarray(surface.bezier_patches.nets)
    u_breaks = np.r_[surface.u.knots[surface.u.spans], surface.u.knots[surface.u.spans[-1] + 1]]
    v_breaks = np.r_[surface.v.knots[surface.v.spans], surface.v.knots[surface.v.spans[-1] + 1]]
    domain = np.array([u0, u1, v0, v1])
    _project(nets, u_breaks, v_breaks, domain, points, u, v)
    x = _feet(nets, u_breaks, v_breaks, u, v)
    return np.stack([u, v], axis=1), x, np.linalg.norm(x - points, axis=1)
