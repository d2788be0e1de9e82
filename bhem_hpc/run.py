"""Run a scene file: build only what it lists, step it, write ParaView output, checkpoints, summary.

Collective: every rank calls :func:`run_scene`; rank 0 writes files. Everything that can be
checked (scene, output directory, restart compatibility) is checked before the first step.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from bhem_hpc.geometry.surface import HermiteSurface
from bhem_hpc.io import SurfaceTimeSeries, read_checkpoint, render_surface_png, write_checkpoint
from bhem_hpc.io.run_directory import (
    OutputDirectoryError,
    check_output_directory,
    start_output_directory,
    write_replacing,
)
from bhem_hpc.model.shell import Dynamics, LineLoad, Loads, PointConstraint, PointLoad, ShellModel
from bhem_hpc.scene import Scene, load_scene
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.dynamics import PrescribedMotion, StepFailure, StepRecord, TimeStepper
from bhem_hpc.solver.petsc import library_versions

log = logging.getLogger(__name__)
SOLVER_PREFIX = "bhem_"
SUMMARY_EVERY_S = 30.0  # wall seconds between rewrites of a running summary.json (at checkpoints)


class RunError(RuntimeError):
    """The run cannot start or continue (output directory, restart, failed step)."""


@dataclass(frozen=True)
class RunOptions:
    scene: Path
    out: Path
    steps: int | None = None
    restart: Path | None = None
    force: bool = False
    progress: bool = True


def physics_hash(scene: Scene) -> str:
    """Identity of a scene's physics (everything but time span and output), for restarts."""
    raw = {k: v for k, v in scene.raw.items() if k not in ("output",)}
    raw["time"] = {k: v for k, v in raw.get("time", {}).items() if k not in ("steps", "duration")}
    canonical = json.dumps(raw, sort_keys=True, default=str)
    grid = scene.surface.grid
    canonical += repr((grid.n1, grid.n2, grid.xi1_range, grid.xi2_range, grid.periodic1, grid.periodic2))
    return hashlib.sha256(canonical.encode()).hexdigest()[:16]


def _check_output(options: RunOptions, continuing: bool, comm: MPI.Comm) -> None:
    error = None
    if comm.rank == 0:
        try:
            check_output_directory(options.out, options.force, continuing)
        except OutputDirectoryError as exc:
            error = str(exc)
    error = comm.bcast(error)
    if error:
        raise RunError(error)


def _is_same_directory(a: Path, b: Path) -> bool:
    return a.exists() and b.exists() and os.path.samefile(a, b)


def build_model(scene: Scene, comm: MPI.Comm) -> ShellModel:
    """The :class:`ShellModel` of a scene: only the listed effects are built."""
    e = scene.effects
    loads = Loads(
        gravity=e.gravity,
        pressure=e.pressure,
        line_loads=tuple(LineLoad(edge, traction) for edge, traction in e.line_loads),
        point_loads=tuple(PointLoad(a, b, force) for a, b, force in e.point_loads),
    )
    dynamics = None if scene.static else Dynamics(scene.dt, e.mass_damping, e.stiffness_damping)
    return ShellModel(
        scene.surface,
        scene.material,
        loads,
        [sc.constraint for sc in scene.constraints],
        hessian=scene.hessian,
        quadrature_points=scene.quadrature,
        comm=comm,
        dynamics=dynamics,
        point_constraints=[
            PointConstraint(p.xi1, p.xi2, p.target_at if p.motion is not None else p.target, p.components)
            for p in scene.point_constraints
        ],
    )


def build_contact(scene: Scene, model: ShellModel, solver: ShellSolver):
    """The scene's :class:`~bhem_hpc.contact.response.ContactHandler`, or None: only scenes that list contact
    effects load the collision code."""
    if scene.contact is None:
        return None
    from bhem_hpc.contact.detection import ContactDetector
    from bhem_hpc.contact.response import ContactHandler, ContactSettings

    c = scene.contact
    patches = model.discretization.patches
    detector = ContactDetector(patches, c.colliders, c.samples_per_side, c.self_collision, c.self_friction)
    settings = ContactSettings(c.push_out, metric=c.metric)
    return ContactHandler(model, solver, detector, settings)


def prescribed_motions(scene: Scene) -> list[PrescribedMotion]:
    """The time-dependent nodal constraints of a scene."""
    motions = []
    for sc in scene.constraints:
        if sc.motion is None:
            continue
        c = sc.constraint
        nodes = np.asarray(c.nodes)
        initial = scene.surface.nodal[nodes[:, 0], nodes[:, 1]][:, list(c.kinds)][:, :, list(c.components)]
        motions.append(PrescribedMotion(c, lambda t, f=sc.motion.values, v0=initial: f(t, v0)))
    return motions


