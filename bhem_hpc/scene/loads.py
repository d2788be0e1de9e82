"""The load tables of ``[effects]``: each load family (``point_loads``, ``line_loads``,
``edge_moments``, ``area_loads``) parses its own tables and registers itself in :data:`LOADS` under
its key (pbrt-v4's ``Create``); every load is scaled by the load factor.

A parser takes one load's table and the surface's parameter grid and returns the load's scene
record (the tuple :class:`~bhem_hpc.scene.records.Effects` keeps under the family's key).
"""

from __future__ import annotations

from pathlib import Path

from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.expression import ExpressionError, finite_on_patches, parse_expression
from bhem_hpc.scene.table import Registry, Table

#: Load families by their ``[effects]`` key: ``parser(table, grid) -> record``.
LOADS = Registry("load")


def _edge(load: Table) -> str:
    return load.get("edge", "a string", check=lambda v: v in bcs.EDGES, expected=f"one of {bcs.EDGES}")


@LOADS.register("point_loads")
def _point_load(load: Table, grid: S.ParameterGrid) -> tuple[float, float, tuple[float, float, float]]:
    """``at = [xi1, xi2]`` on the surface, ``force`` [N]: ``(xi1, xi2, force)``."""
    (lo1, hi1), (lo2, hi2) = grid.xi1_range, grid.xi2_range
    at = load.get("at", "2 numbers", check=lambda v: lo1 <= v[0] <= hi1 and lo2 <= v[1] <= hi2,
                  expected=f"2 numbers (xi1, xi2) in {[lo1, hi1]} x {[lo2, hi2]}")  # fmt: skip
    return at[0], at[1], tuple(load.get("force", "3 numbers"))


@LOADS.register("line_loads")
def _line_load(load: Table, grid: S.ParameterGrid) -> tuple[str, tuple[float, float, float]]:
    """A named ``edge`` and its ``traction`` per rest length [N/m]: ``(edge, traction)``."""
    return _edge(load), tuple(load.get("traction", "3 numbers"))


@LOADS.register("area_loads")
def _area_load(load: Table, grid: S.ParameterGrid) -> tuple[tuple[float, float, float], str | None]:
    """``force`` per rest area [N/m^2], dead, times the optional ``profile`` expression of the
    parameters (finite wherever a quadrature evaluates it): ``(force, profile)``."""
    force = tuple(load.get("force", "3 numbers", expected="3 numbers (force per rest area [N/m^2])"))
    profile = load.get("profile", "a string", None)
    if profile is not None:
        try:
            parse_expression(profile)
        except ExpressionError as exc:
            load.fail("profile", f"an expression of xi1 and xi2 ({exc})", profile)
        if not finite_on_patches(profile, (grid.xi1_range, grid.xi2_range), (grid.n1, grid.n2)):
            load.fail("profile", "an expression finite on the whole surface", profile)
    return force, profile


@LOADS.register("edge_moments")
def _edge_moment(load: Table, grid: S.ParameterGrid) -> tuple[str, float]:
    """A named ``edge`` and its ``moment`` per rest length [N]: ``(edge, moment)``."""
    return _edge(load), float(load.get("moment", "a number", expected="a number (moment per length [N])"))


def parse_loads(effects: Table, path: Path, grid: S.ParameterGrid) -> dict[str, tuple]:
    """Every registered family's records, by its key (empty tuples for families not listed)."""
    records: dict[str, tuple] = {}
    for family in LOADS.names:
        parsed = []
        for i, item in enumerate(effects.get(family, "a list", [])):
            load = Table(path, f"effects.{family}[{i}]", item)
            parsed.append(LOADS[family](load, grid))
            load.done()
        records[family] = tuple(parsed)
    return records
