"""Rational B-spline shell surfaces: exact conversion of NURBS parts onto uniform knots (knot
insertion, degree raising), rational point weights and derivatives, and the parts refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bhem_hpc.geometry.nurbs import NurbsSurface, cylinder_panel, pipe_bend, sphere
from bhem_hpc.geometry.rational_bspline import clamped, insert_knot, join_pieces, on_uniform_knots, split_at_kinks
from bhem_hpc.geometry.surface import SurfaceError


def _compare(part: NurbsSurface, shell, rng, tolerance: float = 1e-12) -> None:
    """Points and first and second derivatives of the shell and the part at random parameters."""
    (u0, u1), (v0, v1) = part.u.domain, part.v.domain
    u, v = u0 + (u1 - u0) * rng.random(300), v0 + (v1 - v0) * rng.random(300)
    point = shell.evaluate(u, v)
    scale = np.abs(part.control).max()
    for mine, theirs in zip((point.x, point.a1, point.a2, point.a11, point.a12, point.a22),
                            part.second_derivatives(u, v), strict=True):  # fmt: skip
        np.testing.assert_allclose(mine, theirs, atol=tolerance * scale * 100)


@pytest.mark.parametrize("degree", [2, 3])
def test_a_cylinder_panel_is_carried_over_exactly(degree, rng):
    """A ruled rational part of degrees (1, 2) raised to one degree and refined to 5 x 4 spans."""
    part = cylinder_panel(25.0, (0.0, 50.0), (50 * math.pi / 180, 130 * math.pi / 180))
    shell = on_uniform_knots(part, (5, 4), degree)
    assert (shell.grid.n1, shell.grid.n2, shell.degree) == (5, 4, degree)
    assert shell.control.shape == (5 + degree, 4 + degree, 3)
    _compare(part, shell, rng)
    u, v = np.meshgrid(np.linspace(0, 50, 7), np.linspace(0, 1, 9), indexing="ij")
    radius = np.hypot(*shell.evaluate(u, v).x[..., :2].transpose(2, 0, 1))
    np.testing.assert_allclose(radius, 25.0, rtol=1e-14)
    np.testing.assert_allclose(shell.nurbs().evaluate(u.ravel(), v.ravel())[0], shell.evaluate(u, v).x.reshape(-1, 3),
                               atol=1e-12)  # fmt: skip


def test_knots_on_a_lattice_are_filled_in_and_refined(rng):
    """Interior knots 0.25 and 0.5 (lattice 4) and random weights: at least 6 spans asked, 8 given."""
    knots = [0, 0, 0, 0, 0.25, 0.5, 1, 1, 1, 1]
    control = rng.normal(size=(6, 4, 3))
    weights = 0.5 + rng.random((6, 4))
    part = NurbsSurface((3, 3), knots, [0, 0, 0, 0, 1, 1, 1, 1], control, weights, "lattice part")
    shell = on_uniform_knots(part, (6, 2))
    assert (shell.grid.n1, shell.grid.n2) == (8, 2)
    _compare(part, shell, rng)


def test_knots_on_no_lattice_are_kept_and_the_spans_mapped_onto_them(rng):
    """A lofted part's knots (0.13, 0.41, 1/pi + 0.5): each span cut into equal parts (8 asked, 4
    spans: 2 each), the shell's uniform spans mapped onto the knot intervals; the same surface in
    the part's parameters, which map back; written back as the same NURBS."""
    knots = [0, 0, 0, 0, 0.13, 0.41, 1 / math.pi + 0.5, 1, 1, 1, 1]
    part = NurbsSurface((3, 3), knots, [0, 0, 0, 0, 1, 1, 1, 1], rng.normal(size=(7, 4, 3)),
                        0.5 + rng.random((7, 4)), "loft")  # fmt: skip
    shell = on_uniform_knots(part, (8, 3))
    assert (shell.grid.n1, shell.grid.n2) == (8, 3) and shell.knots[1] is None
    np.testing.assert_allclose(np.unique(shell.knots[0]), [0, 0.065, 0.13, 0.27, 0.41, 0.5 * (0.41 + knots[6]),
                                                           knots[6], 0.5 * (knots[6] + 1), 1])  # fmt: skip
    s, t = rng.random(300), rng.random(300)
    u, v = shell.model_parameters(s, t)
    np.testing.assert_allclose(shell.evaluate(s, t).x, part.evaluate(u, v)[0], atol=1e-13)
    np.testing.assert_allclose(np.stack(shell.surface_parameters(u, v)), np.stack([s, t]), atol=1e-15)
    np.testing.assert_allclose(shell.nurbs().evaluate(u, v)[0], part.evaluate(u, v)[0], atol=1e-13)
    # span k of the shell is knot interval k: its middle maps to the interval's middle
    assert shell.model_parameters(np.array([2.5 / 8]), np.array([0.0]))[0][0] == pytest.approx(0.2)


