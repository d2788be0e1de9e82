"""Patches joined along part of an edge: a T-junction (two short edges along one long edge) found
and paired, and a plate cut with such a junction bending as the one patch; edges that share no part
refused."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.bodies.coupling import InterfaceCoupling, penalty_stiffness, rest_frames
from bhem_hpc.bodies.petsc import StackedBlocks
from bhem_hpc.geometry import surface as S
from bhem_hpc.geometry.grid import ParameterGrid
from bhem_hpc.geometry.interfaces import (
    EDGE_BOX_SAMPLES,
    InterfaceError,
    edge_overlap,
    element_across,
    find_joints,
    pair_edges,
)
from bhem_hpc.model import bcs
from bhem_hpc.model.loads import AreaLoad, Loads
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solver import ShellSolver

#: A 2 m x 1 m steel plate (x along its length), 1 cm thick.
STEEL = Material(2.0e11, 0.3, 0.01, 7800.0)
#: Hermite spans per metre.
SPANS_PER_M = 4


def _plane(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.stack([u, v, 0 * u], -1)


def _rect(x: tuple[float, float], y: tuple[float, float]) -> S.HermiteSurface:
    spans = [max(1, round(SPANS_PER_M * (r[1] - r[0]))) for r in (x, y)]
    return S.from_callable(_plane, ParameterGrid(spans[0], spans[1], x, y, False, False))


def _t_junction() -> dict[str, S.HermiteSurface]:
    """A strip along the whole plate's length beside two patches of half its length each: the
    strip's edge y = 0.5 meets the two halves' edges along one half each."""
    return {"strip": _rect((0.0, 2.0), (0.0, 0.5)), "left": _rect((0.0, 1.0), (0.5, 1.0)),
            "right": _rect((1.0, 2.0), (0.5, 1.0))}  # fmt: skip


def _arc(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A cylinder of radius 1 m about y: ``u`` the arc length from the top (z = 1), ``v`` along y."""
    return np.stack([np.sin(u), v, np.cos(u)], -1)


def test_a_short_edge_on_a_curved_edge_at_its_top_between_its_samples_is_found():
    """A 4 cm patch beside a 1.94 m curved one, on its edge's top (z = 1 m at u = 0), halfway between
    two of the 33 samples that box the long edge (whose chords pass 0.46 mm below the top, more
    than the tolerance): the box widened by the samples' second difference still holds the short
    edge, and the partial joint is found."""
    end = 32 / 16.5 - 1.0  # the top, u = 0, halfway between samples 16 and 17 of [-1, end]
    spans = ParameterGrid(8, 2, (-1.0, end), (0.0, 0.5), False, False)
    long_patch = S.from_callable(_arc, spans)
    short_patch = S.from_callable(_arc, ParameterGrid(1, 2, (-0.02, 0.02), (0.5, 1.0), False, False))
    samples = long_patch.evaluate(np.linspace(-1.0, end, EDGE_BOX_SAMPLES), np.full(EDGE_BOX_SAMPLES, 0.5)).x
    assert 1.0 - samples[:, 2].max() > 4e-4  # the samples miss the top by more than the tolerance
    joints, _ = find_joints([long_patch, short_patch], 1e-4)
    assert [(j.first, j.first_edge, j.second, j.second_edge, j.partial) for j in joints] == [
        (0, "xi2_max", 1, "xi2_min", True)]  # fmt: skip
    assert joints[0].quadrature.weights.sum() == pytest.approx(0.04, rel=1e-3)


