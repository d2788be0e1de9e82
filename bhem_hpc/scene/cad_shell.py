"""A shell read from a CAD surface model (``type = "cad_shell"``; numpy + stdlib and the CAD
readers): every NURBS part of the file becomes a patch of the shell, a body of its own named
``<name>_<part>``, and patches whose edges meet (whole, or in part) within ``tolerance`` are joined
(:mod:`bhem_hpc.scene.interfaces`'s joints, found instead of listed)::

    [[bodies]]
    name = "hood"
    type = "cad_shell"
    file = "models/hood.3dm"       # IGES (entity 128) or Rhino .3dm, relative to the scene
    patches = [6, 6]               # uniform knot spans of every part's shell surface
    discretization = "bspline3"    # hermite (default), bspline2, bspline3, nurbs
    tolerance = 1e-5               # [m]: edges that meet within this are joined (default 1e-6)
    penalty = 1e3                  # the joints' penalty factor
    dofs = "auto"                  # whole joints that conform share their control points (as a
                                   # joint's dofs: "auto", "shared" or "coupled")
    material = { ... }             # and effects: as a shell body's, for every patch
    [[bodies.constraints]]
    part = 0                       # the part (its index in the file) the constraint holds
    type = "clamp"
    edge = "xi1_min"

Each part is interpolated on the chosen discretization over its own parameter domain
(:func:`~bhem_hpc.geometry.nurbs.shell_surface`): exact for B-spline parts of that degree on
uniform knots, otherwise an approximation whose largest distance from the part the scene reports.
``"nurbs"`` keeps every part exactly, rational and of its own degree (2 or 3), on its knots refined
to at least ``patches`` spans (:func:`~bhem_hpc.geometry.rational_bspline.on_uniform_knots`, which
says why a part cannot be so); a part only C0 at some knots is cut there into pieces.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bhem_hpc.bodies.shared_dofs import SharedDofs
from bhem_hpc.geometry.interfaces import EDGES, FoundJoint, find_joints
from bhem_hpc.scene.bodies import BODY_TYPES, DEFAULT_BODY_TYPE
from bhem_hpc.scene.interfaces import (
    DEFAULT_TOLERANCE,
    DOF_CHOICES,
    InterfaceRecord,
    parse_penalty,
    shared_edge_data,
)
from bhem_hpc.scene.records import Scene
from bhem_hpc.scene.surfaces import model_parts
from bhem_hpc.scene.table import SceneError, Table, regular_file

if TYPE_CHECKING:
    from bhem_hpc.geometry.nurbs import NurbsSurface

#: The tables and keys of a ``cad_shell`` body.
CAD_SHELL_KEYS = ("file", "patches", "discretization", "tolerance", "penalty", "dofs", "material", "effects",
                  "constraints")  # fmt: skip


@dataclass(frozen=True)
class CadShell:
    """A CAD model's parts as patch bodies and the joints found between them.

    Attributes:
        bodies: each part's scene of one body (part order).
        joints: the joints found (part indices); free_edges: ``(part, edge)`` joined to nothing.
        trimmed_edges: ``(part, edge)`` that a part's trim cuts (not joined as edges; a trimmed
            part's trim curves are joined where they run along another part,
            :mod:`bhem_hpc.geometry.trim_joints`).
        penalty: the joints' penalty factor; fit_error: the largest distance [m] of a patch from its part.
        file: the model file.
        shared: each joint's shared control points (:func:`conforming_edge_dofs`, between the parts'
            indices), or None where the joint does not share them.
    """

    bodies: tuple[Scene, ...]
    joints: tuple[FoundJoint, ...]
    free_edges: tuple[tuple[int, str], ...]
    penalty: float
    fit_error: float
    file: Path
    trimmed_edges: tuple[tuple[int, str], ...] = ()
    shared: tuple[SharedDofs | None, ...] = ()
    labels: tuple[str, ...] = ()

    def label(self, body: int) -> str:
        """What names patch ``body``: its part's index, and for a part cut at its kinks
        (``"nurbs"``) the piece's ``<part>_<i>_<j>``."""
        return self.labels[body] if self.labels else str(body)

    def interfaces(self, name: str, first: int) -> tuple[InterfaceRecord, ...]:
        """The joints as the scene's interfaces, the parts being bodies ``first``, ``first + 1``, ...
        named ``<name>_<part>``."""
        shared = self.shared or (None,) * len(self.joints)
        return tuple(InterfaceRecord("joint", f"{name} joint {k}", (first + j.first, first + j.second),
                                     (f"{name}_{self.label(j.first)}", f"{name}_{self.label(j.second)}"),
                                     (j.first_edge, j.second_edge),
                                     self.penalty, j.quadrature, None, True,
                                     None if dofs is None else dofs.moved(first))
                     for k, (j, dofs) in enumerate(zip(self.joints, shared, strict=True)))  # fmt: skip

    def report(self, name: str) -> dict:
        """What a run's summary says of the model: its parts, joints and free edges."""
        label = self.label
        parts = len({label(k).split("_")[0] for k in range(len(self.bodies))})
        return {"body": name, "file": str(self.file), "parts": parts, "patches": len(self.bodies),
                "patch_bodies": [f"{name}_{label(k)}" for k in range(len(self.bodies))],
                "fit_error_m": self.fit_error,
                "joints": [[f"{name}_{label(j.first)}", j.first_edge, f"{name}_{label(j.second)}", j.second_edge,
                            j.quadrature.gap, "partial" if j.partial else "whole"] for j in self.joints],
                "free_edges": [f"{name}_{label(part)} {edge}" for part, edge in self.free_edges],
                "trimmed_edges": [f"{name}_{label(part)} {edge}" for part, edge in self.trimmed_edges],
                "trimmed_parts_joined_to_nothing_along_their_trims": [
                    f"{name}_{label(k)}" for k, body in enumerate(self.bodies) if body.trim is not None
                    and not any(j.first == k and j.first_edge == "trim curve" or j.second == k
                                and j.second_edge == "trim curve" for j in self.joints)]}  # fmt: skip


