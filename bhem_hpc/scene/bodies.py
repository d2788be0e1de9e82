"""Scenes of several bodies (numpy + stdlib only): a ``[[bodies]]`` table per body, each with the
tables a scene of one body has for its shell, and the tables all bodies share at the top::

    [time]            # dt and steps (or duration): one clock for every body
    [solver]          # one Newton solve per time step for all bodies
    [output]

    [[bodies]]
    name = "steel"    # names the body's output folder and its messages
    type = "shell"    # the body type (default "shell"), one of BODY_TYPES
    [bodies.surface]  # and material, effects (gravity, damping, loads), constraints,
    ...               # point_constraints, probes, initial: as in a scene of one body

Each body type parses its own table and registers itself in :data:`BODY_TYPES` (pbrt-v4's
``Create``); a shell body is parsed as the scene of one body it would be alone (with the shared
tables), so every key means what it means there; an error names the body and the key. ``[[colliders]]`` at the top
are the scene's colliders: a body whose ``effects`` list ``contact`` meets them (and itself, with
``self_collision``) as a scene of one body does, and meets every other body whose effects list
contact (Coulomb coefficient between two bodies: the geometric mean of their ``effects.friction``).
Bodies in contact meet by one ``effects.contact.method``: by ``"impulse"`` they share one
push-out distance and impulse metric (``push_out`` and ``metric``); by ``"ipc"`` (IPC's
barrier on collision meshes embedded in them, in the Newton solve) one ``dhat`` and
``barrier_stiffness``. They must be apart at the start. ``[[interfaces]]`` at the top join shell
bodies into one shell along their edges, or sew panels together (:mod:`bhem_hpc.scene.interfaces`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from bhem_hpc.scene.interfaces import InterfaceRecord, parse_interfaces
from bhem_hpc.scene.records import Scene
from bhem_hpc.scene.table import Registry, SceneError, Table

#: The parsers of body tables by type: ``parser(path, tables, other_bodies_in_contact)`` gives the
#: body's scene from its tables (the shared ones included); ``other_bodies_in_contact``: the body is
#: one of several whose effects list contact. The shell body registers itself in
#: :mod:`bhem_hpc.scene.loader`, whose parser of a scene of one body it is.
BODY_TYPES = Registry("body type")
#: The body type of a ``[[bodies]]`` table without a ``type`` key.
DEFAULT_BODY_TYPE = "shell"
#: The tables a body lists (a scene of one body's tables for its shell; a solid's ``file`` and ``sem``).
BODY_KEYS = ("name", "type", "surface", "trim", "material", "effects", "constraints", "point_constraints", "probes",
             "initial", "file", "sem", "materials", "offset", "patches", "discretization", "tolerance",
             "penalty", "dofs")  # fmt: skip
#: The tables every body shares, at the top of the file.
SHARED_KEYS = ("time", "solver", "output")
#: The scene's colliders, at the top: every body with contact effects meets them.
COLLIDERS = "colliders"
#: Where shell bodies are joined or sewn into one shell, at the top.
INTERFACES = "interfaces"
#: Longest body name (it names an output folder).
MAX_BODY_NAME = 64


@runtime_checkable
class SeveralPatches(Protocol):
    """What a body type's parser returns for a body of several patches (a CAD model's parts,
    :mod:`~bhem_hpc.scene.cad_shell`): each patch a shell body, and the joints between them."""

    bodies: tuple[Scene, ...]

    def label(self, body: int) -> str:
        """What names patch ``body`` (the body ``<name>_<label>``)."""
        ...

    def interfaces(self, name: str, first: int) -> tuple[InterfaceRecord, ...]:
        """The joints, the patches being bodies ``first``, ``first + 1``, ... named ``<name>_<part>``."""
        ...

    def report(self, name: str) -> dict:
        """What a run's summary says of it."""
        ...


@dataclass(frozen=True)
class BodiesScene:
    """A scene of several bodies stepped in one Newton solve per time step.

    Attributes:
        path: the scene file.
        names: the bodies' names, in the file's order (the stacked order).
        bodies: each body's scene of one body (the shared tables in each).
        raw: the file's tables.
        interfaces: where shell bodies are joined or sewn into one shell
            (:mod:`~bhem_hpc.scene.interfaces`), and the joints found in CAD models.
        cad_models: each ``cad_shell`` body's report: its parts (bodies ``<name>_<part>``), the
            joints found, its free edges and how far its patches are from its parts
            (:mod:`~bhem_hpc.scene.cad_shell`).
    """

    path: Path
    names: tuple[str, ...]
    bodies: tuple[Scene, ...]
    raw: dict[str, Any]
    interfaces: tuple[InterfaceRecord, ...] = ()
    cad_models: tuple[dict, ...] = ()

    @property
    def first(self) -> Scene:
        """The first body's scene: it holds the shared settings (time, solver, output) as every body does."""
        return self.bodies[0]


