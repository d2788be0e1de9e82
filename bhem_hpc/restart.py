"""Restarts of a run: a checkpoint's identity (the scene's physics and solution method), its checks
against the scene before anything is built, and the records a run continued in place keeps.
Serial functions (every rank may call them on the same files).
"""

from __future__ import annotations

import csv
import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bhem_hpc.bodies.layout import body_array_name
from bhem_hpc.errors import RunError
from bhem_hpc.io import read_checkpoint
from bhem_hpc.io.path_table import read_json_rows
from bhem_hpc.scene import Scene
from bhem_hpc.scene.bodies import BodiesScene
from bhem_hpc.solver.reuse import FactorizationReuse

log = logging.getLogger(__name__)

#: Prefixes of a checkpoint's solver attributes: the refactor policy's state, the contributions'
#: adapted parameters (the IPC barrier's stiffness).
REUSE_PREFIX, ADAPTED_PREFIX = "reuse_", "adapted_"


def solver_checkpoint(solver: Any) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Collective: what a run continued from a checkpoint needs of ``solver`` (a
    :class:`~bhem_hpc.solver.ShellSolver`) to decide as an uninterrupted run: the arrays its kept
    factorization is remade from, and as attributes its refactor policy's state and its
    contributions' adapted parameters."""
    arrays, reuse = solver.reuse_checkpoint()
    attrs = {f"{REUSE_PREFIX}{k}": v for k, v in (reuse | solver.reuse.learned()).items()}
    return arrays, attrs | {f"{ADAPTED_PREFIX}{k}": v for k, v in solver.problem.adapted_parameters().items()}


def restore_solver(solver: Any, arrays: dict, attrs: dict, kept: bool) -> None:
    """Collective: :func:`solver_checkpoint`'s state back into ``solver``; its kept factorization
    remade where the checkpoint has one (``kept``)."""
    solver.problem.restore_adapted(_prefixed(attrs, ADAPTED_PREFIX))
    solver.reuse.restore_learned(_prefixed(attrs, REUSE_PREFIX))
    if kept:
        solver.restore_reuse_checkpoint(arrays, _prefixed(attrs, REUSE_PREFIX))


def _prefixed(attrs: dict, prefix: str) -> dict:
    return {k.removeprefix(prefix): v for k, v in attrs.items() if k.startswith(prefix)}


@dataclass(frozen=True)
class RestartPoint:
    """A checkpoint read for a restart and checked against its scene (:func:`read_restart`).

    Attributes:
        path: the checkpoint file.
        arrays: its datasets by name (raw DOFs ``position_dofs``, ``velocity_dofs``, ...).
        attrs: its attributes (``time``, ``step``, ``physics_hash``, a path's ``load_factor``, ...).
    """

    path: Path
    arrays: dict[str, np.ndarray]
    attrs: dict[str, object]

    @property
    def step(self) -> int:
        """The step (time step or path point) the checkpoint was written after."""
        return int(self.attrs["step"])


#: ``[solver]`` keys that choose how the equations are solved, not which: a run may continue from a
#: checkpoint with other values (e.g. the iterative solver where a factorization ran out of memory).
SOLUTION_METHOD_KEYS = ("linear", "factorization", "options")


def _physics_tables(raw: dict) -> dict:
    """A scene file's tables without those that do not change its physics: output, path settings,
    probes, the time span and the solution method's :data:`SOLUTION_METHOD_KEYS`."""
    raw = {k: v for k, v in raw.items() if k not in ("output", "path", "probes")}
    raw["solver"] = {k: v for k, v in raw.get("solver", {}).items() if k not in SOLUTION_METHOD_KEYS}
    raw["time"] = {k: v for k, v in raw.get("time", {}).items() if k not in ("steps", "duration", "load_steps")}
    return raw


def _grid_identity(scene: Scene) -> str:
    """A shell's parameter grid; a solid's model: its parts' control points, weights and knots."""
    if not isinstance(scene, Scene):
        arrays = [a for p in scene.parts for a in (p.control, p.weights, p.u.knots, p.v.knots)]
        return hashlib.sha256(b"".join(np.ascontiguousarray(a, dtype=float).tobytes() for a in arrays)).hexdigest()
    grid = scene.surface.grid
    return repr((grid.n1, grid.n2, grid.xi1_range, grid.xi2_range, grid.periodic1, grid.periodic2))


