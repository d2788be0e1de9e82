"""``[[constraints]]`` and ``[[point_constraints]]`` tables: each constraint type parses its own table
and registers itself in :data:`CONSTRAINTS` (pbrt-v4's ``Create``).

A type's parser takes the table and the surface and returns its nodal constraints and whether a
``motion`` may drive them (a symmetry plane holds two sets of DOFs fixed: no motion). On B-splines
the nodes are control points: ``clamp`` holds the two outer rows (position and slope),
``simply_supported`` the boundary row (the edge curve).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.scene.motions import check_motion_conflicts, parse_motion
from bhem_hpc.scene.records import SceneConstraint, ScenePoint
from bhem_hpc.scene.table import VALUE_KINDS, Registry, SceneError, Table

#: Constraint types by name: ``parser(table, surface) -> (constraints, movable)``.
CONSTRAINTS = Registry("constraint type")
#: The corners a constraint may name, ``<xi1 end>_<xi2 end>``.
CORNERS = ("min_min", "min_max", "max_min", "max_max")
#: Parsed constraints of one table and whether a motion may drive them.
Parsed = tuple[list[bcs.NodalConstraint], bool]


def nodes_of(t: Table, surface) -> np.ndarray:
    """Nodes of a constraint ``(k, 2)`` from exactly one of 'nodes', 'edge', 'corners'."""
    given = [k for k in ("nodes", "edge", "corners") if k in t.data]
    if len(given) != 1:
        raise SceneError(f"{t.path}: table '{t.name}' needs exactly one of 'nodes', 'edge', 'corners'")
    m1, m2 = surface.node_shape
    try:
        if given[0] == "edge":
            return bcs.edge_nodes(surface.grid, t.get("edge", "a string"), surface.node_shape)
        if given[0] == "corners":
            names = t.get(
                "corners", "a list", check=lambda v: all(c in CORNERS for c in v), expected=f"names from {CORNERS}"
            )
            pick = {"min": 0}
            return np.array([[pick.get(a, m1 - 1), pick.get(b, m2 - 1)] for a, b in (c.split("_") for c in names)])
    except bcs.BoundaryConditionError as exc:
        raise SceneError(f"{t.path}: key '{t.key(given[0])}': {exc}") from exc
    nodes = t.get(
        "nodes",
        "a list",
        check=lambda v: all(VALUE_KINDS["2 integers"](n) for n in v) and len(v) > 0,
        expected="a non-empty list of [i1, i2] integer pairs",
    )
    return np.array(nodes, dtype=np.int64)


def _components(t: Table) -> tuple[int, ...]:
    return tuple(t.get("components", "a list", [0, 1, 2], lambda v: len(v) > 0 and all(c in (0, 1, 2) for c in v),
                       "a non-empty subset of [0, 1, 2]"))  # fmt: skip


@CONSTRAINTS.register("clamp")
def _clamp(t: Table, surface) -> Parsed:
    """Position and every derivative (Hermite), or the two outer rows of control points."""
    nodes = nodes_of(t, surface)
    if surface.kind_count == 1:
        try:
            nodes = bcs.with_inner_row(nodes, surface.node_shape)
        except bcs.BoundaryConditionError as exc:
            raise SceneError(f"{t.path}: table '{t.name}': {exc}") from exc
        return [bcs.NodalConstraint(nodes, (0,), _components(t))], True
    return [bcs.NodalConstraint(nodes, (0, 1, 2, 3), _components(t))], True


@CONSTRAINTS.register("pin")
def _pin(t: Table, surface) -> Parsed:
    """The nodes' positions."""
    return [bcs.NodalConstraint(nodes_of(t, surface), (0,), _components(t))], True


def _edge(t: Table) -> str:
    return t.get("edge", "a string", check=lambda v: v in bcs.EDGES, expected=f"one of {bcs.EDGES}")


def _normal(t: Table) -> str:
    expected = f"one of {bcs.AXES} (the plane's normal)"
    return t.get("normal", "a string", check=lambda v: v in bcs.AXES, expected=expected)


def _edge_support(t: Table, edge: str, make: Callable[[], object]) -> list[bcs.NodalConstraint]:
    """The constraints ``make()`` builds on ``edge``, its errors naming the key."""
    try:
        made = make()
    except bcs.BoundaryConditionError as exc:
        raise SceneError(f"{t.path}: key '{t.key('edge')}' = {edge!r}: {exc}") from exc
    return list(made) if isinstance(made, list) else [made]