def _body_name(t: Table, taken: list[str]) -> str:
    expected = f"a name no other body has (letters, digits, _; at most {MAX_BODY_NAME} characters)"
    return t.get("name", "a string", check=lambda v: v.isidentifier() and len(v) <= MAX_BODY_NAME and v not in taken,
                 expected=expected)  # fmt: skip


def _check_body(t: Table) -> bool:
    """What a body's table may not hold (shared tables, unknown keys); returns whether its effects
    list contact."""
    for key in t.data:
        if key in (*SHARED_KEYS, COLLIDERS, INTERFACES):
            raise SceneError(f"{t.path}: key '{t.key(key)}': [{key}] is shared by all bodies; give it once, at the top")
        if key not in BODY_KEYS:
            t.fail(key, f"absent (a body lists {', '.join(BODY_KEYS)})", t.data[key])
    return _in_contact(t)


def _body_type(t: Table) -> Callable[[Path, dict, bool], Scene]:
    names = BODY_TYPES.names
    kind = t.get("type", "a string", DEFAULT_BODY_TYPE, lambda v: v in names, f"one of {', '.join(names)}")
    return BODY_TYPES[kind]


def parse_bodies(path: Path, raw: dict[str, Any]) -> BodiesScene:
    """The scene of several bodies in ``raw`` (a file's tables): each body's table parsed by the
    parser its ``type`` registered in :data:`BODY_TYPES`.

    Raises:
        SceneError: naming the file, the body and the key.
    """
    top = Table(path, "", raw)
    items = top.get("bodies", "a list", check=lambda v: len(v) >= 1 and all(isinstance(b, dict) for b in v),
                    expected="a list of at least one body table ([[bodies]])")  # fmt: skip
    for key in raw:
        if key not in ("bodies", COLLIDERS, INTERFACES, *SHARED_KEYS):
            hint = "a body's own table (in each [[bodies]])" if key in BODY_KEYS else "unknown"
            raise SceneError(f"{path}: key '{key}' at the top of a scene of several bodies: {hint}; the top holds "
                             f"[[bodies]], [[{COLLIDERS}]], [[{INTERFACES}]] and the shared "
                             f"{', '.join(SHARED_KEYS)}")  # fmt: skip
    shared = {key: raw[key] for key in SHARED_KEYS if key in raw}
    time = shared.get("time", {})
    if isinstance(time, dict) and time.get("static", False) is True:
        raise SceneError(f"{path}: key 'time.static': a scene of several bodies is time-stepped (dt and steps)")
    colliders = {COLLIDERS: raw[COLLIDERS]} if COLLIDERS in raw else {}
    names: list[str] = []
    bodies: list[Scene] = []
    models: list[Any] = []  # the bodies that are several patches of a CAD model, with their names
    tables_of = [Table(path, f"bodies[{k}]", item) for k, item in enumerate(items)]
    several_in_contact = sum(_in_contact(t) for t in tables_of) >= 2
    for k, (item, t) in enumerate(zip(items, tables_of, strict=True)):
        name = _body_name(t, names)
        parse_body = _body_type(t)
        in_contact = _check_body(t)
        tables = {key: value for key, value in item.items() if key not in ("name", "type")} | shared
        tables |= colliders if in_contact else {}
        try:
            parsed = parse_body(path, tables, in_contact and several_in_contact)
        except SceneError as exc:
            where = str(exc).removeprefix(f"{path}: ")
            raise SceneError(f"{path}: body '{name}' (bodies[{k}]): {where}") from None
        if not isinstance(parsed, SeveralPatches):
            bodies.append(parsed)
            names.append(name)
            continue
        models.append((name, len(bodies), parsed))  # several patches: the parts of a model
        parts = [f"{name}_{parsed.label(k)}" for k in range(len(parsed.bodies))]
        if set(parts) & set(names) or any(t.get("name") in parts for t in items[k + 1:]):
            raise SceneError(f"{path}: body '{name}' (bodies[{k}]): its parts are bodies named {name}_0, ... and "
                             "another body has one of these names")  # fmt: skip
        names += parts
        bodies += parsed.bodies
    if colliders and all(body.contact is None for body in bodies):
        raise SceneError(f"{path}: key '{COLLIDERS}' is given but no body lists 'effects.contact'")
    interfaces = parse_interfaces(path, raw[INTERFACES], names, bodies) if INTERFACES in raw else ()
    interfaces += tuple(record for name, first, model in models for record in model.interfaces(name, first))
    reports = tuple(model.report(name) for name, _, model in models)
    scene = BodiesScene(path, tuple(names), tuple(bodies), raw, interfaces, reports)
    _check_follower_loads(scene)
    _check_joined_contact(scene)
    _check_contact_between(scene)
    return scene


