"""The compiled Bezier extraction against the numpy one it compiles."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.compiled import extraction as compiled
from bhem_hpc.geometry import nurbs
from bhem_hpc.geometry import rational_bezier as rb
from bhem_hpc.studies import sem_models, sem_table

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def _random_part(rng, degrees: tuple[int, int], clamped: bool) -> nurbs.NurbsSurface:
    """A part of the given degrees on random non-uniform knots (a double interior knot from degree
    2), clamped or not, random control points and positive weights."""
    directions = []
    for degree in degrees:
        count = degree + 4
        inner = np.sort(rng.uniform(0.1, 0.9, count - degree - 1))
        if degree > 1:
            inner[-1] = inner[-2]  # a double knot
        ends = (np.zeros(degree + 1), np.ones(degree + 1)) if clamped else (
            -np.arange(degree, -1, -1) * 0.1, 1.0 + np.arange(degree + 1) * 0.1)  # fmt: skip
        directions.append((np.r_[ends[0], inner, ends[1]], count))
    (knots_u, n), (knots_v, m) = directions
    return nurbs.NurbsSurface(degrees, knots_u, knots_v, rng.normal(size=(n, m, 3)), 0.3 + rng.random((n, m)))


@pytest.mark.parametrize("clamped", [True, False], ids=["clamped", "unclamped"])
@pytest.mark.parametrize("degrees", [(1, 1), (2, 1), (1, 3), (2, 2), (3, 2), (4, 3)])
def test_compiled_extraction_equals_the_numpy_one_and_evaluates_the_part(rng, degrees, clamped):
    part = _random_part(rng, degrees, clamped)
    ((nets, _),) = compiled.bezier_nets_by_degree([part])
    expected = part.bezier_patches
    np.testing.assert_allclose(nets, expected.nets, rtol=1e-13, atol=1e-13)
    # and on its own: each net reproduces the part on its span pair
    s, t = rng.random(len(nets)), rng.random(len(nets))
    boxes = expected.boxes
    u, v = boxes[:, 0] + s * (boxes[:, 1] - boxes[:, 0]), boxes[:, 2] + t * (boxes[:, 3] - boxes[:, 2])
    np.testing.assert_allclose(rb.evaluate(nets, s, t)[0], part.evaluate(u, v)[0], atol=1e-12)


@pytest.mark.parametrize("model", ["rocket", "mug", "castle", "tyre"])
def test_compiled_groups_equal_the_numpy_ones_on_models(model):
    parts = {"rocket": sem_models.rocket, "mug": lambda: sem_models.refined(sem_models.mug(), sem_table.MUG_REFINEMENT),
             "castle": lambda: sem_models.refined(sem_models.castle(), sem_table.CASTLE_REFINEMENT),
             "tyre": sem_models.tyre}[model]()  # fmt: skip
    expected, found = nurbs.bezier_nets_by_degree(parts), compiled.bezier_nets_by_degree(parts)
    assert [nets.shape for nets, _ in found] == [nets.shape for nets, _ in expected]
    for (nets, part_of_patch), (reference, reference_part) in zip(found, expected, strict=True):
        np.testing.assert_array_equal(part_of_patch, reference_part)
        np.testing.assert_allclose(nets, reference, rtol=1e-13, atol=1e-15)
