"""Unknowns that patches share along conforming interfaces (numpy only).

Two patches of one discretization whose edges have as many knot spans and the same edge data at
rest meet along the same curve for every state of those data, so the data can be one unknown:
the shell is continuous (C0) across the interface exactly, with no penalty and no consistency
error; only the angle between the patches is left to a coupling energy
(:class:`~bhem_hpc.bodies.coupling.InterfaceCoupling` without its displacement term).

- B-splines (one degree, open uniform knots): an edge of the surface is the B-spline curve of its
  edge row of control points; those control points are shared.
- Hermite patches: an edge is the cubic Hermite curve of its nodes' positions and their
  derivatives along the edge; both are shared, the derivative scaled by the ratio of the two
  edges' parameter lengths (and its sign by their directions), ``dx/dxi_B = s dx/dxi_A``. The
  derivatives across the edge and the cross derivatives are each patch's own.

Shared data are named by *entries*, a discretization's rows of its surface data (a B-spline's
control point ``i1 * c2 + i2``; a Hermite node's datum ``(i1 * m2 + i2) * 4 + kind``), which the
discretization maps to its closed DOFs (``entry_closed_blocks``). :func:`conforming_edge_dofs`
finds the shared entries of one interface; :func:`shared_groups` makes groups of DOFs joined
through several interfaces (a corner where patches meet); the reduction that makes each group one
unknown is :class:`~bhem_hpc.bodies.shared_petsc.SharedDofProblem`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bhem_hpc.geometry.bspline import BSplineSurface
from bhem_hpc.geometry.interfaces import EDGES, InterfaceError, edge_line
from bhem_hpc.geometry.rational_bspline import RationalBSplineSurface
from bhem_hpc.geometry.surface import HermiteSurface

#: How far two coefficients of one shared DOF may differ (relative) where interfaces meet in a loop.
COEFFICIENT_TOLERANCE = 1e-9

#: Relative spread of the weight ratios along two rational edges that still makes them one curve.
WEIGHT_TOLERANCE = 1e-9


@dataclass(frozen=True)
class SharedDofs:
    """Surface data of different bodies that are one unknown.

    Attributes:
        first, second: ``(k, 2)`` pairs ``(body, entry)``; row ``i`` of ``second`` is ``scale[i]``
            times row ``i`` of ``first`` (every component). The same on every rank.
        scale: ``(k,)`` the coefficients.
    """

    first: np.ndarray
    second: np.ndarray
    scale: np.ndarray

    @staticmethod
    def join(parts: Sequence[SharedDofs]) -> SharedDofs:
        """Every pair of ``parts``."""
        empty = np.zeros((0, 2), dtype=np.int64)
        return SharedDofs(np.concatenate([empty, *(p.first for p in parts)]),
                          np.concatenate([empty, *(p.second for p in parts)]),
                          np.concatenate([np.zeros(0), *(p.scale for p in parts)]))  # fmt: skip

    def moved(self, offset: int) -> SharedDofs:
        """The same pairs with every body index moved by ``offset`` (the patches' place in a scene)."""
        return SharedDofs(self.first + [offset, 0], self.second + [offset, 0], self.scale)

    def __len__(self) -> int:
        return len(self.first)


def _edge_nodes(shape: tuple[int, int], edge: str) -> np.ndarray:
    """The flat node indices ``i1 * m2 + i2`` of ``edge``'s row on a ``shape`` node grid, in the order along it."""
    nodes = np.arange(shape[0] * shape[1]).reshape(shape)
    return {"xi1_min": nodes[0, :], "xi1_max": nodes[-1, :], "xi2_min": nodes[:, 0], "xi2_max": nodes[:, -1]}[edge]


def _edge_data(surface: BSplineSurface | HermiteSurface, edge: str) -> tuple[list[np.ndarray], np.ndarray, float]:
    """What the edge curve is made of: per kind of shared entry, the entries along the edge
    ``[(c,), ...]``; their rest values ``(kinds, c, 3)``; the edge's parameter length."""
    along, _, (low, high), _ = edge_line(surface.grid, edge)
    nodes = _edge_nodes(surface.node_shape, edge)
    if isinstance(surface, BSplineSurface):
        return [nodes], surface.control.reshape(-1, 3)[nodes][None], high - low
    kinds = (0, 1 + along)  # the position and its derivative along the edge
    entries = [4 * nodes + kind for kind in kinds]
    return entries, np.stack([surface.nodal.reshape(-1, 3)[e] for e in entries]), high - low


def _closed(surface: BSplineSurface | HermiteSurface, edge: str) -> bool:
    """Whether ``edge`` runs along a periodic direction (a closed curve)."""
    return surface.grid.periodic2 if edge.startswith("xi1") else surface.grid.periodic1


def _orders(count: int, closed: bool) -> list[tuple[np.ndarray, float]]:
    """How the second edge's ``count`` data may follow the first's: ``(index of the second's datum
    at each of the first's, direction)``: the same way or the opposite one, and on a closed edge
    from any start."""
    index = np.arange(count)
    starts = range(count) if closed else [0]
    return ([(np.roll(index, -k), 1.0) for k in starts]
            + [(np.roll(index[::-1], k + 1) if closed else index[::-1], -1.0) for k in starts])  # fmt: skip


def _check_kind(surfaces: tuple[object, object], edges: tuple[str, str]) -> None:
    for surface, edge in zip(surfaces, edges, strict=True):
        if not isinstance(surface, BSplineSurface | HermiteSurface):
            raise InterfaceError(f"edge {edge}: a {type(surface).__name__} shares no data with another patch")
        if edge not in EDGES:
            raise InterfaceError(f"edge {edge!r} does not exist; expected one of {EDGES}")
    first, second = surfaces
    if _closed(first, edges[0]) != _closed(second, edges[1]):
        raise InterfaceError(f"edge {edges[0] if _closed(first, edges[0]) else edges[1]} is a closed curve, the "
                             "other edge is not")  # fmt: skip
    if type(first) is not type(second):
        raise InterfaceError(f"a {type(first).__name__} and a {type(second).__name__} share no data")
    if isinstance(first, BSplineSurface) and first.degree != second.degree:
        raise InterfaceError(f"the patches' degrees differ ({first.degree} and {second.degree})")


def conforming_edge_dofs(surfaces: tuple[object, object], bodies: tuple[int, int], edges: tuple[str, str],
                         tolerance: float) -> SharedDofs:  # fmt: skip
    """The entries that two patches' edges share when the interface conforms (see the module).

    Args:
        surfaces: the two patches' rest surfaces (B-spline or Hermite, both of one kind).
        bodies: their bodies' indices in the solve.
        edges: the edge of each (:data:`~bhem_hpc.geometry.interfaces.EDGES`).
        tolerance: [m] how far corresponding positions may lie apart at rest (derivatives: this
            over the edge's parameter length).

    Raises:
        InterfaceError: saying why the interface does not conform: another kind of patch, two
            kinds or degrees, a closed edge against an open one, edges of different numbers of
            spans, or edge data apart by more than ``tolerance`` (the largest distance, in either
            order; on closed edges, from any start).
    """
    _check_kind(surfaces, edges)
    (entries_a, values_a, length_a), (entries_b, values_b, length_b) = (
        _edge_data(s, e) for s, e in zip(surfaces, edges, strict=True))  # fmt: skip
    data = "control points" if len(entries_a) == 1 else "nodes"
    if values_a.shape != values_b.shape:
        raise InterfaceError(f"edges {edges[0]} and {edges[1]} have {values_a.shape[1]} and {values_b.shape[1]} "
                             f"{data} (their knots do not match)")  # fmt: skip
    closed, count = _closed(surfaces[0], edges[0]), values_a.shape[1]
    gaps = []
    for index, direction in _orders(count, closed):
        scales = np.array([1.0] + [direction * length_a / length_b] * (len(entries_a) - 1))
        expected = scales[:, None, None] * values_a
        gap = np.linalg.norm(expected - values_b[:, index], axis=2)  # (kinds, c): derivatives in m per parameter
        gap[1:] *= length_b / (count if closed else max(count - 1, 1))  # as a distance over a span
        gaps.append((float(gap.max()), index, scales))
    gap, index, scales = min(gaps, key=lambda g: g[0])
    if gap > tolerance:
        raise InterfaceError(f"edges {edges[0]} and {edges[1]}: their {data} lie {gap:.3g} m apart (tolerance "
                             f"{tolerance:.3g} m)")  # fmt: skip
    if isinstance(surfaces[0], RationalBSplineSurface):  # one curve only where the weights are proportional
        ratio = surfaces[1].weights.ravel()[entries_b[0][index]] / surfaces[0].weights.ravel()[entries_a[0]]
        if np.ptp(ratio) > WEIGHT_TOLERANCE * ratio.max():
            raise InterfaceError(f"edges {edges[0]} and {edges[1]}: their control points' weights differ (ratios "
                                 f"{ratio.min():.6g} to {ratio.max():.6g}): the edge curves are not one")  # fmt: skip
    first = np.concatenate(entries_a)
    second = np.concatenate([e[index] for e in entries_b])
    scale = np.repeat(scales, [len(e) for e in entries_a])
    return SharedDofs(np.stack([np.full(len(first), bodies[0]), first], axis=1),
                      np.stack([np.full(len(second), bodies[1]), second], axis=1), scale)  # fmt: skip


def shared_groups(first: np.ndarray, second: np.ndarray, scale: np.ndarray,
                  preferred: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The unknown each shared DOF becomes: pairs joined directly or through others (a corner where
    several patches meet) form one group, represented by its smallest ``preferred`` member if it
    has one, else by its smallest.

    Args:
        first, second: ``(k,)`` DOFs (any integer ids) with ``x[second] = scale x[first]``, pairwise.
        scale: ``(k,)`` the pairs' coefficients (nonzero).
        preferred: DOFs a group's representative should be (held ones: the representative carries
            the group's constraint).

    Returns:
        ``(members, representatives, coefficients)``: every non-representative member of a group,
        its group's representative and ``c`` with ``x[member] = c x[representative]``, ``(m,)``
        each, sorted by member.

    Raises:
        ValueError: pairs around a loop whose coefficients disagree (the interfaces contradict
            each other), naming the DOF.
    """
    parent: dict[int, tuple[int, float]] = {}  # k -> (p, w): x[k] = w x[p]

    def find(k: int) -> tuple[int, float]:
        path, node = [], k
        while parent.setdefault(node, (node, 1.0))[0] != node:
            path.append(node)
            node = parent[node][0]
        weight = 1.0
        for step in reversed(path):  # path compression: each node straight to the root
            weight *= parent[step][1]
            parent[step] = (node, weight)
        return node, parent[k][1]

    pairs = zip(np.asarray(first).tolist(), np.asarray(second).tolist(), np.asarray(scale).tolist(), strict=True)
    for a, b, c in pairs:
        (ra, wa), (rb, wb) = find(a), find(b)  # x[a] = wa x[ra], x[b] = wb x[rb], x[b] = c x[a]
        if ra == rb:
            if abs(wb - c * wa) > COEFFICIENT_TOLERANCE * max(abs(wb), abs(c * wa)):
                raise ValueError(f"DOF {b}: the interfaces give it {wb:.6g} and {c * wa:.6g} times DOF {ra}")
        elif rb > ra:
            parent[rb] = (ra, c * wa / wb)
        else:
            parent[ra] = (rb, wb / (c * wa))
    held = set(np.asarray(preferred).tolist())
    groups: dict[int, list[tuple[int, float]]] = {}
    for k in list(parent):
        root, weight = find(k)
        groups.setdefault(root, []).append((k, weight))
    members, representatives, coefficients = [], [], []
    for group in groups.values():
        weights = dict(group)
        chosen = min((k for k in weights if k in held), default=min(weights))
        for k, weight in group:
            if k != chosen:
                members.append(k)
                representatives.append(chosen)
                coefficients.append(weight / weights[chosen])
    order = np.argsort(members)
    return (np.asarray(members, dtype=np.int64)[order], np.asarray(representatives, dtype=np.int64)[order],
            np.asarray(coefficients, dtype=float)[order])  # fmt: skip
