"""Closest points on NURBS surfaces (:class:`~bhem_hpc.geometry.nurbs.NurbsSurface`), numpy and
SciPy only: flat faces in closed form (:mod:`.affine`), others by Newton's method on the squared
distance from seeds on the Bezier patches, with the bounds of the parameter domain held as an
active set and a backtracking test that is dropped close to the foot (where the distance it
measures is flat to round-off)."""

from __future__ import annotations

import numpy as np
import scipy.spatial

from bhem_hpc.geometry.affine import closest_on_parallelogram
from bhem_hpc.geometry.bspline import bernstein
from bhem_hpc.geometry.nurbs import NurbsSurface
from bhem_hpc.geometry.rational_bezier import grid_sums

#: Newton iterations of a closest-point projection.
PROJECTION_ITERATIONS = 40
#: A Newton step of the projection no longer than this (relative to the domain) is taken without
#: testing the distance (quadratic convergence: the next is of the order of its square).
CLOSE_STEP = 1e-6
#: A projection step no longer than this (relative to the domain) is round-off: the search ends.
ROUNDOFF_STEP = 1e-12
#: Step halvings per projection iteration.
BACKTRACKS = 12
#: The shorter steps tried where a projection step fails: ``1/2, 1/4, ..``.
HALVINGS = 0.5 ** np.arange(1, BACKTRACKS)
#: A projection step shortening the squared distance by no more than this fraction of it changes
#: nothing that round-off would not (the distance is stationary at the closest point).
DISTANCE_ROUNDOFF = 4.0 * np.finfo(float).eps