def physics_hash(scene: Scene | BodiesScene) -> str:
    """Identity of a scene's physics (everything but time span, path settings, probes, output and
    the solution method's :data:`SOLUTION_METHOD_KEYS`; of a scene of several bodies, every body's
    tables but their probes), for restarts."""
    raw = _physics_tables(scene.raw)
    if isinstance(scene, BodiesScene):
        raw["bodies"] = [{k: v for k, v in body.items() if k != "probes"} for body in raw["bodies"]]
        grids = [_grid_identity(body) for body in scene.bodies]
    else:
        grids = [_grid_identity(scene)]
    canonical = canonical_json(raw) + "".join(grids)
    return hashlib.sha256(canonical.encode()).hexdigest()[:16]


def solution_method(scene: Scene) -> dict:
    """The scene's :data:`SOLUTION_METHOD_KEYS` that it sets (summary.json keeps them, checkpoints
    as :func:`_canonical_json`)."""
    return {k: v for k, v in scene.raw.get("solver", {}).items() if k in SOLUTION_METHOD_KEYS}


def canonical_json(value: dict) -> str:
    """``value`` as JSON that is equal for equal contents (keys sorted)."""
    return json.dumps(value, sort_keys=True, default=str)


def read_restart(directory: Path, scene: Scene | BodiesScene) -> RestartPoint:
    """The checkpoint in ``directory``, checked to be whole, finite and of this scene's physics."""
    path = directory / "checkpoint.h5"
    if not path.is_file():
        raise RunError(f"--restart {directory}: no checkpoint.h5 there")
    try:
        arrays, attrs = read_checkpoint(path)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise RunError(f"{path}: not a readable checkpoint ({exc})") from None
    if attrs.get("physics_hash") != physics_hash(scene):
        raise RunError(
            f"--restart {directory}: the checkpoint is from a different scene or resolution "
            f"(physics hash {attrs.get('physics_hash')} != {physics_hash(scene)})"
        )
    several = isinstance(scene, BodiesScene)
    problem = (_bodies_checkpoint_problem if several else _checkpoint_problem)(arrays, attrs, scene)
    if problem:
        raise RunError(f"{path}: {problem}")
    method = canonical_json(solution_method(scene.first if several else scene))
    if attrs.get("solution_method") != method:
        log.warning(
            "--restart %s: continuing with solver settings %s instead of the checkpoint's %s; the continued "
            "steps agree with an uninterrupted run within the Newton tolerance, not bit for bit",
            directory, method, attrs.get("solution_method", "(not recorded)"),
        )  # fmt: skip
    return RestartPoint(path, arrays, attrs)


def _checkpoint_problem(arrays: dict, attrs: dict, scene: Scene) -> str | None:
    """What is wrong with a checkpoint's contents, or None."""
    problem = _state_problem(arrays, scene, lambda name: name)
    if problem:
        return problem
    problem = _reuse_problem(arrays, attrs, [np.shape(arrays["position_dofs"])], scene.static, lambda name, _: name)
    if problem:
        return problem
    return _path_problem(arrays, attrs, np.shape(arrays["position_dofs"])) if scene.static else _clock_problem(attrs)


def _state_problem(arrays: dict, scene: Scene, key) -> str | None:
    """What is wrong with one body's position, velocity and surface in a checkpoint (arrays named
    ``key(name)``), or None."""
    names = [key(name) for name in ("position_dofs", "velocity_dofs", "position_nodal")]
    missing = [name for name in names if name not in arrays]
    if missing:
        return f"dataset {missing[0]!r} is missing"
    position, velocity, nodal = (np.asarray(arrays[name]) for name in names)
    if position.shape != velocity.shape or position.ndim < 2 or position.shape[-1] != 3:
        return f"position and velocity DOFs have shapes {position.shape} and {velocity.shape}"
    if nodal.shape != scene.nodal_shape:
        return f"its surface has shape {nodal.shape}, the scene's {scene.nodal_shape}"
    if not all(a.dtype.kind == "f" and np.all(np.isfinite(a)) for a in (position, velocity, nodal)):
        return "it holds non-finite or non-numeric values"
    return None