def run_scene(options: RunOptions, comm: MPI.Comm = MPI.COMM_WORLD) -> dict:
    """Run a scene; returns the summary written to ``out/summary.json``.

    Everything is checked before the output directory is touched; a run that fails after it started
    writing leaves ``summary.json`` with ``status: "failed"``, the error and the last completed
    step. A restart whose ``--out`` is its ``--restart`` directory continues that run's series and
    step records; a restart into another directory starts its series with the restart frame.
    """
    scene, checkpoint, continuing = _prepare(options, comm)
    steps = _steps_to_run(scene, options, checkpoint)
    scene_text = options.scene.read_bytes()  # before the output directory (which may hold it) is replaced

    model = build_model(scene, comm)
    disc = model.discretization
    if checkpoint is not None:  # the DOF layout of this model (rank count for B-splines) must match
        expected = disc.gather_raw_dofs(model.x.x.array).shape
        if checkpoint["arrays"]["position_dofs"].shape != expected:
            raise RunError(
                f"{checkpoint['path']}: its DOFs have shape {checkpoint['arrays']['position_dofs'].shape}, "
                f"this run's {expected}"
            )
    solver = ShellSolver(model, prefix=SOLVER_PREFIX, options=scene.petsc_options)
    summary: dict = {
        "scene": str(options.scene),
        "status": "running",
        "physics_hash": physics_hash(scene),
        "dofs": 3 * disc.num_closed,
        "nonzeros": solver.problem.matrix_nonzeros(),
        "ranks": comm.size,
        "versions": library_versions(),
        "static": scene.static,
        "steps": _previous_steps(options.out, checkpoint) if continuing else [],
    }
    series = None
    try:
        series = _start_output(options, scene, scene_text, summary, checkpoint if continuing else None, comm)
        if scene.static:
            final = _run_static(scene, options, model, solver, series, summary, comm)
        else:
            final = _run_dynamic(scene, options, steps, model, solver, series, summary, checkpoint, comm)
        title = f"{options.scene.name}, t = {summary.get('time', 0):.4g} s"
        _on_rank0(comm, lambda: render_surface_png(options.out / "last.png", final, title), "last.png")
    except Exception as exc:
        summary.update(status="failed", error=str(exc))
        if comm.rank == 0 and options.out.is_dir():
            try:
                _write_summary(options.out, summary)
            except OSError:
                log.error("could not record the failure in %s/summary.json", options.out)
        raise
    finally:
        if series is not None:
            series.close()
        _report_unused_options(solver, summary, comm)
        solver.close()
    summary["status"] = "completed"
    _on_rank0(comm, lambda: _write_summary(options.out, summary), "summary.json")
    return summary


def _report_unused_options(solver: ShellSolver, summary: dict, comm: MPI.Comm) -> None:
    """Options under the run's prefix that PETSc never read (a misspelling, or an option that does
    not apply): a warning and ``summary.json``'s ``unused_petsc_options``."""
    unused = solver.unused_options()
    summary["unused_petsc_options"] = unused
    if unused and comm.rank == 0:
        log.warning("PETSc options never used (misspelled or not applicable): %s", ", ".join(unused))


def _prepare(options: RunOptions, comm: MPI.Comm) -> tuple[Scene, dict | None, bool]:
    """Every check before anything is built: the scene, ``--steps``, the restart and the output
    directory. Returns the scene, the restart checkpoint (or None) and whether the restart
    continues the run in its own directory."""
    scene = load_scene(options.scene)
    if options.steps is not None and options.steps < 1:
        raise RunError(f"--steps must be >= 1, got {options.steps}")
    checkpoint = None
    continuing = False
    if options.restart is not None:
        if scene.static:
            raise RunError(f"--restart {options.restart}: a static scene has no time steps to continue")
        checkpoint = _read_restart(options.restart, scene)
        continuing = _is_same_directory(options.restart, options.out)
    _check_output(options, continuing, comm)
    return scene, checkpoint, continuing


def _start_output(
    options: RunOptions, scene: Scene, scene_text: bytes, summary: dict, continued: dict | None, comm: MPI.Comm
) -> SurfaceTimeSeries | None:
    """Rank 0: a fresh output directory (or the continued one), the scene, a running summary and the
    time series (continuing ``continued``'s checkpoint time, if given); None on other ranks."""

    def start() -> SurfaceTimeSeries:
        if continued is None:
            start_output_directory(options.out)
        write_replacing(options.out / "scene.toml", scene_text)
        _write_summary(options.out, summary)
        return SurfaceTimeSeries(
            options.out / "surface.xdmf", scene.surface, scene.material, scene.output_density,
            continue_at=None if continued is None else float(continued["attrs"]["time"]),
        )  # fmt: skip

    return _on_rank0(comm, start, f"the output directory {options.out}")


