"""Quadrature rules of the shell energy: tensor Gauss per patch, and the B-spline paper's reduced rule.

Every rule is explicit: UFL's own degree estimate for the shell energy is in the hundreds and makes
Newton diverge.

The *reduced* rule (quadratic B-splines only) follows the B-spline FEM paper (§4.1-4.2, Fig. 4).
The interior of the surface is partitioned into dual cells, the cells of the control-point grid,
centred on the interior knots; each dual cell gets two membrane points, alternating between a
``1 x 2`` and a ``2 x 1`` Gauss pattern like a chess board, and one bending point at its centre
(the knot). Knot spans on a boundary of an open direction, where the basis functions are not
symmetric, get their own denser rules: Gauss ``3 x 3`` at the corners, 3 points across the
boundary times 2 along it on the sides, for the membrane, and one bending point at the span centre.

dolfinx integrates cell by cell, so each dual cell is split among the four knot spans that meet at
its knot: a span holds a quarter of each of its corners' dual cells, and a point on a knot line
or at a knot appears in every span that touches it with its weight divided among them. Two
things differ from the paper: a bending point at a knot is evaluated once from each of the four
spans (second derivatives of a quadratic spline jump across knots, so the bending density is the
mean of its four one-sided limits rather than one value), and the sparsity pattern stays that of
whole spans (PETSc stores the couplings a reduced rule leaves zero). The paper's boundary point
counts are not given in its text; the ones above are this module's choice.

Like every reduced rule it can leave zero-energy modes: with a single knot span across a direction
(every span a boundary span, bending sampled only at span centres) the stiffness of a flat strip
has an exact null vector that the full rule does not have; two spans remove it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import dolfinx.mesh
import numpy as np
import ufl

from bhem_hpc.errors import UserError
from bhem_hpc.geometry.hermite import gauss_legendre

GAUSS_POINTS = (2, 3, 4, 5)
REDUCED = "reduced"
#: Gauss points per direction, or the reduced rule of quadratic B-splines.
Quadrature = int | Literal["reduced"]


class QuadratureError(UserError, ValueError):
    """A quadrature rule that does not exist or does not apply to the discretization."""


@dataclass(frozen=True)
class ShellQuadrature:
    """The measures of a model's terms and how many points they evaluate.

    Attributes:
        membrane, bending: the measures of the membrane and bending energies.
        mass: the measure of the mass, gravity and pressure terms (Gauss).
        membrane_points, bending_points: quadrature points evaluated over the whole surface
            (a point on a span boundary counts once per span that evaluates it).
    """

    membrane: ufl.Measure | ufl.measure.MeasureSum
    bending: ufl.Measure | ufl.measure.MeasureSum
    mass: ufl.Measure
    membrane_points: int
    bending_points: int


def gauss_measure(mesh: dolfinx.mesh.Mesh, points_per_direction: int) -> ufl.Measure:
    """Cell measure with an explicit tensor Gauss rule (``n x n`` points per patch)."""
    if points_per_direction not in GAUSS_POINTS:
        raise QuadratureError(
            f"quadrature points per direction = {points_per_direction!r}; expected one of {GAUSS_POINTS}"
        )
    return ufl.Measure("dx", domain=mesh, metadata={"quadrature_degree": 2 * points_per_direction - 1})


def check_quadrature(quadrature: Quadrature, discretization: str) -> None:
    """Raise :class:`QuadratureError` unless ``quadrature`` applies to ``discretization``."""
    if quadrature == REDUCED:
        if discretization != "bspline2":
            raise QuadratureError(
                f"quadrature = 'reduced' is the rule of quadratic B-splines; the surface is {discretization!r}"
            )
        return
    if isinstance(quadrature, bool) or quadrature not in GAUSS_POINTS:
        raise QuadratureError(
            f"quadrature points per direction = {quadrature!r}; expected one of {GAUSS_POINTS} or 'reduced'"
        )


def shell_quadrature(grid_mesh, quadrature: Quadrature, mass_points: int = 3) -> ShellQuadrature:
    """The measures of ``quadrature`` on the knot-span mesh ``grid_mesh`` (a :class:`GridMesh`)."""
    spans = grid_mesh.grid.n1 * grid_mesh.grid.n2
    if quadrature != REDUCED:
        dx = gauss_measure(grid_mesh.mesh, quadrature)
        return ShellQuadrature(dx, dx, dx, spans * quadrature**2, spans * quadrature**2)
    return _reduced_quadrature(grid_mesh, gauss_measure(grid_mesh.mesh, mass_points))


# -- the reduced rule -----------------------------------------------------------------------------
# Span classes: interior spans by chess-board parity, then boundary spans by which directions
# they are on a boundary of.
_INTERIOR = (0, 1)
_BOUNDARY = {(True, False): 2, (False, True): 3, (True, True): 4}
_DUAL_GAUSS = 0.5 / np.sqrt(3.0)  # a 2-point Gauss abscissa of a unit dual cell, from its centre
_CORNERS = ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0))


def _interior_membrane_rule(parity: int) -> tuple[np.ndarray, np.ndarray]:
    """Points ``(4, 2)`` in span coordinates ``(u, v)`` (u along xi1) and weights of an interior span.

    The dual cell at corner ``(i + cu, j + cv)`` uses the ``1 x 2`` pattern (one point on the
    knot line of xi1, two along xi2) when ``i + j + cu + cv`` is even, ``2 x 1`` otherwise. Of its
    two points, the one inside this span's quarter lies on the quarter's knot line, which the
    neighbouring span shares: weight 1/2 (per point) x 1/2 (shared) of the unit dual cell.
    """
    points = []
    for cu, cv in _CORNERS:
        inward = (1.0 - 2.0 * cu, 1.0 - 2.0 * cv)
        if (parity + int(cu) + int(cv)) % 2 == 0:
            points.append((cu, cv + inward[1] * _DUAL_GAUSS))
        else:
            points.append((cu + inward[0] * _DUAL_GAUSS, cv))
    return np.array(points), np.full(4, 0.25)


def _tensor_gauss(n_u: int, n_v: int) -> tuple[np.ndarray, np.ndarray]:
    """Tensor Gauss points ``(n_u n_v, 2)`` on the unit span and their weights."""
    qu, wu = gauss_legendre(n_u)
    qv, wv = gauss_legendre(n_v)
    points = np.array([(a, b) for a in qu for b in qv])
    return points, np.outer(wu, wv).ravel()


def _membrane_rules() -> dict[int, tuple[np.ndarray, np.ndarray]]:
    rules = {parity: _interior_membrane_rule(parity) for parity in _INTERIOR}
    for (across1, across2), tag in _BOUNDARY.items():
        rules[tag] = _tensor_gauss(3 if across1 else 2, 3 if across2 else 2)
    return rules


def _bending_rules() -> dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]]:
    return {
        _INTERIOR: (np.array(_CORNERS), np.full(4, 0.25)),
        tuple(_BOUNDARY.values()): (np.array([[0.5, 0.5]]), np.ones(1)),
    }


def _span_classes(grid_mesh) -> np.ndarray:
    """The class tag of every local cell (owned and ghost)."""
    grid = grid_mesh.grid
    h = np.array([grid.h1, grid.h2])
    origin = np.array([grid.xi1_range[0], grid.xi2_range[0]])
    span = np.rint((grid_mesh.cell_vertices.min(axis=1) - origin) / h).astype(np.int64)  # (cells, 2)
    on1 = ~grid.periodic1 & ((span[:, 0] == 0) | (span[:, 0] == grid.n1 - 1))
    on2 = ~grid.periodic2 & ((span[:, 1] == 0) | (span[:, 1] == grid.n2 - 1))
    tags = (span[:, 0] + span[:, 1]) % 2
    for (across1, across2), tag in _BOUNDARY.items():
        tags[(on1 == across1) & (on2 == across2)] = tag
    return tags.astype(np.int32)


def _to_reference(grid_mesh, points: np.ndarray) -> np.ndarray:
    """Span coordinates ``(n, 2)`` to reference-cell coordinates, through the shared Jacobian.

    The Jacobian is axis aligned, so the map is a signed permutation: applied in integers, the
    same span points give bit-identical reference points (and one compiled kernel) at every size.
    """
    h = np.array([grid_mesh.grid.h1, grid_mesh.grid.h2])
    signed = np.rint(grid_mesh.jacobian / h[:, None]).astype(int)  # d(u, v) / dX, entries 0 or +-1
    inverse = signed.T  # a signed permutation is orthogonal
    reference = points @ inverse.T
    return np.where(inverse.sum(axis=1) < 0, 1.0 + reference, reference)


def _custom(grid_mesh, tags, subdomain, rule: tuple[np.ndarray, np.ndarray]) -> ufl.Measure:
    points, weights = rule
    metadata = {
        "quadrature_rule": "custom",
        "quadrature_degree": 1,
        "quadrature_points": _to_reference(grid_mesh, points).tolist(),
        "quadrature_weights": weights.tolist(),
    }
    return ufl.Measure("dx", domain=grid_mesh.mesh, subdomain_data=tags, subdomain_id=subdomain, metadata=metadata)


def _reduced_quadrature(grid_mesh, mass: ufl.Measure) -> ShellQuadrature:
    classes = _span_classes(grid_mesh)
    cells = np.arange(len(classes), dtype=np.int32)
    tags = dolfinx.mesh.meshtags(grid_mesh.mesh, 2, cells, classes)
    counts = np.bincount(classes[: grid_mesh.mesh.topology.index_map(2).size_local], minlength=5)
    counts = grid_mesh.mesh.comm.allreduce(counts)
    membrane_rules, bending_rules = _membrane_rules(), _bending_rules()
    membrane = [_custom(grid_mesh, tags, tag, rule) for tag, rule in membrane_rules.items()]
    bending = [_custom(grid_mesh, tags, tag, rule) for tag, rule in bending_rules.items()]
    return ShellQuadrature(
        membrane=ufl.measure.MeasureSum(*membrane),
        bending=ufl.measure.MeasureSum(*bending),
        mass=mass,
        membrane_points=int(sum(counts[tag] * len(rule[1]) for tag, rule in membrane_rules.items())),
        bending_points=int(sum(counts[list(tag)].sum() * len(rule[1]) for tag, rule in bending_rules.items())),
    )


def edge_measure(mesh: dolfinx.mesh.Mesh, grid, edges: Sequence[str]) -> ufl.Measure:
    """The facet measure of the knot-span mesh of ``grid`` tagging each listed edge ``i`` with ``i + 1``."""
    mesh.topology.create_connectivity(1, 2)
    tol = 1e-9 * max(grid.h1, grid.h2)
    locators = {
        "xi1_min": lambda p: np.abs(p[0] - grid.xi1_range[0]) < tol,
        "xi1_max": lambda p: np.abs(p[0] - grid.xi1_range[1]) < tol,
        "xi2_min": lambda p: np.abs(p[1] - grid.xi2_range[0]) < tol,
        "xi2_max": lambda p: np.abs(p[1] - grid.xi2_range[1]) < tol,
    }
    facets, tags = [], []
    for i, edge in enumerate(edges):
        found = dolfinx.mesh.locate_entities_boundary(mesh, 1, locators[edge])
        facets.append(found)
        tags.append(np.full(len(found), i + 1, dtype=np.int32))
    facets_all = np.concatenate(facets).astype(np.int32)
    order = np.argsort(facets_all)
    meshtags = dolfinx.mesh.meshtags(mesh, 1, facets_all[order], np.concatenate(tags)[order])
    return ufl.Measure("ds", domain=mesh, subdomain_data=meshtags)
