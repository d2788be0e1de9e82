"""Scene files (TOML): :func:`load_scene` parses and checks a whole file before anything is built
(numpy + stdlib only). The tables are parsed by the modules of what they make: surfaces
(:mod:`.surfaces`), motions (:mod:`.motions`), colliders (:mod:`.colliders`); this module reads the
rest (material, time, solver, output, effects and loads, constraints, probes, path, contact).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import astuple
from pathlib import Path
from typing import Any

import numpy as np

from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.hessian import HESSIAN_KINDS
from bhem_hpc.model.material import BENDING_MODELS, MEMBRANE_MODELS, Material, MaterialError
from bhem_hpc.model.path import PATH_METHODS, ArcLength, PathPlan, PathSettingError, Probe, check_levels
from bhem_hpc.scene.bodies import BODY_TYPES, BodiesScene, parse_bodies
from bhem_hpc.scene.colliders import parse_colliders
from bhem_hpc.scene.constraints import parse_constraints, parse_point_constraints
from bhem_hpc.scene.loads import LOADS, parse_loads
from bhem_hpc.scene.records import Effects, Scene, SceneContact
from bhem_hpc.scene.shared import parse_clock, parse_linear_strategy, parse_output, parse_petsc_options
from bhem_hpc.scene.surfaces import parse_surface
from bhem_hpc.scene.table import SceneError, Table, is_number
from bhem_hpc.scene.trim import parse_trim

# Effects a scene may list; contact effects import the collision code only when listed.
EFFECTS = ("gravity", "pressure", "damping", *LOADS.names, "contact", "self_collision", "friction", "static_friction")


CONTACT_EFFECTS = ("contact", "self_collision", "friction", "static_friction")


#: Longest probe name (it names columns of path.csv and probes.csv and the curves of path.png).
MAX_NAME_LENGTH = 64


MIN_ACCELERATION, MAX_ACCELERATION = 1e-12, 1e6  # m/s^2: solver.acceleration_tolerance
#: solver.acceleration_tolerance by default with contact by "ipc" [m/s^2] (0.1 % of g)
IPC_ACCELERATION_TOLERANCE = 1e-2
#: effects.contact.velocity_tolerance with contact by "ipc" [m/s] (or "auto": IPC's choice, a fraction of the
#: bodies' rest bounding-box diagonal per second, :data:`bhem_hpc.contact.ipc_setup.AUTO_VELOCITY_TOLERANCE`)
VELOCITY_TOLERANCE_RANGE = (1e-9, 1e3)
#: the most Newton iterations of an attempt with contact by "ipc" (solver.options.snes_max_it)
IPC_NEWTON_ITERATIONS = 100


def ipc_newton_settings(factorization: str | None, tolerance: float | None,
                        options: dict) -> tuple[str, float, dict]:  # fmt: skip
    """The Newton of a body in contact by "ipc" where the scene leaves it open: fresh factorizations,
    the acceleration test and :data:`IPC_NEWTON_ITERATIONS`. Kept factorizations' chord steps stall
    in contact on the acceleration test alone (a block hitting the jelly castle: 0.66 per iteration
    for 100 iterations). With IPC's step test at the "auto" tolerance they are a scene's choice, not
    a default: from one checkpoint each they made six of the contact page's windows faster (the ball
    0.70 to 0.52 s/step, needles 0.81 to 0.60, mesh obstacle 0.92 to 0.63, mandrel 3.02 to 2.22,
    cloth on sphere 1.43 to 1.33, cloth pile 8.5 to 7.9) and two runs slower (the linked bands 0.18
    to 0.25; the cotton cloth landing on the spinning sphere, up to 91 iterations a step against 66).
    A relative residual of 1e-9 lies below the barrier's round-off (the hairpin's arms meeting: dt
    halvings either way), and collision-bounded steps need more iterations where contacts close (33
    there)."""
    return (factorization or "fresh", tolerance or IPC_ACCELERATION_TOLERANCE,
            {"snes_max_it": IPC_NEWTON_ITERATIONS, **options})  # fmt: skip


def _read_toml(path: Path) -> dict:
    """The TOML document of a scene file (a regular UTF-8 text file)."""
    if path.exists() and not path.is_file():
        raise SceneError(f"{path}: not a regular file")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise SceneError(f"{path}: cannot read scene file ({exc.strerror})") from exc
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: not a text (UTF-8) file: byte {exc.start} cannot be decoded") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML ({exc})") from exc
    except RecursionError:
        raise SceneError(f"{path}: nested too deeply to be a scene") from None


def _override(raw: dict, overrides: dict[str, dict[str, Any]], path: Path) -> dict:
    """``raw`` with the keys of ``overrides`` replaced (a value None removes the key)."""
    for table, values in overrides.items():
        current = raw.setdefault(table, {})
        if not isinstance(current, dict):
            raise SceneError(f"{path}: '{table}' must be a table to take {sorted(values)}")
        current.update(values)
        for key in [k for k, v in values.items() if v is None]:
            del current[key]
    return raw


def load_scene(path: str | Path, overrides: dict[str, dict[str, Any]] | None = None) -> Scene:
    """Read and validate a scene file. Raises :class:`SceneError` on any problem.

    Args:
        overrides: ``{table: {key: value}}`` replacing keys of the file's tables before validation,
            e.g. ``{"surface": {"patches": [200, 200]}, "solver": {"linear": "iterative"}}``; a
            value None removes the key.
    """
    path = Path(path)
    raw = _override(_read_toml(path), overrides or {}, path)
    if "bodies" in raw:
        raise SceneError(f"{path}: lists [[bodies]] (a scene of several bodies); this command takes a scene of one "
                         "body ([surface], [material], ...); 'bhem-hpc run' runs both")  # fmt: skip
    return _scene(path, raw)


def load_any_scene(path: str | Path) -> Scene | BodiesScene:
    """Read and check a scene of one body (:func:`load_scene`) or of several (``[[bodies]]``,
    :func:`~bhem_hpc.scene.bodies.parse_bodies`). Raises :class:`SceneError` on any problem."""
    path = Path(path)
    raw = _read_toml(path)
    return parse_bodies(path, raw) if "bodies" in raw else _scene(path, raw)


@BODY_TYPES.register("shell")
def _scene(path: Path, raw: dict, other_bodies_in_contact: bool = False) -> Scene:
    """The scene of one body from its file's tables ``raw``; ``other_bodies_in_contact``: the body is
    one of several whose effects list contact (it meets them even without colliders)."""
    top = Table(path, "", raw)
    surface = parse_surface(top.table("surface"), path)
    material = _material(top.table("material"))
    effects = _effects(top.table("effects", None), path, surface.grid)
    static, dt, steps, load_steps = astuple(parse_clock(top))
    solver = top.table("solver", None)
    # the Hessian Newton iterates with: exact for statics (its inertia tells stability), adaptive
    # for time steps (exact where it is positive definite, otherwise every Newton step goes downhill)
    default_hessian = "exact" if static else "adaptive"
    hessian, quadrature, options, linear, factorization = default_hessian, None, {}, "auto", None
    acceleration_tolerance, velocity_tolerance = None, None
    if solver is not None:
        linear, factorization = parse_linear_strategy(solver)
        # the energy trust region minimizes a time step's incremental potential
        kinds = tuple(k for k in HESSIAN_KINDS if not (static and k == "trust_region"))
        hessian = solver.get("hessian", "a string", default_hessian, lambda v: v in kinds,
                             " or ".join(map(repr, kinds)) + (" (a static scene)" if static else ""))  # fmt: skip
        if hessian == "trust_region" and effects.pressure is not None:
            raise SceneError(f"{path}: key 'solver.hessian' = 'trust_region' minimizes a potential, which the "
                             f"follower load effects.pressure = {effects.pressure!r} does not have; use 'adaptive'")
        quadrature = solver.get(
            "quadrature", "an integer or a string", None, lambda v: v in (2, 3, 4, 5, "reduced"),
            "2, 3, 4, 5 (Gauss points per direction) or 'reduced' (quadratic B-splines)",
        )  # fmt: skip
        if quadrature == "reduced" and surface.discretization != "bspline2":
            solver.fail("quadrature", f"2, 3, 4 or 5: 'reduced' needs surface.discretization = 'bspline2', "
                        f"not {surface.discretization!r}", quadrature)  # fmt: skip
        acceleration_tolerance = solver.get(
            "acceleration_tolerance", "a number", None,
            lambda v: not static and MIN_ACCELERATION <= v <= MAX_ACCELERATION,
            "absent: a static scene has no accelerations" if static
            else f"a number in [{MIN_ACCELERATION:g}, {MAX_ACCELERATION:g}] (m/s^2)",
        )  # fmt: skip
        low, high = VELOCITY_TOLERANCE_RANGE
        velocity_tolerance = solver.get(
            "velocity_tolerance", "a number or a string", None,
            lambda v: not static and (v == "auto" or (not isinstance(v, str) and low <= v <= high)),
            "absent: a static scene has no velocities" if static else f'a speed in [{low:g}, {high:g}] [m/s] or "auto"',
        )  # fmt: skip
        options = parse_petsc_options(solver)
        solver.done()
    every, density = parse_output(top)
    constraints = parse_constraints(top, surface, path)
    points = parse_point_constraints(top, surface, path)
    contact = _contact(top, path, static, other_bodies_in_contact)
    if contact is not None and contact.method == "impulse" and surface.discretization.startswith("nurbs"):
        raise SceneError(f"{path}: key 'effects.contact.method' = 'impulse': the impulse response's collision "
                         "detection needs polynomial patches and this shell's are rational (surface "
                         "discretization 'nurbs'): use method = 'ipc'")  # fmt: skip
    if contact is not None and contact.method == "ipc":
        factorization, acceleration_tolerance, options = ipc_newton_settings(factorization, acceleration_tolerance,
                                                                             options)  # fmt: skip
    if contact is not None and any(isinstance(sc.constraint, bcs.NodalTie) for sc in constraints):
        raise SceneError(f"{path}: contact effects and symmetry planes on a B-spline surface cannot be combined "
                         "(contact rows would push the tied control points)")  # fmt: skip
    trim = parse_trim(top.table("trim", None), surface, quadrature, effects, points, contact)
    probes = _probes(top, surface)
    plan = _path_plan(top, static, load_steps, probes, path)
    initial_velocity = _initial_velocity(top, static)
    top.done()
    return Scene(
        path=path,
        surface=surface,
        material=material,
        constraints=constraints,
        effects=effects,
        static=static,
        dt=dt,
        steps=steps,
        load_steps=load_steps,
        hessian=hessian,
        quadrature=quadrature,
        trim=trim,
        linear=linear,
        factorization=factorization or "reuse",
        acceleration_tolerance=acceleration_tolerance,
        velocity_tolerance=velocity_tolerance,
        petsc_options=dict(options),
        point_constraints=points,
        output_every=every,
        output_density=density,
        raw=raw,
        contact=contact,
        path_plan=plan,
        probes=probes,
        initial_velocity=initial_velocity,
    )


def _initial_velocity(top: Table, static: bool) -> tuple[float, float, float] | None:
    """``[initial] velocity = [vx, vy, vz]``: the whole shell's velocity at the start [m/s]."""
    initial = top.table("initial", None)
    if initial is None:
        return None
    if static:
        initial.fail("velocity", "absent: a static scene has no velocities", initial.data.get("velocity"))
    velocity = initial.get("velocity", "3 numbers", check=lambda v: len(v) == 3 and all(math.isfinite(c) for c in v),
                           expected="3 finite numbers [m/s]")  # fmt: skip
    initial.done()
    return tuple(float(c) for c in velocity)