def _reuse_problem(arrays: dict, attrs: dict, shapes: list[tuple], static: bool, key) -> str | None:
    """What is wrong with a checkpoint's refactor policy state or its kept-factorization state (if
    it has one), or None; ``shapes``: each body's DOF shape, ``key(name, body)`` the name of a body's array."""
    learned = [attrs.get(f"{REUSE_PREFIX}{k}", 0.0) for k in FactorizationReuse.LEARNED_KEYS]
    if not _all_counts(learned):
        return f"its refactor policy attributes {learned} (the reductions learned) are not numbers >= 0"
    if key("factorization_state_dofs", 0) not in arrays:
        return None
    kept_names = ("factorization_state_dofs",) + (() if static else ("factorization_previous_dofs",))
    for body, shape in enumerate(shapes):
        for name in (key(name, body) for name in kept_names):
            kept = np.asarray(arrays.get(name, np.zeros(0)))
            if kept.shape != shape or kept.dtype.kind != "f" or not np.all(np.isfinite(kept)):
                return f"dataset {name!r} (the kept factorization's state) is missing or damaged"
    counters = [attrs.get(f"{REUSE_PREFIX}{k}") for k in FactorizationReuse.STATE_KEYS]
    if not _all_counts(counters):
        return f"its refactor policy attributes {counters} are missing or not numbers >= 0"
    return None


def _all_counts(values: list) -> bool:
    """Whether every value is a finite number >= 0 (a refactor policy attribute of a checkpoint)."""
    return all(isinstance(v, int | float | np.number) and np.isfinite(v) and v >= 0 for v in values)


def _bodies_checkpoint_problem(arrays: dict, attrs: dict, scene: BodiesScene) -> str | None:
    """What is wrong with the checkpoint of a run of several bodies, or None."""
    count = len(scene.bodies)

    def key(array: str, body: int) -> str:
        return body_array_name(array, body, count)

    for k, (name, body) in enumerate(zip(scene.names, scene.bodies, strict=True)):
        problem = _state_problem(arrays, body, lambda array, k=k: key(array, k))
        if problem:
            return f"body '{name}' (bodies[{k}]): {problem}"
    shapes = [np.shape(arrays[key("position_dofs", k)]) for k in range(count)]
    return _reuse_problem(arrays, attrs, shapes, False, key) or _clock_problem(attrs)


def _path_problem(arrays: dict, attrs: dict, shape: tuple) -> str | None:
    """What is wrong with a static run's path data in a checkpoint (and its clock), or None."""
    previous = np.asarray(arrays.get("previous_position_dofs", np.zeros(0)))
    if previous.shape != shape or previous.dtype.kind != "f" or not np.all(np.isfinite(previous)):
        return "dataset 'previous_position_dofs' (the path's previous point) is missing or damaged"
    factor = attrs.get("load_factor")
    if isinstance(factor, bool) or not isinstance(factor, int | float | np.floating) or not np.isfinite(factor):
        return f"its 'load_factor' attribute {factor!r} is not a number"
    return _clock_problem(attrs)


def _clock_problem(attrs: dict) -> str | None:
    try:
        time_value, step = float(attrs["time"]), int(attrs["step"])
    except (KeyError, TypeError, ValueError):
        return "its 'time' and 'step' attributes are missing or not numbers"
    if not (np.isfinite(time_value) and time_value >= 0 and step >= 0):
        return f"time {time_value!r} and step {step!r} are not a valid point of a run"
    return None


def check_path_left(scene: Scene, checkpoint: RestartPoint) -> None:
    """A restart of a finished static path is refused before the output (and its summary) is touched."""
    done, factor = checkpoint.step, float(checkpoint.attrs.get("load_factor", 0.0))  # dynamic checkpoints have none
    if scene.static and scene.path_plan is not None and scene.path_plan.is_complete(done, factor):
        raise RunError(f"{checkpoint.path}: the path is complete: the checkpoint is its last point (step {done}, "
                       f"load factor {factor:.6g})")  # fmt: skip


def previous_steps(out: Path, checkpoint: RestartPoint) -> list[dict]:
    """The step records of the run being continued, up to its checkpoint (from ``steps.jsonl``,
    which has every step's record before that step's checkpoint is written)."""
    return read_json_rows(out / "steps.jsonl", checkpoint.step)


def check_same_probes(scene: Scene, directory: Path) -> None:
    """A run continued in place keeps its probes: the table it continues (``path.csv`` of a static
    run, ``probes.csv`` of a dynamic one) must have a column set for each of the scene's probes and
    no other, else its rows would mix two sets of columns."""
    table = directory / ("path.csv" if scene.static else "probes.csv")
    try:
        with open(table, newline="") as f:
            header = next(csv.reader(f), [])
    except OSError:
        header = None
    if header is None and not scene.static:
        return  # a dynamic run without probes.csv starts one
    before = sorted(column[: -len("_ux")] for column in header or () if column.endswith("_ux"))
    now = sorted(p.name for p in scene.probes)
    if before != now:
        raise RunError(f"--restart {directory}: the scene's probes {now} are not those of the run it continues "
                       f"({table.name}: {before}); keep them, or continue into another --out")  # fmt: skip
