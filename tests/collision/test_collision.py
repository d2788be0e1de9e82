"""The numpy-only collision package: Bezier nets, ray-patch intersection, point-patch CCD."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import assert_imports_without, ray_triangle_distances

from bhem_hpc.collision import (
    BoundReached,
    PatchBVH,
    aabb,
    control_nets,
    evaluate,
    intersect_patch,
    intersect_rays,
    point_patch_toi,
    split_u,
    subpatch,
    trace_rays,
)
from bhem_hpc.geometry import surface as S

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def test_collision_imports_numpy_only():
    assert_imports_without("bhem_hpc.collision")


def random_surface(rng, n1=2, n2=2, wobble=0.15):
    flat = S.flat_rectangle(1.0, 1.0, n1, n2)
    return S.HermiteSurface(flat.grid, flat.nodal + wobble * rng.normal(size=flat.nodal.shape))


def test_nets_reproduce_the_surface_and_split_exactly(rng):
    surface = random_surface(rng)
    nets = control_nets(surface.grid, surface.nodal)
    u, v = rng.random(50), rng.random(50)
    for p in range(4):
        p1, p2 = divmod(p, 2)
        np.testing.assert_allclose(evaluate(nets[p], u, v), surface.evaluate((p1 + u) / 2, (p2 + v) / 2).x, atol=1e-13)
    net = nets[0]
    left, right = split_u(net, 0.3)
    np.testing.assert_allclose(evaluate(left, u, v), evaluate(net, 0.3 * u, v), atol=1e-13)
    np.testing.assert_allclose(evaluate(right, u, v), evaluate(net, 0.3 + 0.7 * u, v), atol=1e-13)
    sub = subpatch(net, 0.2, 0.7, 0.1, 0.4)
    np.testing.assert_allclose(evaluate(sub, u, v), evaluate(net, 0.2 + 0.5 * u, 0.1 + 0.3 * v), atol=1e-13)
    lo, hi = aabb(sub)
    dense = evaluate(sub, *np.meshgrid(np.linspace(0, 1, 30), np.linspace(0, 1, 30)))
    assert np.all(dense >= lo - 1e-15) and np.all(dense <= hi + 1e-15)
    # velocities map the same (linear) way
    velocity = rng.normal(size=surface.nodal.shape)
    moved = control_nets(surface.grid, surface.nodal + 0.1 * velocity)
    np.testing.assert_allclose(moved, nets + 0.1 * control_nets(surface.grid, velocity), atol=1e-14)


def _reference_first_hit(net, origin, direction, resolution=96):
    """Brute force: fine triangle tessellation (Moller-Trumbore), polished by Newton."""
    g = np.linspace(0.0, 1.0, resolution + 1)
    uu, vv = np.meshgrid(g, g, indexing="ij")
    points = evaluate(net, uu, vv)
    a, b, c, d = points[:-1, :-1], points[1:, :-1], points[1:, 1:], points[:-1, 1:]
    best = None
    for p0, p1, p2 in ((a, b, c), (a, c, d)):
        t = ray_triangle_distances(origin, direction, p0.reshape(-1, 3), p1.reshape(-1, 3), p2.reshape(-1, 3), 1e-9)
        k = int(np.argmin(t))
        if np.isfinite(t[k]) and (best is None or t[k] < best[0]):
            i, j = divmod(k, resolution)
            best = (t[k], (i + 0.5) / resolution, (j + 0.5) / resolution)
    if best is None:
        return None
    tau, u, v = best
    for _ in range(30):  # Newton polish
        r = evaluate(net, u, v) - origin - tau * direction
        jac = np.column_stack([evaluate(net, u, v, du=1), evaluate(net, u, v, dv=1), -direction])
        step = np.linalg.solve(jac, r)
        u, v, tau = u - step[0], v - step[1], tau - step[2]
    return tau


def test_first_hit_matches_brute_force_on_random_patches_and_rays(rng):
    compared = 0
    for _ in range(8):
        net = control_nets(*(lambda s: (s.grid, s.nodal))(random_surface(rng, 1, 1, 0.3)))[0]
        for _ in range(8):
            target = evaluate(net, *rng.random(2))
            origin = target + rng.normal(size=3) * 2.0
            direction = target - origin + 0.05 * rng.normal(size=3)
            hit = intersect_patch(net, origin, direction)
            reference = _reference_first_hit(net, origin, direction, resolution=64)
            if reference is None:
                if hit is not None:  # only allowed if it is a genuine intersection
                    residual = evaluate(net, hit.u, hit.v) - origin - hit.tau * direction
                    assert np.linalg.norm(residual) < 1e-9
                continue
            compared += 1
            assert hit is not None, "missed a hit the reference finds"
            assert abs(hit.tau - reference) <= 1e-8 * max(1.0, reference)
    assert compared >= 40


def _grazing_rays(rng, net, tilts, count):
    for _ in range(count):
        u, v = 0.2 + 0.6 * rng.random(2)
        point = evaluate(net, u, v)
        normal = np.cross(evaluate(net, u, v, du=1), evaluate(net, u, v, dv=1))
        normal /= np.linalg.norm(normal)
        tangent = evaluate(net, u, v, du=1)
        tangent /= np.linalg.norm(tangent)
        for tilt in tilts:
            direction = tangent - tilt * normal
            yield point - 0.3 * direction, direction  # crosses the surface at `point` at a shallow angle


def test_grazing_rays_are_not_missed(rng):
    net = control_nets(*(lambda s: (s.grid, s.nodal))(random_surface(rng, 1, 1, 0.2)))[0]
    for origin, direction in _grazing_rays(rng, net, (1e-1, 1e-2, 3e-3), 2):
        reference = _reference_first_hit(net, origin, direction, resolution=48)
        hit = intersect_patch(net, origin, direction)
        assert reference is not None and hit is not None
        if hit.tau < reference - 1e-8:  # an earlier crossing the tessellation missed: must be genuine
            assert np.linalg.norm(evaluate(net, hit.u, hit.v) - origin - hit.tau * direction) < 1e-9
        else:
            assert abs(hit.tau - reference) <= 1e-8


def test_very_shallow_rays_report_the_bound_but_never_a_miss(rng):
    """At 1e-6 rad, proving no earlier crossing by subdivision exceeds the bound: the search warns
    and returns a genuine hit (possibly the second of two close crossings), never None."""
    net = control_nets(*(lambda s: (s.grid, s.nodal))(random_surface(rng, 1, 1, 0.2)))[0]
    origin, direction = next(_grazing_rays(rng, net, (1e-6,), 1))
    with pytest.warns(BoundReached, match="stopped after 500 sub-patches"):
        hit = intersect_patch(net, origin, direction, max_subpatches=500)
    assert hit is not None and abs(hit.tau - 0.3) < 1e-4
    assert np.linalg.norm(evaluate(net, hit.u, hit.v) - origin - hit.tau * direction) < 1e-9


def test_vectorized_search_equals_the_per_ray_search_on_random_and_grazing_rays(rng):
    """trace_rays (all rays and sub-patches at once) against intersect_patch and the brute-force
    reference, on one random patch: random rays and grazing rays down to 3e-3 rad."""
    net = control_nets(*(lambda s: (s.grid, s.nodal))(random_surface(rng, 1, 1, 0.25)))[0]
    bvh = PatchBVH(net[None])
    rays = list(_grazing_rays(rng, net, (1e-1, 1e-2, 3e-3), 2))
    for _ in range(30):
        target = evaluate(net, *rng.random(2))
        origin = target + rng.normal(size=3) * 2.0
        rays.append((origin, target - origin + 0.05 * rng.normal(size=3)))
    origins, directions = (np.array(a) for a in zip(*rays, strict=True))
    for newton in (True, False):
        hits = trace_rays(bvh, origins, directions, newton=newton)
        compared = 0
        for k, (origin, direction) in enumerate(rays):
            single = intersect_patch(net, origin, direction, newton=newton)
            reference = _reference_first_hit(net, origin, direction, resolution=48)
            if single is None:
                assert hits.patch[k] == -1 and not np.isfinite(hits.tau[k])
                assert reference is None
                continue
            compared += 1
            assert hits.patch[k] == 0 and abs(hits.tau[k] - single.tau) <= 1e-8 * max(1.0, single.tau)
            point = evaluate(net, hits.u[k], hits.v[k])
            assert np.linalg.norm(point - origin - hits.tau[k] * direction) < 1e-8
            if reference is not None and hits.tau[k] >= reference - 1e-8:
                assert abs(hits.tau[k] - reference) <= 1e-8 * max(1.0, reference)
        assert compared >= 30


def test_vectorized_search_reports_its_bounds(rng):
    net = control_nets(*(lambda s: (s.grid, s.nodal))(random_surface(rng, 1, 1, 0.2)))[0]
    origin, direction = next(_grazing_rays(rng, net, (1e-6,), 1))
    with pytest.warns(BoundReached, match="500 sub-patches"):
        hits = trace_rays(PatchBVH(net[None]), origin[None], direction[None], max_subpatches=500)
    assert hits.patch[0] == 0 and abs(hits.tau[0] - 0.3) < 1e-4
    with pytest.warns(BoundReached, match="3 splitting rounds"):
        trace_rays(PatchBVH(net[None]), origin[None], direction[None], max_rounds=3)
    with pytest.raises(ValueError, match="ray 1 has a non-finite"):
        trace_rays(PatchBVH(net[None]), np.zeros((2, 3)), np.array([[0, 0, 1.0], [np.nan, 0, 1]]))
    with pytest.raises(ValueError, match=r"ray direction is zero \(ray 0\)"):
        trace_rays(PatchBVH(net[None]), np.zeros((1, 3)), np.zeros((1, 3)))


def test_bvh_over_many_patches_finds_the_same_first_hit_and_newton_is_faster(rng):
    surface = S.from_callable(
        lambda a, b: np.stack([a, b, 0.1 * np.sin(6 * a) * np.cos(5 * b)], -1), S.ParameterGrid(10, 10, (0, 1), (0, 1))
    )
    nets = control_nets(surface.grid, surface.nodal)
    bvh = PatchBVH(nets)
    origins = np.column_stack([rng.random(15), rng.random(15), np.full(15, 1.0)])
    directions = np.column_stack([0.1 * rng.normal(size=15), 0.1 * rng.normal(size=15), -np.ones(15)])
    hits = intersect_rays(bvh, origins, directions)
    plain = intersect_rays(bvh, origins, directions, newton=False)
    for o, d, hit, slow in zip(origins, directions, hits, plain, strict=True):
        brute = [intersect_patch(net, o, d, k) for k, net in enumerate(nets)]
        brute = [h for h in brute if h is not None]
        if not brute:
            assert hit is None
            continue
        first = min(brute, key=lambda h: h.tau)
        assert hit is not None and abs(hit.tau - first.tau) < 1e-9 and hit.patch == first.patch
        assert slow is not None and abs(slow.tau - first.tau) < 1e-8


def test_bad_rays_and_patches():
    net = control_nets(*(lambda s: (s.grid, s.nodal))(S.flat_rectangle(1, 1, 1, 1)))[0]
    with pytest.raises(ValueError, match="ray direction is zero"):
        intersect_patch(net, np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="non-finite"):
        intersect_patch(net, np.zeros(3), np.array([np.nan, 0, 1]))
    with pytest.raises(ValueError, match="degenerate patch"):
        intersect_patch(np.ones((4, 4, 3)), np.zeros(3), np.array([0, 0, 1.0]))


def _moving(rng):
    surface = random_surface(rng, 1, 1, 0.2)
    net = control_nets(surface.grid, surface.nodal)[0]
    velocity = control_nets(surface.grid, 0.5 * rng.normal(size=surface.nodal.shape))[0]
    return net, velocity


def _reference_toi(net, velocity, x0, xv, dt):
    """Earliest root of x(u, v, t) = x0 + t xv by Newton from a dense grid of starts."""
    best = None
    for t_start in np.linspace(0, dt, 21):
        for u in (0.1, 0.5, 0.9):
            for v in (0.1, 0.5, 0.9):
                uu, vv, tt = u, v, t_start
                for _ in range(25):
                    moved = net + tt * velocity
                    r = evaluate(moved, uu, vv) - x0 - tt * xv
                    jac = np.column_stack(
                        [evaluate(moved, uu, vv, du=1), evaluate(moved, uu, vv, dv=1), evaluate(velocity, uu, vv) - xv]
                    )
                    try:
                        step = np.linalg.solve(jac, r)
                    except np.linalg.LinAlgError:
                        break
                    uu, vv, tt = uu - step[0], vv - step[1], tt - step[2]
                r = evaluate(net + tt * velocity, uu, vv) - x0 - tt * xv
                if np.linalg.norm(r) < 1e-10 and -1e-12 <= uu <= 1 and -1e-12 <= vv <= 1 and 0 <= tt <= dt:
                    best = tt if best is None else min(best, tt)
    return best


def test_ccd_is_never_later_than_the_first_contact(rng):
    dt = 1.0
    for _ in range(10):
        net, velocity = _moving(rng)
        u, v, t_hit = rng.random(), rng.random(), 0.2 + 0.6 * rng.random()
        contact = evaluate(net + t_hit * velocity, u, v)
        xv = rng.normal(size=3)
        x0 = contact - t_hit * xv
        toi = point_patch_toi(net, velocity, x0, xv, dt)
        assert toi is not None
        reference = _reference_toi(net, velocity, x0, xv, dt)
        assert reference is not None and reference <= t_hit + 1e-9
        assert toi[0] <= reference + 1e-12
        # what it reports is a real (near) contact: the point is within a few tolerances of the patch
        t, tu, tv = toi
        gap = evaluate(net + t * velocity, tu, tv) - (x0 + t * xv)
        assert np.linalg.norm(gap) <= 1e-8


def test_ccd_tangential_touch_and_clear_miss(rng):
    flat = control_nets(*(lambda s: (s.grid, s.nodal))(S.flat_rectangle(1, 1, 1, 1)))[0]
    still = np.zeros_like(flat)
    # a point skimming down to touch z = 0 tangentially at t = 0.5 (parabola-free: straight line
    # that touches the plane only at the boundary of its travel, then the patch moves up into it)
    rising = np.zeros_like(flat)
    rising[..., 2] = 1.0  # the patch rises at 1 m/s
    x0, xv = np.array([0.3, 0.4, 0.5]), np.array([0.2, 0.0, 0.0])  # moves parallel, 0.5 m above
    toi = point_patch_toi(flat, rising, x0, xv, 1.0)
    assert toi is not None and abs(toi[0] - 0.5) < 1e-8
    assert point_patch_toi(flat, still, x0, xv, 1.0) is None  # parallel at 0.5 m: never touches
    grazing = point_patch_toi(flat, still, np.array([0.5, 0.5, 1e-10]), np.array([0.1, 0.0, 0.0]), 1.0)
    assert grazing is not None and grazing[0] <= 1e-9  # within tolerance from the start
    with pytest.raises(ValueError, match="dt must be"):
        point_patch_toi(flat, still, x0, xv, 0.0)
