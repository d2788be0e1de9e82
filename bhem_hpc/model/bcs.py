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

from bhem_hpc.errors import UserError
from bhem_hpc.geometry.surface import KIND_NAMES, HermiteSurface, ParameterGrid

EDGES = ("xi1_min", "xi1_max", "xi2_min", "xi2_max")


class BoundaryConditionError(UserError, ValueError):
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


@dataclass(frozen=True)
class NodalTie:
    """Tie ``components`` of the control points ``nodes`` (the slaves) to those of ``masters``: each
    slave keeps its rest offset from its master (B-spline surfaces; e.g. a symmetry plane's second
    row of control points following the first, so that the slope across the edge stays normal)."""

    nodes: np.ndarray
    masters: np.ndarray
    components: tuple[int, ...]
    kinds: tuple[int, ...] = (0,)
    values: None = None

    def validate(self, grid: ParameterGrid, node_shape: tuple[int, int] | None = None, kind_count: int = 4) -> None:
        if kind_count != 1:
            raise BoundaryConditionError("ties join control points of B-spline surfaces only")
        if np.shape(self.nodes) != np.shape(self.masters):
            raise BoundaryConditionError("a tie needs one master per slave control point")
        for nodes in (self.nodes, self.masters):
            NodalConstraint(nodes, (0,), self.components).validate(grid, node_shape, kind_count)


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


def along_kind(edge: str) -> int:
    """The Hermite kind of the derivative along a boundary edge (d2 on the xi1 edges, d1 on the xi2
    ones); the other first derivative runs across it."""
    return 2 if edge.startswith("xi1") else 1


def simply_supported(surface, edge: str) -> NodalConstraint:
    """A simply supported edge of any surface, taken like the other edge helpers (the same as
    :func:`support_edge`)."""
    if isinstance(surface, ParameterGrid):
        raise TypeError("simply_supported takes the surface, as the other edge helpers do, not its ParameterGrid")
    return support_edge(surface, edge)


def prescribe(
    nodes: np.ndarray, kinds: Sequence[str], components: Sequence[int], values: np.ndarray
) -> NodalConstraint:
    """Prescribe parametric values of chosen kinds (names from ``KIND_NAMES``) and components."""
    if values is None:
        raise BoundaryConditionError(
            "prescribe needs values (NodalConstraint(nodes, kinds) holds the initial ones)"
        )
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
    return NodalConstraint(edge_nodes(surface.grid, edge), (0, along_kind(edge)))


AXES = ("x", "y", "z")


def _axis(normal: str | int) -> int:
    if normal in AXES:
        return AXES.index(normal)
    if normal in (0, 1, 2) and not isinstance(normal, bool):
        return int(normal)
    raise BoundaryConditionError(f"plane normal {normal!r} must be one of {AXES} (or 0, 1, 2)")


def _edge_in_plane(surface, edge: str, axis: int, what: str) -> None:
    """Raise unless ``edge`` exists and the rest edge lies in a plane normal to coordinate ``axis``."""
    edge_nodes(surface.grid, edge, surface.node_shape)  # raises for an edge that does not exist
    grid = surface.grid
    t = np.linspace(0.0, 1.0, 8 * max(grid.n1, grid.n2) + 1)
    (lo1, hi1), (lo2, hi2) = grid.xi1_range, grid.xi2_range
    xi1 = {"xi1_min": np.full_like(t, lo1), "xi1_max": np.full_like(t, hi1)}.get(edge, lo1 + t * (hi1 - lo1))
    xi2 = {"xi2_min": np.full_like(t, lo2), "xi2_max": np.full_like(t, hi2)}.get(edge, lo2 + t * (hi2 - lo2))
    points = surface.evaluate(xi1, xi2).x
    size = float(np.ptp(surface.evaluate(*grid.node_parameters()).x.reshape(-1, 3), axis=0).max())
    spread = float(np.ptp(points[:, axis]))
    if spread > 1e-9 * size:
        raise BoundaryConditionError(
            f"{what} on edge {edge!r}: the edge does not lie in a plane normal to {AXES[axis]} "
            f"(its {AXES[axis]} coordinates spread over {spread:.3g})"
        )


