"""Trimmed shells: a patch simulated only where its trim loops say (:mod:`bhem_hpc.geometry.trim`).

The shell's forms keep their tensor Gauss rule on every knot span; each cell integrand is
multiplied by a quadrature function ``chi`` (a dolfinx ``Quadrature`` element on the same rule):
1 at the points of spans wholly inside, 0 outside, and on the spans the trim cuts the moment-fitted
weight over the Gauss weight (:func:`~bhem_hpc.geometry.trim.cut_cell_rule`). Every potential, its
gradient and every Hessian kind are multiplied alike (``chi`` does not depend on the state), so the
projected Hessians stay positive semi-definite (the fitted weights are non-negative). Edge
integrals (line loads, edge moments) are not multiplied: they are refused on edges the trim cuts.

Entries (Hermite nodal values, B-spline control points) that move no point of the kept region
have no mass and no stiffness: they are held where they are (:func:`outside_constraints`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import basix
import numpy as np
import ufl
from dolfinx import fem

from bhem_hpc.geometry.surface import ParameterGrid
from bhem_hpc.geometry.trim import OUTSIDE, CutCellRule, TrimError, check_loops, cut_cell_rule, inside
from bhem_hpc.model.bcs import NodalConstraint

#: How far [relative to the parameter domain's diagonal] a loop's ends may be apart and its points
#: outside the domain.
LOOP_TOLERANCE = 1e-9
#: Points sampled along each edge to decide whether the trim keeps it whole.
EDGE_SAMPLES = 257


@dataclass(frozen=True)
class Trim:
    """A patch's trim: checked loops (:func:`~bhem_hpc.geometry.trim.check_loops`) and the rule on
    its knot spans.

    Attributes:
        loops: the loops ``(n_k, 2)`` in the patch's parameters, outer ones counterclockwise.
        rule: the cut-cell rule of the spans in the grid's order ``p1 * n2 + p2``.
        points: Gauss points per direction of the rule (the shell's quadrature).
    """

    loops: tuple[np.ndarray, ...]
    rule: CutCellRule
    points: int

    @classmethod
    def of(cls, grid: ParameterGrid, loops: Sequence, points: int, where: str = "trim") -> Trim:
        """Check ``loops`` on ``grid``'s parameter domain and fit the rule of ``points`` x ``points``
        Gauss points on its spans (:class:`~bhem_hpc.geometry.trim.TrimError` naming ``where``)."""
        domain = (grid.xi1_range, grid.xi2_range)
        diagonal = float(np.hypot(grid.xi1_range[1] - grid.xi1_range[0], grid.xi2_range[1] - grid.xi2_range[0]))
        if grid.periodic1 or grid.periodic2:
            raise TrimError(f"{where}: a surface closed in a direction (periodic) cannot be trimmed")
        checked = check_loops(loops, domain, LOOP_TOLERANCE * diagonal, where)
        p1, p2 = (a.ravel() for a in np.meshgrid(np.arange(grid.n1), np.arange(grid.n2), indexing="ij"))
        lows = np.column_stack([grid.xi1_range[0] + p1 * grid.h1, grid.xi2_range[0] + p2 * grid.h2])
        rule = cut_cell_rule(checked, lows, lows + [grid.h1, grid.h2], points)
        if np.all(rule.states == OUTSIDE):
            raise TrimError(f"{where}: the loops keep no knot span of the surface")
        return cls(tuple(checked), rule, points)

    def keeps_edge(self, grid: ParameterGrid, edge: str) -> bool:
        """Whether the whole ``edge`` (``"xi1_min"``, ...) lies in the kept region."""
        t = np.linspace(0.0, 1.0, EDGE_SAMPLES)
        (a, b), (c, d) = grid.xi1_range, grid.xi2_range
        # a hair inside the domain: a loop along the edge itself keeps it
        inset = 1e-9 * max(b - a, d - c)
        along1, along2 = a + inset + t * (b - a - 2 * inset), c + inset + t * (d - c - 2 * inset)
        points = {"xi1_min": (np.full_like(t, a + inset), along2), "xi1_max": (np.full_like(t, b - inset), along2),
                  "xi2_min": (along1, np.full_like(t, c + inset)),
                  "xi2_max": (along1, np.full_like(t, d - inset))}[edge]  # fmt: skip
        return bool(np.all(inside(self.loops, np.column_stack(points))))

    def keeps(self, xi: np.ndarray) -> np.ndarray:
        """Whether each parameter point ``(k, 2)`` lies in the kept region."""
        return inside(self.loops, np.asarray(xi, dtype=float).reshape(-1, 2))

    @property
    def kept_spans(self) -> np.ndarray:
        """Spans ``(k,)`` (order ``p1 * n2 + p2``) with some weight."""
        return np.flatnonzero(self.rule.states != OUTSIDE)


def outside_constraints(patch_entries: np.ndarray, trim: Trim, node_shape: tuple[int, int],
                        kinds: int) -> list[NodalConstraint]:  # fmt: skip
    """Constraints that hold every node none of whose entries moves a kept span.

    Args:
        patch_entries: the entries of each span ``(spans, k)`` (a discretization's patch layout).
        node_shape: the surface's nodes (Hermite) or control points (B-splines) per direction.
        kinds: entries per node (Hermite 4: position and derivatives; B-splines 1).
    """
    used = np.zeros(node_shape[0] * node_shape[1] * kinds, dtype=bool)
    used[np.unique(patch_entries[trim.kept_spans])] = True
    idle = np.flatnonzero(~used.reshape(-1, kinds).any(axis=1))
    if not len(idle):
        return []
    nodes = np.column_stack(np.unravel_index(idle, node_shape))
    return [NodalConstraint(nodes=nodes, kinds=tuple(range(kinds)))]


def weight_function(grid_mesh, trim: Trim) -> fem.Function:
    """``chi``: the rule's weight over the Gauss weight at every quadrature point of every local
    cell (owned and ghost) of ``grid_mesh`` (a :class:`~bhem_hpc.discretization.grid_mesh.GridMesh`)."""
    mesh, grid, n = grid_mesh.mesh, grid_mesh.grid, trim.points
    degree = 2 * n - 1
    element = ufl.FiniteElement("Quadrature", mesh.ufl_cell(), degree=degree, quad_scheme="default")
    space = fem.FunctionSpace(mesh, element)
    chi = fem.Function(space, name="trim_weight")
    reference, _ = basix.make_quadrature(basix.CellType.quadrilateral, degree)
    if len(reference) != n * n:
        raise ValueError(f"basix's rule of degree {degree} has {len(reference)} points, not {n * n}")
    vertices = grid_mesh.cell_vertices  # (cells, 4, 2)
    h = np.array([grid.h1, grid.h2])
    origin = np.array([grid.xi1_range[0], grid.xi2_range[0]])
    lows = origin + h * np.rint((vertices.min(axis=1) - origin) / h)
    spans = np.rint((lows - origin) / h).astype(np.int64)
    span = spans[:, 0] * grid.n2 + spans[:, 1]
    # each reference point's parameters in its cell, as unit-span coordinates; the rule's point it is
    xi = vertices[:, None, 0, :] + reference @ grid_mesh.jacobian.T  # (cells, n*n, 2)
    unit = (xi - lows[:, None, :]) / h
    match = np.argmin(np.linalg.norm(unit[:, :, None, :] - trim.rule.points[None, None], axis=3), axis=2)
    dofs = np.array([space.dofmap.cell_dofs(c) for c in range(len(vertices))])  # (cells, n*n)
    chi.x.array[dofs.ravel()] = trim.rule.factors[span[:, None], match].ravel()
    return chi


def restrict(form: ufl.Form, chi: fem.Function) -> ufl.Form:
    """``form`` with every cell integrand multiplied by ``chi`` (its integrals must use ``chi``'s
    rule: a Gauss measure of the same degree)."""
    degree = chi.function_space.ufl_element().degree()
    integrals = []
    for integral in form.integrals():
        if integral.integral_type() != "cell":
            integrals.append(integral)
            continue
        metadata = integral.metadata()
        if metadata.get("quadrature_degree") != degree or metadata.get("quadrature_rule", "default") != "default":
            raise TrimError(f"a trimmed shell integrates with its Gauss rule of degree {degree}, got {metadata}")
        integrals.append(integral.reconstruct(integrand=chi * integral.integrand()))
    return ufl.Form(integrals)


def restrict_term(term, chi: fem.Function):
    """A model :class:`~bhem_hpc.model.shell.Term` with its form and Hessian replacements restricted."""

    def hessian(replacement):
        return lambda test, trial: restrict(replacement(test, trial), chi)

    return dataclasses.replace(term, form=restrict(term.form, chi),
                               hessians={kind: hessian(h) for kind, h in term.hessians.items()})  # fmt: skip


def check_trimmed(trim: Trim, grid: ParameterGrid, loads, point_constraints: Sequence) -> None:
    """What a trimmed model refuses (:class:`~bhem_hpc.geometry.trim.TrimError`): edge loads on an
    edge the trim cuts, and point loads or point constraints outside the kept region."""
    for name, edge_loads in (("line_loads", loads.line_loads), ("edge_moments", loads.edge_moments)):
        for k, load in enumerate(edge_loads):
            if not trim.keeps_edge(grid, load.edge):
                raise TrimError(f"{name}[{k}] acts on edge '{load.edge}', which the trim cuts: edge loads need "
                                "an edge the trim keeps whole")  # fmt: skip
    for name, points in (("point_loads", loads.point_loads), ("point_constraints", point_constraints)):
        for k, point in enumerate(points):
            if not trim.keeps(np.array([point.xi1, point.xi2]))[0]:
                raise TrimError(f"{name}[{k}] at (xi1, xi2) = ({point.xi1:g}, {point.xi2:g}) lies outside the "
                                "trimmed surface")  # fmt: skip
