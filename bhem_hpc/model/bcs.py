"""Boundary conditions on nodal DOFs (paper §4.2), independent of dolfinx and PETSc.

A :class:`NodalConstraint` fixes chosen parametric kinds (x, d1, d2, d12) and components of
chosen nodes. Nodes are *distinct-node* indices ``(i1, i2)`` of the surface's grid (a closed
direction stores seam nodes once). Target values are parametric nodal data; ``None`` holds the
values of the initial state.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from bhem_hpc.geometry.surface import KIND_NAMES, HermiteSurface, ParameterGrid

EDGES = ("xi1_min", "xi1_max", "xi2_min", "xi2_max")


class BoundaryConditionError(ValueError):
    """A boundary condition names nodes, kinds or components that do not exist."""


@dataclass(frozen=True)
class NodalConstraint:
    """Fix ``kinds`` x ``components`` of ``nodes``.

    Attributes:
        nodes: ``(k, 2)`` distinct-node indices.
        kinds: parametric kinds, 0..3 = x, d1, d2, d12.
        components: 0, 1, 2 = x, y, z.
        values: ``None`` (hold the initial values) or an array broadcastable to
            ``(k, len(kinds), len(components))`` of parametric target values.
    """

    nodes: np.ndarray
    kinds: tuple[int, ...]
    components: tuple[int, ...] = (0, 1, 2)
    values: np.ndarray | None = field(default=None)

    def validate(self, grid: ParameterGrid, node_shape: tuple[int, int] | None = None, kind_count: int = 4) -> None:
        """Check against a surface on ``grid`` whose data sit at ``node_shape`` nodes (default: the
        grid's Hermite nodes; a B-spline's control points) with ``kind_count`` kinds each."""
        nodes = np.asarray(self.nodes)
        if nodes.ndim != 2 or nodes.shape[1] != 2 or len(nodes) == 0:
            raise BoundaryConditionError(f"constraint nodes must be a non-empty (k, 2) array, got shape {nodes.shape}")
        m1, m2 = node_shape or grid.node_shape
        bad = (nodes[:, 0] < 0) | (nodes[:, 0] >= m1) | (nodes[:, 1] < 0) | (nodes[:, 1] >= m2)
        if np.any(bad):
            raise BoundaryConditionError(
                f"constraint names node {tuple(int(v) for v in nodes[bad][0])}, which does not exist: "
                f"the grid has nodes (0..{m1 - 1}, 0..{m2 - 1})"
            )
        if not self.kinds or any(k not in range(kind_count) for k in self.kinds):
            raise BoundaryConditionError(
                f"constraint kinds {self.kinds!r} must be a non-empty subset of {KIND_NAMES[:kind_count]}"
            )
        if not self.components or any(c not in range(3) for c in self.components):
            raise BoundaryConditionError(
                f"constraint components {self.components!r} must be a non-empty subset of 0, 1, 2"
            )
        if self.values is not None:
            values = np.asarray(self.values, dtype=float)
            try:
                np.broadcast_to(values, (len(nodes), len(self.kinds), len(self.components)))
            except ValueError as exc:
                raise BoundaryConditionError(
                    f"constraint values of shape {values.shape} do not fit "
                    f"(nodes={len(nodes)}, kinds={len(self.kinds)}, components={len(self.components)})"
                ) from exc
            if not np.all(np.isfinite(values)):
                raise BoundaryConditionError("constraint values contain NaN/Inf")


def target_surface(initial: HermiteSurface, constraints: Sequence[NodalConstraint]) -> HermiteSurface:
    """The initial surface with every prescribed value written in (parametric units); any surface
    with ``nodal`` data ``(m1, m2, kinds, 3)`` and ``with_nodal`` (Hermite, B-spline)."""
    nodal = initial.nodal.copy()
    for c in constraints:
        c.validate(initial.grid, initial.node_shape, initial.kind_count)
        if c.values is None:
            continue
        nodes = np.asarray(c.nodes)
        values = np.broadcast_to(np.asarray(c.values, float), (len(nodes), len(c.kinds), len(c.components)))
        for a, kind in enumerate(c.kinds):
            for b, comp in enumerate(c.components):
                nodal[nodes[:, 0], nodes[:, 1], kind, comp] = values[:, a, b]
    return initial.with_nodal(nodal)


def edge_nodes(grid: ParameterGrid, edge: str, node_shape: tuple[int, int] | None = None) -> np.ndarray:
    """Nodes on a boundary edge of parameter space, shape ``(k, 2)``: the grid's distinct nodes, or
    the nodes of ``node_shape`` (a B-spline's control points)."""
    m1, m2 = node_shape or grid.node_shape
    if edge not in EDGES:
        raise BoundaryConditionError(f"edge {edge!r} does not exist; expected one of {EDGES}")
    if (edge.startswith("xi1") and grid.periodic1) or (edge.startswith("xi2") and grid.periodic2):
        raise BoundaryConditionError(f"edge {edge!r} does not exist: the surface is closed in that direction")
    if edge == "xi1_min":
        return np.stack([np.zeros(m2, int), np.arange(m2)], axis=1)
    if edge == "xi1_max":
        return np.stack([np.full(m2, m1 - 1), np.arange(m2)], axis=1)
    if edge == "xi2_min":
        return np.stack([np.arange(m1), np.zeros(m1, int)], axis=1)
    return np.stack([np.arange(m1), np.full(m1, m2 - 1)], axis=1)


def clamp(nodes: np.ndarray) -> NodalConstraint:
    """Fix all four nodal vectors (position and orientation)."""
    return NodalConstraint(np.asarray(nodes).reshape(-1, 2), (0, 1, 2, 3))


def pin(nodes: np.ndarray) -> NodalConstraint:
    """Fix the position only."""
    return NodalConstraint(np.asarray(nodes).reshape(-1, 2), (0,))


def simply_supported(grid: ParameterGrid, edge: str) -> NodalConstraint:
    """Hinged edge: position and the derivative along the edge fixed, rotation about it free."""
    along = 2 if edge.startswith("xi1") else 1
    return NodalConstraint(edge_nodes(grid, edge), (0, along))


def prescribe(
    nodes: np.ndarray, kinds: Sequence[str], components: Sequence[int], values: np.ndarray
) -> NodalConstraint:
    """Prescribe parametric values of chosen kinds (names from ``KIND_NAMES``) and components."""
    try:
        kind_ids = tuple(KIND_NAMES.index(k) for k in kinds)
    except ValueError as exc:
        raise BoundaryConditionError(f"kinds {list(kinds)!r} must be names from {KIND_NAMES}") from exc
    return NodalConstraint(np.asarray(nodes).reshape(-1, 2), kind_ids, tuple(components), np.asarray(values, float))


def with_inner_row(nodes: np.ndarray, node_shape: tuple[int, int]) -> np.ndarray:
    """Boundary control points with their inward neighbours ``(k', 2)``: on a B-spline the two outer
    rows of control points hold the position and the slope (a clamp)."""
    c1, c2 = node_shape
    nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, 2)
    on_boundary = (nodes[:, 0] == 0) | (nodes[:, 0] == c1 - 1) | (nodes[:, 1] == 0) | (nodes[:, 1] == c2 - 1)
    if not np.all(on_boundary):
        raise BoundaryConditionError(
            "clamp on a B-spline surface needs boundary control points (edge or corners); "
            f"{tuple(int(v) for v in nodes[~on_boundary][0])} is interior"
        )
    inward1 = np.where(nodes[:, 0] == 0, 1, np.where(nodes[:, 0] == c1 - 1, c1 - 2, nodes[:, 0]))
    inward2 = np.where(nodes[:, 1] == 0, 1, np.where(nodes[:, 1] == c2 - 1, c2 - 2, nodes[:, 1]))
    neighbours = (np.stack([inward1, nodes[:, 1]], 1), np.stack([nodes[:, 0], inward2], 1))
    neighbours += (np.stack([inward1, inward2], 1),)
    return np.unique(np.concatenate([nodes, *neighbours]), axis=0)


def clamp_edge(surface, edge: str) -> NodalConstraint:
    """Clamp a boundary edge of any surface: Hermite nodes with all four nodal vectors, or a
    B-spline's two outer rows of control points."""
    nodes = edge_nodes(surface.grid, edge, surface.node_shape)
    if surface.kind_count == 1:
        return NodalConstraint(with_inner_row(nodes, surface.node_shape), (0,))
    return clamp(nodes)


def support_edge(surface, edge: str) -> NodalConstraint:
    """Simply support a boundary edge of any surface: the edge curve held, its rotation free
    (Hermite: position and the derivative along the edge; B-splines: the boundary control points)."""
    if surface.kind_count == 1:
        return NodalConstraint(edge_nodes(surface.grid, edge, surface.node_shape), (0,))
    return simply_supported(surface.grid, edge)
