"""Timings: one Newton iteration on N x N sheets, time steps of scenes, ray tracing.

Collective functions: call them on every rank of ``comm``; rank 0 writes files and prints.
"""

from __future__ import annotations

import platform
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

from bhem_hpc.blas import openblas_core
from bhem_hpc.errors import InputError
from bhem_hpc.geometry import bspline
from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import Loads, ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.studies.study import flat_sheet


def benchmark(
    patches: int,
    hessian: str = "exact",
    repeats: int = 3,
    comm: MPI.Comm = MPI.COMM_WORLD,
    options: dict | None = None,
    discretization: str = "hermite",
    quadrature: int | str | None = None,
) -> dict:
    """Time one Newton iteration on an ``N x N`` sheet (patches or knot spans) in a deformed,
    stressed state.

    The sheet (1 m, Y 1e4 Pa, nu 0.3, h 1 mm, rho 200: the paper's cloth) is stretched 2 % and
    carries a two-wave bump, so membrane, bending and geometric stiffness are all active.
    Reports the median of ``repeats`` iterations after one warm-up (JIT, symbolic analysis).
    ``quadrature``: Gauss points per direction or ``"reduced"``; None: the discretization's default.
    """
    if patches < 1:
        raise InputError(f"--patches must be >= 1, got {patches!r}")
    material = Material(young=1e4, poisson=0.3, thickness=1e-3, density=200.0)
    rest = flat_sheet(discretization, 1.0, 1.0, patches, patches)

    def position(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        bump = 0.05 * np.sin(2 * np.pi * a) * np.sin(np.pi * b)
        return np.stack([1.02 * a + 0.01 * np.sin(np.pi * b), b, bump], axis=-1)

    if discretization == "hermite":
        state = S.from_callable(position, rest.grid)
    else:
        state = bspline.from_callable(position, rest.grid, degree=rest.degree)
    model = ShellModel(
        rest,
        material,
        Loads(gravity=(0.0, 0.0, -9.81)),
        [bcs.clamp_edge(rest, "xi2_min")],
        hessian=hessian,
        quadrature_points=quadrature,
        comm=comm,
        initial=state,
    )
    with ShellSolver(model, prefix="bhem_bench_", options=options) as solver:
        time_newton_iteration(solver)
        runs = [time_newton_iteration(solver) for _ in range(repeats)]
        nnz = solver.problem.matrix_nonzeros()
    keys = ("assemble_residual_s", "assemble_jacobian_s", "factor_s", "solve_s", "newton_iteration_s")
    result = {
        "patches": patches,
        "discretization": discretization,
        "quadrature": model.quadrature_points,
        "membrane_points": model.quadrature.membrane_points,
        "bending_points": model.quadrature.bending_points,
        "dofs": 3 * model.discretization.num_closed,
        "nnz": nnz,
        "ranks": comm.size,
        "hessian": hessian,
    }
    for key in keys:
        result[key] = float(np.median([r[key] for r in runs]))
    result["factor_gflop"] = runs[-1]["factor_gflop"]
    result["factor_gflops"] = result["factor_gflop"] / result["factor_s"]
    result["host"] = platform.node()
    return result


def time_newton_iteration(solver: ShellSolver) -> dict[str, float]:
    """One Newton iteration of ``solver`` at its model's current state, phase by phase.

    Assembles the residual and the Jacobian, factorizes (numeric factorization; the symbolic
    analysis is reused once done) and solves, without updating the state.

    Returns:
        Seconds per phase (``assemble_residual_s``, ``assemble_jacobian_s``, ``factor_s``,
        ``solve_s``, ``newton_iteration_s``) and ``factor_gflop`` (MUMPS RINFOG(3)).
    """
    comm = solver.model.comm
    ksp = solver.snes.getKSP()
    pc = ksp.getPC()
    step = solver.x.duplicate()
    solver.problem.state_to_vector(solver.x)

    def timed(action) -> float:
        comm.Barrier()
        t0 = time.perf_counter()
        action()
        comm.Barrier()
        return time.perf_counter() - t0

    def residual() -> None:
        solver.problem.update_state(solver.x)
        solver.problem.assemble_residual(solver.x, solver.f)

    times = {
        "assemble_residual_s": timed(residual),
        "assemble_jacobian_s": timed(lambda: solver.problem.assemble_jacobian(solver.jacobian)),
    }
    ksp.setOperators(solver.jacobian)
    times["factor_s"] = timed(pc.setUp)
    times["solve_s"] = timed(lambda: ksp.solve(solver.f, step))
    times["newton_iteration_s"] = sum(times.values())
    factor_matrix = solver.factor_matrix()
    times["factor_gflop"] = factor_matrix.getMumpsRinfog(3) / 1e9 if factor_matrix is not None else float("nan")
    times["negative_pivots"] = solver.negative_pivots()
    step.destroy()
    return times


def sheet_step_benchmark(
    patches: int,
    discretization: str = "hermite",
    quadrature: int | str | None = None,
    steps: int = 5,
    comm: MPI.Comm = MPI.COMM_WORLD,
) -> dict:
    """Time implicit Euler steps (dt 10 ms) of the cloth sheet of :func:`benchmark`, clamped along
    one edge and falling from flat under gravity: the mean of ``steps`` steps after one untimed."""
    from bhem_hpc.model.shell import Dynamics
    from bhem_hpc.solver.dynamics import TimeStepper

    material = Material(young=1e4, poisson=0.3, thickness=1e-3, density=200.0)
    rest = flat_sheet(discretization, 1.0, 1.0, patches, patches)
    model = ShellModel(
        rest, material, Loads(gravity=(0.0, 0.0, -9.81)), [bcs.clamp_edge(rest, "xi2_min")],
        quadrature_points=quadrature, comm=comm, dynamics=Dynamics(0.01),
    )  # fmt: skip
    with ShellSolver(model, prefix="bhem_bench_") as solver:
        stepper = TimeStepper(model, solver)
        stepper.advance()
        reports = [stepper.advance() for _ in range(steps)]
    wall = float(np.mean([r.wall_s for r in reports]))
    return {
        "step_s": comm.allreduce(wall, op=MPI.MAX),
        "newton_per_step": float(np.mean([r.newton_iterations for r in reports])),
    }


def scene_benchmark(
    scene_path: Path,
    steps: int,
    hessian: str | None = None,
    comm: MPI.Comm = MPI.COMM_WORLD,
    warmup: int = 1,
    samples_per_side: int | None = None,
    overrides: dict[str, dict] | None = None,
) -> dict:
    """Time ``steps`` implicit Euler steps of a scene after ``warmup`` untimed steps, without output.

    With contact effects the collision time (detection and response) is reported as well.
    ``overrides``: scene keys replaced, ``{table: {key: value}}`` (e.g. the patches, the linear
    solver). Besides times per step: the linear solver chosen, Krylov iterations per linear solve,
    refactorizations per step and each rank's peak resident memory so far (the largest).
    """
    import dataclasses
    import resource

    from bhem_hpc.run import SOLVER_PREFIX, build_contact, build_model, prescribed_motions
    from bhem_hpc.scene import load_scene
    from bhem_hpc.solver.dynamics import StepFailure, TimeStepper

    if steps < 1:
        raise InputError(f"--steps must be >= 1, got {steps!r}")
    scene = load_scene(scene_path, overrides)
    if scene.static:
        raise InputError(f"{scene_path}: a static scene has no time steps to benchmark")
    if hessian is not None:
        scene = dataclasses.replace(scene, hessian=hessian)
    if samples_per_side is not None:
        if scene.contact is None:
            raise InputError(f"{scene_path}: --samples needs a scene with contact effects")
        if not 1 <= samples_per_side <= 16:
            raise InputError(f"--samples must be in 1..16, got {samples_per_side}")
        scene = dataclasses.replace(
            scene, contact=dataclasses.replace(scene.contact, samples_per_side=samples_per_side)
        )
    model = build_model(scene, comm)
    with ShellSolver(model, prefix=SOLVER_PREFIX, options=scene.petsc_options,
                     factorization=scene.factorization, linear=scene.linear,
                     acceleration_tolerance=scene.acceleration_tolerance) as solver:  # fmt: skip
        contact = build_contact(scene, model, solver.problem)
        stepper = TimeStepper(model, solver, prescribed_motions(scene), contact=contact)
        try:
            for _ in range(max(warmup, 1)):
                stepper.advance()
            reports = [stepper.advance() for _ in range(steps)]
        except StepFailure as exc:
            raise InputError(f"{scene_path}: cannot be benchmarked: {exc}") from None
        assemble = sum(r.assembly_s for r in reports)
        factor = sum(r.factorization_s for r in reports)
        linear_solve = sum(r.linear_solve_s for r in reports)
        nnz = solver.problem.matrix_nonzeros()
        linear = solver.linear.kind
        dominance = solver.linear.mass_dominance
        fallbacks = len(solver.fallbacks)
        samples = contact.detector.num_samples if contact is not None else 0
        if contact is not None:
            contact.close()
    wall = float(np.mean([r.wall_s for r in reports]))
    collision = float(np.mean([r.collision_s for r in reports]))
    newton = sum(r.newton_iterations for r in reports)
    solves = sum(r.linear_solves for r in reports)
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # Linux: kilobytes
    return {
        "scene": str(scene_path),
        "patches": [scene.surface.grid.n1, scene.surface.grid.n2],
        "linear": linear,
        "dt": scene.dt,
        "mass_dominance": dominance,
        "factorization": scene.factorization,
        "linear_fallbacks": fallbacks,
        "linear_solve_per_step_s": comm.allreduce(linear_solve / steps, op=MPI.MAX),
        "krylov_per_solve": sum(r.krylov_iterations for r in reports) / max(solves, 1) if linear != "direct" else 0.0,
        "refactorizations_per_step": sum(r.refactorizations for r in reports) / steps,
        "newton_iteration_s": comm.allreduce(wall, op=MPI.MAX) * steps / max(newton, 1),
        "peak_memory_per_rank_gb": comm.allreduce(peak_kb, op=MPI.MAX) / 1e6,
        "hessian": scene.hessian,
        "blas": openblas_core(),
        "dofs": 3 * model.discretization.num_closed,
        "nnz": nnz,
        "ranks": comm.size,
        "steps": steps,
        "step_s": comm.allreduce(wall, op=MPI.MAX),
        "newton_per_step": float(np.mean([r.newton_iterations for r in reports])),
        "assembly_per_step_s": assemble / steps,
        "factor_per_step_s": factor / steps,
        "recoveries": int(sum(r.recoveries for r in reports)),
        "collision_per_step_s": comm.allreduce(collision, op=MPI.MAX),
        "detection_per_step_s": comm.allreduce(float(np.mean([r.detection_s for r in reports])), op=MPI.MAX),
        "projections_per_step": float(np.mean([r.projections for r in reports])),
        "collision_fraction": comm.allreduce(collision, op=MPI.MAX) / comm.allreduce(wall, op=MPI.MAX),
        "contacts_per_step": float(np.mean([r.contacts for r in reports])),
        "sample_points": samples,
        "self_collision": bool(scene.contact is not None and scene.contact.self_collision),
        "warmup": warmup,
    }


def ray_benchmark(patches: int = 10, resolution: int = 32) -> dict:
    """Rays per second on a draped-looking ``patches x patches`` surface, midpoint-only vs
    Newton-guided splitting, measured in one run (paper Table 1). Serial, numpy only."""
    import time as _time

    from bhem_hpc.collision import PatchBVH, control_nets, trace_rays

    surface = S.from_callable(
        lambda a, b: np.stack([a, b, 0.15 * np.sin(5 * a) * np.cos(4 * b) - 0.3 * (a - 0.5) ** 2], axis=-1),
        S.ParameterGrid(patches, patches, (0.0, 1.0), (0.0, 1.0)),
    )
    bvh = PatchBVH(control_nets(surface.grid, surface.nodal))
    s, t = np.meshgrid(np.linspace(0.05, 0.95, resolution), np.linspace(0.05, 0.95, resolution), indexing="ij")
    eye = np.array([0.5, -1.0, 1.5])
    targets = np.stack([s.ravel(), t.ravel(), np.zeros(s.size)], axis=-1)
    directions = targets - eye
    origins = np.broadcast_to(eye, directions.shape)
    result = {"patches": patches, "rays": int(len(directions))}
    hits = {}
    for label, newton in (("midpoint", False), ("newton", True)):
        start = _time.perf_counter()
        hits[label] = trace_rays(bvh, origins, directions, newton=newton)
        elapsed = _time.perf_counter() - start
        result[f"{label}_rays_per_s"] = len(directions) / elapsed
    result["speedup"] = result["newton_rays_per_s"] / result["midpoint_rays_per_s"]
    both = (hits["midpoint"].patch >= 0) & (hits["newton"].patch >= 0)
    result["hits"] = int(both.sum())
    result["max_tau_difference"] = float(np.abs(hits["midpoint"].tau[both] - hits["newton"].tau[both]).max(initial=0.0))
    return result


def format_ray_row(row: dict) -> str:
    """One line of ``bhem-hpc bench --rays``."""
    return (
        f"{row['patches']}x{row['patches']} patches, {row['rays']} rays ({row['hits']} hits): midpoint "
        f"{row['midpoint_rays_per_s']:.0f} rays/s, Newton-guided {row['newton_rays_per_s']:.0f} rays/s "
        f"({row['speedup']:.1f}x), max |tau difference| {row['max_tau_difference']:.1e}"
    )


def format_scene_row(row: dict) -> str:
    """One line of ``bhem-hpc bench --scene``."""
    collision = (
        f"; collision {row['collision_per_step_s']:.4f} s/step "
        f"({100 * row['collision_fraction']:.1f} % of the step; detection "
        f"{row['detection_per_step_s']:.4f} s, {row['projections_per_step']:.1f} projections; "
        f"{row['sample_points']} sample points, {row['contacts_per_step']:.0f} contacts/step)"
        if row["sample_points"]
        else ""
    )
    krylov = f", {row['krylov_per_solve']:.1f} Krylov iterations/solve" if row["linear"] == "iterative" else ""
    return (
        f"{row['scene']}: {row['dofs']} DoFs, {row['ranks']} rank(s), {row['hessian']} Hessian, "
        f"{row['linear']} linear solver{krylov}, peak memory {row['peak_memory_per_rank_gb']:.2f} GB/rank, "
        f"{row['steps']} steps: {row['step_s']:.3f} s/step, {row['newton_per_step']:.2f} Newton "
        f"iterations/step (assembly {row['assembly_per_step_s']:.3f} s, factorization "
        f"{row['factor_per_step_s']:.3f} s per step), {row['recoveries']} recoveries" + collision
    )


def format_newton_table(rows: list[dict], hessian: str, repeats: int) -> str:
    """The table of ``bhem-hpc bench --patches ...``: one row per sheet size (all on one rank count)."""
    ranks = rows[0]["ranks"] if rows else MPI.COMM_WORLD.size
    lines = [
        f"Newton iteration, {hessian} Hessian, {ranks} rank(s), median of {repeats}",
        f"{'patches':>8} {'DoFs':>7} {'nnz':>9} {'residual':>9} {'jacobian':>9} {'factor':>8} "
        f"{'solve':>8} {'total':>8} {'GFlop/s':>8}",
    ]
    for r in rows:
        lines.append(
            f"{r['patches']:>8} {r['dofs']:>7} {r['nnz']:>9} {r['assemble_residual_s']:>9.4f} "
            f"{r['assemble_jacobian_s']:>9.4f} {r['factor_s']:>8.4f} {r['solve_s']:>8.4f} "
            f"{r['newton_iteration_s']:>8.4f} {r['factor_gflops']:>8.2f}"
        )
    return "\n".join(lines)
