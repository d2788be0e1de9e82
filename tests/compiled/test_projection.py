"""The compiled closest points against the numpy projection they compile, and against exact shapes."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.compiled import projection as compiled
from bhem_hpc.geometry import nurbs
from bhem_hpc.geometry import projection as reference
from bhem_hpc.studies import sem_models


@pytest.mark.parametrize("model", ["torus", "rocket", "mug"])
def test_compiled_closest_points_equal_the_numpy_projection(rng, model):
    parts = {"torus": lambda: [nurbs.torus(1.0, 0.3)], "rocket": sem_models.rocket, "mug": sem_models.mug}[model]()
    control = np.concatenate([p.control.reshape(-1, 3) for p in parts])
    lo, hi = control.min(axis=0), control.max(axis=0)
    points = lo - 0.2 * (hi - lo) + 1.4 * rng.random((600, 3)) * (hi - lo)
    for part in parts:
        _, expected_feet, expected = reference.closest_points(part, points)
        parameters, feet, distance = compiled.closest_points(part, points)
        np.testing.assert_allclose(distance, expected, atol=1e-12 * np.ptp(hi - lo) + 1e-15)
        # the foot is the surface's point at its parameters, and the numpy projection's (its
        # parameters may differ by a period on a closed part's seam)
        np.testing.assert_allclose(feet, part.evaluate(parameters[:, 0], parameters[:, 1])[0], atol=1e-12)
        np.testing.assert_allclose(feet, expected_feet, atol=1e-7 * np.ptp(hi - lo))


def test_compiled_closest_points_on_the_sphere_are_radial(rng):
    radius = 1.3
    points = rng.standard_normal((500, 3)) * rng.uniform(0.1, 3.0, (500, 1))
    _, feet, distance = compiled.closest_points(nurbs.sphere(radius), points)
    length = np.linalg.norm(points, axis=1)
    np.testing.assert_allclose(distance, np.abs(length - radius), atol=1e-12)
    np.testing.assert_allclose(feet, radius * points / length[:, None], atol=1e-11)


def test_compiled_closest_points_on_flat_faces_equal_the_closed_form(rng):
    faces = nurbs.box_faces([0.0, 0.0, 0.0], [2.0, 1.0, 0.5], degree=2, spans=(2, 3))
    points = rng.uniform(-1.0, 3.0, (500, 3))
    for face in faces:
        assert face.flat_frame is not None
        expected_parameters, expected_feet, expected = reference.closest_points(face, points)
        parameters, feet, distance = compiled.closest_points(face, points)
        np.testing.assert_allclose(parameters, expected_parameters, atol=1e-14)
        np.testing.assert_allclose(feet, expected_feet, atol=1e-14)
        np.testing.assert_allclose(distance, expected, atol=1e-14)
