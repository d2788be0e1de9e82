"""Unknowns that patches share along conforming interfaces (numpy only).

Two B-spline patches of one degree whose edges have the same number of knot spans and the same
control points at rest (in either order) meet along the same curve for every position of those
control points: an edge of an open, uniform B-spline surface is the B-spline curve of its edge row
of control points. Making those control points one unknown keeps the shell continuous (C0) across
the interface exactly, with no penalty and no consistency error; only the angle between the
patches is left to a coupling energy (:class:`~bhem_hpc.bodies.coupling.InterfaceCoupling`
without its displacement term).

:func:`conforming_edge_dofs` finds the shared control points of one interface;
:class:`SharedDofs` collects them for a solve (the reduction that makes them one unknown is
:class:`~bhem_hpc.bodies.shared_petsc.SharedDofProblem`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bhem_hpc.geometry.bspline import BSplineSurface
from bhem_hpc.geometry.interfaces import EDGES, InterfaceError


@dataclass(frozen=True)
class SharedDofs:
    """Closed DOFs of different bodies that are one unknown.

    Attributes:
        first, second: ``(k, 2)`` pairs ``(body, body-global closed DOF)``; row ``i`` of ``first``
            and row ``i`` of ``second`` are one unknown. The same on every rank.
    """

    first: np.ndarray
    second: np.ndarray

    @staticmethod
    def join(parts: Sequence[SharedDofs]) -> SharedDofs:
        """Every pair of ``parts``."""
        empty = np.zeros((0, 2), dtype=np.int64)
        return SharedDofs(np.concatenate([empty, *(p.first for p in parts)]),
                          np.concatenate([empty, *(p.second for p in parts)]))  # fmt: skip

    def __len__(self) -> int:
        return len(self.first)


def _edge_rows(surface: BSplineSurface, edge: str) -> np.ndarray:
    """The control-point entries (``i1 * c2 + i2``) of ``edge``'s row, in the order along it, ``(c,)``."""
    c1, c2 = surface.node_shape
    entries = np.arange(c1 * c2).reshape(c1, c2)
    return {"xi1_min": entries[0, :], "xi1_max": entries[-1, :], "xi2_min": entries[:, 0],
            "xi2_max": entries[:, -1]}[edge]  # fmt: skip


def conforming_edge_dofs(surfaces: tuple[object, object], bodies: tuple[int, int], edges: tuple[str, str],
                         tolerance: float) -> SharedDofs:  # fmt: skip
    """The closed DOFs that two patches' edges share when the interface conforms.

    Args:
        surfaces: the two patches' rest surfaces.
        bodies: their bodies' indices in the solve.
        edges: the edge of each (:data:`~bhem_hpc.geometry.interfaces.EDGES`).
        tolerance: [m] how far corresponding control points may lie apart at rest.

    Returns:
        Three pairs (x, y, z) per control point of the edge row.

    Raises:
        InterfaceError: saying why the interface does not conform: a patch that is not a B-spline,
            two degrees, a periodic edge direction, edge rows of different lengths, or control points
            apart by more than ``tolerance`` (the largest distance, in either order).
    """
    for surface, edge in zip(surfaces, edges, strict=True):
        if not isinstance(surface, BSplineSurface):
            raise InterfaceError(f"edge {edge}: only B-spline patches share control points (a "
                                 f"{type(surface).__name__} is joined by the coupling energy)")  # fmt: skip
        if edge not in EDGES:
            raise InterfaceError(f"edge {edge!r} does not exist; expected one of {EDGES}")
        if (surface.grid.periodic2 if edge.startswith("xi1") else surface.grid.periodic1):
            raise InterfaceError(f"edge {edge} is a closed curve: sharing its control points is not offered")
    first, second = surfaces
    if first.degree != second.degree:
        raise InterfaceError(f"the patches' degrees differ ({first.degree} and {second.degree})")
    rows = [_edge_rows(s, e) for s, e in zip(surfaces, edges, strict=True)]
    if len(rows[0]) != len(rows[1]):
        raise InterfaceError(f"edges {edges[0]} and {edges[1]} have {len(rows[0])} and {len(rows[1])} control points "
                             "(their knots do not match)")  # fmt: skip
    a, b = first.control.reshape(-1, 3)[rows[0]], second.control.reshape(-1, 3)[rows[1]]
    gaps = [np.linalg.norm(a - b, axis=1).max(), np.linalg.norm(a - b[::-1], axis=1).max()]
    if min(gaps) > tolerance:
        raise InterfaceError(f"edges {edges[0]} and {edges[1]}: their control points lie {min(gaps):.3g} m apart "
                             f"(tolerance {tolerance:.3g} m)")  # fmt: skip
    partner = rows[1] if gaps[0] <= gaps[1] else rows[1][::-1]
    components = np.arange(3)
    dofs = [(3 * np.asarray(r, dtype=np.int64)[:, None] + components).ravel() for r in (rows[0], partner)]
    return SharedDofs(np.stack([np.full(len(dofs[0]), bodies[0]), dofs[0]], axis=1),
                      np.stack([np.full(len(dofs[1]), bodies[1]), dofs[1]], axis=1))  # fmt: skip


def shared_groups(stacked_first: np.ndarray, stacked_second: np.ndarray,
                  preferred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The unknown each shared stacked DOF becomes: pairs joined directly or through others (a
    corner where several patches meet) form one group, represented by its smallest ``preferred``
    member if it has one, else by its smallest.

    Args:
        stacked_first, stacked_second: ``(k,)`` stacked global DOFs that are one unknown, pairwise.
        preferred: stacked global DOFs a group's representative should be (held ones: the
            representative carries the group's constraint).

    Returns:
        ``(members, representatives)``: every non-representative member of a group and its
        group's representative, ``(m,)`` each, sorted by member.
    """
    parent: dict[int, int] = {}

    def find(k: int) -> int:
        root = k
        while parent.setdefault(root, root) != root:
            root = parent[root]
        while parent[k] != root:  # path compression: later finds are short
            parent[k], k = root, parent[k]
        return root

    for a, b in zip(np.asarray(stacked_first).tolist(), np.asarray(stacked_second).tolist(), strict=True):
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    held = set(np.asarray(preferred).tolist())
    groups: dict[int, list[int]] = {}
    for k in list(parent):
        groups.setdefault(find(k), []).append(k)
    members, representatives = [], []
    for group in groups.values():
        root = min((k for k in group if k in held), default=min(group))
        members += [k for k in group if k != root]
        representatives += [root] * (len(group) - 1)
    order = np.argsort(members)
    return (np.asarray(members, dtype=np.int64)[order], np.asarray(representatives, dtype=np.int64)[order])
