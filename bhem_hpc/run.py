"""Run a scene file: build only what it lists, step it, write ParaView output, checkpoints, summary.

Collective: every rank calls :func:`run_scene`; rank 0 writes files. Everything that can be
checked (scene, output directory, restart compatibility) is checked before the first step.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from bhem_hpc.geometry.surface import HermiteSurface
from bhem_hpc.io import SurfaceTimeSeries, read_checkpoint, render_surface_png, write_checkpoint
from bhem_hpc.model.shell import Dynamics, LineLoad, Loads, PointConstraint, PointLoad, ShellModel
from bhem_hpc.scene import Scene, load_scene
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.dynamics import PrescribedMotion, StepFailure, StepRecord, TimeStepper
from bhem_hpc.solver.petsc import library_versions

log = logging.getLogger(__name__)
SOLVER_PREFIX = "bhem_"


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


def _check_output(options: RunOptions, comm: MPI.Comm) -> None:
    error = None
    if comm.rank == 0:
        out = options.out
        try:
            if out.exists() and any(out.iterdir()) and not options.force:
                error = f"output directory {out} exists and is not empty: pass --force to overwrite it"
            else:
                out.mkdir(parents=True, exist_ok=True)
                probe = out / ".write-test"
                probe.write_text("")
                probe.unlink()
        except OSError as exc:
            error = f"output directory {out} cannot be written: {exc.strerror}"
    error = comm.bcast(error)
    if error:
        raise RunError(error)


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
    """Run a scene; returns the summary written to ``out/summary.json``."""
    scene = load_scene(options.scene)
    if options.steps is not None and options.steps < 1:
        raise RunError(f"--steps must be >= 1, got {options.steps}")
    checkpoint = None
    if options.restart is not None:
        checkpoint = _read_restart(options.restart, scene)
    _check_output(options, comm)
    if comm.rank == 0:
        shutil.copyfile(options.scene, options.out / "scene.toml")

    model = build_model(scene, comm)
    disc = model.discretization
    solver = ShellSolver(model, prefix=SOLVER_PREFIX, options=scene.petsc_options)
    summary: dict = {
        "scene": str(options.scene),
        "physics_hash": physics_hash(scene),
        "dofs": 3 * disc.num_closed,
        "nonzeros": solver.problem.matrix_nonzeros(),
        "ranks": comm.size,
        "versions": library_versions(),
        "static": scene.static,
        "steps": [],
    }
    series = (
        SurfaceTimeSeries(options.out / "surface.xdmf", scene.surface, scene.material, scene.output_density)
        if comm.rank == 0
        else None
    )
    try:
        if scene.static:
            final = _run_static(scene, model, solver, series, summary, comm)
        else:
            final = _run_dynamic(scene, options, model, solver, series, summary, checkpoint, comm)
    finally:
        if series is not None:
            series.close()
        solver.close()
    if comm.rank == 0:
        render_surface_png(options.out / "last.png", final, f"{options.scene.name}, t = {summary.get('time', 0):.4g} s")
        tmp = options.out / "summary.json.tmp"
        tmp.write_text(json.dumps(summary, indent=1) + "\n")
        os.replace(tmp, options.out / "summary.json")
    return summary


def _read_restart(directory: Path, scene: Scene) -> dict:
    path = directory / "checkpoint.h5"
    if not path.exists():
        raise RunError(f"--restart {directory}: no checkpoint.h5 there")
    arrays, attrs = read_checkpoint(path)
    if attrs.get("physics_hash") != physics_hash(scene):
        raise RunError(
            f"--restart {directory}: the checkpoint is from a different scene or resolution "
            f"(physics hash {attrs.get('physics_hash')} != {physics_hash(scene)})"
        )
    return {"arrays": arrays, "attrs": attrs}


def _energies(model: ShellModel) -> dict[str, float]:
    e = model.energies()
    return {k: float(v) for k, v in e.items()}


def _run_static(scene, model, solver, series, summary, comm) -> HermiteSurface:
    """Solve a static scene; returns the final surface (gathered on every rank)."""
    start = time.perf_counter()
    report = solver.solve(scene.load_steps)
    surface = model.state_surface()
    if series is not None:
        series.write(1.0, surface)
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


def _run_dynamic(scene, options, model, solver, series, summary, checkpoint, comm) -> HermiteSurface:
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
    total = options.steps if options.steps is not None else scene.steps
    surface = model.state_surface()
    if series is not None and checkpoint is None:
        series.write(stepper.time, surface)
    progress = _progress(total, options.progress and comm.rank == 0)
    try:
        for _ in range(total):
            record = stepper.advance()
            t_out = time.perf_counter()
            if stepper.step % scene.output_every == 0 or _ == total - 1:  # the last step always writes
                surface = model.state_surface()
                if series is not None:
                    series.write(stepper.time, surface)
                _checkpoint(options.out / "checkpoint.h5", model, surface, stepper, summary, comm)
            output_s = time.perf_counter() - t_out
            summary["steps"].append(_step_summary(record, output_s, _energies(model)))
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


def _checkpoint(
    path: Path, model: ShellModel, surface: HermiteSurface, stepper: TimeStepper, summary: dict, comm: MPI.Comm
) -> None:
    position = model.discretization.gather_raw_dofs(model.x.x.array)
    velocity = model.discretization.gather_raw_dofs(model.velocity.x.array)
    if comm.rank == 0:
        write_checkpoint(
            path,
            {"position_dofs": position, "velocity_dofs": velocity, "position_nodal": surface.nodal},
            {"time": stepper.time, "step": stepper.step, "physics_hash": summary["physics_hash"]},
        )


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