def _part_constraints(t: Table, parts: int) -> list[list[dict]]:
    """Each part's constraint tables (their ``part`` key taken out)."""
    items = t.get("constraints", "a list", [], lambda v: all(isinstance(c, dict) for c in v), "a list of tables")
    out: list[list[dict]] = [[] for _ in range(parts)]
    for k, item in enumerate(items):
        part = item.get("part")
        if not isinstance(part, int) or isinstance(part, bool) or not 0 <= part < parts:
            raise SceneError(f"{t.path}: key '{t.key(f'constraints[{k}].part')}' must be the part (0..{parts - 1}) "
                             f"the constraint holds, got {part!r}")  # fmt: skip
        out[part].append({key: value for key, value in item.items() if key != "part"})
    return out


@BODY_TYPES.register("cad_shell")
def parse_cad_shell(path: Path, tables: dict, other_bodies_in_contact: bool = False) -> CadShell:
    """The patches of a ``cad_shell`` body table (with the shared tables), each parsed by the
    shell body's parser, and the joints between them.

    Raises:
        SceneError: naming the file, the key and, for a part, the part.
    """
    from bhem_hpc.geometry.nurbs import shell_fit_error  # the CAD code loads for CAD models only

    t = Table(path, "", {k: v for k, v in tables.items() if k in CAD_SHELL_KEYS})
    for key in tables:
        if key not in (*CAD_SHELL_KEYS, "time", "solver", "output", "colliders"):
            t.fail(key, f"absent (a cad_shell body lists {', '.join(CAD_SHELL_KEYS)})", tables[key])
    file = t.get("file", "a string")
    target = regular_file(t, "file", file, path)
    try:
        parts = model_parts(target)
    except ValueError as exc:
        raise SceneError(f"{path}: key 'file': {exc}") from None
    patches = t.get("patches", "2 integers", check=lambda v: min(v) >= 1, expected="2 integers >= 1 (per part)")
    discretization = t.get("discretization", "a string", "hermite")
    tolerance = t.get("tolerance", "a number", DEFAULT_TOLERANCE, lambda v: 0 < v and math.isfinite(v),
                      "a length > 0 [m]")  # fmt: skip
    penalty = parse_penalty(t)
    dofs = t.get("dofs", "a string", "auto", lambda v: v in DOF_CHOICES, ", ".join(f'"{v}"' for v in DOF_CHOICES))
    constraints = _part_constraints(t, len(parts))
    parse_shell: Callable[..., Scene] = BODY_TYPES[DEFAULT_BODY_TYPE]
    shared = {k: v for k, v in tables.items() if k in ("time", "solver", "output", "colliders", "material", "effects")}
    bodies, labels, surfaces = [], [], []
    for k, part in enumerate(parts):
        for patch in _patches_of(t, k, part, patches, discretization, constraints[k]):
            surface = {"kind": "cad_part", "file": file, "part": k, "patches": patch.patches,
                       "discretization": discretization} | ({} if patch.piece is None else {"piece": patch.piece})
            trim = {} if part.loops is None else {"trim": {"loops": _shell_loops(part, patch, discretization)}}
            try:
                bodies.append(parse_shell(path, shared | {"surface": surface, "constraints": patch.constraints} | trim,
                                          other_bodies_in_contact))  # fmt: skip
            except SceneError as exc:
                raise SceneError(f"{path}: part {k} ({part.surface.name}): "
                                 f"{str(exc).removeprefix(f'{path}: ')}") from None  # fmt: skip
            labels.append(patch.label)
            surfaces.append(patch.surface)
    joints, free = find_joints([body.surface for body in bodies], tolerance)
    # an edge a trim cuts is no edge of the shell: its joints go, and it is listed as trimmed
    trimmed = {(k, edge) for k, body in enumerate(bodies) if body.trim is not None
               for edge in EDGES if not body.trim.keeps_edge(body.surface.grid, edge)}  # fmt: skip
    joints = [j for j in joints if (j.first, j.first_edge) not in trimmed and (j.second, j.second_edge) not in trimmed]
    if trimmed:  # free: the edges left in no joint (a dropped joint's partner among them)
        joined = {edge for j in joints for edge in ((j.first, j.first_edge), (j.second, j.second_edge))}
        free = sorted({(k, e) for k in range(len(bodies)) for e in EDGES} - joined - trimmed,
                      key=lambda item: (item[0], EDGES.index(item[1])))  # fmt: skip
    if any(part.loops is not None for part in parts):  # trimmed parts meet others along their trim curves
        from bhem_hpc.geometry.trim_joints import edges_joined, find_trim_joints

        shells = [body.surface for body in bodies]
        curves = find_trim_joints(surfaces, shells,
                                  [body.trim.loops if body.trim is not None else None for body in bodies],
                                  tolerance, joints)  # fmt: skip
        along = set().union(*(edges_joined(j, shells) for j in curves)) if curves else set()
        joints, free = joints + curves, [edge for edge in free if edge not in along]
    fit = max(shell_fit_error(part, body.surface) for part, body in zip(surfaces, bodies, strict=True))
    shared = tuple(_joint_dofs(t, dofs, joint, bodies, tolerance) for joint in joints)
    return CadShell(tuple(bodies), tuple(joints), tuple(free), penalty, fit, target, tuple(sorted(trimmed)), shared,
                    tuple(labels))