def _material(t: Table) -> Material:
    values = {k: t.get(k, "a number") for k in ("young", "poisson", "thickness")}
    values["density"] = t.get("density", "a number", 0.0)
    values["membrane"] = t.get("membrane", "a string", "svk", lambda v: v in MEMBRANE_MODELS,
                               f"one of {MEMBRANE_MODELS}")  # fmt: skip
    values["bending"] = t.get("bending", "a string", "svk", lambda v: v in BENDING_MODELS, f"one of {BENDING_MODELS}")
    values["shear_ratio"] = t.get("shear_ratio", "a number", None)
    t.done()
    try:
        return Material(**values)
    except MaterialError as exc:
        raise SceneError(f"{t.path}: {exc}") from exc


def _effects(t: Table | None, path: Path, grid: S.ParameterGrid) -> Effects:
    if t is None:
        return Effects()
    for key in t.data:
        if key not in EFFECTS:
            raise SceneError(f"{path}: unknown effect 'effects.{key}' (known: {EFFECTS})")
    for key in CONTACT_EFFECTS:
        t.used.add(key)  # read by _contact
    gravity = t.get("gravity", "3 numbers", None)
    pressure = t.get("pressure", "a number", None)
    mass_damping = stiffness_damping = 0.0
    damping = t.table("damping", None)
    if damping is not None:
        if not damping.data:
            raise SceneError(
                f"{path}: effect 'effects.damping' lists no coefficient (expected 'mass' and/or 'stiffness')"
            )
        mass_damping = damping.get("mass", "a number", 0.0, lambda v: v >= 0, "a number >= 0 [1/s]")
        stiffness_damping = damping.get("stiffness", "a number", 0.0, lambda v: v >= 0, "a number >= 0 [s]")
        damping.done()
    loads = parse_loads(t, path, grid)
    t.done()
    return Effects(
        gravity=tuple(gravity) if gravity is not None else None,
        pressure=pressure,
        mass_damping=mass_damping,
        stiffness_damping=stiffness_damping,
        **loads,
    )