def _on_rank0(comm: MPI.Comm, action, what: str):
    """Run a file operation on rank 0 and raise :class:`RunError` on every rank if it fails (so no
    rank waits for a collective that rank 0 never reaches). Returns the action's result on rank 0,
    None elsewhere."""
    error = result = None
    if comm.rank == 0:
        try:
            result = action()
        except (OSError, ValueError, RuntimeError) as exc:  # h5py reports failed writes as RuntimeError
            detail = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            error = f"cannot write {what}: {detail}"
    error = comm.bcast(error)
    if error:
        raise RunError(error)
    return result


def _steps_to_run(scene: Scene, options: RunOptions, checkpoint: dict | None) -> int:
    """``--steps``, or the steps left to the scene's end (all of them without a restart)."""
    if options.steps is not None or checkpoint is None:
        return options.steps if options.steps is not None else scene.steps
    done = int(checkpoint["attrs"]["step"])
    if done >= scene.steps:
        raise RunError(
            f"--restart {options.restart}: the checkpoint is at step {done}, the scene's last "
            f"({scene.steps} steps): pass --steps to continue past it"
        )
    return scene.steps - done


def _previous_steps(out: Path, checkpoint: dict) -> list[dict]:
    """The step records of the run being continued, up to its checkpoint."""
    try:
        previous = json.loads((out / "summary.json").read_text())["steps"]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    last = int(checkpoint["attrs"]["step"])
    return [row for row in previous if isinstance(row, dict) and row.get("step", last + 1) <= last]


def _write_summary(out: Path, summary: dict) -> None:
    write_replacing(out / "summary.json", (json.dumps(summary, indent=1) + "\n").encode())


def _read_restart(directory: Path, scene: Scene) -> dict:
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
    problem = _checkpoint_problem(arrays, attrs, scene)
    if problem:
        raise RunError(f"{path}: {problem}")
    return {"arrays": arrays, "attrs": attrs, "path": path}


def _checkpoint_problem(arrays: dict, attrs: dict, scene: Scene) -> str | None:
    """What is wrong with a checkpoint's contents, or None."""
    names = ("position_dofs", "velocity_dofs", "position_nodal")
    missing = [name for name in names if name not in arrays]
    if missing:
        return f"dataset {missing[0]!r} is missing"
    position, velocity, nodal = (np.asarray(arrays[name]) for name in names)
    if position.shape != velocity.shape or position.ndim < 2 or position.shape[-1] != 3:
        return f"position and velocity DOFs have shapes {position.shape} and {velocity.shape}"
    if nodal.shape != scene.surface.nodal.shape:
        return f"its surface has shape {nodal.shape}, the scene's {scene.surface.nodal.shape}"
    if not all(a.dtype.kind == "f" and np.all(np.isfinite(a)) for a in (position, velocity, nodal)):
        return "it holds non-finite or non-numeric values"
    return _clock_problem(attrs)


def _clock_problem(attrs: dict) -> str | None:
    try:
        time_value, step = float(attrs["time"]), int(attrs["step"])
    except (KeyError, TypeError, ValueError):
        return "its 'time' and 'step' attributes are missing or not numbers"
    if not (np.isfinite(time_value) and time_value >= 0 and step >= 0):
        return f"time {time_value!r} and step {step!r} are not a valid point of a run"
    return None


def _energies(model: ShellModel) -> dict[str, float]:
    e = model.energies()
    return {k: float(v) for k, v in e.items()}


def _run_static(scene, options, model, solver, series, summary, comm) -> HermiteSurface:
    """Solve a static scene, writing its frame and checkpoint; returns the final surface (gathered
    on every rank)."""
    start = time.perf_counter()
    report = solver.solve(scene.load_steps)
    surface = _write_state(options.out, series, model, 1.0, 1, summary, comm)
    summary["time"] = 1.0
    summary["steps"].append(
        {
            "step": 1,
            "load_steps": report.load_steps,
            "newton_iterations": sum(report.newton_iterations),
            "wall_s": time.perf_counter() - start,
            "energies": _energies(model),
        }
    )
    return surface


