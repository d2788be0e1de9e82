"""The ``[trim]`` table: the part of a scene's surface that is simulated (a trimmed surface).

``loops`` lists closed polygons in the surface's parameters ``(xi1, xi2)`` (for a rectangle: its
in-plane coordinates from its corner), each repeating its first point at its end; the region inside
an odd number of them is kept (an outer loop and its holes). The model integrates over that region
only (cut-cell quadrature, :mod:`bhem_hpc.model.trimmed`); the output shows the kept patches' part.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from bhem_hpc.geometry.bspline import DEFAULT_QUADRATURE
from bhem_hpc.geometry.trim import MAX_TRIM_POINTS, Trim, TrimError, check_trimmed
from bhem_hpc.scene.table import SceneError, Table, is_number

LOOPS = "a list of loops, each a list of at least 4 [xi1, xi2] pairs whose last repeats the first"


def _is_loops(value) -> bool:
    return bool(value) and all(
        isinstance(loop, list) and 4 <= len(loop) <= MAX_TRIM_POINTS
        and all(isinstance(p, list) and len(p) == 2 and all(is_number(c) for c in p) for p in loop)
        for loop in value
    )  # fmt: skip


def parse_trim(t: Table | None, surface, quadrature: int | str | None, effects, points: Sequence,
               contact) -> Trim | None:  # fmt: skip
    """The scene's :class:`~bhem_hpc.geometry.trim.Trim` (None without a ``[trim]`` table), checked
    against the scene's surface, quadrature, loads (``effects``), point constraints and contact."""
    if t is None:
        return None
    path: Path = t.path
    loops = t.get("loops", "a list", check=_is_loops, expected=LOOPS)
    t.done()
    if contact is not None and contact.method != "ipc":
        raise SceneError(f"{path}: table 'trim' with effects.contact by impulses: a trimmed surface meets others by "
                         "IPC (contact = { method = \"ipc\" }), whose collision mesh keeps only what the trim "
                         "keeps; impulses would sample the part trimmed away")  # fmt: skip
    if quadrature == "reduced":
        raise SceneError(f"{path}: table 'trim' with solver.quadrature = 'reduced': a trimmed surface integrates "
                         "with Gauss points (2, 3, 4 or 5)")  # fmt: skip
    rule = quadrature if quadrature is not None else DEFAULT_QUADRATURE[surface.discretization]
    try:
        trim = Trim.of(surface.grid, loops, rule, where="trim.loops")
        edge_loads = [(f"effects.{family}[{k}]", load[0]) for family in ("line_loads", "edge_moments")
                      for k, load in enumerate(getattr(effects, family))]  # fmt: skip
        named = [(f"effects.point_loads[{k}]", a, b) for k, (a, b, _) in enumerate(effects.point_loads)]
        named += [(f"point_constraints[{k}]", p.xi1, p.xi2) for k, p in enumerate(points)]
        check_trimmed(trim, surface.grid, edge_loads, named)
    except TrimError as exc:
        raise SceneError(f"{path}: {exc}") from None
    return trim