def _probes(top: Table, surface) -> tuple[Probe, ...]:
    """``[[probes]]``: named material points ``at = [xi1, xi2]`` inside the parameter domain."""
    probes = []
    grid = surface.grid
    for i, item in enumerate(top.get("probes", "a list", [])):
        t = Table(top.path, f"probes[{i}]", item)
        name = t.get("name", "a string", check=lambda v: v.isidentifier() and len(v) <= MAX_NAME_LENGTH,
                     expected=f"a name (letters, digits, _; at most {MAX_NAME_LENGTH} characters)")  # fmt: skip
        inside = f"2 numbers (xi1, xi2) in {list(grid.xi1_range)} x {list(grid.xi2_range)}"
        at = t.get("at", "2 numbers", check=lambda v: grid.xi1_range[0] <= v[0] <= grid.xi1_range[1]
                   and grid.xi2_range[0] <= v[1] <= grid.xi2_range[1], expected=inside)  # fmt: skip
        if name in [p.name for p in probes]:
            t.fail("name", "a name no other probe has", name)
        probes.append(Probe(name, float(at[0]), float(at[1])))
        t.done()
    return tuple(probes)


def _path_plan(top: Table, static: bool, load_steps: int, probes: tuple[Probe, ...], path: Path) -> PathPlan | None:
    """``[path]`` of a static scene (default: load control to 1 in ``time.load_steps`` levels)."""
    t = top.table("path", None)
    if not static:
        if t is not None:
            raise SceneError(f"{path}: table 'path' needs a static scene ('time.static = true')")
        return None
    if t is None:
        return PathPlan("load", tuple(np.arange(1, load_steps + 1) / load_steps))
    method = t.get("method", "a string", check=lambda v: v in PATH_METHODS, expected=f"one of {PATH_METHODS}")
    max_cuts = t.get("max_cuts", "an integer", 8, lambda v: 0 <= v <= 50, "an integer in 0..50")
    options = parse_petsc_options(t)
    try:
        if method == "load":
            plan = PathPlan("load", _levels(t, "levels", "target"), max_cuts=max_cuts, options=options)
        elif method == "displacement":
            names = [p.name for p in probes]
            probe = t.get("probe", "a string", check=lambda v: v in names, expected=f"the name of a probe {names}")
            component = t.get("component", "a string", check=lambda v: v in ("x", "y", "z"), expected="'x', 'y' or 'z'")
            values = _levels(t, "values", "target", default_target=None)
            plan = PathPlan("displacement", probe=probe, component="xyz".index(component), values=values,
                            max_cuts=max_cuts, options=options)  # fmt: skip
        else:
            plan = PathPlan("arc_length", arc_length=_arc_length(t), options=options)
    except PathSettingError as exc:
        raise SceneError(f"{path}: path.{exc}") from None
    t.done()
    return plan


