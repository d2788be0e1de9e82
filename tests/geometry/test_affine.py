"""Flat NURBS faces that are affine maps of their parameters: the test, and closest points in
closed form against the optimality conditions and against Newton's projection."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.geometry import affine, nurbs, projection

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def frame_of(surface: nurbs.NurbsSurface) -> affine.AffineFrame | None:
    return surface.flat_frame


def test_greville_abscissae_are_the_means_of_inner_knots():
    knots = np.array([0, 0, 0, 0, 0.2, 0.5, 0.5, 0.9, 1.3, 1.3, 1.3, 1.3])
    expected = [knots[i + 1 : i + 4].mean() for i in range(8)]
    np.testing.assert_allclose(affine.greville(knots, 3, 8), expected, rtol=0, atol=1e-15)


@pytest.mark.parametrize(("degree", "spans"), [(1, (1, 1)), (2, (3, 2)), (3, (2, 4))])
def test_box_faces_are_affine_with_their_corners(degree, spans):
    for face in nurbs.box_faces([0.1, -0.2, 0.3], [0.7, 0.5, 1.1], degree, spans):
        frame = frame_of(face)
        assert frame is not None
        (u0, u1), (v0, v1) = face.u.domain, face.v.domain
        u, v = np.array([u0, u1, u0, 0.3 * u0 + 0.7 * u1]), np.array([v0, v0, v1, 0.6 * v0 + 0.4 * v1])
        scaled_u, scaled_v = (u - u0) / (u1 - u0), (v - v0) / (v1 - v0)
        mapped = frame.origin + scaled_u[:, None] * frame.along_u + scaled_v[:, None] * frame.along_v
        np.testing.assert_allclose(mapped, face.evaluate(u, v)[0], rtol=0, atol=1e-14)


def test_curved_reweighted_and_reparametrized_faces_are_not_affine():
    face = nurbs.box_faces([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], degree=2)[0]
    assert frame_of(face) is not None
    assert frame_of(nurbs.sphere(1.0)) is None
    weights = face.weights.copy()
    weights[1, 1] = 1.5  # the same plane, another parametrization
    assert frame_of(nurbs.NurbsSurface(face.degrees, face.u.knots, face.v.knots, face.control, weights)) is None
    control = face.control.copy()
    control[1, 1, 1] += 0.05  # moved within the plane x = 0
    assert frame_of(face.with_control(control)) is None
    control = face.control.copy()
    control[1, 1, 0] += 1e-6  # off the plane
    assert frame_of(face.with_control(control)) is None


def test_closest_points_on_a_skewed_parallelogram_satisfy_the_optimality_conditions(rng):
    """The squared distance over the unit square is a convex quadratic: its minimum is where each
    parameter's gradient vanishes inside (0, 1), is >= 0 at 0 and <= 0 at 1."""
    frame = affine.AffineFrame(np.array([0.2, -0.1, 0.4]), np.array([1.0, 0.3, -0.2]), np.array([0.6, 0.9, 0.5]))
    points = rng.uniform(-2.0, 3.0, size=(5000, 3))
    scaled, nearest = affine.closest_on_parallelogram(points, frame)
    assert np.all((scaled >= 0.0) & (scaled <= 1.0))
    np.testing.assert_allclose(
        nearest, frame.origin + scaled[:, :1] * frame.along_u + scaled[:, 1:] * frame.along_v, rtol=0, atol=1e-14
    )
    gradient = np.stack([(nearest - points) @ frame.along_u, (nearest - points) @ frame.along_v], axis=1)
    scale = 1e-12 * np.linalg.norm(points - nearest, axis=1)[:, None] + 1e-13
    assert np.all(np.where(scaled <= 0.0, gradient >= -scale, True))
    assert np.all(np.where(scaled >= 1.0, gradient <= scale, True))
    interior = (scaled > 0.0) & (scaled < 1.0)
    assert np.all(np.abs(gradient[interior]) <= scale.repeat(2, axis=1)[interior])
    # every kind of foot occurs: inside, on edges, at corners
    on_edges = ((scaled == 0.0) | (scaled == 1.0)).sum(axis=1)
    assert np.bincount(on_edges, minlength=3).min() > 100


def test_closest_points_on_flat_faces_agree_with_newtons_projection(rng, monkeypatch):
    def faces() -> list[nurbs.NurbsSurface]:  # new ones each time: a face keeps its frame once asked
        return nurbs.box_faces([0.0, 0.0, 0.0], [0.17, 0.016, 0.18], degree=2, spans=(2, 3))

    points = rng.uniform(-0.3, 0.4, size=(2000, 3))
    closed = [projection.closest_points(face, points) for face in faces()]
    monkeypatch.setattr(nurbs.NurbsSurface, "flat_frame", None)  # Newton's projection
    evaluated = []
    second_derivatives = nurbs.NurbsSurface.second_derivatives
    monkeypatch.setattr(nurbs.NurbsSurface, "second_derivatives",
                        lambda self, u, v: evaluated.append(len(u)) or second_derivatives(self, u, v))  # fmt: skip
    for face, (parameters, nearest, distance) in zip(faces(), closed, strict=True):
        newton_parameters, newton_nearest, newton_distance = projection.closest_points(face, points)
        np.testing.assert_allclose(distance, newton_distance, rtol=0, atol=1e-14)
        np.testing.assert_allclose(nearest, newton_nearest, rtol=0, atol=1e-13)
        np.testing.assert_allclose(parameters, newton_parameters, rtol=0, atol=1e-11)
    assert evaluated  # Newton's method ran
