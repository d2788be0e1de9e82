"""Quadrature rules: the reduced rule of quadratic B-splines covers every span once, integrates what
it must exactly, counts its points, and is refused where it does not apply."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.geometry import bspline as B
from bhem_hpc.geometry import surface as S
from bhem_hpc.model import quadrature as Q
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import ModelError, ShellModel

MATERIAL = Material(young=1e3, poisson=0.3, thickness=0.05, density=2.0)


def test_every_rule_covers_its_span_once():
    rules = {**Q._membrane_rules(), **Q._bending_rules()}
    for points, weights in rules.values():
        assert abs(weights.sum() - 1.0) < 1e-15
        assert np.all((points >= 0.0) & (points <= 1.0))


def test_interior_membrane_points_lie_on_knot_lines_in_alternating_patterns():
    """Each point sits on a span edge (u or v in {0, 1}) at the dual cell's Gauss abscissa; the two
    parities are mirror images of each other."""
    g = 0.5 / np.sqrt(3.0)
    for parity in (0, 1):
        points, _ = Q._interior_membrane_rule(parity)
        on_edge = np.isin(points, (0.0, 1.0))
        assert np.all(on_edge.sum(axis=1) == 1)
        off = points[~on_edge]
        assert np.allclose(np.minimum(off, 1 - off), g)
    even, odd = Q._interior_membrane_rule(0)[0], Q._interior_membrane_rule(1)[0]
    mirrored = np.stack([1 - even[:, 0], even[:, 1]], axis=1)
    assert {tuple(np.round(p, 12)) for p in mirrored} == {tuple(np.round(p, 12)) for p in odd}


def test_energies_of_a_uniform_state_match_the_full_rule(comm):
    """A uniformly stretched flat sheet: constant energy density, which every weight set
    integrates exactly."""
    rest = B.flat_rectangle(1.0, 0.7, 6, 5, degree=2)
    state = B.BSplineSurface(rest.grid, 2, rest.control * np.array([1.05, 0.98, 1.0]))
    full = ShellModel(rest, MATERIAL, comm=comm, initial=state).energies()
    reduced = ShellModel(rest, MATERIAL, comm=comm, initial=state, quadrature_points="reduced").energies()
    assert full["membrane"] > 0
    assert abs(reduced["membrane"] / full["membrane"] - 1) < 1e-12
    assert abs(reduced["bending"]) < 1e-12 * full["membrane"]


def test_point_counts(comm):
    """n x n spans: interior spans 4 + 4 points, side spans 3 x 2 + 1, corner spans 3 x 3 + 1."""
    n = 7
    model = ShellModel(B.flat_rectangle(1.0, 1.0, n, n, degree=2), MATERIAL, comm=comm, quadrature_points="reduced")
    interior, sides, corners = (n - 2) ** 2, 4 * (n - 2), 4
    assert model.quadrature.membrane_points == 4 * interior + 6 * sides + 9 * corners
    assert model.quadrature.bending_points == 4 * interior + sides + corners
    gauss = ShellModel(B.flat_rectangle(1.0, 1.0, n, n, degree=2), MATERIAL, comm=comm)
    assert gauss.quadrature.membrane_points == gauss.quadrature.bending_points == 9 * n * n


def test_the_reduced_rule_is_refused_where_it_does_not_apply(comm):
    with pytest.raises(ModelError, match="'reduced' is the rule of quadratic B-splines; the surface is 'hermite'"):
        ShellModel(S.flat_rectangle(1.0, 1.0, 2, 2), MATERIAL, comm=comm, quadrature_points="reduced")
    with pytest.raises(ModelError, match="the surface is 'bspline3'"):
        ShellModel(B.flat_rectangle(1.0, 1.0, 3, 3, degree=3), MATERIAL, comm=comm, quadrature_points="reduced")
    with pytest.raises(ModelError, match=r"expected one of \(2, 3, 4, 5\) or 'reduced'"):
        ShellModel(B.flat_rectangle(1.0, 1.0, 3, 3, degree=2), MATERIAL, comm=comm, quadrature_points="full")