def test_a_t_junction_is_found_and_each_short_edge_pairs_with_its_half_of_the_long_one():
    """``find_joints`` joins the halves to each other (whole edges) and each to its half of the
    strip's edge (partial); the quadrature of a partial joint runs over the shared metre only, from
    either side, and its partners coincide."""
    patches = _t_junction()
    joints, free = find_joints(list(patches.values()), 1e-9)
    found = sorted((j.first, j.first_edge, j.second, j.second_edge, j.partial) for j in joints)
    assert found == [(0, "xi2_max", 1, "xi2_min", True), (0, "xi2_max", 2, "xi2_min", True),
                     (1, "xi1_max", 2, "xi1_min", False)]  # fmt: skip
    assert sorted(free) == [(0, "xi1_max"), (0, "xi1_min"), (0, "xi2_min"), (1, "xi1_min"), (1, "xi2_max"),
                            (2, "xi1_max"), (2, "xi2_max")]  # fmt: skip
    strip, right = patches["strip"], patches["right"]
    for first, first_edge, second, second_edge in ((strip, "xi2_max", right, "xi2_min"),
                                                   (right, "xi2_min", strip, "xi2_max")):  # fmt: skip
        quadrature = pair_edges(first, first_edge, second, second_edge, 1e-9, partial=True)
        assert quadrature.weights.sum() == pytest.approx(1.0, rel=1e-12)
        x_first = first.evaluate(*quadrature.first.T).x
        x_second = second.evaluate(*quadrature.second.T).x
        assert np.abs(x_first - x_second).max() < 1e-12 and quadrature.gap < 1e-12
        assert x_first[:, 0].min() > 1.0 and x_first[:, 0].max() < 2.0
    assert edge_overlap(strip, "xi2_max", right, "xi2_min", 1e-9) == pytest.approx((1.0, 2.0), abs=1e-12)


def test_edges_that_share_no_part_are_refused_as_partial_joints_and_whole_ones_need_the_whole_edge():
    """Edges meeting end to end (one point) or apart share no part; the strip's edge along the
    right half is no whole joint."""
    patches = _t_junction()
    with pytest.raises(InterfaceError, match="share no part of an edge"):  # end to end along y = 0.5
        pair_edges(patches["left"], "xi1_min", patches["right"], "xi1_max", 1e-9, partial=True)
    with pytest.raises(InterfaceError, match="share no part of an edge"):  # parallel, 0.5 m apart
        pair_edges(patches["strip"], "xi2_min", patches["right"], "xi2_min", 1e-9, partial=True)
    with pytest.raises(InterfaceError, match="do not meet"):
        pair_edges(patches["strip"], "xi2_max", patches["right"], "xi2_min", 1e-9)


def test_a_plate_cut_with_a_t_junction_bends_as_the_one_patch(comm):
    """The plate clamped at x = 0 under a uniform load, as one patch and as the T-junction's three
    patches (two partial joints, one whole): the free corners' deflections agree within 3e-4 (the
    penalty's compliance; measured 5.3e-5)."""
    load = Loads(area_loads=(AreaLoad((0.0, 0.0, -2.0e3)),))
    whole = _rect((0.0, 2.0), (0.0, 1.0))
    one = ShellModel(whole, STEEL, load, [bcs.clamp_edge(whole, "xi1_min")], comm=comm)
    with ShellSolver(one) as solver:
        solver.solve()
    corners = [(np.array(2.0), np.array(0.0)), (np.array(2.0), np.array(1.0))]
    expected = [float(one.state_surface().evaluate(*c).x[2]) for c in corners]
    patches = _t_junction()
    keys = list(patches)
    models = [ShellModel(p, STEEL, load, [bcs.clamp_edge(p, "xi1_min")] if k != "right" else [], comm=comm)
              for k, p in patches.items()]  # fmt: skip
    blocks = StackedBlocks(models)
    joints, _ = find_joints(list(patches.values()), 1e-9)
    couplings = []
    for j in joints:
        a, b = patches[keys[j.first]], patches[keys[j.second]]
        element = min(element_across(a, j.first_edge), element_across(b, j.second_edge))
        stiffness = penalty_stiffness(STEEL.young, STEEL.poisson, STEEL.thickness, element)
        couplings.append(InterfaceCoupling(blocks, (j.first, j.second), j.quadrature,
                                           rest_frames(a, b, j.quadrature), stiffness))  # fmt: skip
    with ShellSolver(models, contributions=couplings) as solver:
        solver.solve()
    joined = [float(models[0].state_surface().evaluate(*corners[0]).x[2]),
              float(models[2].state_surface().evaluate(*corners[1]).x[2])]  # fmt: skip
    assert expected[0] < -1e-3  # a deflection worth comparing
    np.testing.assert_allclose(joined, expected, rtol=3e-4)
