"""Run a scene of several bodies (``[[bodies]]``): one Newton solve per time step for all bodies,
each body's ParaView series in a folder of its own, one collection of them all.

The output directory holds ``scene.toml``, ``summary.json`` and ``steps.jsonl`` as a run of one body
does, ``<body>/surface.xdmf`` (``.h5``, ``.pvd`` and ``surface_frames/``) and ``<body>/probes.csv``
for each body, ``bodies.pvd`` (every body's frames as the parts of one ParaView collection) and
``last.png`` (every body ray traced, each in its colour). Collective: every rank calls
:func:`run_bodies`; rank 0 writes files. A scene of several bodies writes no checkpoint: it is run
from its start.
"""

from __future__ import annotations

import hashlib
import time
from pathlib import Path

from mpi4py import MPI

from bhem_hpc.bodies.body import ShellBody
from bhem_hpc.errors import RunError
from bhem_hpc.geometry.surface import HermiteSurface
from bhem_hpc.io import render_surface_png
from bhem_hpc.io.interruption import Interruption, RunInterrupted
from bhem_hpc.io.path_table import CsvTable, probe_columns
from bhem_hpc.io.run_directory import start_output_directory, write_replacing
from bhem_hpc.io.run_summary import RunSummary
from bhem_hpc.io.vtu import write_pvd
from bhem_hpc.model.path import ProbeSet
from bhem_hpc.restart import canonical_json, solution_method
from bhem_hpc.run import (
    SOLVER_PREFIX,
    RunOptions,
    StepRecords,
    build_model,
    close_solver,
    contact_detector,
    contact_settings,
    make_solver,
    on_rank0,
    prescribed_motions,
    progress_bar,
    record_failure,
    step_summary,
)
from bhem_hpc.scene.bodies import BodiesScene
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.dynamics import PrescribedMotion, StepFailure, TimeStepper
from bhem_hpc.solver.petsc import library_versions


class BodiesOutput:
    """Rank 0's files of a run of several bodies: each body's time series and probe table, and the
    collection of all bodies' frames (``bodies.pvd``)."""

    def __init__(self, out: Path, bodies: list[ShellBody]):
        self.out = out
        self.names = [body.name for body in bodies]
        self.series = []
        for body in bodies:
            (out / body.name).mkdir()
            self.series.append(body.writer(out / body.name / "surface.xdmf"))
        self.probe_tables = [CsvTable(out / body.name / "probes.csv", []) if body.scene.probes else None
                             for body in bodies]  # fmt: skip

    def write(self, time_value: float, surfaces: list[HermiteSurface]) -> None:
        """A frame of every body at ``time_value``, and the collection listing every frame so far."""
        for series, surface in zip(self.series, surfaces, strict=True):
            series.write(time_value, surface)
        frames, parts = [], []
        for part, (name, series) in enumerate(zip(self.names, self.series, strict=True)):
            for t, file in series.frame_files():
                frames.append((t, f"{name}/{file}"))
                parts.append(part)
        write_pvd(self.out / "bodies.pvd", frames, parts)

    def close(self) -> None:
        for series in self.series:
            series.close()


def _physics_hash(scene: BodiesScene) -> str:
    raw = {k: v for k, v in scene.raw.items() if k != "output"}
    return hashlib.sha256(canonical_json(raw).encode()).hexdigest()[:16]


def _motions(scene: BodiesScene) -> list[PrescribedMotion]:
    """Every body's prescribed motions, each naming its body."""
    return [PrescribedMotion(m.constraint, m.values, body=k)
            for k, body in enumerate(scene.bodies) for m in prescribed_motions(body)]  # fmt: skip


def run_bodies(options: RunOptions, scene: BodiesScene, comm: MPI.Comm) -> dict:
    """Run ``scene`` into ``options.out`` (locked and checked by the caller, which refuses a restart);
    returns the summary."""
    first = scene.first
    steps = options.steps if options.steps is not None else first.steps
    scene_text = options.scene.read_bytes()
    bodies = [ShellBody(name, k, body, build_model(body, comm))
              for k, (name, body) in enumerate(zip(scene.names, scene.bodies, strict=True))]  # fmt: skip
    models = [body.model for body in bodies]
    solver = make_solver(models, first, options.scene)
    summary = RunSummary(
        scene=str(options.scene), physics_hash=_physics_hash(scene), solution_method=solution_method(first),
        dofs=solver.bodies.closed_sizes[1], nonzeros=solver.problem.matrix_nonzeros(), ranks=comm.size,
        versions=library_versions(), static=False, linear_solver=solver.linear.as_dict(),
        factorization=first.factorization,
        bodies=[{"name": body.name, "dofs": 3 * body.model.discretization.num_closed, "mass_kg": body.mass(),
                 "discretization": body.scene.surface.discretization} for body in bodies],
    )  # fmt: skip
    output: BodiesOutput | None = None
    try:

        def start() -> BodiesOutput:
            start_output_directory(options.out, list(scene.names))
            write_replacing(options.out / "scene.toml", scene_text)
            summary.write(options.out)
            return BodiesOutput(options.out, bodies)

        output = on_rank0(comm, start, f"the output directory {options.out}")
        surfaces = _step(options, scene, bodies, solver, summary, output, steps)
        title = f"{options.scene.name}, t = {summary.time or 0:.4g} s"
        on_rank0(comm, lambda: render_surface_png(options.out / "last.png", surfaces, title), "last.png")
    except Exception as exc:
        record_failure(summary, exc, options.out, comm)
        raise
    finally:
        if output is not None:
            output.close()
        close_solver(solver, summary, comm)
    summary.status = "completed"
    on_rank0(comm, lambda: summary.write(options.out), "summary.json")
    return summary.as_dict()