def _run_dynamic(scene, options, steps, model, solver, series, summary, checkpoint, comm) -> HermiteSurface:
    """Step a dynamic scene, writing frames and checkpoints; returns the final surface."""
    contact = build_contact(scene, model, solver)
    if contact is not None:
        summary["contact"] = {
            "colliders": len(scene.contact.colliders),
            "sample_points": contact.detector.num_samples,
        }
    stepper = TimeStepper(model, solver, prescribed_motions(scene), contact=contact)
    if checkpoint is not None:
        arrays, attrs = checkpoint["arrays"], checkpoint["attrs"]
        _restore(model, arrays)
        stepper.time, stepper.step = float(attrs["time"]), int(attrs["step"])
    surface = model.state_surface()
    if comm.bcast(series is not None and not series.times):  # a continued series has its restart frame
        _on_rank0(comm, lambda: series.write(stepper.time, surface), "a frame")
    progress = _progress(steps, options.progress and comm.rank == 0)
    last_summary = time.perf_counter()
    try:
        for k in range(steps):
            record = stepper.advance()
            t_out = time.perf_counter()
            wrote = stepper.step % scene.output_every == 0 or k == steps - 1  # the last step always writes
            if wrote:
                surface = _write_state(options.out, series, model, stepper.time, stepper.step, summary, comm)
            output_s = time.perf_counter() - t_out
            summary["steps"].append(_step_summary(record, output_s, _energies(model)))
            # the step records up to a checkpoint, at most every SUMMARY_EVERY_S: a killed or
            # requeued job's continuation keeps them
            if wrote and comm.bcast(time.perf_counter() - last_summary >= SUMMARY_EVERY_S):
                _on_rank0(comm, lambda: _write_summary(options.out, summary), "summary.json")
                last_summary = time.perf_counter()
            progress(record, stepper)
    except StepFailure as exc:
        raise RunError(str(exc)) from exc
    finally:
        progress(None, stepper)
        if contact is not None:
            contact.close()
    summary["time"] = stepper.time
    return surface


def _step_summary(record: StepRecord, output_s: float, energies: dict[str, float]) -> dict:
    """A step's row of ``summary.json``."""
    names = ("step", "time", "newton_iterations", "recoveries", "negative_pivots", "regularized_iterations")
    row = {name: getattr(record, name) for name in names}
    row["wall_s"] = record.wall_s + output_s
    for name in ("assembly_s", "factorization_s", "linear_solve_s", "collision_s", "contacts"):
        row[name] = getattr(record, name)
    return row | {"output_s": output_s, "energies": energies}


def _restore(model: ShellModel, arrays: dict[str, np.ndarray]) -> None:
    """Set position and velocity from a checkpoint's raw DOF arrays (bit-exact)."""
    disc = model.discretization
    model.x.x.array[:] = disc.scatter_raw_dofs(arrays["position_dofs"])
    model.velocity.x.array[:] = disc.scatter_raw_dofs(arrays["velocity_dofs"])


def _write_state(
    out: Path, series, model: ShellModel, time_value: float, step: int, summary: dict, comm: MPI.Comm
) -> HermiteSurface:
    """Write the current state as a frame and a checkpoint; returns it as a surface (every rank)."""
    surface = model.state_surface()
    _on_rank0(comm, lambda: series.write(time_value, surface), "a frame of surface.h5")
    _checkpoint(out / "checkpoint.h5", model, surface, time_value, step, summary, comm)
    return surface


def _checkpoint(
    path: Path, model: ShellModel, surface: HermiteSurface, time_value: float, step: int, summary: dict,
    comm: MPI.Comm,
) -> None:  # fmt: skip
    """Write the state at ``time_value`` (a static run: load factor 1, zero velocity)."""
    position = model.discretization.gather_raw_dofs(model.x.x.array)
    velocity_array = model.velocity.x.array if model.dynamics is not None else np.zeros_like(model.x.x.array)
    velocity = model.discretization.gather_raw_dofs(velocity_array)
    _on_rank0(comm, lambda: write_checkpoint(
            path,
            {"position_dofs": position, "velocity_dofs": velocity, "position_nodal": surface.nodal},
            {"time": time_value, "step": step, "physics_hash": summary["physics_hash"],
             "static": model.dynamics is None},
        ), path.name)  # fmt: skip


def _progress(total: int, enabled: bool):
    """A tqdm bar on rank 0 showing step, simulated time, Newton iterations and recoveries."""
    if not enabled:
        return lambda report, stepper: None
    from tqdm import tqdm

    bar = tqdm(total=total, unit="step", dynamic_ncols=True, disable=None)  # None: off when not a terminal
    recoveries = [0]

    def update(report, stepper) -> None:
        if report is None:
            bar.close()
            return
        recoveries[0] += report.recoveries
        bar.set_postfix_str(f"t={stepper.time:.4g}s newton={report.newton_iterations} recoveries={recoveries[0]}")
        bar.update(1)

    return update