def _levels(t: Table, key: str, target_key: str, default_target: float | None = 1.0) -> tuple[float, ...]:
    """``key = [...]``, or ``steps = n`` equal steps to ``target_key`` (default ``default_target``)."""
    if key in t.data:
        values = t.get(key, "a list")
        return tuple(check_levels(key, values).tolist())
    steps = t.get("steps", "an integer", check=lambda v: 1 <= v <= 100_000, expected=f"an integer in 1..100000 "
                  f"(or '{key}', a list)")  # fmt: skip
    target = t.get(target_key, "a number", ... if default_target is None else default_target)
    return tuple(float(target) * k / steps for k in range(1, steps + 1))


def _arc_length(t: Table) -> ArcLength:
    initial = t.get("initial_step", "a number", expected="a number > 0 (first arc length [m])")
    low_high = t.get("load_factor_range", "2 numbers", [-math.inf, 1.0])
    settings = ArcLength(
        initial_step=initial,
        min_step=t.get("min_step", "a number", 0.0),
        max_step=t.get("max_step", "a number", math.inf),
        max_steps=t.get("max_steps", "an integer", 100),
        load_factor_range=(float(low_high[0]), float(low_high[1])),
        target_iterations=t.get("target_iterations", "an integer", 5),
        max_cuts=t.get("max_cuts", "an integer", 8),
        direction=t.get("direction", "an integer", 1),
    )
    settings.validate(prefix="")
    return settings


