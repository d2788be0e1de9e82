"""Run a scene of several bodies (``[[bodies]]``): one Newton solve per time step for all bodies,
each body's ParaView series in a folder of its own, one collection of them all.

The output directory holds ``scene.toml``, ``summary.json`` and ``steps.jsonl`` as a run of one body
does, ``<body>/surface.xdmf`` (``.h5``, ``.pvd`` and ``surface_frames/``) and ``<body>/probes.csv``
for each body, ``bodies.pvd`` (every body's frames as the parts of one ParaView collection) and
``last.png`` (every body ray traced, each in its colour), and ``checkpoint.h5`` with every body's
state (arrays numbered by body, :func:`~bhem_hpc.bodies.layout.body_array_name`) at each frame:
``--restart`` continues the run in its own directory (its series, probe tables and step records)
or into another one, as a run of one body. Collective: every rank calls :func:`run_bodies`; rank 0
writes files.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from bhem_hpc.bodies.body import Body, ShellBody
from bhem_hpc.bodies.layout import body_array_name
from bhem_hpc.bodies.petsc import StackedBlocks
from bhem_hpc.bodies.shared_dofs import SharedDofs
from bhem_hpc.bodies.solid import SolidBody, build_solid_model
from bhem_hpc.errors import RunError
from bhem_hpc.geometry.surface import HermiteSurface
from bhem_hpc.io import render_surface_png, write_checkpoint
from bhem_hpc.io.cad import ShellPart, write_parts
from bhem_hpc.io.interruption import Interruption, RunInterrupted
from bhem_hpc.io.path_table import CsvTable, probe_columns, read_rows
from bhem_hpc.io.render import TrimmedSurface
from bhem_hpc.io.run_directory import start_output_directory, write_replacing
from bhem_hpc.io.run_summary import RunSummary
from bhem_hpc.io.vtu import write_pvd
from bhem_hpc.model.path import ProbeSet
from bhem_hpc.restart import (
    RestartPoint,
    physics_hash,
    previous_steps,
    restore_solver,
    solution_method,
    solver_checkpoint,
)
from bhem_hpc.run import (
    SOLVER_PREFIX,
    RunOptions,
    StepRecords,
    build_model,
    checkpoint_attributes,
    contact_settings,
    make_solver,
    prescribed_motions,
    progress_bar,
    step_summary,
    steps_to_run,
)
from bhem_hpc.run_ending import on_rank0, summarized
from bhem_hpc.scene import Scene
from bhem_hpc.scene.bodies import BodiesScene
from bhem_hpc.scene.solids import SolidScene
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.dynamics import PrescribedMotion, StepFailure, TimeStepper, body_state
from bhem_hpc.solver.petsc import library_versions
from bhem_hpc.solver.state import StackedState

log = logging.getLogger(__name__)


class BodiesOutput:
    """Rank 0's files of a run of several bodies: each body's time series and probe table, the
    collection of all bodies' frames (``bodies.pvd``), and each CAD shell's deformed model at every
    frame (``<name>/frame_NNNNNN.igs``: one NURBS part per part of its file, exact, trimmed where
    it is, a part's pieces joined back; the result opens in the modeller it came from).

    Args:
        continued: the checkpoint of the run continued in ``out`` (its frames and probe rows up to
            the checkpoint are kept), or None for a fresh ``out``.
        cad_models: the CAD shells' reports (:meth:`CadShell.report`: ``body``, ``patch_bodies``).
    """

    def __init__(self, out: Path, bodies: list[Body], continued: RestartPoint | None = None,
                 cad_models: Sequence[dict] = ()):  # fmt: skip
        self.out = out
        self.names = [body.name for body in bodies]
        self.bodies = bodies
        self.cad_models = [(m["body"], [self.names.index(b) for b in m["patch_bodies"]]) for m in cad_models]
        for model, _ in self.cad_models:
            (out / model).mkdir(exist_ok=continued is not None)
        self.series = []
        continue_at = None if continued is None else float(continued.attrs["time"])
        for body in bodies:
            (out / body.name).mkdir(exist_ok=continued is not None)
            self.series.append(body.writer(out / body.name / "surface.xdmf", continue_at))
        self.probe_tables = [
            CsvTable(out / body.name / "probes.csv",
                     read_rows(out / body.name / "probes.csv", continued.step) if continued is not None else [])
            if body.scene.probes else None
            for body in bodies
        ]  # fmt: skip

    def write(self, time_value: float, surfaces: list) -> None:
        """A frame of every body at ``time_value``, and the collection listing every frame so far."""
        for series, surface in zip(self.series, surfaces, strict=True):
            series.write(time_value, surface)
        for model, members in self.cad_models:
            frame = len(self.series[members[0]].times) - 1
            labels = {k: self.names[k].removeprefix(model + "_") for k in members}
            write_parts(self.out / model / f"frame_{frame:06d}.igs",
                        model_parts(model, [(labels[k], surfaces[k], self.bodies[k]) for k in members]))
        frames, parts = [], []
        for part, (name, series) in enumerate(zip(self.names, self.series, strict=True)):
            for t, file in series.frame_files():
                frames.append((t, f"{name}/{file}"))
                parts.append(part)
        write_pvd(self.out / "bodies.pvd", frames, parts)

    def close(self) -> None:
        for series in self.series:
            series.close()


def model_parts(model: str, patches: list[tuple[str, object, Body]]) -> list[ShellPart]:
    """A CAD shell's patches ``(label, surface, body)`` as the parts of its model file, in the
    model's order: a part cut at its C0 knots into pieces (labels ``<part>_<i>_<j>``) joined back
    into one (:func:`~bhem_hpc.geometry.rational_bspline.join_pieces`)."""
    from bhem_hpc.geometry.rational_bspline import join_pieces  # the CAD geometry loads for CAD models only

    parts: dict[str, dict[tuple[int, int], tuple[object, Body]]] = {}
    for label, surface, body in patches:
        part, _, piece = label.partition("_")
        place = tuple(int(k) for k in piece.split("_")) if piece else (0, 0)
        parts.setdefault(part, {})[place] = (surface, body)
    out = []
    for part, pieces in parts.items():
        if len(pieces) == 1:
            surface, body = pieces[0, 0]
            out.append(cad_part(surface, body, f"{model} {part}"))
            continue
        rows, columns = (max(place[a] for place in pieces) + 1 for a in (0, 1))
        grid = [[pieces[i, j][0].nurbs() for j in range(columns)] for i in range(rows)]
        out.append(ShellPart(join_pieces(grid, f"{model} {part}")))
    return out


def cad_part(surface, body: Body, name: str) -> ShellPart:
    """A patch's surface as the NURBS part of a model file, with its trim loops in the part's own
    parameters where it is trimmed."""
    trim = body.scene.trim if isinstance(body.scene, Scene) else None
    loops = None if trim is None else tuple(np.column_stack(surface.model_parameters(loop[:, 0], loop[:, 1]))
                                            for loop in trim.loops)  # fmt: skip
    return ShellPart(surface.nurbs(name), loops)


def _motions(scene: BodiesScene) -> list[PrescribedMotion]:
    """Every body's prescribed motions, each naming its body."""
    return [PrescribedMotion(m.constraint, m.values, body=k)
            for k, body in enumerate(scene.bodies) for m in prescribed_motions(body)]  # fmt: skip


def run_bodies(options: RunOptions, scene: BodiesScene, checkpoint: RestartPoint | None, continuing: bool,
               comm: MPI.Comm) -> dict:  # fmt: skip
    """Run ``scene`` into ``options.out`` (locked and checked by the caller), from its start or from
    ``checkpoint`` (checked by the caller; ``continuing``: in its own directory); returns the summary."""
    first = scene.first
    steps = steps_to_run(first, options, checkpoint)
    scene_text = options.scene.read_bytes()
    bodies = [make_body(name, k, body, comm) for k, (name, body) in enumerate(zip(scene.names, scene.bodies,
                                                                                  strict=True))]  # fmt: skip
    models = [body.model for body in bodies]
    for model in scene.cad_models:
        if comm.rank == 0:
            log.info("%s: %d parts in %d patches, %d joints, free edges: %s; edges trimmed away: %s; trimmed parts "
                     "joined to nothing along their trims: %s; patches within %.3g m of their parts", model["body"],
                     model["parts"], model["patches"], len(model["joints"]), ", ".join(model["free_edges"]) or "none",
                     ", ".join(model["trimmed_edges"]) or "none",
                     ", ".join(model["trimmed_parts_joined_to_nothing_along_their_trims"]) or "none",
                     model["fit_error_m"])  # fmt: skip
    blocks = StackedBlocks(models)  # where the barrier and the couplings see every body's blocks
    barrier = bodies_barrier(bodies, blocks, scene, options.scene)
    couplings = interface_couplings(scene, bodies, blocks)
    shared = [record.shared for record in scene.interfaces if record.shared is not None]
    solver = make_solver(models, first, options.scene, ([barrier] if barrier is not None else []) + couplings,
                         SharedDofs.join(shared) if shared else None)  # fmt: skip
    summary = RunSummary(
        scene=str(options.scene), physics_hash=physics_hash(scene), solution_method=solution_method(first),
        dofs=solver.x.getSize(), nonzeros=solver.problem.matrix_nonzeros(), ranks=comm.size,
        versions=library_versions(), static=False, linear_solver=solver.linear.as_dict(),
        factorization=first.factorization,
        bodies=[{"name": body.name, "dofs": body.dofs, "mass_kg": body.mass(), "discretization": body.kind}
                for body in bodies],
        steps=previous_steps(options.out, checkpoint) if continuing else [],
        interfaces=[record.summary() for record in scene.interfaces] or None,
        cad_models=list(scene.cad_models) or None,
    )  # fmt: skip
    output: BodiesOutput | None = None
    with summarized(summary, barrier, solver, options.out, comm, lambda: output and output.close()):

        def start() -> BodiesOutput:
            if not continuing:
                start_output_directory(options.out, list(scene.names), [m["body"] for m in scene.cad_models])
            write_replacing(options.out / "scene.toml", scene_text)
            summary.write(options.out)
            return BodiesOutput(options.out, bodies, checkpoint if continuing else None, scene.cad_models)

        if barrier is not None:
            summary.contact = {**barrier.summary(), "bodies": [b.name for b in bodies if b.scene.contact is not None]}
        output = on_rank0(comm, start, f"the output directory {options.out}")
        run = _BodiesRun(options, scene, bodies, solver, summary, output, comm)
        surfaces = _step(run, checkpoint, continuing, steps)
        title = f"{options.scene.name}, t = {summary.time or 0:.4g} s"
        drawn = [s if not isinstance(b.scene, Scene) or b.scene.trim is None else TrimmedSurface(s, b.scene.trim.loops)
                 for b, s in zip(bodies, surfaces, strict=True)]  # fmt: skip
        on_rank0(comm, lambda: render_surface_png(options.out / "last.png", drawn, title), "last.png")
    return summary.as_dict()


def make_body(name: str, index: int, scene, comm: MPI.Comm) -> Body:
    """Collective: the body of a ``[[bodies]]`` table by its type (a solid's record or a shell's scene)."""
    if isinstance(scene, SolidScene):
        return SolidBody(name, index, scene, build_solid_model(scene, comm, name))
    return ShellBody(name, index, scene, build_model(scene, comm))


def _frame(output: BodiesOutput | None, models: list, stepper: TimeStepper, comm: MPI.Comm) -> list[HermiteSurface]:
    """Write every body's frame at the stepper's state (collective); returns the surfaces."""
    surfaces = [m.state_surface() for m in models]
    on_rank0(comm, lambda: output.write(stepper.time, surfaces), "a frame of the bodies")
    return surfaces


def _probe_rows(output: BodiesOutput | None, probes: list, stepper: TimeStepper, comm: MPI.Comm) -> None:
    """Every body's probe row at the stepper's state (collective)."""
    for k, probe_set in enumerate(probes):
        if probe_set is not None:
            row = {"step": stepper.step, "time": stepper.time} | probe_columns(probe_set.record())
            on_rank0(comm, lambda k=k, row=row: output.probe_tables[k].add(row), "probes.csv")


def interface_couplings(scene: BodiesScene, bodies: list[Body], blocks: StackedBlocks) -> list:
    """Collective: the penalty couplings of the scene's interfaces (joints and seams between its
    shell bodies; :mod:`bhem_hpc.bodies.coupling`): the stiffer side's stiffness over the narrower
    side's element, the angle term for joints and for seams that keep their angle, the displacement
    term where the patches do not share their edge's data."""
    if not scene.interfaces:
        return []
    from bhem_hpc.bodies.coupling import InterfaceCoupling, penalty_stiffness, rest_frames
    from bhem_hpc.geometry.interfaces import element_size

    couplings = []
    for record in scene.interfaces:
        sides = [scene.bodies[k] for k in record.bodies]
        element = min(element_size(side.surface, edge) for side, edge in zip(sides, record.edges, strict=True))
        stiffness = np.max([penalty_stiffness(side.material.young, side.material.poisson, side.material.thickness,
                                              element, record.penalty) for side in sides], axis=0)  # fmt: skip
        if not record.keep_angle:
            stiffness[1] = 0.0
        if record.shared is not None:  # the shared control points keep the edges one curve
            stiffness[0] = 0.0
        frames = rest_frames(sides[0].surface, sides[1].surface, record.quadrature)
        name = f"{record.where} ({record.kind} of {record.names[0]} and {record.names[1]})"
        couplings.append(InterfaceCoupling(blocks, record.bodies, record.quadrature, frames, tuple(stiffness), name,
                                           record.sewing_time))  # fmt: skip
    return couplings


def _joined_meshes(scene: BodiesScene, in_contact: list[Body]) -> list[tuple[int, int]]:
    """The interfaces between bodies in contact, as pairs of their places among ``in_contact``."""
    place = {body.index: k for k, body in enumerate(in_contact)}
    return [(place[a], place[b]) for a, b in (r.bodies for r in scene.interfaces) if a in place and b in place]


def bodies_barrier(bodies: list[Body], blocks: StackedBlocks, scene: BodiesScene, scene_file: Path):
    """Collective: IPC's barrier between the collision meshes of every body whose contact method is
    ``"ipc"`` (each other, themselves where a shell's self-collision says so, the scene's colliders),
    checked to start apart; or None."""
    in_contact = [body for body in bodies if body.scene.contact is not None and body.scene.contact.method == "ipc"]
    if not in_contact:
        return None
    from bhem_hpc.contact.ipc_contribution import CoarseCollisionMesh
    from bhem_hpc.contact.ipc_setup import check_chord_gaps, scene_barrier

    contact = in_contact[0].scene.contact
    meshes = [body.collision_mesh() for body in in_contact]
    barrier = scene_barrier(meshes, [blocks.open_offsets[body.index] for body in in_contact],
                            blocks.global_open_blocks, blocks.comm, contact, scene_file,
                            _joined_meshes(scene, in_contact))  # fmt: skip
    try:
        check_chord_gaps(meshes, barrier.dhat)
    except CoarseCollisionMesh as exc:
        body = in_contact[exc.body]
        raise RunError(f"{scene_file}: body '{body.name}' (bodies[{body.index}]): key "
                       f"'effects.contact.collision_cells' = {body.scene.contact.collision_cells}: {exc}") from exc
    positions = np.concatenate([body.model.open_positions for body in bodies])
    problem = barrier.starting_problem(positions)
    if problem is not None:
        names = ", ".join(body.name for body in in_contact)
        raise RunError(f"{scene_file}: the bodies in contact ({names}) start in contact with each other, their "
                       f"colliders or themselves ('ipc' needs them apart): {problem}")  # fmt: skip
    return barrier


def bodies_contact(bodies: list[Body], solver: ShellSolver, scene: BodiesScene):
    """The :class:`~bhem_hpc.contact.response.ContactHandler` of every body whose effects list contact
    by impulses (their colliders, themselves and each other) in ``solver`` (made of the bodies'
    models), or None."""
    in_contact = [body.scene.contact is not None and body.scene.contact.method == "impulse" for body in bodies]
    if not any(in_contact):
        return None
    from bhem_hpc.contact.bodies import BodiesDetector, StackedEntries
    from bhem_hpc.contact.response import ContactHandler

    problems = [solver.problem] if len(bodies) == 1 else solver.problem.problems  # (one body's is not stacked)
    parts = [None] * len(bodies)
    try:
        for k, (body, problem) in enumerate(zip(bodies, problems, strict=True)):
            if in_contact[k]:
                parts[k] = body.impulse_contact(problem, f"{SOLVER_PREFIX}contact_{body.name}_")
        surfaces = [part.surface if part is not None else body.contact_surface()
                    for body, part in zip(bodies, parts, strict=True)]  # fmt: skip
        entries = StackedEntries(surfaces)
        frictions = [body.scene.contact.friction if part is not None else 0.0
                     for body, part in zip(bodies, parts, strict=True)]  # fmt: skip
        detector = BodiesDetector(entries, [part.detector if part is not None else None for part in parts], frictions,
                                  [record.bodies for record in scene.interfaces])  # fmt: skip
        settings = contact_settings(bodies[in_contact.index(True)].scene)
    except Exception:
        for part in parts:
            if part is not None:
                part.projector.close()
        raise
    return ContactHandler.between_bodies(problems, detector, lambda b: parts[b].projector, bodies[0].model.comm,
                                         settings)


def _step(run: _BodiesRun, checkpoint: RestartPoint | None, continuing: bool, steps: int) -> list[HermiteSurface]:
    """Advance every body ``steps`` time steps with the bodies' contact handler (closed at the end),
    from the start or from ``checkpoint``; returns the bodies' final surfaces."""
    bodies, summary = run.bodies, run.summary
    handler = bodies_contact(bodies, run.solver, run.scene)
    if handler is not None:
        summary.contact = {body.name: {"colliders": len(body.scene.contact.colliders), "sample_points": d.num_samples}
                           for body, d in zip(bodies, handler.detector.detectors, strict=True)
                           if d is not None}  # fmt: skip
    state = StackedState([body_state(m) for m in run.models])  # body after body, even of one body
    stepper = TimeStepper(run.models, run.solver, _motions(run.scene), contact=handler, state=state)
    try:
        if checkpoint is not None:
            _restore(run, stepper, checkpoint)
        return _advance(run, stepper, steps, fresh_series=not continuing)
    finally:
        if handler is not None:
            handler.close()


def _restore(run: _BodiesRun, stepper: TimeStepper, checkpoint: RestartPoint) -> None:
    """Collective: every body's state, the clock and the kept factorization of ``checkpoint``."""
    arrays, attrs = checkpoint.arrays, checkpoint.attrs
    restore_solver(run.solver, arrays, attrs, run.key("factorization_state_dofs", 0) in arrays)
    for k, state in enumerate(stepper.state.states):
        state.set_raw(arrays[run.key("position_dofs", k)], arrays[run.key("velocity_dofs", k)])
    stepper.time, stepper.step = float(attrs["time"]), int(attrs["step"])


def _advance(run: _BodiesRun, stepper: TimeStepper, steps: int, fresh_series: bool) -> list[HermiteSurface]:
    """The time steps: frames (with a checkpoint) every ``output.every`` steps, the last one and one
    a stop signal ends with; a step record each; returns the bodies' final surfaces. A fresh series
    starts with the current state's frame (a continued one has it)."""
    options, scene, models, comm, summary = run.options, run.scene, run.models, run.comm, run.summary
    probes = [ProbeSet(m, body.probes) if body.probes else None for m, body in zip(models, scene.bodies, strict=True)]
    if comm.bcast(fresh_series):
        surfaces = _frame(run.output, models, stepper, comm)
        _probe_rows(run.output, probes, stepper, comm)
    else:
        surfaces = [m.state_surface() for m in models]
    records = StepRecords(options.out, summary, comm)
    progress = progress_bar(steps, options.progress and comm.rank == 0)
    every = scene.first.output_every
    checkpoint_s = 0.0  # a checkpoint's write time counts to the next step's output_s
    try:
        with Interruption() as interruption:
            for k in range(steps):
                record = stepper.advance()
                t_out = time.perf_counter()
                stop = interruption.requested(comm)  # every rank stops after the same step
                wrote = stepper.step % every == 0 or k == steps - 1 or stop is not None
                if wrote:
                    surfaces = _frame(run.output, models, stepper, comm)
                _probe_rows(run.output, probes, stepper, comm)
                records.add(step_summary(record, time.perf_counter() - t_out + checkpoint_s, None))
                t_checkpoint = time.perf_counter()
                if wrote:  # after the step's rows: a restart from it finds them all
                    run.write_checkpoint(stepper, surfaces)
                checkpoint_s = time.perf_counter() - t_checkpoint
                summary.time = stepper.time
                progress(record, stepper)
                if stop is not None:
                    raise RunInterrupted(f"{options.scene}: stopped by {stop} after step {stepper.step} "
                                         f"(t = {stepper.time:.6g} s); its state is the last frame and the "
                                         f"checkpoint: continue with --restart {options.out}")  # fmt: skip
    except StepFailure as exc:
        raise RunError(str(exc)) from exc
    finally:
        progress(None, stepper)
    return surfaces


@dataclass
class _BodiesRun:
    """What the stages of one run of several bodies share (collective, every rank; ``output`` on
    rank 0 only)."""

    options: RunOptions
    scene: BodiesScene
    bodies: list[Body]
    solver: ShellSolver
    summary: RunSummary
    output: BodiesOutput | None
    comm: MPI.Comm

    @property
    def models(self) -> list:
        return [body.model for body in self.bodies]

    def key(self, name: str, body: int) -> str:
        """The name of body ``body``'s array ``name`` in the checkpoint."""
        return body_array_name(name, body, len(self.bodies))

    def write_checkpoint(self, stepper: TimeStepper, surfaces: list[HermiteSurface]) -> None:
        """Collective: ``checkpoint.h5`` with every body's raw position and velocity DOFs and surface,
        the kept factorization's state and the clock."""
        arrays, solver_attrs = solver_checkpoint(self.solver)  # a continued run remakes the kept factorization
        for k, (state, surface) in enumerate(zip(stepper.state.states, surfaces, strict=True)):
            arrays[self.key("position_dofs", k)] = state.raw_position()
            arrays[self.key("velocity_dofs", k)] = state.raw_velocity()
            arrays[self.key("position_nodal", k)] = surface.nodal
        attrs = checkpoint_attributes((stepper.time, stepper.step), self.summary, False)
        attrs |= solver_attrs
        path = self.options.out / "checkpoint.h5"
        on_rank0(self.comm, lambda: write_checkpoint(path, arrays, attrs), path.name)