def _check_follower_loads(scene: BodiesScene) -> None:
    """Several bodies are solved on their total potential, which a follower pressure does not have."""
    if len(scene.bodies) < 2:
        return
    for k, body in enumerate(scene.bodies):
        if isinstance(body, Scene) and body.effects.pressure is not None:  # a shell's (solids take none)
            raise SceneError(f"{scene.path}: body '{scene.names[k]}': key 'effects.pressure' = "
                             f"{body.effects.pressure!r}: a follower pressure has no potential, and a scene of "
                             f"{len(scene.bodies)} bodies (or patches) is solved on its total potential; use "
                             "effects.area_loads (a dead load) or one body")  # fmt: skip


def _in_contact(t: Table) -> bool:
    effects = t.data.get("effects", {})
    return isinstance(effects, dict) and "contact" in effects


def _check_joined_contact(scene: BodiesScene) -> None:
    """Patches joined into one shell meet colliders and other bodies but not each other, nor
    themselves: self-collision of a joined body is refused."""
    for record in scene.interfaces:
        for k in record.bodies:
            contact = scene.bodies[k].contact
            if contact is not None and contact.self_collision:
                raise SceneError(f"{scene.path}: body '{scene.names[k]}' (bodies[{k}]): key "
                                 f"'effects.self_collision': a body joined to another by {record.where} does "
                                 "not collide with itself (its patches are one shell; self-contact of a shell of "
                                 "several patches is not offered)")  # fmt: skip


def _check_contact_between(scene: BodiesScene) -> None:
    """Bodies in contact share one method and its settings, and start apart (by the impulse
    response, a body crossing another at the start would be pushed through it; IPC's barrier
    checks its collision meshes when it is made)."""
    path = scene.path
    contact = [k for k, body in enumerate(scene.bodies) if body.contact is not None]
    if len(contact) < 2:
        return
    first = contact[0]

    def where(k: int) -> str:
        return f"body '{scene.names[k]}' (bodies[{k}])"

    method = scene.bodies[first].contact.method
    ipc_shared = ("dhat", "barrier_stiffness", "eps_v", "velocity_tolerance")
    shared = ("push_out", "metric") if method == "impulse" else ipc_shared
    for k in contact[1:]:
        if scene.bodies[k].contact.method != method:
            raise SceneError(f"{path}: {where(k)}: key 'effects.contact.method' is "
                             f"{scene.bodies[k].contact.method!r} but {where(first)} has {method!r}: bodies in "
                             "contact meet by one method")  # fmt: skip
        for key in shared:
            mine, theirs = getattr(scene.bodies[k].contact, key), getattr(scene.bodies[first].contact, key)
            if mine != theirs:
                raise SceneError(f"{path}: {where(k)}: key 'effects.contact.{key}' is {mine!r} but {where(first)} "
                                 f"has {theirs!r}: bodies in contact share one {key}")  # fmt: skip
    joined = {frozenset(record.bodies) for record in scene.interfaces}
    if method == "ipc":
        return
    from bhem_hpc.contact.bodies import lattice_crossing  # the collision code loads for contact scenes only

    for a in contact:
        for b in contact:
            if a == b or frozenset((a, b)) in joined:
                continue
            per_side = scene.bodies[a].contact.samples_per_side
            point = lattice_crossing(_lattice(scene.bodies[a], per_side), _patch_nets(scene.bodies[b]))
            if point is not None:
                keys = " or ".join(f"'{key}'" for key in sorted({_placement(scene.bodies[k]) for k in (a, b)}))
                raise SceneError(f"{path}: {where(a)} and {where(b)} overlap at the start near "
                                 f"{np.array2string(point, precision=4)}: key {keys} of one of them must place them "
                                 "apart (bodies in contact start apart)")  # fmt: skip


def _lattice(body: Any, per_side: int) -> tuple[np.ndarray, np.ndarray]:
    """A body's sample lattice as segments (a shell's surface, a solid's parts)."""
    from bhem_hpc.contact.bodies import lattice_segments, part_segments

    return lattice_segments(body.surface, per_side) if isinstance(body, Scene) else part_segments(body.parts, per_side)


def _patch_nets(body: Any) -> np.ndarray:
    """A body's patches as contact sees them: a shell's Bezier nets, a solid's homogeneous ones."""
    if isinstance(body, Scene):
        return body.surface.bezier_nets()
    from bhem_hpc.contact.solid_surface import SolidContactSurface

    return SolidContactSurface(body.parts, 1).nets(np.concatenate([part.control.reshape(-1, 3) for part in body.parts]))


def _placement(body: Any) -> str:
    """The key that places a body: a shell's surface, a solid's offset."""
    return "surface" if isinstance(body, Scene) else "offset"
