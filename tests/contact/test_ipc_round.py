"""Round colliders met by the IPC barrier through their exact signed distance (numpy; ipctk for
the reference barrier): the barrier function against ipc-toolkit's, the energy against ipc-toolkit's
vertex-plane pair on a very large sphere, finite differences of gradient and Hessian, the step
bound against the exact first fraction, the offset's guarantee for triangles, and which colliders
the barrier meets this way."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bhem_hpc.collision.colliders import Capsule, Cylinder, Plane, Sphere
from bhem_hpc.contact.ipc_round import (
    GAP_KEPT,
    STRETCH_ALLOWANCE,
    RoundObstacles,
    allowed_circumradius,
    circumradii,
    clamped_log_barrier,
    round_offset,
)

ipctk = pytest.importorskip("ipctk")

#: one small right triangle: its circumradius (half the hypotenuse) sets the offsets
TRIANGLE = (np.array([[0, 1, 2]]), np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0]]))


def _obstacles(colliders, dhat=1e-3) -> RoundObstacles:
    triangles, rest = TRIANGLE
    return RoundObstacles(colliders, list(range(len(colliders))), allowed_circumradius(rest, triangles), dhat)


def test_the_barrier_and_its_derivatives_are_ipc_toolkits():
    rng = np.random.default_rng(3)
    s_hat = 1e-6
    s = np.concatenate([rng.uniform(1e-12, s_hat, 20), [s_hat, 2 * s_hat]])
    value, first, second = clamped_log_barrier(s, s_hat)
    for k, x in enumerate(s):
        assert value[k] == pytest.approx(ipctk.barrier(x, s_hat), rel=1e-12, abs=1e-300)
        assert first[k] == pytest.approx(ipctk.barrier_first_derivative(x, s_hat), rel=1e-12, abs=1e-300)
        assert second[k] == pytest.approx(ipctk.barrier_second_derivative(x, s_hat), rel=1e-10, abs=1e-300)


def test_a_very_large_sphere_meets_a_vertex_as_ipc_toolkits_plane_does():
    """Energy and gradient of a vertex 0.4 mm above the top of a sphere of radius 1e6 m equal
    ipc-toolkit's vertex-plane pair at the same gap (the offset is 5e-11 m there)."""
    radius, dhat, stiffness, gap = 1e6, 1e-3, 250.0, 4e-4
    obstacles = _obstacles([Sphere(np.array([0.0, 0.0, -radius]), radius)], dhat)
    vertex = np.array([[0.0, 0.0, gap + obstacles.offsets[0]]])
    points = np.asfortranarray(np.array([[0.0, 0.0, gap], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]))
    faces = np.array([[0, 1, 2]], dtype=np.int32)
    mesh = ipctk.CollisionMesh(points, ipctk.edges(faces), faces)
    plane = ipctk.Hyperplane(np.array([0.0, 0.0, 1.0]), np.zeros(3))
    mesh.planes = [plane]
    pairs = ipctk.NormalCollisions()
    pairs.pv_collisions = [ipctk.PlaneVertexNormalCollision(plane, 0)]
    reference = ipctk.BarrierPotential(dhat, stiffness)
    assert obstacles.energy(vertex, stiffness) == pytest.approx(reference(pairs, mesh, points), rel=1e-9)
    assert obstacles.gradient(vertex, stiffness)[0] == pytest.approx(reference.gradient(pairs, mesh, points)[:3],
                                                                     rel=1e-9)  # fmt: skip


@pytest.mark.parametrize("collider", [
    Sphere(np.array([0.0, 0.0, -0.2]), 0.2),
    Cylinder(np.array([0.0, 0.0, -0.05]), np.array([0.3, 1.0, 0.0]), 0.05),
    Capsule(np.array([-0.1, 0.0, -0.03]), np.array([0.1, 0.02, -0.03]), 0.03),
])  # fmt: skip
def test_gradient_and_hessian_by_finite_differences(collider):
    """Seeded vertices within dhat: the gradient is the energy's; the projected Hessian's normal
    part is the exact Hessian's (the curvature term it drops has none), its tangent part zero."""
    rng = np.random.default_rng(11)
    dhat, stiffness = 1e-3, 1e3
    obstacles = _obstacles([collider], dhat)
    surface = rng.normal(size=(6, 3))
    surface[:, 2] = np.abs(surface[:, 2])
    distance, normal = collider.signed_distance(surface * 0.01)
    on = surface * 0.01 - distance[:, None] * normal  # feet on the surface
    vertices = on + normal * (obstacles.offsets[0] + rng.uniform(0.2, 0.8, (6, 1)) * dhat)
    gradient = obstacles.gradient(vertices, stiffness)
    hessian = obstacles.hessian(vertices, stiffness)
    h = 1e-9
    for v in range(len(vertices)):
        for c in range(3):
            plus, minus = vertices.copy(), vertices.copy()
            plus[v, c] += h
            minus[v, c] -= h
            numeric = (obstacles.energy(plus, stiffness) - obstacles.energy(minus, stiffness)) / (2 * h)
            assert numeric == pytest.approx(gradient[v, c], rel=1e-5, abs=1e-9 * np.abs(gradient).max())
        n = obstacles.gaps(vertices[v:v + 1])[1][0, 0]
        moved = np.arange(len(vertices)) == v
        along = [obstacles.gradient(vertices + moved[:, None] * t * n, stiffness)[v] @ n for t in (1e-8, -1e-8)]
        exact = (along[0] - along[1]) / 2e-8
        assert n @ hessian[v] @ n == pytest.approx(max(exact, 0.0), rel=1e-5)
        assert np.linalg.eigvalsh(hessian[v]).min() >= -1e-9 * np.abs(hessian[v]).max()
        tangent = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        assert abs(tangent @ hessian[v] @ tangent) <= 1e-9 * np.abs(hessian[v]).max()