def _shell_loops(part, patch: _Patch, discretization: str) -> list[list[list[float]]]:
    """A trimmed part's loops in its patch's parameters: the part's own, but for exact patches on
    the part's non-uniform knots, whose uniform spans map onto the knot intervals (each loop vertex
    mapped; the loops are dense polylines)."""
    if discretization != "nurbs":
        return [loop.tolist() for loop in part.loops]
    from bhem_hpc.geometry.rational_bspline import on_uniform_knots

    shell = on_uniform_knots(patch.surface, tuple(patch.patches))
    return [np.column_stack(shell.surface_parameters(loop[:, 0], loop[:, 1])).tolist() for loop in part.loops]


@dataclass(frozen=True)
class _Patch:
    """One patch of a part: its label, its piece ``[i, j]`` (None: the whole part), its NURBS
    surface, its knot spans and its constraint tables."""

    label: str
    piece: list[int] | None
    surface: NurbsSurface
    patches: list[int]
    constraints: list[dict]


def _patches_of(t: Table, k: int, part, patches: list[int], discretization: str,
                constraints: list[dict]) -> list[_Patch]:  # fmt: skip
    """The patches of part ``k``: the part itself, or with ``"nurbs"`` its pieces between the knots
    where it is only C0 (:func:`~bhem_hpc.geometry.rational_bspline.split_at_kinks`), the part's
    spans shared among them and its constraints on the pieces along their edges and at their corners."""
    from bhem_hpc.geometry.rational_bspline import split_at_kinks

    pieces = split_at_kinks(part.surface) if discretization == "nurbs" else [[part.surface]]
    counts = (len(pieces), len(pieces[0]))
    if counts == (1, 1):
        return [_Patch(str(k), None, part.surface, patches, constraints)]
    if part.loops is not None:
        t.fail("discretization", f'"hermite", "bspline2" or "bspline3": part {k} ({part.surface.name}) is trimmed '
               f"and only C0 along some knots ({counts[0]} x {counts[1]} pieces); its rational patches would cut its "
               "trim", discretization)  # fmt: skip
    spans = [math.ceil(n / c) for n, c in zip(patches, counts, strict=True)]
    return [_Patch(f"{k}_{i}_{j}", [i, j], surface, spans, _piece_constraints(t, k, constraints, (i, j), counts))
            for i, row in enumerate(pieces) for j, surface in enumerate(row)]  # fmt: skip