def _contact(top: Table, path: Path, static: bool, other_bodies: bool) -> SceneContact | None:
    """``effects.contact`` / ``self_collision`` / ``friction`` and the ``[[colliders]]`` list;
    ``other_bodies``: other bodies in contact are met as well."""
    effects = top.data.get("effects", {}) if isinstance(top.data.get("effects"), dict) else {}
    listed = [k for k in CONTACT_EFFECTS if k in effects]
    colliders_raw = top.get("colliders", "a list", [])
    if not listed:
        if colliders_raw:
            raise SceneError(f"{path}: key 'colliders' is given but 'effects.contact' is not listed")
        return None
    if static:
        raise SceneError(f"{path}: contact effects {listed} need a dynamic scene ('time.static' is true)")
    if "contact" not in effects:
        raise SceneError(f"{path}: effects {listed} need 'effects.contact' as well")
    from bhem_hpc.contact.metrics import CONTACT_METHODS  # loaded only for contact scenes

    settings = effects["contact"]
    if settings is True:
        settings = {}
    et = Table(path, "effects.contact", settings)
    method = et.get("method", "a string", "impulse", lambda v: v in CONTACT_METHODS, f"one of {CONTACT_METHODS}")
    if method == "ipc":
        return parse_ipc_contact(et, Table(path, "effects", effects), colliders_raw, path, other_bodies)
    return parse_impulse_contact(et, effects, colliders_raw, path, other_bodies)


def parse_impulse_contact(et: Table, effects: dict, colliders_raw: list, path: Path, other_bodies: bool,
                          key: str = "effects") -> SceneContact:  # fmt: skip
    """``effects.contact`` with ``method = "impulse"``: the push-out distance, samples and metric of
    the response between steps, the colliders and self-collision (``key``: where ``effects`` is)."""
    from bhem_hpc.contact.metrics import CONTACT_METRICS

    push_out = et.get("push_out", "a number", 1e-4, lambda v: v > 0, "a number > 0 [m]")
    samples = et.get("samples_per_side", "an integer", 2, lambda v: 1 <= v <= 16, "an integer in 1..16")
    metric = et.get("metric", "a string", "mass", lambda v: v in CONTACT_METRICS, f"one of {CONTACT_METRICS}")
    et.done()
    friction = effects.get("friction", 0.0)
    if not (is_number(friction) and friction >= 0):
        raise SceneError(
            f"{path}: key '{key}.friction' must be a number >= 0 (Coulomb coefficient), got {friction!r}"
        )
    if "static_friction" in effects:
        raise SceneError(f"{path}: key '{key}.static_friction' = {effects['static_friction']!r}: impulses "
                         "have one Coulomb coefficient ('effects.friction'); static and kinetic ones take "
                         "method = 'ipc'")  # fmt: skip
    self_collision, self_friction = _self_collision(effects.get("self_collision", False), friction, path)
    if not colliders_raw and not self_collision and not other_bodies:
        raise SceneError(f"{path}: 'effects.contact' is listed but there are no 'colliders' and no self-collision")
    colliders = parse_colliders(colliders_raw, friction, path)
    return SceneContact(colliders, push_out, samples, self_collision, self_friction, metric, friction)


