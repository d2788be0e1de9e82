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

import basix
import numpy as np
import ufl
from dolfinx import fem

from bhem_hpc.geometry.surface import ParameterGrid
from bhem_hpc.geometry.trim import Trim, TrimError, check_trimmed
from bhem_hpc.model.bcs import NodalConstraint


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


def check_model(trim: Trim, grid: ParameterGrid, loads, point_constraints: Sequence) -> None:
    """:func:`check_trimmed` of a model's :class:`~bhem_hpc.model.loads.Loads` and point constraints."""
    edge_loads = [(f"{family}[{k}]", load.edge) for family in ("line_loads", "edge_moments")
                  for k, load in enumerate(getattr(loads, family))]  # fmt: skip
    points = [(f"{family}[{k}]", p.xi1, p.xi2) for family, items in (("point_loads", loads.point_loads),
              ("point_constraints", point_constraints)) for k, p in enumerate(items)]  # fmt: skip
    check_trimmed(trim, grid, edge_loads, points)
