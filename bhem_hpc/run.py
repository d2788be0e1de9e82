"""Run a scene file: build only what it lists, step it, write ParaView output, checkpoints, summary.

Collective: every rank calls :func:`run_scene`; rank 0 writes files. Everything that can be
checked (scene, output directory, restart compatibility) is checked before the first step.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from bhem_hpc.bodies.shared_dofs import SharedDofs
from bhem_hpc.errors import RunError
from bhem_hpc.geometry.surface import HermiteSurface
from bhem_hpc.io import SurfaceTimeSeries, render_surface_png, write_checkpoint
from bhem_hpc.io.interruption import Interruption, RunInterrupted
from bhem_hpc.io.path_table import CsvTable, JsonLinesTable, plot_path, probe_columns, read_rows
from bhem_hpc.io.render import TrimmedSurface
from bhem_hpc.io.run_directory import (
    OutputDirectoryError,
    OutputLock,
    check_output_directory,
    start_output_directory,
    write_replacing,
)
from bhem_hpc.io.run_summary import RunSummary
from bhem_hpc.model.expression import ufl_expression
from bhem_hpc.model.path import PathPlan, ProbeSet
from bhem_hpc.model.shell import AreaLoad, Dynamics, EdgeMoment, LineLoad, Loads, PointConstraint, PointLoad, ShellModel
from bhem_hpc.restart import (
    RestartPoint,
    canonical_json,
    check_path_left,
    check_same_probes,
    physics_hash,
    previous_steps,
    read_restart,
    restore_solver,
    solution_method,
    solver_checkpoint,
)
from bhem_hpc.run_ending import on_rank0, summarized
from bhem_hpc.scene import Scene
from bhem_hpc.scene.bodies import BodiesScene
from bhem_hpc.scene.loader import load_any_scene
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.dynamics import PrescribedMotion, StepFailure, StepRecord, TimeStepper
from bhem_hpc.solver.linear import LinearSolverError
from bhem_hpc.solver.petsc import library_versions
from bhem_hpc.solver.problem import ShellProblem
from bhem_hpc.solver.state import ShellState
from bhem_hpc.solver.step_test import StepVelocityTest, auto_velocity_tolerance

log = logging.getLogger(__name__)
SOLVER_PREFIX = "bhem_"
SUMMARY_EVERY_S = 30.0  # wall seconds between rewrites of a running summary.json (at checkpoints)


@dataclass(frozen=True)
class RunOptions:
    scene: Path
    out: Path
    steps: int | None = None
    restart: Path | None = None
    force: bool = False
    progress: bool = True


def check_output(options: RunOptions, continuing: bool, comm: MPI.Comm) -> None:
    _on_rank0_directory(comm, lambda: check_output_directory(options.out, options.force, continuing))


def _on_rank0_directory(comm: MPI.Comm, action) -> None:
    """Run an output-directory ``action`` on rank 0; its :class:`OutputDirectoryError` becomes a
    :class:`RunError` on every rank."""
    error = None
    if comm.rank == 0:
        try:
            action()
        except OutputDirectoryError as exc:
            error = str(exc)
    error = comm.bcast(error)
    if error:
        raise RunError(error)


def _is_same_directory(a: Path, b: Path) -> bool:
    return a.exists() and b.exists() and os.path.samefile(a, b)


@dataclass
class _Run:
    """What the stages of one run share: its options and scene, the model, solver and state
    (collective, every rank; the state is the one writer of position and velocity), the summary,
    and, once started, the time series (rank 0) and the stop signals."""

    options: RunOptions
    scene: Scene
    model: ShellModel
    solver: ShellSolver
    state: ShellState
    summary: RunSummary
    comm: MPI.Comm
    series: SurfaceTimeSeries | None = None
    interruption: Interruption | None = None


def build_model(scene: Scene, comm: MPI.Comm) -> ShellModel:
    """The :class:`ShellModel` of a scene: only the listed effects are built."""
    e = scene.effects
    loads = Loads(
        gravity=e.gravity,
        pressure=e.pressure,
        line_loads=tuple(LineLoad(edge, traction) for edge, traction in e.line_loads),
        point_loads=tuple(PointLoad(a, b, force) for a, b, force in e.point_loads),
        area_loads=tuple(AreaLoad(force, profile and ufl_expression(profile)) for force, profile in e.area_loads),
        edge_moments=tuple(EdgeMoment(edge, moment) for edge, moment in e.edge_moments),
    )
    dynamics = None if scene.static else Dynamics(scene.dt, e.mass_damping, e.stiffness_damping)
    model = ShellModel(
        scene.surface,
        scene.material,
        loads,
        [sc.constraint for sc in scene.constraints],
        hessian=scene.hessian,
        quadrature_points=scene.quadrature if scene.trim is None else scene.trim,
        comm=comm,
        dynamics=dynamics,
        point_constraints=[
            PointConstraint(p.xi1, p.xi2, p.target_at if p.motion is not None else p.target, p.components)
            for p in scene.point_constraints
        ],
    )
    if scene.initial_velocity is not None:  # a translation's entries: the rest surface moved by v, less the rest
        disc = model.discretization
        moved = scene.surface.transformed(np.eye(3), np.asarray(scene.initial_velocity))
        model.velocity.x.array[:] = disc.entries_to_open(disc.entries_of_surface(moved)
                                                         - disc.entries_of_surface(scene.surface))  # fmt: skip
    return model


def ipc_barrier(scene: Scene, model: ShellModel, scene_file: Path):
    """The :class:`~bhem_hpc.contact.ipc_contribution.IpcBarrier` of a scene with contact by ``ipc``,
    checked to start apart from its colliders (collective); None for a scene without it."""
    if scene.contact is None or scene.contact.method != "ipc":
        return None
    from bhem_hpc.contact.ipc_contribution import CoarseCollisionMesh
    from bhem_hpc.contact.ipc_friction import surface_friction
    from bhem_hpc.contact.ipc_setup import check_chord_gaps, scene_barrier, shell_mesh

    c, material = scene.contact, scene.material
    mesh = shell_mesh(model, c.collision_cells, material.density, material.thickness, c.self_collision,
                      surface_friction(c))  # fmt: skip
    barrier = scene_barrier([mesh], [0], model.global_open_blocks, model.comm, c, scene_file)
    try:
        check_chord_gaps([mesh], barrier.dhat)
    except CoarseCollisionMesh as exc:
        raise RunError(f"{scene_file}: key 'effects.contact.collision_cells' = {c.collision_cells}: {exc}") from exc
    problem = barrier.starting_problem(model.x.x.array)
    if problem is not None:
        raise RunError(f"{scene_file}: the shell starts in contact with its colliders or itself ('ipc' needs it "
                       f"apart): {problem}")  # fmt: skip
    return barrier


def build_contact(scene: Scene, model: ShellModel, problem: ShellProblem):
    """The scene's :class:`~bhem_hpc.contact.response.ContactHandler` for ``model`` and its ``problem``
    in the solver, or None: only scenes that list contact effects load the collision code (contact
    by ``ipc`` is the solver's barrier contribution, :func:`ipc_barrier`)."""
    if scene.contact is None or scene.contact.method == "ipc":
        return None
    from bhem_hpc.contact.response import ContactHandler

    return ContactHandler(model, problem, contact_detector(scene, model), contact_settings(scene))


def contact_detector(scene: Scene, model: ShellModel):
    """The :class:`~bhem_hpc.contact.detection.ContactDetector` of a scene with contact effects."""
    from bhem_hpc.contact.detection import ContactDetector

    c = scene.contact
    return ContactDetector(model.discretization.patches, c.colliders, c.samples_per_side, c.self_collision,
                           c.self_friction)  # fmt: skip


def contact_settings(scene: Scene):
    """The :class:`~bhem_hpc.contact.response.ContactSettings` of a scene with contact effects."""
    from bhem_hpc.contact.response import ContactSettings

    return ContactSettings(scene.contact.push_out, metric=scene.contact.metric)


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

    One run at a time writes ``out``: it holds ``out``'s lock (:class:`OutputLock`) from its checks
    to its end. Everything is checked before the output directory is touched; a run that fails after it started
    writing leaves ``summary.json`` with ``status: "failed"``, the error and the last completed
    step. A restart whose ``--out`` is its ``--restart`` directory continues that run's series and
    step records; a restart into another directory starts its series with the restart frame.
    """
    scene, checkpoint, continuing = _prepare(options, comm)
    lock = lock_output(options.out, comm)
    try:
        check_output(options, continuing, comm)
        if isinstance(scene, BodiesScene):
            from bhem_hpc.bodies.run import run_bodies  # it builds on this module's stages

            return run_bodies(options, scene, checkpoint, continuing, comm)
        return _run_locked(options, scene, checkpoint, continuing, comm)
    finally:
        if lock is not None:
            lock.release()


def lock_output(out: Path, comm: MPI.Comm) -> OutputLock | None:
    """Rank 0 takes the output directory's lock (None on the other ranks); every rank raises
    :class:`RunError` when another run holds it."""
    lock = OutputLock(out) if comm.rank == 0 else None
    _on_rank0_directory(comm, lambda: lock.acquire())
    return lock


def _run_locked(options: RunOptions, scene: Scene, checkpoint: RestartPoint | None, continuing: bool,
                comm: MPI.Comm) -> dict:  # fmt: skip
    """The run itself, once its output directory is locked and checked (see :func:`run_scene`)."""
    steps = steps_to_run(scene, options, checkpoint)
    scene_text = options.scene.read_bytes()  # before the output directory (which may hold it) is replaced

    model = build_model(scene, comm)
    disc = model.discretization
    if checkpoint is not None:  # the DOF layout of this model (rank count for B-splines) must match
        expected = ShellState(model).raw_position().shape
        if checkpoint.arrays["position_dofs"].shape != expected:
            raise RunError(
                f"{checkpoint.path}: its DOFs have shape {checkpoint.arrays['position_dofs'].shape}, "
                f"this run's {expected}"
            )
    barrier = ipc_barrier(scene, model, options.scene)
    solver = make_solver(model, scene, options.scene, [barrier] if barrier is not None else [])
    velocity_test = solver.problem.step_velocity_test
    summary = RunSummary(
        scene=str(options.scene),
        physics_hash=physics_hash(scene),
        solution_method=solution_method(scene),
        dofs=3 * disc.num_closed,
        nonzeros=solver.problem.matrix_nonzeros(),
        ranks=comm.size,
        versions=library_versions(),
        static=scene.static,
        linear_solver=solver.linear.as_dict(),
        contact=barrier.summary() if barrier is not None else None,
        factorization=scene.factorization,
        steps=previous_steps(options.out, checkpoint) if continuing else [],
        velocity_tolerance_m_s=None if velocity_test is None else velocity_test.tolerance,
    )
    run = _Run(options, scene, model, solver, ShellState(model), summary, comm)
    with summarized(summary, barrier, solver, options.out, comm, lambda: run.series and run.series.close()):
        run.series = _start_output(run, scene_text, checkpoint if continuing else None)
        with Interruption() as run.interruption:
            if scene.static:
                final = _run_static(run, steps, checkpoint, continuing)
            else:
                final = _run_dynamic(run, steps, checkpoint)
        where = f"load factor {summary.load_factor:.4g}" if scene.static else f"t = {summary.time or 0:.4g} s"
        title = f"{options.scene.name}, {where}"
        drawn = final if scene.trim is None else TrimmedSurface(final, scene.trim.loops)
        on_rank0(comm, lambda: render_surface_png(options.out / "last.png", drawn, title), "last.png")
    return summary.as_dict()


def make_solver(model: ShellModel | list[ShellModel], scene: Scene, scene_file: Path,
                contributions: list | None = None, shared_dofs: SharedDofs | None = None) -> ShellSolver:  # fmt: skip
    """The run's solver of ``model`` (or several bodies' models) with the scene's ``[solver]``
    settings (a scene of several bodies: any body's, they share them), the energy
    ``contributions`` (by default, of one shell, the barrier of its contact by ``ipc``) and the
    DOFs the bodies share."""
    if contributions is None:
        barrier = ipc_barrier(scene, model, scene_file)
        contributions = [barrier] if barrier is not None else []
    velocity = scene.velocity_tolerance if isinstance(scene, Scene) else None  # a solid's [solver] has no such key
    if velocity is not None and not isinstance(model, ShellModel):
        raise RunError(f"{scene_file}: key 'solver.velocity_tolerance' = {velocity!r} applies to a scene of one "
                       "shell; leave it out with several bodies")  # fmt: skip
    try:
        solver = ShellSolver(model, prefix=SOLVER_PREFIX, options=scene.petsc_options,
                             factorization=scene.factorization, linear=scene.linear, contributions=contributions,
                             acceleration_tolerance=scene.acceleration_tolerance, shared_dofs=shared_dofs)  # fmt: skip
    except LinearSolverError as exc:
        raise RunError(f"{scene_file}: key 'solver.linear' = {scene.linear!r}: {exc}") from None
    if velocity is not None:  # the line search and the energy trust region both take it
        tolerance = auto_velocity_tolerance(model.rest_diagonal) if velocity == "auto" else float(velocity)
        solver.problem.step_velocity_test = StepVelocityTest(tolerance, model.comm,
                                                             block_weights=model.discretization.open_block_weights())
    return solver


def _prepare(options: RunOptions, comm: MPI.Comm) -> tuple[Scene | BodiesScene, RestartPoint | None, bool]:
    """Every check before anything is built but the output directory's (done under its lock): the
    scene, ``--steps`` and the restart. Returns the scene, the restart checkpoint (or None) and
    whether the restart continues the run in its own directory."""
    scene = load_any_scene(options.scene)
    if options.steps is not None and options.steps < 1:
        raise RunError(f"--steps must be >= 1, got {options.steps}")
    if options.restart is None:
        return scene, None, False
    checkpoint = read_restart(options.restart, scene)
    continuing = _is_same_directory(options.restart, options.out)
    if isinstance(scene, BodiesScene):
        steps_to_run(scene.first, options, checkpoint)  # a finished run is refused before the output is touched
        if continuing:
            for name, body in zip(scene.names, scene.bodies, strict=True):
                check_same_probes(body, options.restart / name)
        return scene, checkpoint, continuing
    check_path_left(scene, checkpoint)
    if continuing:
        check_same_probes(scene, options.restart)
    return scene, checkpoint, continuing


def _start_output(run: _Run, scene_text: bytes, continued: RestartPoint | None) -> SurfaceTimeSeries | None:
    """Rank 0: a fresh output directory (or the continued one), the scene, a running summary and the
    time series (continuing ``continued``'s checkpoint time, if given); None on other ranks."""
    out, scene = run.options.out, run.scene

    def start() -> SurfaceTimeSeries:
        if continued is None:
            start_output_directory(out)
        write_replacing(out / "scene.toml", scene_text)
        run.summary.write(out)
        return SurfaceTimeSeries(
            out / "surface.xdmf", scene.surface, scene.material, scene.written_density,
            continue_at=None if continued is None else float(continued.attrs["time"]), trim=scene.trim,
        )  # fmt: skip

    return on_rank0(run.comm, start, f"the output directory {out}")


def steps_to_run(scene: Scene, options: RunOptions, checkpoint: RestartPoint | None) -> int:
    """``--steps``, or the steps left to the scene's end (all of them without a restart)."""
    if scene.static:  # --steps bounds the path points of this run
        return options.steps if options.steps is not None else scene.path_plan.point_count
    if options.steps is not None or checkpoint is None:
        return options.steps if options.steps is not None else scene.steps
    done = checkpoint.step
    if done >= scene.steps:
        raise RunError(
            f"--restart {options.restart}: the checkpoint is at step {done}, the scene's last "
            f"({scene.steps} steps): pass --steps to continue past it"
        )
    return scene.steps - done


class StepRecords:
    """``summary.json``'s step records, each also appended to ``steps.jsonl`` (collective
    :meth:`add`; call it before the step's checkpoint, so that a restart finds it)."""

    def __init__(self, out: Path, summary: RunSummary, comm: MPI.Comm):
        self.summary, self.comm = summary, comm
        self.table = JsonLinesTable(out / "steps.jsonl", summary.steps) if comm.rank == 0 else None

    def add(self, row: dict) -> None:
        self.summary.steps.append(row)
        on_rank0(self.comm, lambda: self.table.add(row), "steps.jsonl")


def _energies(model: ShellModel) -> dict[str, float]:
    e = model.energies()
    return {k: float(v) for k, v in e.items()}


def _run_static(run: _Run, steps: int, checkpoint: RestartPoint | None, continuing: bool) -> HermiteSurface:
    """Follow ``steps`` more points of a static scene's path (:class:`~bhem_hpc.model.path.PathPlan`),
    writing per converged point a frame, a row of ``path.csv`` and of the summary, and a checkpoint;
    ``path.png`` at the end (also when a step fails or a signal stops the run after a point: the
    converged part stays in every file). Returns the final surface."""
    from bhem_hpc.solver.path import PathError, PathFollower

    scene, options, model, solver, summary = run.scene, run.options, run.model, run.solver, run.summary
    plan: PathPlan = scene.path_plan
    start, first_step, previous, arc_step = (0.0, 0.0), 0, None, None
    if checkpoint is not None:
        arrays, attrs = checkpoint.arrays, checkpoint.attrs
        disc = model.discretization
        run.state.set_raw(arrays["position_dofs"])
        previous = disc.open_to_closed(disc.scatter_raw_dofs(arrays["previous_position_dofs"]))
        start, first_step = (float(attrs["load_factor"]), float(attrs.get("arc_length", 0.0))), int(attrs["step"])
        arc_step = float(attrs.get("arc_step", np.nan))
    motions = prescribed_motions(scene)
    if motions:  # a motion's time is the load factor: rotations turn the nodal vectors along the path
        solver.prescribed = lambda factor: model.prescribed_values([m.at(factor) for m in motions])
    output = _PathOutput(run, first_step if continuing else None)
    follower = PathFollower(solver, scene.probes, SOLVER_PREFIX + "path_", plan.options, *start, previous,
                            first_step, on_point=output.write)  # fmt: skip
    output.follower = follower
    if checkpoint is not None:  # the next point's checkpoint names its previous point: the path's direction
        output.previous_raw = checkpoint.arrays["position_dofs" if continuing else "previous_position_dofs"]
    try:
        if not continuing:  # a new series starts with the path's start (or the restart point)
            output.write(follower.path[0])
        _follow(plan, follower, first_step, steps, arc_step)
    except PathError as exc:
        raise RunError(str(exc)) from exc
    finally:
        output.plot(options.scene.name)
        follower.close()
    summary.time, summary.load_factor, summary.path_method = output.last_time, follower.load_factor, plan.method
    return output.surface


def _follow(plan: PathPlan, follower, done: int, count: int, arc_step: float | None) -> None:
    """Run ``count`` more points of ``plan`` after the ``done`` already on the path (arc length
    continues with the checkpoint's adapted step ``arc_step``)."""
    from dataclasses import replace

    settings = plan.arc_length
    if plan.method == "load":
        follower.load_control(plan.levels[done : done + count], max_cuts=plan.max_cuts)
    elif plan.method == "displacement":
        follower.displacement_control(plan.probe, plan.component, plan.values[done : done + count],
                                      max_cuts=plan.max_cuts)  # fmt: skip
    else:
        step = arc_step if arc_step is not None and np.isfinite(arc_step) else settings.initial_step
        step = float(np.clip(step, settings.min_step, settings.max_step))
        follower.arc_length(replace(settings, initial_step=step, min_step=min(settings.min_step, step),
                                    max_steps=min(count, plan.point_count - done)))  # fmt: skip


class _PathOutput:
    """The files of a static run, one update per converged path point (collective :meth:`write`)."""

    def __init__(self, run: _Run, continued_step: int | None):
        out, scene = run.options.out, run.scene
        self.out, self.model, self.plan, self.series = out, run.model, scene.path_plan, run.series
        self.summary, self.comm, self.state = run.summary, run.comm, run.state
        self.records = StepRecords(out, run.summary, run.comm)
        self.interruption, self.scene_path = run.interruption, run.options.scene
        self.probes = [p.name for p in scene.probes]
        keep = read_rows(out / "path.csv", continued_step) if continued_step is not None else []
        self.table = CsvTable(out / "path.csv", keep) if run.comm.rank == 0 else None
        self.previous_raw = None
        self.follower = None
        self.surface = None
        self.last_time = 0.0
        self.started = time.perf_counter()

    def write(self, point) -> None:
        """Frame, path.csv and summary rows, then the checkpoint (with the previous point's DOFs);
        a stop signal then ends the run (:class:`RunInterrupted`)."""
        time_value = point.load_factor if self.plan.time_is_load_factor else point.arc_length
        raw = self.state.raw_position()
        previous = raw if self.previous_raw is None else self.previous_raw
        extra = {"position_dofs": raw, "previous_position_dofs": previous}
        attrs = {"load_factor": point.load_factor, "arc_length": point.arc_length}
        if self.follower is not None and np.isfinite(self.follower.arc_step):
            attrs["arc_step"] = self.follower.arc_step
        self.surface = _write_frame(self.series, self.model, time_value, self.comm)
        self.previous_raw = raw
        self.last_time = time_value
        row = {"step": point.step, "load_factor": point.load_factor, "arc_length": point.arc_length,
               "newton_iterations": point.newton_iterations, "failed_attempts": point.failed_attempts,
               "negative_pivots": point.negative_pivots,
               "stable": point.stable, "event": point.event,
               "event_load_factor": point.events[0].load_factor if point.events else ""}  # fmt: skip
        row |= {f"energy_{k}": float(v) for k, v in point.energies.items()} | probe_columns(point.probes)
        on_rank0(self.comm, lambda: self.table.add(row), "path.csv")
        now = time.perf_counter()
        self.records.add(row | {"events": [e.as_dict() for e in point.events], "wall_s": now - self.started})
        self.started = now  # the checkpoint's time counts to the next point
        _checkpoint(self.out / "checkpoint.h5", self.state, self.surface, (time_value, point.step), self.summary,
                    self.comm, extra, attrs)  # fmt: skip
        stop = self.interruption.requested(self.comm)
        if stop is not None:
            raise RunInterrupted(
                f"{self.scene_path}: stopped by {stop} after path point {point.step} (load factor "
                f"{point.load_factor:.6g}); its state is the last frame and the checkpoint: continue with "
                f"--restart {self.out}"
            )

    def plot(self, title: str) -> None:
        def draw() -> None:
            if len(self.table.rows) > 1:
                plot_path(self.table.rows, self.probes, self.out / "path.png", title)

        on_rank0(self.comm, draw, "path.png")


def _run_dynamic(run: _Run, steps: int, checkpoint: RestartPoint | None) -> HermiteSurface:
    """Step a dynamic scene, writing frames and checkpoints; returns the final surface. A stop
    signal (``run.interruption``) ends it after the step in progress, written, with
    :class:`RunInterrupted`."""
    scene, options, model, solver, summary = run.scene, run.options, run.model, run.solver, run.summary
    series, comm, interruption = run.series, run.comm, run.interruption
    contact = build_contact(scene, model, solver.problem)
    if contact is not None:
        summary.contact = {"colliders": len(scene.contact.colliders), "sample_points": contact.detector.num_samples}
    stepper = TimeStepper(model, solver, prescribed_motions(scene), contact=contact, state=run.state)
    if checkpoint is not None:
        arrays, attrs = checkpoint.arrays, checkpoint.attrs
        restore_solver(solver, arrays, attrs, "factorization_state_dofs" in arrays)
        stepper.state.set_raw(arrays["position_dofs"], arrays["velocity_dofs"])
        stepper.time, stepper.step = float(attrs["time"]), int(attrs["step"])
    surface = model.state_surface()
    probes = _ProbeTable(options.out, model, scene, stepper.step if checkpoint is not None else None, comm)
    if comm.bcast(series is not None and not series.times):  # a continued series has its restart frame
        on_rank0(comm, lambda: series.write(stepper.time, surface), "a frame")
        probes.write(stepper)
    progress = progress_bar(steps, options.progress and comm.rank == 0)
    records = StepRecords(options.out, summary, comm)
    last_summary = time.perf_counter()
    checkpoint_s = 0.0  # a checkpoint's write time counts to the next step's output_s
    try:
        for k in range(steps):
            record = stepper.advance()
            t_out = time.perf_counter()
            stop = interruption.requested(comm)  # every rank stops after the same step
            # the last step always writes, and so does one a signal stops after
            wrote = stepper.step % scene.output_every == 0 or k == steps - 1 or stop is not None
            if wrote:
                surface = _write_frame(series, model, stepper.time, comm)
            probes.write(stepper)
            energies = _energies(model) if wrote else None  # a few assemblies: with the frames only
            records.add(step_summary(record, time.perf_counter() - t_out + checkpoint_s, energies))
            t_checkpoint = time.perf_counter()
            if wrote:  # after the step's rows: a restart from it finds them all
                arrays, attrs = solver_checkpoint(solver)  # a continued run remakes the kept factorization
                _checkpoint(options.out / "checkpoint.h5", run.state, surface, (stepper.time, stepper.step), summary,
                            comm, arrays, attrs)  # fmt: skip
            # summary.json shows the records so far, at most every SUMMARY_EVERY_S (a restart reads
            # them from steps.jsonl)
            if wrote and comm.bcast(time.perf_counter() - last_summary >= SUMMARY_EVERY_S):
                on_rank0(comm, lambda: summary.write(options.out), "summary.json")
                last_summary = time.perf_counter()
            checkpoint_s = time.perf_counter() - t_checkpoint
            progress(record, stepper)
            if stop is not None:
                summary.time = stepper.time
                raise RunInterrupted(
                    f"{options.scene}: stopped by {stop} after step {stepper.step} (t = {stepper.time:.6g} s); its "
                    f"state is the last frame and the checkpoint: continue with --restart {options.out}"
                )
    except StepFailure as exc:
        raise RunError(str(exc)) from exc
    finally:
        progress(None, stepper)
        if contact is not None:
            contact.close()
    summary.time = stepper.time
    return surface


class _ProbeTable:
    """``probes.csv`` of a dynamic run: time, step and every probe's position and displacement per
    step (continuing the rows of a run continued in place)."""

    def __init__(self, out: Path, model: ShellModel, scene: Scene, restart_step: int | None, comm: MPI.Comm):
        self.comm = comm
        self.probes = ProbeSet(model, scene.probes) if scene.probes else None
        keep = read_rows(out / "probes.csv", restart_step) if restart_step is not None else []
        self.table = CsvTable(out / "probes.csv", keep) if comm.rank == 0 and self.probes else None

    def write(self, stepper: TimeStepper) -> None:
        """A row for the stepper's current state (collective)."""
        if self.probes is None:
            return
        row = {"step": stepper.step, "time": stepper.time} | probe_columns(self.probes.record())
        on_rank0(self.comm, lambda: self.table.add(row), "probes.csv")


def step_summary(record: StepRecord, output_s: float, energies: dict[str, float] | None) -> dict:
    """A step's row of ``summary.json`` (the energies at steps that wrote a frame)."""
    names = ("step", "time", "newton_iterations", "recoveries", "dt_halvings", "regularized_retries",
             "trust_region_solves", "trust_region_failures", "negative_pivots", "regularized_iterations",
             "projected_iterations", "refactorizations", "chord_iterations", "refactor_retries",
             "krylov_iterations", "collider_pushes", "start_guesses")  # fmt: skip
    row = {name: getattr(record, name) for name in names}
    row["wall_s"] = record.wall_s + output_s
    for name in ("assembly_s", "factorization_s", "linear_solve_s", "collision_s", "contacts"):
        row[name] = getattr(record, name)
    row["output_s"] = output_s
    return row if energies is None else row | {"energies": energies}


def _write_frame(series, model: ShellModel, time_value: float, comm: MPI.Comm) -> HermiteSurface:
    """Write the current state as a frame of the series; returns it as a surface (every rank)."""
    surface = model.state_surface()
    on_rank0(comm, lambda: series.write(time_value, surface), "a frame of surface.h5")
    return surface


def _checkpoint(
    path: Path, state: ShellState, surface: HermiteSurface, clock: tuple[float, int], summary: RunSummary,
    comm: MPI.Comm, arrays: dict, attrs: dict,
) -> None:  # fmt: skip
    """Write the state at ``clock`` = (time, step) (a static run: zero velocity, the path point's
    load factor and the previous point's DOFs in ``arrays`` and ``attrs``; the position's raw DOFs
    are gathered unless ``arrays`` holds them already)."""
    position = arrays.get("position_dofs")
    if position is None:
        position = state.raw_position()
    data = {"position_dofs": position, "velocity_dofs": state.raw_velocity(), "position_nodal": surface.nodal}
    meta = checkpoint_attributes(clock, summary, state.model.dynamics is None) | attrs
    data |= arrays
    on_rank0(comm, lambda: write_checkpoint(path, data, meta), path.name)


def checkpoint_attributes(clock: tuple[float, int], summary: RunSummary, static: bool) -> dict:
    """A checkpoint's identity and clock: time, step, the run's physics hash and solution method."""
    return {"time": clock[0], "step": clock[1], "physics_hash": summary.physics_hash,
            "solution_method": canonical_json(summary.solution_method), "static": static}  # fmt: skip


def progress_bar(total: int, enabled: bool):
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