def parse_ipc_contact(et: Table, effects: Table, colliders_raw: list, path: Path, other_bodies: bool,
                      cells: int = 4) -> SceneContact:  # fmt: skip
    """``effects.contact`` with ``method = "ipc"``: a barrier against the colliders (resting or
    translating; spheres also spinning) and, with ``other_bodies``, the other bodies in contact
    (``cells``: collision cells per side by default); lagged friction by ``effects.friction`` /
    ``static_friction`` and the colliders' ``friction`` / ``static_friction``."""
    from bhem_hpc.collision.colliders import Plane
    from bhem_hpc.contact.ipc_friction import DEFAULT_EPS_V, EPS_V_RANGE
    from bhem_hpc.contact.metrics import COLLISION_CELLS_RANGE

    dhat = et.get("dhat", "a number", None, lambda v: 1e-9 <= v <= 1.0, "a length in [1e-9, 1] [m]")
    kappa = et.get("barrier_stiffness", "a number", None, lambda v: 0 < v <= 1e15, "a number in (0, 1e15] [N/m]")
    low, high = COLLISION_CELLS_RANGE
    cells = et.get("collision_cells", "an integer", cells, lambda v: low <= v <= high, f"an integer in {low}..{high}")
    low, high = EPS_V_RANGE
    eps_v = et.get("eps_v", "a number", DEFAULT_EPS_V, lambda v: low <= v <= high,
                   f"a sticking speed in [{low:g}, {high:g}] [m/s]")  # fmt: skip
    low, high = VELOCITY_TOLERANCE_RANGE
    velocity_tolerance = et.get("velocity_tolerance", "a number or a string", None,
                                lambda v: v == "auto" or (not isinstance(v, str) and low <= v <= high),
                                f'a speed in [{low:g}, {high:g}] [m/s] or "auto"')  # fmt: skip
    et.done()
    self_collision = effects.data.get("self_collision", False)
    if not isinstance(self_collision, bool):
        raise SceneError(f"{path}: key '{effects.key('self_collision')}' = {self_collision!r}: contact by 'ipc' takes "
                         "a boolean (within the shell, its 'friction' acts)")  # fmt: skip
    coefficient = "a number >= 0 (Coulomb coefficient)"
    friction = effects.get("friction", "a number", 0.0, lambda v: v >= 0, coefficient)
    static_friction = effects.get("static_friction", "a number", None, lambda v: v >= 0, coefficient)
    if not colliders_raw and not self_collision and not other_bodies:
        raise SceneError(f"{path}: 'effects.contact' with method 'ipc' needs 'colliders' (planes, spheres, meshes), "
                         "'effects.self_collision' = true or another body in contact")  # fmt: skip
    colliders = parse_colliders(colliders_raw, friction, path, static_friction, method="ipc")
    for entry in colliders:
        collider = entry.collider
        if isinstance(collider, Plane) and np.any(collider.velocity != 0) and (entry.friction or entry.static_friction):
            raise SceneError(f"{path}: key '{entry.key}.friction' = {entry.friction!r} (static "
                             f"{entry.static_friction!r}; its own, or the body's 'effects.friction'): a translating "
                             "plane meets the shell without friction by 'ipc' (ipc-toolkit's plane contacts rub "
                             "against a plane at rest); a mesh collider moving so takes friction")  # fmt: skip
    return SceneContact(colliders, 0.0, 1, self_collision, friction, method="ipc", dhat=dhat, barrier_stiffness=kappa,
                        collision_cells=cells, friction=friction, static_friction=static_friction,
                        eps_v=eps_v, velocity_tolerance=velocity_tolerance)  # fmt: skip


def _self_collision(value: Any, friction: float, path: Path) -> tuple[bool, float]:
    """``effects.self_collision``: a boolean, or a table with its own ``friction``."""
    if isinstance(value, dict):
        st = Table(path, "effects.self_collision", value)
        self_friction = st.get("friction", "a number", friction, lambda v: v >= 0, "a number >= 0")
        st.done()
        return True, self_friction
    if not isinstance(value, bool):
        raise SceneError(f"{path}: key 'effects.self_collision' must be a boolean or a table, got {value!r}")
    return value, friction
