"""The ``[[interfaces]]`` of a scene of several bodies (numpy + stdlib only): shell bodies (patches,
panels) joined into one shell along their edges. Each interface type parses its own table and
registers itself in :data:`INTERFACE_TYPES`::

    [[interfaces]]
    type = "joint"                  # the default: edges that meet at rest stay together, and the
    bodies = ["roof", "wall"]       # angle between the patches across them stays what it is at
    edges = ["xi1_max", "xi1_min"]  # rest (smooth, or a fold)
    penalty = 1e3                   # alpha of the penalty rule (bhem_hpc.bodies.coupling)
    tolerance = 1e-6                # [m] how far apart the edges may be at rest
    partial = false                 # join only the part the edges share (a T-junction)
    dofs = "auto"                   # patches whose edges conform (one discretization, as many spans,
                                    # the same edge data at rest) share that data (B-spline control
                                    # points; Hermite positions and slopes along the edge), the
                                    # penalty keeping only the angle ("auto": where they conform;
                                    # "shared": refused where not; "coupled": never)

    [[interfaces]]
    type = "seam"                   # edges apart at rest, sewn together: the stitches shorten
    bodies = ["front", "back"]      # from their rest length to zero over sewing_time
    edges = ["xi1_max", "xi1_min"]
    sewing_time = 0.3               # [s]
    reverse = false                 # the edges run in opposite directions
    keep_angle = false              # also keep the panels' rest angle across the seam

The edges are checked against the bodies' rest surfaces here, before anything is built: a joint's
edges must meet within ``tolerance`` (a partial one's along a part of positive length), a seam's
sides must have about one length.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from bhem_hpc.bodies.shared_dofs import SharedDofs, conforming_edge_dofs
from bhem_hpc.geometry.interfaces import EDGES, EdgeQuadrature, InterfaceError, Patch, pair_edges, pair_seam
from bhem_hpc.scene.records import Scene
from bhem_hpc.scene.table import Registry, SceneError, Table

#: The parsers of interface types: ``parser(table, names, bodies) -> InterfaceRecord``.
INTERFACE_TYPES = Registry("interface type")
#: The interface type of a table without ``type``.
DEFAULT_INTERFACE_TYPE = "joint"
#: The penalty factors a scene may give (below, the coupling is soft; above, the Newton systems
#: lose their digits to it: a folded steel plate failed to converge at 1e7).
PENALTY_RANGE = (1.0, 1.0e6)
#: A joint's ``dofs``: share the edge's control points where the patches conform, always (refused
#: where they do not), or never (the penalty couples them).
DOF_CHOICES = ("auto", "shared", "coupled")
#: The default largest rest distance between a joint's edges [m].
DEFAULT_TOLERANCE = 1e-6


@dataclass(frozen=True)
class InterfaceRecord:
    """An interface of a scene, checked against the rest surfaces.

    Attributes:
        kind: its type (``"joint"``, ``"seam"``); where: ``interfaces[k]``, for messages.
        bodies: the two bodies' places; names: their names; edges: their edges.
        penalty: the penalty factor alpha.
        quadrature: the interface's points on both sides.
        sewing_time: a seam's [s] (None: a joint).
        keep_angle: whether the angle across it is kept (always for a joint).
        shared: the control points a joint's patches share (``dofs = "shared"``), or None.
    """

    kind: str
    where: str
    bodies: tuple[int, int]
    names: tuple[str, str]
    edges: tuple[str, str]
    penalty: float
    quadrature: EdgeQuadrature
    sewing_time: float | None
    keep_angle: bool
    shared: SharedDofs | None = None

    def summary(self) -> dict:
        """What a run's summary.json says of it."""
        return {"type": self.kind, "bodies": list(self.names), "edges": list(self.edges), "penalty": self.penalty,
                "points": len(self.quadrature.weights), "length_m": float(self.quadrature.weights.sum()),
                "rest_gap_m": self.quadrature.gap,
                "sewing_time_s": self.sewing_time, "keeps_angle": self.keep_angle,
                "shared_dofs": 0 if self.shared is None else 3 * len(self.shared)}  # fmt: skip


def _pair(t: Table, names: Sequence[str], bodies: Sequence) -> tuple[tuple[int, int], tuple[str, str]]:
    """The two shell bodies an interface names and their edges."""
    pair = t.get("bodies", "a list", check=lambda v: len(v) == 2 and all(n in names for n in v),
                 expected=f"the names of two bodies of the scene ({', '.join(names)})")  # fmt: skip
    for name in pair:
        if not isinstance(bodies[names.index(name)], Scene):
            t.fail("bodies", "two shell bodies (a solid has no edges to join)", pair)
    edges = t.get("edges", "a list", check=lambda v: len(v) == 2 and all(e in EDGES for e in v),
                  expected=f"two edges, one of each body, each one of {', '.join(EDGES)}")  # fmt: skip
    return (names.index(pair[0]), names.index(pair[1])), (edges[0], edges[1])


def parse_penalty(t: Table) -> float:
    """An interface's ``penalty`` factor (default 1e3), within :data:`PENALTY_RANGE`."""
    low, high = PENALTY_RANGE
    return float(t.get("penalty", "a number", 1.0e3, lambda v: low <= v <= high, f"a number in [{low:g}, {high:g}]"))


