"""NURBS surfaces: exact conics, derivatives, the rational basis, Bezier extraction, sub-patches,
the crossings of axis-parallel lines, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import assert_imports_without

from bhem_hpc.geometry import nurbs, projection
from bhem_hpc.geometry import rational_bezier as rb
from bhem_hpc.geometry.surface import SurfaceError

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def random_surface(rng) -> nurbs.NurbsSurface:
    """Degree 3 x 2 on non-uniform knots with a double interior knot, random positive weights."""
    knots_u = np.array([0, 0, 0, 0, 0.2, 0.5, 0.5, 0.9, 1.3, 1.3, 1.3, 1.3])  # 8 control points
    knots_v = np.array([-1, -1, -1, 0.1, 0.6, 2, 2, 2])  # 5 control points
    control = rng.normal(size=(8, 5, 3))
    return nurbs.NurbsSurface((3, 2), knots_u, knots_v, control, 0.3 + rng.random((8, 5)))


def random_parameters(surface, rng, count=200):
    (u0, u1), (v0, v1) = surface.u.domain, surface.v.domain
    return u0 + (u1 - u0) * rng.random(count), v0 + (v1 - v0) * rng.random(count)


def test_nurbs_modules_import_numpy_only():
    assert_imports_without("bhem_hpc.geometry.nurbs")
    assert_imports_without("bhem_hpc.geometry.rational_bezier")
    assert_imports_without("bhem_hpc.geometry.affine")
    assert_imports_without("bhem_hpc.geometry.projection")
    assert_imports_without("bhem_hpc.solids.quadrature")


def test_sphere_and_torus_are_exact_with_outward_normals(rng):
    sphere = nurbs.sphere(2.0, center=(1.0, -1.0, 0.5))
    u, v = random_parameters(sphere, rng)
    point, x_u, x_v = sphere.evaluate(u, v)
    offset = point - (1.0, -1.0, 0.5)
    np.testing.assert_allclose(np.linalg.norm(offset, axis=1), 2.0, atol=1e-14)
    assert np.all(np.einsum("sc,sc->s", np.cross(x_u, x_v), offset) > 0.0)
    torus = nurbs.torus(1.0, 0.3)
    point, x_u, x_v = torus.evaluate(u, v)
    rho = np.hypot(point[:, 0], point[:, 1])
    np.testing.assert_allclose(np.hypot(rho - 1.0, point[:, 2]), 0.3, atol=1e-14)
    tube_centre = np.c_[point[:, :2] / rho[:, None], np.zeros(len(u))]
    assert np.all(np.einsum("sc,sc->s", np.cross(x_u, x_v), point - tube_centre) > 0.0)


def test_derivatives_match_central_differences(rng):
    surface = random_surface(rng)
    u, v = random_parameters(surface, rng, 50)
    u = np.clip(u, 1e-4, 1.3 - 1e-4)
    v = np.clip(v, -1 + 1e-4, 2 - 1e-4)
    _, x_u, x_v = surface.evaluate(u, v)
    h = 1e-6
    fd_u = (surface.evaluate(u + h, v)[0] - surface.evaluate(u - h, v)[0]) / (2 * h)
    fd_v = (surface.evaluate(u, v + h)[0] - surface.evaluate(u, v - h)[0]) / (2 * h)
    scale = np.abs(x_u).max() + np.abs(x_v).max()
    np.testing.assert_allclose(x_u, fd_u, atol=1e-7 * scale)
    np.testing.assert_allclose(x_v, fd_v, atol=1e-7 * scale)


def test_rational_basis_partitions_unity_and_maps_control_points(rng):
    surface = random_surface(rng)
    u, v = random_parameters(surface, rng)
    index, values = surface.basis_matrix(u, v)
    np.testing.assert_allclose(values.sum(axis=1), 1.0, atol=1e-14)
    assert values.min() >= 0.0
    mapped = np.einsum("sk,skc->sc", values, surface.control.reshape(-1, 3)[index])
    np.testing.assert_allclose(mapped, surface.evaluate(u, v)[0], atol=1e-13)


def test_bezier_extraction_is_exact(rng):
    surface = random_surface(rng)
    patches = surface.bezier_patches
    assert patches.nets.shape == (4 * 3, 4, 3, 4)  # spans: u 4 nonempty, v 3 nonempty
    s, t = rng.random(len(patches.nets)), rng.random(len(patches.nets))
    boxes = patches.boxes
    u, v = boxes[:, 0] + s * (boxes[:, 1] - boxes[:, 0]), boxes[:, 2] + t * (boxes[:, 3] - boxes[:, 2])
    point, x_u, x_v = surface.evaluate(u, v)
    bezier, x_s, x_t = rb.evaluate(patches.nets, s, t)
    np.testing.assert_allclose(bezier, point, atol=1e-13)
    np.testing.assert_allclose(x_s, x_u * (boxes[:, 1] - boxes[:, 0])[:, None], atol=1e-12)
    np.testing.assert_allclose(x_t, x_v * (boxes[:, 3] - boxes[:, 2])[:, None], atol=1e-12)


@pytest.mark.parametrize("knots", [[0, 0, 0, 1, 1, 1], [0, 1, 2, 3, 4, 5]], ids=["clamped", "unclamped"])
def test_bezier_extraction_of_one_span_is_exact(rng, knots):
    """A part of p + 1 control points per direction has one span: on clamped knots its net is its
    control net, on unclamped ones the span's B-splines are other polynomials than Bernstein's."""
    knots = np.asarray(knots, dtype=float)
    surface = nurbs.NurbsSurface((2, 2), knots, knots, rng.normal(size=(3, 3, 3)), 0.5 + rng.random((3, 3)))
    patches = surface.bezier_patches
    assert patches.nets.shape == (1, 3, 3, 4)
    (u0, u1, v0, v1), s, t = patches.boxes[0], rng.random(50), rng.random(50)
    point = surface.evaluate(u0 + s * (u1 - u0), v0 + t * (v1 - v0))[0]
    np.testing.assert_allclose(rb.evaluate(np.repeat(patches.nets, 50, axis=0), s, t)[0], point, atol=1e-13)


def test_subpatches_are_exact_restrictions(rng):
    surface = random_surface(rng)
    nets = surface.bezier_patches.nets
    lo = 0.8 * rng.random((len(nets), 2))
    hi = lo + 0.05 + (1.0 - lo - 0.05) * rng.random((len(nets), 2))
    boxes = np.stack([lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1]], axis=1)
    s, t = rng.random(len(nets)), rng.random(len(nets))
    inner = rb.evaluate(rb.subpatches(nets, boxes), s, t)[0]
    outer = rb.evaluate(nets, lo[:, 0] + s * (hi[:, 0] - lo[:, 0]), lo[:, 1] + t * (hi[:, 1] - lo[:, 1]))[0]
    np.testing.assert_allclose(inner, outer, atol=1e-13)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_axis_lines_cross_the_sphere_exactly_twice(axis):
    radius, count = 1.5, 48
    sphere = nurbs.sphere(radius)
    # an odd count puts lines through the seams between patches (they must count once)
    coordinates = -radius + (np.arange(count + 1) + 0.5) * 2 * radius / (count + 1)
    crossings = rb.axis_line_crossings(sphere.bezier_patches.nets, axis, coordinates, coordinates)
    a = coordinates[crossings.line // len(coordinates)]
    b = coordinates[crossings.line % len(coordinates)]
    depth = np.sqrt(radius**2 - a**2 - b**2)
    np.testing.assert_allclose(np.abs(crossings.position), depth, atol=1e-8)
    # entering (against the outward normal) below the centre, leaving above
    np.testing.assert_array_equal(crossings.direction, np.sign(crossings.position))
    inside = (coordinates[:, None] ** 2 + coordinates[None, :] ** 2 < radius**2).ravel()
    counts = np.bincount(crossings.line, minlength=inside.size)
    np.testing.assert_array_equal(counts, 2 * inside)


def test_inserted_knots_leave_the_surface_and_its_derivatives_unchanged(rng):
    """Random knots, one on a double knot (which becomes triple), into both directions of a rational
    degree 3 x 2 surface: the same points and first derivatives everywhere, one more control row
    (column) per knot."""
    surface = random_surface(rng)
    u_values, v_values = [0.5, *(0.01 + 1.28 * rng.random(3))], list(-0.99 + 2.98 * rng.random(2))
    refined = nurbs.insert_knots(surface, u_values, v_values)
    assert refined.control.shape == (8 + 4, 5 + 2, 3)
    u, v = random_parameters(surface, rng)
    for before, after in zip(surface.evaluate(u, v), refined.evaluate(u, v), strict=True):
        np.testing.assert_allclose(after, before, atol=1e-12)
    with pytest.raises(SurfaceError, match=r"part 4: a knot to insert must lie inside \(0\.0, 1\.3\), got 1\.3"):
        nurbs.insert_knots(surface.with_name("part 4"), [1.3])


def test_refining_halves_the_widest_spans_first():
    torus = nurbs.refine(nurbs.torus(1.0, 0.3), (5, 0))
    assert torus.control.shape == (14, 9, 3)
    assert sorted(set(torus.u.knots)) == pytest.approx([0, 0.0625, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1])


def test_bad_nurbs_input_is_refused_with_its_value():
    knots = np.array([0, 0, 0, 1, 1, 1.0])
    control = np.zeros((3, 3, 3))
    with pytest.raises(SurfaceError, match=r"weights must be positive.*0\.0.*\(1, 2\)"):
        weights = np.ones((3, 3))
        weights[1, 2] = 0.0
        nurbs.NurbsSurface((2, 2), knots, knots, control, weights, name="part 4")
    with pytest.raises(SurfaceError, match="non-decreasing"):
        nurbs.NurbsSurface((2, 2), np.array([0, 0, 1, 0.5, 1, 1.0]), knots, control)
    with pytest.raises(SurfaceError, match="must have 6 entries"):
        nurbs.NurbsSurface((2, 2), knots[:-1], knots, control)
    with pytest.raises(SurfaceError, match="degree must be an integer"):
        nurbs.NurbsSurface((0, 2), knots, knots, control)
    with pytest.raises(SurfaceError, match="repeat more than the degree"):
        nurbs.NurbsSurface((1, 2), np.array([0, 0, 0.5, 0.5, 0.5, 1, 1.0]), knots, np.zeros((5, 3, 3)))
    with pytest.raises(SurfaceError, match="domain"):
        nurbs.sphere(1.0).evaluate(np.array([1.5]), np.array([0.5]))


def test_second_derivatives_match_central_differences(rng):
    surface = random_surface(rng)
    u, v = random_parameters(surface, rng, 40)
    u, v = np.clip(u, 1e-4, 1.3 - 1e-4), np.clip(v, -1 + 1e-4, 2 - 1e-4)
    _, _, _, x_uu, x_uv, x_vv = surface.second_derivatives(u, v)
    h = 1e-6
    scale = np.abs(x_uu).max() + np.abs(x_vv).max()
    np.testing.assert_allclose(
        x_uu, (surface.evaluate(u + h, v)[1] - surface.evaluate(u - h, v)[1]) / (2 * h), atol=1e-6 * scale
    )
    np.testing.assert_allclose(
        x_uv, (surface.evaluate(u, v + h)[1] - surface.evaluate(u, v - h)[1]) / (2 * h), atol=1e-6 * scale
    )
    np.testing.assert_allclose(
        x_vv, (surface.evaluate(u, v + h)[2] - surface.evaluate(u, v - h)[2]) / (2 * h), atol=1e-6 * scale
    )


def test_closest_points_on_sphere_torus_and_face(rng):
    points = 0.6 * rng.normal(size=(3000, 3))
    _, nearest, distance = projection.closest_points(nurbs.sphere(1.0), points)
    np.testing.assert_allclose(distance, np.abs(np.linalg.norm(points, axis=1) - 1.0), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(nearest, axis=1), 1.0, atol=1e-14)
    # the foot itself to round-off, not only the distance (which is flat there: a foot off by
    # 1e-8 of the distance changes it by round-off, and a secondary ray from it misses by as much)
    radial = points / np.linalg.norm(points, axis=1)[:, None]
    np.testing.assert_allclose(nearest, radial, rtol=0, atol=1e-13)
    _, _, distance = projection.closest_points(nurbs.torus(1.0, 0.3), points)
    rho = np.hypot(points[:, 0], points[:, 1])
    np.testing.assert_allclose(distance, np.abs(np.hypot(rho - 1.0, points[:, 2]) - 0.3), atol=1e-12)
    face = nurbs.box_faces([0.0, 0.0, 0.0], [1.0, 1.0, 1.0])[0]  # x = 0, 0 <= y, z <= 1
    _, _, distance = projection.closest_points(face, points)
    clamped = np.c_[np.zeros(len(points)), np.clip(points[:, 1:], 0.0, 1.0)]
    np.testing.assert_allclose(distance, np.linalg.norm(points - clamped, axis=1), atol=1e-12)


def test_closest_points_on_a_flat_face_end_when_the_distance_stops_falling(rng, monkeypatch):
    """On a flat biquadratic face Newton lands in a few steps; the parameters of some points then
    crept by round-off (1e-14 to 1e-12) to the iteration limit. The projection ends once a step no
    longer shortens the distance beyond its round-off, with the exact distances. The face's middle
    control point moved within its plane keeps its rectangle but makes its map not affine (Newton's
    method, not the closed form, projects onto it) and couples its parameters: a foot on an edge
    needs the edge held (a coupled step clamped onto the edge moves along it by the wrong amount),
    and far points need Gauss-Newton's step where Newton's model fails."""
    face = nurbs.box_faces([0.0, 0.0, 0.0], [0.17, 0.016, 0.18], degree=2)[0]  # x = 0, 0 <= y <= 0.016, 0 <= z <= 0.18
    control = face.control.copy()
    control[1, 1, 1:] += [0.002, 0.02]
    face = face.with_control(control)
    points = rng.uniform(-0.3, 0.4, size=(2000, 3))
    calls = []
    second_derivatives = nurbs.NurbsSurface.second_derivatives

    def counted(self, u, v):
        calls.append(len(u))
        return second_derivatives(self, u, v)

    monkeypatch.setattr(nurbs.NurbsSurface, "second_derivatives", counted)
    _, _, distance = projection.closest_points(face, points)
    clamped = np.c_[np.zeros(len(points)), np.clip(points[:, 1], 0.0, 0.016), np.clip(points[:, 2], 0.0, 0.18)]
    np.testing.assert_allclose(distance, np.linalg.norm(points - clamped, axis=1), atol=1e-14)
    assert len(calls) <= 8  # far below PROJECTION_ITERATIONS, which creeping steps reached


def test_first_hits_of_rays_inside_a_sphere(rng):
    origins = 0.4 * rng.normal(size=(600, 3))
    origins = origins[np.linalg.norm(origins, axis=1) < 0.9]
    directions = rng.normal(size=origins.shape)
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    far = np.full(len(origins), 10.0)
    hits = rb.first_hits(nurbs.sphere(1.0).bezier_patches.nets, origins, directions, np.zeros(len(origins)), far)
    along = np.einsum("ij,ij->i", origins, directions)
    exact = -along + np.sqrt(along**2 - (origins**2).sum(axis=1) + 1.0)
    np.testing.assert_allclose(hits.tau, exact, atol=1e-9)
    # a stretch that ends before the sphere finds nothing
    short = rb.first_hits(
        nurbs.sphere(1.0).bezier_patches.nets, origins, directions, np.zeros(len(origins)), 0.5 * exact
    )
    assert np.all(short.patch == -1) and np.all(np.isinf(short.tau))


def _sphere_crossing(origins: np.ndarray, directions: np.ndarray, radius: float, after: float) -> np.ndarray:
    """The first ``tau > after`` where the rays cross the sphere ``radius`` about the origin (inf: none)."""
    along = np.einsum("ij,ij->i", origins, directions)
    discriminant = along**2 - (origins**2).sum(axis=1) + radius**2
    root = np.sqrt(np.maximum(discriminant, 0.0))
    near, far = -along - root, -along + root
    tau = np.where(near > after, near, np.where(far > after, far, np.inf))
    return np.where(discriminant > 0.0, tau, np.inf)


def test_first_hits_of_rays_leaving_a_surface_find_the_next_one(rng):
    """Rays from points on a sphere (the secondary rays of the blending weights start on a part):
    the crossing at the start is not searched, the next surface is found (the inner sphere where
    the ray passes through it, else the far side), and rays pointing out find nothing."""
    points = rng.normal(size=(300, 3))
    points /= np.linalg.norm(points, axis=1)[:, None]
    inward = -points + 0.9 * rng.normal(size=points.shape)
    inward /= np.linalg.norm(inward, axis=1)[:, None]
    keep = np.einsum("ij,ij->i", inward, points) < -0.05  # rays into the sphere, none grazing it
    points, inward = points[keep], inward[keep]
    nets = np.concatenate([nurbs.sphere(1.0).bezier_patches.nets, nurbs.sphere(0.5).bezier_patches.nets])
    start, far = np.full(len(points), 1e-7), np.full(len(points), 10.0)
    hits = rb.first_hits(nets, points, inward, start, far)
    exact = np.minimum(_sphere_crossing(points, inward, 0.5, 1e-7), _sphere_crossing(points, inward, 1.0, 1e-7))
    assert np.all(np.isfinite(exact))
    np.testing.assert_allclose(hits.tau, exact, atol=1e-8)
    outward = rb.first_hits(nets, points, -inward, start, far)
    assert np.all(outward.patch == -1) and np.all(np.isinf(outward.tau))


def unit_cube_faces(bent: bool) -> list[nurbs.NurbsSurface]:
    """The unit cube's faces, bicubic on 2 x 2 spans; ``bent``: each face's inner control points
    moved within its plane (the same square, a map of its parameters that is not affine, so that
    rays meet it by Newton's method instead of the plane's one solve)."""
    faces = nurbs.box_faces([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], degree=3, spans=(2, 2))
    if not bent:
        return faces
    moved = []
    for face in faces:
        control = face.control.copy()
        in_plane = int(np.argmax(np.ptp(control.reshape(-1, 3), axis=0)))  # an axis along the face
        control[1:-1, 1:-1, in_plane] += 0.03
        moved.append(face.with_control(control))
    return moved


@pytest.mark.parametrize("bent", [False, True])
def test_rays_from_inside_a_box_leave_it_through_the_nearest_face(rng, bent):
    faces = unit_cube_faces(bent)
    nets = np.concatenate([face.bezier_patches.nets for face in faces])
    assert rb._affine(nets, 1e-12)[0].sum() == (0 if bent else len(nets))  # the plane's solve or Newton's
    origins = rng.uniform(0.05, 0.95, size=(2000, 3))
    directions = rng.normal(size=origins.shape)
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    hits = rb.first_hits(nets, origins, directions, np.zeros(len(origins)), np.full(len(origins), 10.0))
    with np.errstate(divide="ignore"):
        exits = np.where(directions > 0.0, (1.0 - origins) / directions, -origins / directions)
    np.testing.assert_allclose(hits.tau, exits.min(axis=1), rtol=0, atol=1e-12)


@pytest.mark.parametrize("bent", [False, True])
def test_rays_through_a_boxs_corner_edge_hit_it_on_either_side_of_round_off(rng, bent):
    """A secondary ray from a round tower's foot through its axis passes a box's corner edge there.
    Rays from outside the box that touch it only along that edge, offset 1e-11 into the box or
    away from it (round-off of the foot), all meet it at the edge: a crossing within the edges'
    slack counts, and the rays are tested against boxes that much wider."""
    faces = unit_cube_faces(bent)
    nets = np.concatenate([face.bezier_patches.nets for face in faces])
    count = 400
    heights = rng.uniform(0.1, 0.9, count)
    angles = rng.uniform(0.1, 0.5 * np.pi - 0.1, count)
    # from x < 0 through the edge x = y = 0 on to y < 0: outside the box but for the edge
    directions = np.stack([np.cos(angles), -np.sin(angles), np.zeros(count)], axis=1)
    toward_box = np.stack([np.sin(angles), np.cos(angles), np.zeros(count)], axis=1)
    offsets = rng.uniform(-1e-11, 1e-11, count)[:, None] * toward_box
    origins = np.stack([-np.cos(angles), np.sin(angles), heights], axis=1) + offsets
    hits = rb.first_hits(nets, origins, directions, np.zeros(count), np.full(count, 10.0))
    np.testing.assert_allclose(hits.tau, 1.0, atol=1e-10)


@pytest.mark.parametrize("bent", [False, True])
def test_rays_in_the_plane_of_a_flat_face_do_not_hit_it(rng, bent):
    """A ray lying in a face's plane touches the face along a line and crosses it nowhere: no hit.
    Round-off tilts such a ray (a secondary ray from a box's bottom edge up along its side): with a
    start ``1e-16`` off the plane and a tilt of ``1e-16``, Newton's singular steps met the side face
    at ``tau = -offset / tilt``, anywhere along the ray; the plane's solve divides by a tilt of
    round-off. The bottom face, which the rays cross at its edge, is the first hit; rays crossing a
    face's plane hit it exactly."""
    faces = unit_cube_faces(bent)
    nets = np.concatenate([face.bezier_patches.nets for face in faces])
    first_patch = np.cumsum([0] + [len(face.bezier_patches.nets) for face in faces])

    def patches_of(axis: int, value: float) -> np.ndarray:
        (k,) = [k for k, face in enumerate(faces) if np.allclose(face.control[..., axis], value)]
        return np.arange(first_patch[k], first_patch[k + 1])

    count = 300
    starts = np.stack([rng.uniform(-1e-16, 1e-16, count), rng.uniform(0.1, 0.9, count), np.full(count, -0.5)], axis=1)
    up = np.stack([rng.uniform(-1e-16, 1e-16, count), np.zeros(count), np.ones(count)], axis=1)
    hits = rb.first_hits(nets, starts, up, np.zeros(count), np.full(count, 10.0))
    np.testing.assert_allclose(hits.tau, 0.5, atol=1e-12)
    assert np.isin(hits.patch, patches_of(2, 0.0)).all()
    # beyond the bottom face only the top face is crossed
    after = rb.first_hits(nets, starts, up, np.full(count, 0.5 + 1e-9), np.full(count, 10.0))
    np.testing.assert_allclose(after.tau, 1.5, atol=1e-12)
    assert np.isin(after.patch, patches_of(2, 1.0)).all()
    # rays through the top face's plane from above hit it where they cross it
    above = np.stack([rng.uniform(0.1, 0.9, count), rng.uniform(0.1, 0.9, count), np.full(count, 2.0)], axis=1)
    down = np.tile([0.0, 0.0, -1.0], (count, 1))
    crossing = rb.first_hits(nets, above, down, np.zeros(count), np.full(count, 10.0))
    np.testing.assert_allclose(crossing.tau, 1.0, atol=1e-12)
    assert np.isin(crossing.patch, patches_of(2, 1.0)).all()