@CONSTRAINTS.register("simply_supported")
def _simply_supported(t: Table, surface) -> Parsed:
    """A named ``edge``: the edge curve held, its rotation free."""
    edge = _edge(t)
    return _edge_support(t, edge, lambda: bcs.hinged_edge(surface, edge)), True


CONSTRAINTS.register("hinged")(_simply_supported)


@CONSTRAINTS.register("symmetry")
def _symmetry(t: Table, surface) -> Parsed:
    """A named ``edge`` in a symmetry plane of axis ``normal``: no motion."""
    edge, normal = _edge(t), _normal(t)
    return _edge_support(t, edge, lambda: bcs.symmetry_edge(surface, edge, normal)), False


@CONSTRAINTS.register("diaphragm")
def _diaphragm(t: Table, surface) -> Parsed:
    """A named ``edge`` held in the plane of axis ``normal`` (a rigid diaphragm)."""
    edge, normal = _edge(t), _normal(t)
    return _edge_support(t, edge, lambda: bcs.diaphragm_edge(surface, edge, normal)), True


@CONSTRAINTS.register("fix")
def _fix(t: Table, surface) -> Parsed:
    """Named nodal ``kinds`` (x, d1, d2, d12) and ``components`` of the nodes."""
    nodes = nodes_of(t, surface)
    names = t.get("kinds", "a list", check=lambda v: len(v) > 0 and all(k in S.KIND_NAMES for k in v),
                  expected=f"a non-empty list of names from {S.KIND_NAMES}")  # fmt: skip
    kinds = tuple(S.KIND_NAMES.index(k) for k in names)
    return [bcs.NodalConstraint(nodes, kinds, _components(t))], True


def parse_constraints(top: Table, surface, path: Path) -> tuple[SceneConstraint, ...]:
    """``[[constraints]]``: each table by its ``type``, validated against the surface, with its
    motion; conflicting motions refused."""
    out = []
    for i, item in enumerate(top.get("constraints", "a list", [])):
        t = Table(path, f"constraints[{i}]", item)
        kind = t.get("type", "a string", check=lambda v: v in CONSTRAINTS.names, expected=f"one of {CONSTRAINTS.names}")
        constraints, movable = CONSTRAINTS[kind](t, surface)
        for constraint in constraints:
            try:
                constraint.validate(surface.grid, surface.node_shape, surface.kind_count)
            except bcs.BoundaryConditionError as exc:
                raise SceneError(f"{path}: table '{t.name}': {exc}") from exc
        motion_table = t.table("motion", None) if movable else None
        motion = parse_motion(motion_table, constraints[0]) if motion_table is not None else None
        t.done()
        out += [SceneConstraint(c, motion, t.name) for c in constraints]
    check_motion_conflicts(out, path)
    return tuple(out)


def parse_point_constraints(top: Table, surface, path: Path) -> tuple[ScenePoint, ...]:
    """``[[point_constraints]]``: material points ``at = [xi1, xi2]`` held (augmented Lagrangian) at
    ``target`` (default: where they start), or moved by a motion."""
    out = []
    grid = surface.grid
    for i, item in enumerate(top.get("point_constraints", "a list", [])):
        t = Table(path, f"point_constraints[{i}]", item)
        at = t.get("at", "2 numbers", expected="[xi1, xi2] parameters of the material point")
        try:
            grid.locate(np.array(at[0]), np.array(at[1]))
        except S.SurfaceError as exc:
            raise SceneError(f"{path}: key '{t.key('at')}': {exc}") from exc
        components = _components(t)
        start = surface.evaluate(np.array(at[0]), np.array(at[1])).x
        target = tuple(t.get("target", "3 numbers", list(start)))
        motion_table = t.table("motion", None)
        motion = None
        if motion_table is not None:
            shape = bcs.NodalConstraint(np.zeros((1, 2), dtype=np.int64), (0,), components)
            motion = parse_motion(motion_table, shape)
        t.done()
        out.append(ScenePoint(float(at[0]), float(at[1]), components, target, motion))
    return tuple(out)