def _edge_rows(surface, edge: str, rows: int) -> np.ndarray:
    """The boundary row of nodes (control points) of ``edge`` and the ``rows - 1`` rows inside it."""
    nodes = edge_nodes(surface.grid, edge, surface.node_shape)
    c1, c2 = surface.node_shape
    step = {"xi1_min": (1, 0), "xi1_max": (-1, 0), "xi2_min": (0, 1), "xi2_max": (0, -1)}[edge]
    layers = [nodes + k * np.asarray(step) for k in range(rows)]
    out = np.concatenate(layers)
    if np.any(out < 0) or np.any(out[:, 0] >= c1) or np.any(out[:, 1] >= c2):
        raise BoundaryConditionError(f"edge {edge!r}: the surface has fewer than {rows} rows of nodes across it")
    return out


def _not_at_right_angles(edge: str, axis: int) -> BoundaryConditionError:
    return BoundaryConditionError(
        f"symmetry plane on edge {edge!r}: the rest surface does not cross the plane normal to "
        f"{AXES[axis]} at right angles there (a symmetric structure does)"
    )


def hinged_edge(surface, edge: str) -> NodalConstraint:
    """A hinge along a boundary edge: the edge's positions held, its rotation about the edge free
    (the same as :func:`support_edge`, the scene's ``simply_supported``)."""
    return support_edge(surface, edge)


def symmetry_edge(surface, edge: str, normal: str | int) -> list[NodalConstraint]:
    """A boundary edge on a plane of symmetry normal to a coordinate axis ``n``: the edge stays in the
    plane and the surface keeps crossing it at right angles (its tangent across the edge along ``n``),
    so the displacement is even across the plane.

    Hermite nodal vectors of the edge: the ``n`` component of the position and of the derivative
    along the edge; the in-plane components of the derivative across the edge and of its change
    along the edge (zero at rest). B-splines: the ``n`` component of the boundary row of control
    points held, the second row's in-plane components tied to the boundary row's (a
    :class:`NodalTie`).

    Raises:
        BoundaryConditionError: the edge is not in such a plane, or the rest surface does not cross it
            at right angles.
    """
    axis = _axis(normal)
    _edge_in_plane(surface, edge, axis, "symmetry plane")
    in_plane = tuple(c for c in range(3) if c != axis)
    if surface.kind_count == 1:
        return _spline_symmetry(surface, edge, axis, in_plane)
    nodes = edge_nodes(surface.grid, edge)
    along = along_kind(edge)
    across = 3 - along
    slope = surface.nodal[nodes[:, 0], nodes[:, 1], across]
    if np.abs(slope[:, in_plane]).max() > 1e-9 * float(np.abs(slope).max()):
        raise _not_at_right_angles(edge, axis)
    return [NodalConstraint(nodes, (0, along), (axis,)), NodalConstraint(nodes, (across, 3), in_plane)]


def _spline_symmetry(surface, edge: str, axis: int, in_plane: tuple[int, ...]) -> list:
    """B-splines: the slope across the edge is ``P1 - P0`` (second row minus boundary row), so the
    boundary row's normal components are held and the second row's in-plane components are tied to
    the boundary row's (its normal component stays free: the surface may stretch across the plane)."""
    rows = _edge_rows(surface, edge, 2)
    boundary, second = np.split(rows, 2)
    control = surface.nodal[..., 0, :]
    slope = control[second[:, 0], second[:, 1]] - control[boundary[:, 0], boundary[:, 1]]
    if np.abs(slope[:, in_plane]).max() > 1e-3 * float(np.abs(slope).max()):  # interpolated shapes: ~1e-5
        raise _not_at_right_angles(edge, axis)
    return [NodalConstraint(boundary, (0,), (axis,)), NodalTie(second, boundary, in_plane)]


def diaphragm_edge(surface, edge: str, normal: str | int) -> NodalConstraint:
    """A boundary edge fixed to a rigid diaphragm in the plane normal to a coordinate axis: rigid in
    its plane (the edge's in-plane displacements held), flexible out of it (the displacement along
    the normal and every rotation free), as the end diaphragms of a barrel vault.

    Hermite: the in-plane components of the edge's positions and derivatives along it. B-splines:
    the in-plane components of the boundary row of control points."""
    axis = _axis(normal)
    _edge_in_plane(surface, edge, axis, "rigid diaphragm")
    in_plane = tuple(c for c in range(3) if c != axis)
    nodes = edge_nodes(surface.grid, edge, surface.node_shape)
    if surface.kind_count == 1:
        return NodalConstraint(nodes, (0,), in_plane)
    return NodalConstraint(nodes, (0, along_kind(edge)), in_plane)
