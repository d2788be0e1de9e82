"""Trim loops and cut-cell quadrature: exact moments, the region's area and polynomial integrals
over a disk and a square with a hole, and clear refusals of loops that bound no region."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.geometry.trim import (
    CUT,
    INSIDE,
    OUTSIDE,
    TrimError,
    check_loops,
    clip_to_box,
    cut_cell_rule,
    inside,
    legendre_moments,
)

UNIT = ((0.0, 1.0), (0.0, 1.0))


def circle(centre, radius, count=400, clockwise=False):
    angles = np.linspace(0.0, 2 * np.pi, count + 1)
    if clockwise:
        angles = angles[::-1]
    return np.column_stack([centre[0] + radius * np.cos(angles), centre[1] + radius * np.sin(angles)])


def cells(n):
    edges = np.linspace(0.0, 1.0, n + 1)
    lows = np.array([(a, b) for a in edges[:-1] for b in edges[:-1]])
    return lows, lows + 1.0 / n


def integrate(rule, lows, highs, f):
    """sum over cells of the rule's weights times f at the mapped points."""
    size = highs - lows
    total = 0.0
    for c in range(len(lows)):
        x = lows[c] + rule.points * size[c]
        total += float(np.sum(rule.weights[c] * f(x[:, 0], x[:, 1]))) * size[c].prod()
    return total


def test_moments_of_a_triangle_are_exact():
    """int s^a t^b over the triangle (0,0), (1,0), (0,1) is a! b! / (a + b + 2)!; the Legendre
    moments are combinations of these: compare P_0 = 1, P_1 = 2s - 1 and P_2."""
    triangle = np.array([(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)])
    moments = legendre_moments([triangle], 2)
    assert moments[0, 0] == pytest.approx(0.5, abs=1e-14)
    # int (2s - 1) = 2/6 - 1/2; int (2s-1)(2t-1) = 4/24 - 2/6 - 2/6 + 1/2
    assert moments[1, 0] == pytest.approx(2 / 6 - 0.5, abs=1e-14)
    assert moments[1, 1] == pytest.approx(4 / 24 - 4 / 6 + 0.5, abs=1e-14)
    # P_2(s) = 6 s^2 - 6 s + 1: 6/12 - 6/6 + 1/2 = 0
    assert moments[2, 0] == pytest.approx(6 / 12 - 1 + 0.5, abs=1e-14)
    # clockwise: the signs turn
    assert legendre_moments([triangle[::-1]], 2)[0, 0] == pytest.approx(-0.5, abs=1e-14)


def test_clipping_a_concave_polygon_keeps_its_area_in_the_box():
    """An L-shaped polygon over the unit square clipped to [0.25, 0.75]^2: the area inside is
    the box's less the L's notch there."""
    shape = np.array([(0, 0), (1, 0), (1, 0.5), (0.5, 0.5), (0.5, 1), (0, 1)], dtype=float)
    clipped = clip_to_box(shape, np.array([0.25, 0.25]), np.array([0.75, 0.75]))
    area = legendre_moments([clipped], 0)[0, 0]
    assert area == pytest.approx(0.25 - 0.0625, abs=1e-14)


@pytest.mark.parametrize(("n", "degree", "misfit"), [(2, 1, 0.2), (3, 2, 0.07), (4, 3, 0.07), (6, 2, 1e-3)])
def test_a_disk_is_integrated_to_the_polygons_values(n, degree, misfit):
    """Disk of radius 0.35 (a 400-gon) on 10 x 10 cells: the area is the polygon's (Green's theorem
    on the whole loop) to round-off; int x^2 + y is the polygon's within what the cut cells' moment
    misfit allows, which more points than moments shrink."""
    loops = check_loops([circle((0.5, 0.5), 0.35)], UNIT, 1e-9)
    lows, highs = cells(10)
    rule = cut_cell_rule(loops, lows, highs, n, degree)
    whole = legendre_moments(loops, 2)
    assert integrate(rule, lows, highs, lambda x, y: np.ones_like(x)) == pytest.approx(whole[0, 0], rel=1e-12)
    assert whole[0, 0] == pytest.approx(np.pi * 0.35**2, rel=1e-4)
    assert np.all(rule.weights >= 0.0)
    assert set(np.unique(rule.states)) == {OUTSIDE, INSIDE, CUT}
    # s^2 = (P_2 + 3 P_1 + 2) / 6 and t = (P_1 + 1) / 2 in the shifted Legendre polynomials
    polygon = (whole[2, 0] + 3 * whole[1, 0] + 2 * whole[0, 0]) / 6 + (whole[0, 1] + whole[0, 0]) / 2
    value = integrate(rule, lows, highs, lambda x, y: x**2 + y)
    assert value == pytest.approx(polygon, rel=10 * misfit * 0.05)  # cut cells hold ~5 % of the area
    assert 0.0 < rule.residuals.max() < misfit


def test_a_hole_is_taken_out_whatever_its_orientation():
    outer = np.array([(0.1, 0.1), (0.9, 0.1), (0.9, 0.9), (0.1, 0.9), (0.1, 0.1)])
    hole = circle((0.5, 0.5), 0.2, count=200)  # counterclockwise: check_loops turns it
    loops = check_loops([outer, hole], UNIT, 1e-9)
    lows, highs = cells(8)
    rule = cut_cell_rule(loops, lows, highs, 3)
    area = integrate(rule, lows, highs, lambda x, y: np.ones_like(x))
    assert area == pytest.approx(0.64 - legendre_moments([loops[1][::-1]], 0)[0, 0], rel=1e-9)
    assert inside(loops, np.array([[0.5, 0.5], [0.2, 0.2], [0.05, 0.5]])).tolist() == [False, True, False]


def test_bad_loops_are_refused_by_name():
    square = np.array([(0.1, 0.1), (0.9, 0.1), (0.9, 0.9), (0.1, 0.9), (0.1, 0.1)])
    with pytest.raises(TrimError, match=r"patches\[1\].trim\[0\] is not closed"):
        check_loops([square[:-1]], UNIT, 1e-9, where="patches[1].trim")
    with pytest.raises(TrimError, match=r"trim\[0\] leaves the patch's parameter domain .* point 1"):
        check_loops([square + [0.2, 0.0]], UNIT, 1e-9)
    bow = np.array([(0.1, 0.1), (0.9, 0.9), (0.9, 0.3), (0.1, 0.9), (0.1, 0.1)])
    with pytest.raises(TrimError, match="loop 0 crosses itself"):
        check_loops([bow], UNIT, 1e-9)
    with pytest.raises(TrimError, match="loop 1 crosses loop 0"):
        check_loops([square, circle((0.9, 0.5), 0.05)], UNIT, 1e-9)
    with pytest.raises(TrimError, match="bounds no area"):
        check_loops([np.array([(0.1, 0.1), (0.5, 0.5), (0.9, 0.9), (0.1, 0.1)])], UNIT, 1e-9)
