"""The ``solid`` body of a scene of several bodies: an SEM solid read from a NURBS model (numpy +
stdlib; the CAD file is read here, so that a bad model is refused before anything is built)::

    [[bodies]]
    name = "castle"
    type = "solid"
    file = "castle.igs"         # IGES or Rhino .3dm, relative to the scene
    offset = [0.0, 0.0, 0.1]    # the model moved by this vector [m] (default: where the file has it)
    [bodies.material]           # density [kg/m^3], young [Pa], poisson, model ("neo-hookean", "stvk")
                                # or, several materials: [[bodies.materials]] with parts = ["hub*", ...]
                                # (part names, * and ? as in file names) and the same keys
    [bodies.sem]                # degree (1, 2), lines_per_side, quadrature_order, sparsity or alpha,
                                # origins ("flow", "single"), error_stiffness [Pa]
    [bodies.effects]            # gravity = [gx, gy, gz] [m/s^2];
                                # wind = { acceleration = [ax, ay, az], period = T }: a body force
                                # a sin(2 pi t / T) per unit mass;
                                # contact = { method = "ipc", dhat, barrier_stiffness, collision_cells,
                                # eps_v }: IPC's barrier on its boundary against the colliders and
                                # other bodies; friction, static_friction: its Coulomb coefficients;
                                # or contact = { method = "impulse", push_out, samples_per_side,
                                # metric }: impulses between steps; friction: its Coulomb coefficient
    [[bodies.constraints]]      # type = "hold": the control points inside box = [[x0, y0, z0], [x1, y1, z1]]
                                # (components = [0, 1, 2] by default) keep their place
    [bodies.initial]            # velocity = [vx, vy, vz] [m/s]

It shares ``[time]``, ``[solver]`` (``hessian`` "projected", "exact" or "adaptive"; the linear
strategy and PETSc options) and ``[output]`` with every body (:mod:`.shared`). A solid is
time-stepped. It meets the scene's colliders and the other bodies in contact through IPC's barrier on
its boundary (each part tessellated on ``collision_cells`` cells per side), or by impulses between
steps on its exact rational patches (``samples_per_side`` samples per knot span and side; parts of
degree 3 at most); its parts never meet each other (a modeller's parts overlap).
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bhem_hpc.geometry.nurbs import NurbsSurface
from bhem_hpc.geometry.surface import SurfaceError
from bhem_hpc.scene.bodies import BODY_TYPES
from bhem_hpc.scene.records import SceneContact
from bhem_hpc.scene.shared import parse_clock, parse_linear_strategy, parse_output, parse_petsc_options
from bhem_hpc.scene.table import SceneError, Table, regular_file, vector
from bhem_hpc.solids.elasticity import MODELS
from bhem_hpc.solids.sem import SolidMaterial, SolidOptions

#: The Hessian kinds of a solid's solve (``"adaptive"``: exact, projected where LDL^T shows
#: negative pivots).
SOLID_HESSIAN_CHOICES = ("projected", "exact", "adaptive")
#: The solver keys a solid reads (``quadrature`` belongs to the shells of the scene).
SOLID_SOLVER_KEYS = ("hessian", "linear", "factorization", "options", "quadrature", "acceleration_tolerance")
#: The largest ray-cast lines per side (the quadrature's cost grows with its square).
MAX_LINES_PER_SIDE = 256
#: Collision-mesh cells per side of each part by default (contact by "ipc").
SOLID_COLLISION_CELLS = 8


@dataclass(frozen=True)
class HeldRegion:
    """Control points inside the box ``lo, hi`` [m] keep the ``components`` of their place."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    components: tuple[int, ...] = (0, 1, 2)
    key: str = ""

    def points(self, control: np.ndarray) -> np.ndarray:
        """Indices of the control points ``(n, 3)`` inside the box."""
        inside = np.all((control >= np.asarray(self.lo)) & (control <= np.asarray(self.hi)), axis=1)
        return np.flatnonzero(inside)


@dataclass(frozen=True)
class Wind:
    """A body force per unit mass ``acceleration sin(2 pi t / period)`` [m/s^2]."""

    acceleration: tuple[float, float, float]
    period: float

    def at(self, t: float) -> np.ndarray:
        return np.asarray(self.acceleration) * math.sin(2.0 * math.pi * t / self.period)