def _piece_constraints(t: Table, k: int, constraints: list[dict], place: tuple[int, int],
                       counts: tuple[int, int]) -> list[dict]:  # fmt: skip
    """A part's constraints on its piece at ``place`` of ``counts``: an ``edge`` on the pieces along
    it, ``corners`` on the pieces at them; ``nodes`` name no piece's and are refused."""
    ends = {"xi1_min": place[0] == 0, "xi1_max": place[0] == counts[0] - 1,
            "xi2_min": place[1] == 0, "xi2_max": place[1] == counts[1] - 1}  # fmt: skip
    out = []
    for n, item in enumerate(constraints):
        if "nodes" in item:
            t.fail(f"constraints[{n}].nodes", f"'edge' or 'corners': part {k} is cut at its C0 knots into "
                   f"{counts[0]} x {counts[1]} pieces, whose nodes the part's indices do not name", item["nodes"])
        if "edge" in item and ends.get(item["edge"], True):
            out.append(item)
        elif "corners" in item:
            mine = [c for c in item["corners"] if isinstance(c, str) and "_" in c
                    and ends.get(f"xi1_{c.split('_')[0]}", True) and ends.get(f"xi2_{c.split('_')[1]}", True)]
            out += [item | {"corners": mine}] if mine else []
        elif "edge" not in item:
            out.append(item)
    return out


def _joint_dofs(t: Table, dofs: str, joint: FoundJoint, bodies: list[Scene], tolerance: float) -> SharedDofs | None:
    """The control points a found joint's parts share (``dofs``: "auto" where it conforms, "shared"
    refused where not, "coupled" never); partial and trim-curve joints share none."""
    whole = not joint.partial and "trim curve" not in (joint.first_edge, joint.second_edge)
    if dofs == "coupled" or (dofs == "auto" and not whole):
        return None
    where = f"parts {joint.first} ({joint.first_edge}) and {joint.second} ({joint.second_edge})"
    if not whole:
        t.fail("dofs", f'"auto" or "coupled": {where} are joined along a part of an edge or a trim curve', dofs)
    return shared_edge_data(t, dofs, (bodies[joint.first].surface, bodies[joint.second].surface),
                            (joint.first, joint.second), (joint.first_edge, joint.second_edge), tolerance,
                            f"{where} do not conform")  # fmt: skip