def test_the_step_bound_stops_where_the_kept_share_of_the_gap_is_left():
    """Straight at a sphere's centre the first fraction is (1 - kept) g0 / |step|; seeded random
    motions past a sphere and a cylinder: at the bound every gap is at least its kept share, and a
    little further some gap is below it (or the bound is the whole step)."""
    sphere = Sphere(np.array([0.0, 0.0, 0.0]), 0.1)
    obstacles = _obstacles([sphere])
    start = np.array([[0.0, 0.0, 0.1 + obstacles.offsets[0] + 0.02]])
    end = start - np.array([[0.0, 0.0, 0.05]])
    assert obstacles.step_bound(start, end) == pytest.approx((1 - GAP_KEPT) * 0.02 / 0.05, rel=1e-6)
    rng = np.random.default_rng(5)
    for collider in (sphere, Cylinder(np.zeros(3), np.array([1.0, 1.0, 0.0]), 0.1)):
        obstacles = _obstacles([collider])
        for _ in range(20):
            directions = rng.normal(size=(50, 3))
            directions /= np.linalg.norm(directions, axis=1)[:, None]
            start = directions * rng.uniform(0.105, 0.2, (50, 1))
            start = start[obstacles.gaps(start)[0][0] > 0.002]  # outside the cylinder too
            end = start + rng.normal(scale=0.1, size=start.shape)
            bound = obstacles.step_bound(start, end)
            g0 = obstacles.gaps(start)[0][0]
            at = obstacles.gaps(start + bound * (end - start))[0][0]
            assert np.all(at >= GAP_KEPT * g0 * (1 - 1e-5))
            if bound < 1.0:
                further = obstacles.gaps(start + min(1.0, bound * 1.001) * (end - start))[0][0]
                assert np.any(further < GAP_KEPT * g0)


def test_triangles_whose_vertices_keep_the_offset_stay_outside_the_exact_shape():
    """Seeded triangles no larger than the allowance, their vertices just at the offset outside a
    sphere of radius 0.05 m: none of their points (barycentric samples) is inside it."""
    rng = np.random.default_rng(7)
    radius, rho = 0.05, 0.02
    offset = round_offset(radius, rho)
    weights = rng.dirichlet(np.ones(3), size=400)
    for _ in range(200):
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        tangent = np.cross(normal, rng.normal(size=3))
        tangent /= np.linalg.norm(tangent)
        other = np.cross(normal, tangent)
        angles = rng.uniform(0, 2 * np.pi, 3)
        points = rho * rng.uniform(0.5, 1.0) * (np.cos(angles)[:, None] * tangent + np.sin(angles)[:, None] * other)
        points += normal * radius  # a triangle across the sphere's top at height r, its circumcircle ≤ rho
        points *= (radius + offset) / np.linalg.norm(points, axis=1)[:, None]  # vertices pushed to the offset
        assert circumradii(points, np.array([[0, 1, 2]]))[0] <= rho * (1 + 1e-6) * (radius + offset) / radius
        inner = np.linalg.norm(weights @ points, axis=1).min()
        assert inner >= radius * (1 - 1e-9) - rho * 1e-4


def test_the_barrier_meets_exactly_the_static_frictionless_round_colliders_within_dhat():
    """A static frictionless sphere and a wide cylinder: their signed distances; a moving sphere,
    one with friction and a needle so thin that its offset exceeds dhat: tessellated; a plane:
    ipc-toolkit's plane."""
    from bhem_hpc.contact.ipc_friction import FRICTIONLESS, Friction
    from bhem_hpc.contact.ipc_setup import _obstacles as obstacles_of

    colliders = [Sphere(np.zeros(3), 0.2), Cylinder(np.zeros(3), np.array([0.0, 1.0, 0.0]), 40.0),
                 Sphere(np.zeros(3), 0.2, velocity=np.array([0.0, 0.0, 1.0])), Sphere(np.zeros(3), 0.2),
                 Capsule(np.zeros(3), np.array([0.1, 0.0, 0.0]), 1e-4), Plane(np.zeros(3), np.array([0.0, 0.0, 1.0]))]
    frictions = [FRICTIONLESS, FRICTIONLESS, FRICTIONLESS, Friction(0.3), FRICTIONLESS, FRICTIONLESS]
    rho = STRETCH_ALLOWANCE * 0.005
    assert round_offset(1e-4, rho) > 1e-3 > round_offset(0.2, rho)
    cover = np.array([[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]])
    obstacles = obstacles_of(colliders, 1e-3, cover, [not f.any for f in frictions], rho)
    assert [index for _, index in obstacles.round] == [0, 1]
    assert [index for *_, index in obstacles.meshes] == [2, 3, 4]
    assert obstacles.plane_colliders == [5]
    assert math.isclose(round_offset(0.2, rho), math.hypot(0.2, rho) - 0.2)