@dataclass(frozen=True)
class SolidScene:
    """A solid body of a scene, with the settings every body shares (:mod:`.shared`): the fields a
    run reads of any body have the names a shell's :class:`~bhem_hpc.scene.records.Scene` gives them."""

    path: Path
    file: Path
    parts: tuple[NurbsSurface, ...]
    materials: tuple[SolidMaterial, ...]  # one per part
    options: SolidOptions
    gravity: tuple[float, float, float] | None
    wind: Wind | None
    held: tuple[HeldRegion, ...]
    dt: float
    steps: int
    hessian: str
    linear: str = "auto"
    factorization: str = "reuse"
    petsc_options: dict[str, Any] = field(default_factory=dict)
    output_every: int = 1
    output_density: int = 4
    initial_velocity: tuple[float, float, float] | None = None
    raw: dict[str, Any] = field(default_factory=dict)
    static: bool = False
    acceleration_tolerance: float | None = None
    contact: SceneContact | None = None
    probes: tuple = ()
    path_plan: None = None
    constraints: tuple = ()

    @property
    def nodal_shape(self) -> tuple[int, ...]:
        """``(control points, 3)``: what a checkpoint keeps of a frame."""
        return sum(part.control[..., 0].size for part in self.parts), 3


def _materials(top: Table, parts: tuple[NurbsSurface, ...]) -> tuple[SolidMaterial, ...]:
    """``material`` for every part, or ``[[materials]]`` each naming its ``parts`` (patterns)."""
    if "materials" not in top.data:
        return (_material(top.table("material")),) * len(parts)
    if "material" in top.data:
        raise SceneError(f"{top.path}: give one of 'material' and 'materials', not both")
    items = top.get("materials", "a list", check=lambda v: len(v) >= 1 and all(isinstance(m, dict) for m in v),
                    expected="a list of material tables ([[materials]]) with their parts")  # fmt: skip
    names = [part.name for part in parts]
    chosen: list[SolidMaterial | None] = [None] * len(parts)
    for k, item in enumerate(items):
        t = Table(top.path, f"materials[{k}]", item)
        patterns = t.get("parts", "a list", check=lambda v: len(v) >= 1 and all(isinstance(p, str) for p in v),
                         expected="a list of part names (* and ? match any characters)")  # fmt: skip
        material = _material(t, skip=("parts",))
        for pattern in patterns:
            matched = [i for i, name in enumerate(names) if fnmatch.fnmatchcase(name, pattern)]
            if not matched:
                t.fail("parts", f"names of the model's parts ({', '.join(names)})", pattern)
            for i in matched:
                if chosen[i] is not None:
                    t.fail("parts", f"parts no other material names (part {names[i]!r} has one)", pattern)
                chosen[i] = material
    missing = [name for name, material in zip(names, chosen, strict=True) if material is None]
    if missing:
        raise SceneError(f"{top.path}: key 'materials': parts without a material: {', '.join(missing)}")
    return tuple(chosen)


def _material(t: Table, skip: tuple[str, ...] = ()) -> SolidMaterial:
    t.used.update(skip)
    values = {k: t.get(k, "a number") for k in ("density", "young", "poisson")}
    model = t.get("model", "a string", "neo-hookean", lambda v: v in MODELS, f"one of {sorted(MODELS)}")
    t.done()
    material = SolidMaterial(values["density"], values["young"], values["poisson"], model)
    try:
        return material.checked(f"{t.path}: key '{t.name}'")
    except SurfaceError as exc:
        raise SceneError(str(exc)) from None