def shared_edge_data(t: Table, dofs: str, surfaces: tuple[Patch, Patch], places: tuple[int, int],
                     edges: tuple[str, str], tolerance: float, unmatched: str) -> SharedDofs | None:  # fmt: skip
    """What a whole joint's patches share by its ``dofs`` (:data:`DOF_CHOICES`): the edge data where
    they conform ("auto", "shared"), None where they do not ("auto") or for "coupled".

    Raises:
        SceneError: "shared" where they do not conform, saying ``unmatched`` and why.
    """
    if dofs == "coupled":
        return None
    try:
        return conforming_edge_dofs(surfaces, places, edges, tolerance)
    except InterfaceError as exc:
        if dofs == "shared":
            raise SceneError(f"{t.path}: key '{t.key('dofs')}' = \"shared\": {unmatched}: {exc}") from None
        return None


def _paired(t: Table, names: Sequence[str], bodies: Sequence, places: tuple[int, int],
            pair: Callable[[Patch, Patch], EdgeQuadrature]) -> tuple[tuple[str, str], EdgeQuadrature]:  # fmt: skip
    """The two bodies' names and the quadrature ``pair`` finds between their rest surfaces; its
    refusal as the scene's, naming the interface's key, the bodies and their edges."""
    named = (names[places[0]], names[places[1]])
    try:
        return named, pair(bodies[places[0]].surface, bodies[places[1]].surface)
    except InterfaceError as exc:
        where = str(exc).replace("the first patch", f"body '{named[0]}'").replace("the second", f"body '{named[1]}'")
        where = where.replace("the first panel", f"body '{named[0]}'")
        raise SceneError(f"{t.path}: key '{t.key('edges')}': {where}") from None


@INTERFACE_TYPES.register("joint")
def _joint(t: Table, names: Sequence[str], bodies: Sequence) -> InterfaceRecord:
    places, edges = _pair(t, names, bodies)
    penalty = parse_penalty(t)
    tolerance = t.get("tolerance", "a number", DEFAULT_TOLERANCE, lambda v: 0 < v and math.isfinite(v),
                      "a length > 0 [m]")  # fmt: skip
    partial = t.get("partial", "a boolean", False)
    dofs = t.get("dofs", "a string", "auto", lambda v: v in DOF_CHOICES, ", ".join(f'"{v}"' for v in DOF_CHOICES))
    if dofs == "shared" and partial:
        t.fail("dofs", '"auto" or "coupled" for a partial joint (only whole edges that conform share control '
               'points)', dofs)  # fmt: skip
    t.done()

    def joint(first: Patch, second: Patch) -> EdgeQuadrature:
        return pair_edges(first, edges[0], second, edges[1], tolerance, partial=partial)

    pair, quadrature = _paired(t, names, bodies, places, joint)
    shared = None if partial else shared_edge_data(
        t, dofs, (bodies[places[0]].surface, bodies[places[1]].surface), places, edges, tolerance,
        f"bodies '{pair[0]}' and '{pair[1]}' do not conform along {edges[0]} and {edges[1]}")  # fmt: skip
    return InterfaceRecord("joint", t.name, places, pair, edges, penalty, quadrature, None, True, shared)


@INTERFACE_TYPES.register("seam")
def _seam(t: Table, names: Sequence[str], bodies: Sequence) -> InterfaceRecord:
    places, edges = _pair(t, names, bodies)
    penalty = parse_penalty(t)
    sewing_time = t.get("sewing_time", "a number", check=lambda v: v > 0, expected="a time > 0 [s]")
    reverse = t.get("reverse", "a boolean", False)
    keep_angle = t.get("keep_angle", "a boolean", False)
    t.done()
    pair, quadrature = _paired(t, names, bodies, places, lambda a, b: pair_seam(a, edges[0], b, edges[1], reverse))
    return InterfaceRecord("seam", t.name, places, pair, edges, penalty, quadrature, float(sewing_time), keep_angle)


def parse_interfaces(path: Path, items: object, names: Sequence[str], bodies: Sequence) -> tuple[InterfaceRecord, ...]:
    """The ``[[interfaces]]`` list of a scene of several bodies (``names``, ``bodies``: the parsed
    bodies in order), each parsed by its type.

    Raises:
        SceneError: naming the file, the interface, the key and, for edges that do not fit, the
            bodies, their edges and the gap or lengths.
    """
    if not isinstance(items, list) or not all(isinstance(item, dict) for item in items):
        raise SceneError(f"{path}: key 'interfaces' must be a list of interface tables ([[interfaces]]), got "
                         f"{items!r}")  # fmt: skip
    records = []
    types = INTERFACE_TYPES.names
    for k, item in enumerate(items):
        t = Table(path, f"interfaces[{k}]", item)
        kind = t.get("type", "a string", DEFAULT_INTERFACE_TYPE, lambda v: v in types, f"one of {', '.join(types)}")
        records.append(INTERFACE_TYPES[kind](t, names, bodies))
    return tuple(records)