@pytest.mark.parametrize("degree", [2, 3])
def test_unclamped_parts_are_clamped_exactly(degree, rng):
    """A modeller's periodic-style part (uniform unclamped knots along u): clamped by knot insertion
    at its domain's ends, then carried over as any other; the same surface over its domain."""
    count = 7
    knots_v = np.r_[np.zeros(degree + 1), 0.4, np.ones(degree + 1)]
    part = NurbsSurface((degree, degree), np.arange(count + degree + 1, dtype=float), knots_v,
                        rng.normal(size=(count, len(knots_v) - degree - 1, 3)),
                        0.5 + rng.random((count, len(knots_v) - degree - 1)), "unclamped")  # fmt: skip
    knots = clamped(part).u.knots
    assert np.all(knots[: degree + 1] == degree) and np.all(knots[-degree - 1 :] == count)
    (u0, u1), (v0, v1) = part.u.domain, part.v.domain
    u, v = u0 + (u1 - u0) * rng.random(100), v0 + (v1 - v0) * rng.random(100)
    for mine, theirs in zip(clamped(part).second_derivatives(u, v), part.second_derivatives(u, v), strict=True):
        np.testing.assert_allclose(mine, theirs, atol=1e-11)
    shell = on_uniform_knots(part, (8, 3))
    assert shell.grid.xi1_range == (degree, count)
    np.testing.assert_allclose(shell.evaluate(*shell.surface_parameters(u, v)).x, part.evaluate(u, v)[0], atol=1e-13)


@pytest.mark.parametrize("part", [sphere(1.0), pipe_bend(0.3, 0.05, (0.0, 1.0))], ids=["sphere", "bend"])
def test_pieces_cut_at_kinks_join_back_into_the_part(part, rng):
    """split_at_kinks and join_pieces are inverses (the sphere: 4 x 2 pieces, its knots again);
    pieces refined as shells join into a finer part of the same surface."""
    pieces = split_at_kinks(part)
    joined = join_pieces(pieces, "joined")
    np.testing.assert_array_equal(joined.u.knots, part.u.knots)
    np.testing.assert_allclose(joined.control, part.control, atol=1e-15)
    refined = join_pieces([[on_uniform_knots(p, (3, 3)).nurbs() for p in row] for row in pieces], "refined")
    (u0, u1), (v0, v1) = part.u.domain, part.v.domain
    u, v = u0 + (u1 - u0) * rng.random(200), v0 + (v1 - v0) * rng.random(200)
    np.testing.assert_allclose(refined.evaluate(u, v)[0], part.evaluate(u, v)[0], atol=1e-14)


def test_a_knot_repeated_below_the_degree_is_kept(rng):
    """A cubic part that is C1 at u = 0.3 (a double knot): carried over on its own knots, the double
    knot kept (10 control points along u for 6 spans), the same surface."""
    knots = [0, 0, 0, 0, 0.3, 0.3, 0.7, 1, 1, 1, 1]
    part = NurbsSurface((3, 3), knots, [0, 0, 0, 0, 1, 1, 1, 1], rng.normal(size=(7, 4, 3)),
                        0.6 + rng.random((7, 4)), "C1 part")  # fmt: skip
    shell = on_uniform_knots(part, (6, 2))
    assert shell.grid.n1 == 6 and shell.control.shape == (10, 5, 3)
    assert np.count_nonzero(shell.knots[0] == 0.3) == 2
    s, t = rng.random(200), rng.random(200)
    np.testing.assert_allclose(shell.evaluate(s, t).x, part.evaluate(*shell.model_parameters(s, t))[0], atol=1e-13)


def test_knot_insertion_keeps_the_curve(rng):
    knots = np.array([0, 0, 0, 0.3, 1, 1, 1], float)
    homogeneous = np.concatenate([rng.normal(size=(4, 3)), 0.5 + rng.random((4, 1))], axis=1)
    new_knots, inserted = insert_knot(knots, 2, homogeneous, 0.6)
    np.testing.assert_array_equal(new_knots, [0, 0, 0, 0.3, 0.6, 1, 1, 1])
    before = NurbsSurface((2, 1), knots, [0, 0, 1, 1], np.repeat((homogeneous[:, :3] / homogeneous[:, 3:])[:, None],
                          2, 1), np.repeat(homogeneous[:, 3:], 2, 1))  # fmt: skip
    after = NurbsSurface((2, 1), new_knots, [0, 0, 1, 1], np.repeat((inserted[:, :3] / inserted[:, 3:])[:, None],
                         2, 1), np.repeat(inserted[:, 3:], 2, 1))  # fmt: skip
    t = rng.random(50)
    np.testing.assert_allclose(after.evaluate(t, t)[0], before.evaluate(t, t)[0], atol=1e-13)


@pytest.mark.parametrize(
    ("part", "message"),
    [
        (sphere(1.0), r"the u knot 0.25 repeats 2 times: the part is only C0 there.*cut it there.*a polynomial"),
        (NurbsSurface((4, 2), [0] * 5 + [1] * 5, [0, 0, 0, 1, 1, 1], np.zeros((5, 3, 3))), "degree 2 or 3"),
        (NurbsSurface((1, 2), [0, 0, 0.5, 1, 1], [0, 0, 0, 1, 1, 1], np.zeros((3, 3, 3))),
         "u direction has degree 1 and several spans"),
    ],
)
def test_parts_a_rational_patch_cannot_hold_are_refused_saying_why(part, message):
    with pytest.raises(SurfaceError, match=message):
        on_uniform_knots(part, (4, 4))