def _frame(output: BodiesOutput | None, models: list, probes: list, stepper: TimeStepper,
           comm: MPI.Comm) -> list[HermiteSurface]:  # fmt: skip
    """Write every body's frame and probe row at the stepper's state (collective); returns the surfaces."""
    surfaces = [m.state_surface() for m in models]
    on_rank0(comm, lambda: output.write(stepper.time, surfaces), "a frame of the bodies")
    for k, probe_set in enumerate(probes):
        if probe_set is not None:
            row = {"step": stepper.step, "time": stepper.time} | probe_columns(probe_set.record())
            on_rank0(comm, lambda k=k, row=row: output.probe_tables[k].add(row), "probes.csv")
    return surfaces


def bodies_contact(bodies: list[ShellBody], solver: ShellSolver):
    """The :class:`~bhem_hpc.contact.response.ContactHandler` of every body whose effects list contact
    (their colliders, themselves and each other) in ``solver`` (made of the bodies' models), or None."""
    in_contact = [body.scene.contact is not None for body in bodies]
    if not any(in_contact):
        return None
    from bhem_hpc.contact.bodies import BodiesDetector, StackedEntries
    from bhem_hpc.contact.response import ContactHandler

    models = [body.model for body in bodies]
    entries = StackedEntries([m.discretization for m in models], [m.x.x.array.size for m in models])
    detectors = [contact_detector(body.scene, body.model) if body.scene.contact is not None else None
                 for body in bodies]  # fmt: skip
    frictions = [body.scene.contact.friction if body.scene.contact is not None else 0.0 for body in bodies]
    detector = BodiesDetector(entries, detectors, frictions)
    settings = contact_settings(bodies[in_contact.index(True)].scene)
    prefixes = [f"{SOLVER_PREFIX}contact_{body.name}_" for body in bodies]
    return ContactHandler.between_bodies(models, solver.problem.problems, detector, settings, prefixes)


def _step(options: RunOptions, scene: BodiesScene, bodies: list[ShellBody], solver: ShellSolver,
          summary: RunSummary, output: BodiesOutput | None, steps: int) -> list[HermiteSurface]:  # fmt: skip
    """Advance every body ``steps`` time steps with the bodies' contact handler (closed at the end);
    returns the bodies' final surfaces."""
    handler = bodies_contact(bodies, solver)
    if handler is not None:
        summary.contact = {body.name: {"colliders": len(body.scene.contact.colliders), "sample_points": d.num_samples}
                           for body, d in zip(bodies, handler.detector.detectors, strict=True)
                           if d is not None}  # fmt: skip
    models = [body.model for body in bodies]
    try:
        return _advance(options, scene, models, TimeStepper(models, solver, _motions(scene), contact=handler),
                        summary, output, steps)  # fmt: skip
    finally:
        if handler is not None:
            handler.close()


def _advance(options: RunOptions, scene: BodiesScene, models: list, stepper: TimeStepper, summary: RunSummary,
             output: BodiesOutput | None, steps: int) -> list[HermiteSurface]:  # fmt: skip
    """The time steps: frames every ``output.every`` steps, the last one and one a stop signal ends
    with; a step record each; returns the bodies' final surfaces."""
    probes = [ProbeSet(m, body.probes) if body.probes else None for m, body in zip(models, scene.bodies, strict=True)]
    surfaces = _frame(output, models, probes, stepper, comm := stepper.solver.bodies.comm)
    records = StepRecords(options.out, summary, comm)
    progress = progress_bar(steps, options.progress and comm.rank == 0)
    every = scene.first.output_every
    try:
        with Interruption() as interruption:
            for k in range(steps):
                record = stepper.advance()
                t_out = time.perf_counter()
                stop = interruption.requested(comm)  # every rank stops after the same step
                if stepper.step % every == 0 or k == steps - 1 or stop is not None:
                    surfaces = _frame(output, models, probes, stepper, comm)
                records.add(step_summary(record, time.perf_counter() - t_out, None))
                summary.time = stepper.time
                progress(record, stepper)
                if stop is not None:
                    raise RunInterrupted(f"{options.scene}: stopped by {stop} after step {stepper.step} "
                                         f"(t = {stepper.time:.6g} s); its state is the last frame")  # fmt: skip
    except StepFailure as exc:
        raise RunError(str(exc)) from exc
    finally:
        progress(None, stepper)
    return surfaces
