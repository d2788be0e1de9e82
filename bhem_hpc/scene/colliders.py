"""The ``[[colliders]]`` list: each collider type parses its own table and registers itself in
:data:`COLLIDERS`; the collision code is imported only when a scene lists colliders."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bhem_hpc.scene.table import Registry, SceneError, Table, regular_file

#: Parsers of the collider types: ``(table, scene path, velocity) -> colliders``.
COLLIDERS = Registry("collider type")
#: Needles of one grid, checked before any is made.
MAX_NEEDLES = 100_000


def parse_colliders(items: list, friction: float, path: Path, static_friction: float | None = None,
                    method: str = "impulse") -> tuple:  # fmt: skip
    """The ``[[colliders]]`` list as collider entries, each with its friction coefficient (by default
    the body's ``friction``) and, for contact by ``"ipc"``, its static one (by default the body's
    ``static_friction``, else its own kinetic one) and a sphere's ``spin``."""
    from bhem_hpc.collision.colliders import ColliderError
    from bhem_hpc.contact.detection import ColliderEntry

    types = COLLIDERS.names
    entries = []
    coefficient = "a number >= 0 (Coulomb coefficient)"
    for i, item in enumerate(items):
        t = Table(path, f"colliders[{i}]", item)
        kind = t.get("type", "a string", check=lambda v: v in types, expected=f"one of {types}")
        mu = t.get("friction", "a number", friction, lambda v: v >= 0, coefficient)
        for key, what in (("static_friction", "static friction coefficients"), ("spin", "spinning colliders"),
                          ("spin_from", "spinning colliders")):  # fmt: skip
            if method != "ipc" and key in t.data:
                raise SceneError(f"{path}: key '{t.key(key)}' = {t.data[key]!r}: {what} are for contact method "
                                 "'ipc' only")  # fmt: skip
        mu_s = t.get("static_friction", "a number", static_friction, lambda v: v >= 0, coefficient)
        try:
            velocity = t.get("velocity", "3 numbers", [0.0, 0.0, 0.0])
            made = COLLIDERS[kind](t, path, velocity)
            # a table that makes several colliders (needles: capsules) names each by its place in it
            keys = [t.name] if len(made) == 1 else [f"{t.name} (capsule {k})" for k in range(len(made))]
            entries += [ColliderEntry(c, mu, mu_s, key) for c, key in zip(made, keys, strict=True)]
        except ColliderError as exc:
            raise SceneError(f"{path}: key '{t.name}': {exc}") from exc
        t.done()
    return tuple(entries)


def _radius(t: Table) -> float:
    return float(t.get("radius", "a number", check=lambda v: v > 0, expected="a number > 0 [m]"))


@COLLIDERS.register("plane")
def _plane(t: Table, path: Path, velocity: list[float]) -> list[Any]:
    from bhem_hpc.collision import colliders as C

    return [C.Plane(t.get("point", "3 numbers"), t.get("normal", "3 numbers"), velocity)]


@COLLIDERS.register("sphere")
def _sphere(t: Table, path: Path, velocity: list[float]) -> list[Any]:
    from bhem_hpc.collision import colliders as C

    radius = _radius(t)
    spin = t.get("spin", "3 numbers", [0.0, 0.0, 0.0])  # angular velocity [rad/s] about the centre
    spin_from = t.get("spin_from", "a number", 0.0, lambda v: v >= 0, "a time >= 0 [s] (when the spin starts)")
    return [C.Sphere(t.get("center", "3 numbers"), radius, velocity, spin, spin_from)]


@COLLIDERS.register("cylinder")
def _cylinder(t: Table, path: Path, velocity: list[float]) -> list[Any]:
    from bhem_hpc.collision import colliders as C

    radius = _radius(t)
    return [C.Cylinder(t.get("point", "3 numbers"), t.get("axis", "3 numbers"), radius, velocity)]


@COLLIDERS.register("capsule")
def _capsule(t: Table, path: Path, velocity: list[float]) -> list[Any]:
    from bhem_hpc.collision import colliders as C

    radius = _radius(t)
    return [C.Capsule(t.get("a", "3 numbers"), t.get("b", "3 numbers"), radius, velocity)]


@COLLIDERS.register("needles")
def _needles(t: Table, path: Path, velocity: list[float]) -> list[Any]:
    """A grid of vertical needles (capsules) standing on the plane ``z = origin[2]``."""
    from bhem_hpc.collision import colliders as C

    origin = np.asarray(t.get("origin", "3 numbers"), dtype=float)
    spacing = t.get("spacing", "2 numbers")
    count = t.get(
        "count", "2 integers", check=lambda v: min(v) >= 1 and v[0] * v[1] <= MAX_NEEDLES,
        expected=f"2 integers >= 1, at most {MAX_NEEDLES} needles in all",
    )  # fmt: skip
    length = t.get("length", "a number", check=lambda v: v > 0, expected="a number > 0 [m]")
    radius = _radius(t)
    out = []
    for i in range(count[0]):
        for j in range(count[1]):
            foot = origin + np.array([i * spacing[0], j * spacing[1], 0.0])
            out.append(C.Capsule(foot, foot + np.array([0.0, 0.0, length]), radius, velocity))
    return out


def _file_collider(t: Table, path: Path, velocity: list[float], kind: str) -> list[Any]:
    """A triangle mesh (``mesh``) or Bezier patch model read from ``file``, scaled and translated."""
    from bhem_hpc.collision import colliders as C

    file = t.get("file", "a string")
    target = regular_file(t, "file", file, path)
    scale = t.get("scale", "a number", 1.0, lambda v: v > 0, "a number > 0")
    translate = np.asarray(t.get("translate", "3 numbers", [0.0, 0.0, 0.0]), dtype=float)
    if kind == "mesh":
        mesh = C.TriangleMesh.read(target, velocity)
        return [C.TriangleMesh(mesh.vertices * scale + translate, mesh.triangles, mesh.velocity, str(target))]
    model = C.PatchModel.load(target)
    return [C.PatchModel(model.nets * scale + translate, np.asarray(velocity, dtype=float))]


@COLLIDERS.register("mesh")
def _mesh(t: Table, path: Path, velocity: list[float]) -> list[Any]:
    return _file_collider(t, path, velocity, "mesh")


@COLLIDERS.register("patches")
def _patches(t: Table, path: Path, velocity: list[float]) -> list[Any]:
    return _file_collider(t, path, velocity, "patches")