def _options(t: Table | None) -> SolidOptions:
    if t is None:
        return SolidOptions(sparsity=0.3)
    degree = t.get("degree", "an integer", 2, lambda v: v in (1, 2), "1 or 2 (shape-matching polynomial degree)")
    lines = t.get("lines_per_side", "an integer", 24, lambda v: 2 <= v <= MAX_LINES_PER_SIDE,
                  f"an integer in 2..{MAX_LINES_PER_SIDE}")  # fmt: skip
    order = t.get("quadrature_order", "an integer", 2, lambda v: 1 <= v <= 8, "an integer in 1..8")
    if "sparsity" in t.data and "alpha" in t.data:
        raise SceneError(f"{t.path}: table '{t.name}' takes one of 'sparsity' and 'alpha', not both")
    alpha = t.get("alpha", "a number", None, lambda v: v > 0, "a number > 0 (blending cutoff [m])")
    sparsity = t.get("sparsity", "a number", None if alpha is not None else 0.3, lambda v: 0 < v <= 1,
                     "a number in (0, 1] (share of parts blended at a point)")  # fmt: skip
    origins = t.get("origins", "a string", "flow", lambda v: v in ("flow", "single"), "'flow' or 'single'")
    gamma = t.get("error_stiffness", "a number", None, lambda v: v > 0, "a number > 0 [Pa]")
    t.done()
    return SolidOptions(degree=degree, lines_per_side=lines, quadrature_order=order, sparsity=sparsity, alpha=alpha,
                        origins=origins, error_stiffness=gamma)  # fmt: skip


def _contact(t: Table, colliders_raw: list, other_bodies: bool) -> SceneContact | None:
    """``effects.contact``: IPC's barrier in the solve, or impulses between steps."""
    from bhem_hpc.scene.loader import parse_impulse_contact, parse_ipc_contact

    if "contact" not in t.data:
        if colliders_raw:
            raise SceneError(f"{t.path}: key 'colliders' is given but '{t.key('contact')}' is not listed")
        return None
    if "self_collision" in t.data:
        t.fail("self_collision", "absent: a solid's parts never meet each other", t.data["self_collision"])
    settings = t.data["contact"] if t.data["contact"] is not True else {}
    contact = Table(t.path, t.key("contact"), settings)
    method = contact.get("method", "a string", "ipc", lambda v: v in ("ipc", "impulse"), "'ipc' or 'impulse'")
    t.used.add("contact")
    if not colliders_raw and not other_bodies:
        raise SceneError(f"{t.path}: key '{t.key('contact')}': a solid's contact needs 'colliders' (planes, spheres, "
                         "meshes) or another body in contact")  # fmt: skip
    if method == "ipc":
        return parse_ipc_contact(contact, t, colliders_raw, t.path, other_bodies, SOLID_COLLISION_CELLS)
    for key in ("friction", "static_friction"):
        t.used.add(key)
    return parse_impulse_contact(contact, t.data, colliders_raw, t.path, other_bodies, t.name)


def _effects(t: Table | None) -> tuple[tuple[float, float, float] | None, Wind | None]:
    if t is None:
        return None, None
    gravity = t.get("gravity", "3 numbers", None)
    wind = None
    wind_table = t.table("wind", None)
    if wind_table is not None:
        acceleration = wind_table.get("acceleration", "3 numbers")
        period = wind_table.get("period", "a number", check=lambda v: v > 0, expected="a number > 0 [s]")
        wind_table.done()
        wind = Wind(tuple(float(c) for c in acceleration), float(period))
    t.done()
    return (tuple(float(c) for c in gravity) if gravity is not None else None), wind


def _held(top: Table, parts: tuple[NurbsSurface, ...]) -> tuple[HeldRegion, ...]:
    items = top.get("constraints", "a list", [], lambda v: all(isinstance(c, dict) for c in v),
                    "a list of tables ([[constraints]])")  # fmt: skip
    control = np.concatenate([p.control.reshape(-1, 3) for p in parts])
    regions = []
    for k, item in enumerate(items):
        t = Table(top.path, f"constraints[{k}]", item)
        t.get("type", "a string", check=lambda v: v == "hold", expected="'hold' (control points inside a box)")
        box = t.get("box", "a list", check=lambda v: len(v) == 2 and all(vector(3)(c) for c in v),
                    expected="two corners [[x0, y0, z0], [x1, y1, z1]] [m]")  # fmt: skip
        components = t.get("components", "a list", [0, 1, 2],
                           lambda v: len(v) >= 1 and len(set(v)) == len(v) and all(c in (0, 1, 2) for c in v),
                           "distinct components among 0, 1, 2")  # fmt: skip
        t.done()
        lo, hi = np.minimum(*map(np.asarray, box)), np.maximum(*map(np.asarray, box))
        region = HeldRegion(tuple(lo), tuple(hi), tuple(components), t.name)
        if not len(region.points(control)):
            t.fail("box", f"a box holding at least one control point (the model spans {control.min(axis=0)} to "
                          f"{control.max(axis=0)})", box)  # fmt: skip
        regions.append(region)
    return tuple(regions)