def closest_points(surface: NurbsSurface, points: np.ndarray, seeds_per_side: int = 8):
    """Closest points on ``surface`` to ``points (Q, 3)``: parameters ``(Q, 2)``, the surface points
    ``(Q, 3)`` and the distances ``(Q,)``.

    A surface that is an affine map of its parameters (a flat face) gets its closest points in
    closed form (:mod:`.affine`). Others start from the nearest of ``seeds_per_side^2`` samples per
    Bezier patch (SciPy's k-d tree: a part of many patches has tens of thousands of samples), then
    take Newton steps on ``|x(u, v) - X|^2 / 2`` (Gauss-Newton's where its Hessian is indefinite or
    Newton's step fails) within the domain, a parameter held on a bound its gradient points out of.
    A step is taken where it shortens the distance (all halvings of a step that fails are tried in
    one evaluation), and without that test once it is shorter than :data:`CLOSE_STEP`. At most
    :data:`PROJECTION_ITERATIONS`; a point stops when its step no longer moves it.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    (u0, u1), (v0, v1) = surface.u.domain, surface.v.domain
    if surface.flat_frame is not None:  # a flat face: in closed form
        scaled, x = closest_on_parallelogram(points, surface.flat_frame)
        parameters = np.stack([u0 + scaled[:, 0] * (u1 - u0), v0 + scaled[:, 1] * (v1 - v0)], axis=1)
        return parameters, x, np.linalg.norm(x - points, axis=1)
    u, v = nearest_seeds(surface, points, seeds_per_side)
    active = np.arange(len(points))
    for _ in range(PROJECTION_ITERATIONS):
        if not len(active):
            break
        x, x_u, x_v, x_uu, x_uv, x_vv = surface.second_derivatives(u[active], v[active])
        residual = x - points[active]
        g1, g2 = (x_u * residual).sum(1), (x_v * residual).sum(1)
        # Newton on |x - X|^2 / 2; where its Hessian is not positive definite, Gauss-Newton's
        gauss = (x_u * x_u).sum(1), (x_u * x_v).sum(1), (x_v * x_v).sum(1)
        full = [h + (second * residual).sum(1) for h, second in zip(gauss, (x_uu, x_uv, x_vv), strict=True)]
        newton = (full[0] > 0.0) & (full[0] * full[2] - full[1] ** 2 > 1e-12 * (full[0] + full[2]) ** 2)
        hessian = tuple(np.where(newton, f, g) for f, g in zip(full, gauss, strict=True))
        # a parameter on the domain's edge whose gradient points out of it is held there (the active
        # set of the bounds): the coupled step clamped onto the edge moves along it by the wrong
        # amount where the parameters' metric couples them
        hold = (((u[active] <= u0) & (g1 > 0.0)) | ((u[active] >= u1) & (g1 < 0.0)),
                ((v[active] <= v0) & (g2 > 0.0)) | ((v[active] >= v1) & (g2 < 0.0)))  # fmt: skip
        du, dv = _projection_step(g1, g2, hessian, hold)
        distance = (residual**2).sum(1)
        moved = np.zeros(len(active))
        # close to the closest point Newton's step is exact to second order while the distance it
        # shortens is below round-off: it is taken as it is (the foot to round-off, not to the
        # square root of it), and a step of round-off is the last
        step = np.abs(du) / (u1 - u0) + np.abs(dv) / (v1 - v0)
        close = newton & (step <= CLOSE_STEP)
        taken = np.flatnonzero(close)
        u[active[taken]] = np.clip(u[active[taken]] + du[taken], u0, u1)
        v[active[taken]] = np.clip(v[active[taken]] + dv[taken], v0, v1)
        moved[taken] = np.where(step[taken] > ROUNDOFF_STEP, step[taken], 0.0)
        # backtracking elsewhere: far outside a convex part a full step can overshoot
        far = np.flatnonzero(~close)
        pending = _backtrack(surface, points, (u, v), (du, dv), active, distance, far, np.ones(1), moved)
        # where the full step failed and its model shortens the squared distance by no more than
        # round-off (the point is at its closest, or far off where the distance is flat), no
        # shorter step would shorten it measurably: the point stops without halvings
        negligible = -(g1 * du + g2 * dv) <= DISTANCE_ROUNDOFF * distance
        pending = pending[~negligible[pending]]
        pending = _backtrack(surface, points, (u, v), (du, dv), active, distance, pending, HALVINGS, moved)
        # far from a part whose parameters bend, Newton's model can fail where Gauss-Newton's descends
        retry = pending[newton[pending]]
        if len(retry):
            du[retry], dv[retry] = _projection_step(g1[retry], g2[retry], tuple(h[retry] for h in gauss),
                                                    tuple(h[retry] for h in hold))  # fmt: skip
            _backtrack(surface, points, (u, v), (du, dv), active, distance, retry, np.r_[1.0, HALVINGS], moved)
        active = active[moved > 1e-14]
    x = surface.evaluate(u, v)[0]
    return np.stack([u, v], axis=1), x, np.linalg.norm(x - points, axis=1)


def nearest_seeds(surface: NurbsSurface, points: np.ndarray, seeds_per_side: int) -> tuple[np.ndarray, np.ndarray]:
    """The parameters ``u, v (Q,)`` of the nearest to each of ``points (Q, 3)`` of ``seeds_per_side^2``
    samples per Bezier patch of ``surface`` (the centres of a regular grid of each patch's box;
    SciPy's k-d tree: a part of many patches has tens of thousands of samples)."""
    grid = (np.arange(seeds_per_side) + 0.5) / seeds_per_side
    boxes = surface.bezier_patches.boxes
    seed_u = (boxes[:, None, None, 0] + grid[None, :, None] * (boxes[:, 1] - boxes[:, 0])[:, None, None]).repeat(
        seeds_per_side, axis=2
    )
    seed_v = (boxes[:, None, None, 2] + grid[None, None, :] * (boxes[:, 3] - boxes[:, 2])[:, None, None]).repeat(
        seeds_per_side, axis=1
    )
    seed_u, seed_v = seed_u.ravel(), seed_v.ravel()
    # the seeds from the Bezier nets: every patch on one local grid (two products, not a basis per point)
    nets = surface.bezier_patches.nets
    seeds = grid_sums(nets, bernstein(grid, nets.shape[1] - 1), bernstein(grid, nets.shape[2] - 1))
    seeds = (seeds[..., :3] / seeds[..., 3:]).reshape(-1, 3)
    nearest = scipy.spatial.KDTree(seeds).query(points)[1]
    return seed_u[nearest].copy(), seed_v[nearest].copy()


def _projection_step(g1: np.ndarray, g2: np.ndarray, hessian: tuple[np.ndarray, np.ndarray, np.ndarray],
                     hold: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The step ``(du, dv)`` that solves ``hessian (h11, h12, h22) [du, dv] = -[g1, g2]`` (each
    ``(K,)``); where ``hold`` keeps one parameter on its bound, the other's own step; where the
    metric is singular (a pole), a gradient step along the nonzero tangent."""
    h11, h12, h22 = hessian
    det = h11 * h22 - h12**2
    safe = det > 1e-14 * (h11 + h22) ** 2
    along_u, along_v = -g1 / np.maximum(h11, 1e-300), -g2 / np.maximum(h22, 1e-300)
    du = np.where(safe, -(h22 * g1 - h12 * g2) / np.where(safe, det, 1.0), along_u)
    dv = np.where(safe, -(h11 * g2 - h12 * g1) / np.where(safe, det, 1.0), along_v)
    hold_u, hold_v = hold
    return np.where(hold_u, 0.0, np.where(hold_v, along_u, du)), np.where(hold_v, 0.0, np.where(hold_u, along_v, dv))


def _backtrack(surface: NurbsSurface, points: np.ndarray, parameters: tuple[np.ndarray, np.ndarray],
               steps: tuple[np.ndarray, np.ndarray], active: np.ndarray, distance: np.ndarray, pending: np.ndarray,
               scales: np.ndarray, moved: np.ndarray) -> np.ndarray:  # fmt: skip
    """One round of :func:`closest_points`' backtracking: for each ``pending`` index into
    ``active``, the first of ``scales (K,)`` (decreasing) whose clamped step shortens the squared
    ``distance``, all trials evaluated in one call. Updates ``parameters`` (each ``(Q,)``) and
    ``moved`` (the accepted step's relative length, 0 where it shortens the distance no more than
    round-off) in place; returns the indices still pending."""
    if not len(pending):  # every step of the round before shortened its distance
        return pending
    (u, v), (du, dv) = parameters, steps
    (u0, u1), (v0, v1) = surface.u.domain, surface.v.domain
    at = active[pending]
    u_try = np.clip(u[at][:, None] + scales[None, :] * du[pending][:, None], u0, u1)
    v_try = np.clip(v[at][:, None] + scales[None, :] * dv[pending][:, None], v0, v1)
    x_try = surface.evaluate(u_try.ravel(), v_try.ravel())[0].reshape(len(at), len(scales), 3)
    trial = ((x_try - points[at][:, None, :]) ** 2).sum(2)
    better = trial <= distance[pending][:, None]
    found = better.any(axis=1)
    first = better.argmax(axis=1)[found]
    rows = np.flatnonzero(found)
    taken, u_new, v_new, trial = pending[found], u_try[rows, first], v_try[rows, first], trial[rows, first]
    # a step that no longer shortens the distance beyond its round-off ends the point's search:
    # where the distance is stationary the parameters crept by round-off (1e-14 to 1e-12 a step on
    # flat faces) to the iteration limit
    progress = distance[taken] - trial > DISTANCE_ROUNDOFF * distance[taken]
    step = np.abs(u_new - u[at[found]]) / (u1 - u0) + np.abs(v_new - v[at[found]]) / (v1 - v0)
    moved[taken[progress]] = step[progress]
    u[at[found]], v[at[found]] = u_new, v_new
    return pending[~found]