def _solver(top: Table) -> tuple[str, str, str | None, dict, float | None]:
    from bhem_hpc.scene.loader import MAX_ACCELERATION, MIN_ACCELERATION

    solver = top.table("solver", None)
    if solver is None:
        return "projected", "auto", None, {}, None
    for key in solver.data:
        if key not in SOLID_SOLVER_KEYS:
            raise SceneError(f"{top.path}: key 'solver.{key}': a scene with a solid reads solver keys "
                             f"{', '.join(SOLID_SOLVER_KEYS)}")  # fmt: skip
    hessian = solver.get("hessian", "a string", "projected", lambda v: v in SOLID_HESSIAN_CHOICES,
                         " or ".join(map(repr, SOLID_HESSIAN_CHOICES)) + " (a scene with a solid)")  # fmt: skip
    linear, factorization = parse_linear_strategy(solver)
    tolerance = solver.get("acceleration_tolerance", "a number", None,
                           lambda v: MIN_ACCELERATION <= v <= MAX_ACCELERATION,
                           f"a number in [{MIN_ACCELERATION:g}, {MAX_ACCELERATION:g}] (m/s^2)")  # fmt: skip
    return hessian, linear, factorization, parse_petsc_options(solver), tolerance


def _initial_velocity(top: Table) -> tuple[float, float, float] | None:
    initial = top.table("initial", None)
    if initial is None:
        return None
    velocity = initial.get("velocity", "3 numbers", expected="3 finite numbers [m/s]")
    initial.done()
    return tuple(float(c) for c in velocity)


def _read_model(top: Table) -> tuple[Path, tuple[NurbsSurface, ...]]:
    from bhem_hpc.io.cad import read_parts  # the CAD readers load with solids only

    name = top.get("file", "a string", expected="a NURBS model file (IGES or .3dm), relative to the scene")
    file = regular_file(top, "file", name, top.path)
    try:
        parts = tuple(read_parts(file))
    except SurfaceError as exc:
        raise SceneError(f"{top.path}: key 'file' = {name!r}: {exc}") from None
    offset = top.get("offset", "3 numbers", None, expected="3 finite numbers [m] (the model moved by them)")
    if offset is not None:
        parts = tuple(part.with_control(part.control + np.asarray(offset, dtype=float)) for part in parts)
    return file, parts


@BODY_TYPES.register("solid")
def parse_solid(path: Path, raw: dict, other_bodies_in_contact: bool = False) -> SolidScene:
    """A solid body's scene from its tables ``raw`` (the shared ones included)."""
    top = Table(path, "", raw)
    file, parts = _read_model(top)
    clock = parse_clock(top)
    if clock.static:
        raise SceneError(f"{path}: key 'time.static': a solid is time-stepped (dt and steps)")
    materials = _materials(top, parts)
    options = _options(top.table("sem", None))
    effects = top.table("effects", None)
    colliders_raw = top.get("colliders", "a list", [])
    contact = _contact(effects if effects is not None else Table(path, "effects", {}), colliders_raw,
                       other_bodies_in_contact)  # fmt: skip
    gravity, wind = _effects(effects)
    held = _held(top, parts)
    hessian, linear, factorization, petsc_options, tolerance = _solver(top)
    every, density = parse_output(top)
    initial_velocity = _initial_velocity(top)
    top.done()
    if contact is not None:  # a barrier's Newton, as a shell's in contact by "ipc"
        from bhem_hpc.scene.loader import ipc_newton_settings

        factorization, tolerance, petsc_options = ipc_newton_settings(factorization, tolerance, petsc_options)
    return SolidScene(path=path, file=file, parts=parts, materials=materials, options=options, gravity=gravity,
                      wind=wind, held=held, dt=clock.dt, steps=clock.steps, hessian=hessian, linear=linear,
                      factorization=factorization or "reuse", petsc_options=dict(petsc_options), output_every=every,
                      output_density=density, initial_velocity=initial_velocity, raw=raw, contact=contact,
                      acceleration_tolerance=tolerance)  # fmt: skip
