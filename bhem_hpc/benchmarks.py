"""Benchmarks: Newton iterations on N x N sheets, time steps of scenes, ray tracing, the paper's Table 2.

Collective functions: call them on every rank of ``comm``; rank 0 writes files and prints.
"""

from __future__ import annotations

import json
import platform
from pathlib import Path

import numpy as np
from mpi4py import MPI

from bhem_hpc.blas import blas_label, openblas_core
from bhem_hpc.errors import InputError
from bhem_hpc.geometry import bspline
from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import DEFAULT_QUADRATURE, Loads, ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.studies.study import METHOD_RULES, flat_sheet, method_name


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
        state = bspline.from_callable(position, rest.grid, rest.degree)
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
        solver.time_newton_iteration()
        runs = [solver.time_newton_iteration() for _ in range(repeats)]
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
    from bhem_hpc.solver.dynamics import TimeStepper

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
                     factorization=scene.factorization, linear=scene.linear) as solver:  # fmt: skip
        contact = build_contact(scene, model, solver)
        stepper = TimeStepper(model, solver, prescribed_motions(scene), contact=contact)
        for _ in range(max(warmup, 1)):
            stepper.advance()
        reports = [stepper.advance() for _ in range(steps)]
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


#: The paper's Table 2 (DoFs, nonzeros, collider sample points, dt [ms], t_int and t_obj [s] per step,
#: self-collision) for the scenes that exist in jobs/, with the warm-up steps that reach the
#: interesting phase (contact, twisting) before timing.
PAPER_TABLE_2 = (
    ("twisting", "Twisting (Fig. 18)", 1.15e4, 1.19e6, "-", 2, 0.20, None, "-", 1),
    ("ball", "Ball (Fig. 2)", 1.15e4, 1.17e6, "-", 2, 4.80, 0.0023, "no", 70),
    ("mesh-obstacle", "Armadillo (Fig. 3)", 1.15e4, 1.19e6, "2.8k", 1, 2.90, 1.84, "no", 110),
    ("needles", "Needles (Fig. 4)", 1.15e4, 1.19e6, "3.6k", 2, 5.05, 26.66, "yes", 40),
    ("parasol", "Umbrella (Fig. 5)", 2.02e4, 1.76e6, "-", 2, 12.47, None, "-", 1),
    ("crushed-can", "Can (Fig. 8)", 5.3e3, 4.97e5, "-", 2, 4.55, None, "-", 15),
    ("mandrel", "Cans (Fig. 22)", 1.15e4, 1.13e6, "-", 0.04, 5.29, 0.0024, "no", 20),
    ("locking", "Locking (Fig. 21)", None, None, "-", 2, 3.38, 4.37, "yes", 1),
)


def paper_comparison(jobs_dir: Path, steps: int = 5, comm: MPI.Comm = MPI.COMM_WORLD) -> list[dict]:
    """Time steps of the jobs of the paper's Table 2: each scene's warm-up steps untimed, then the
    mean of ``steps`` steps without output; every row carries the paper's figures too."""
    rows = []
    for job, label, dofs, nnz, samples, dt_ms, t_int, t_obj, sc, warmup in PAPER_TABLE_2:
        row = scene_benchmark(jobs_dir / f"{job}.toml", steps, comm=comm, warmup=warmup)
        row.update(label=label, paper=(dofs, nnz, samples, dt_ms, t_int, t_obj, sc))
        rows.append(row)
    return rows


#: Jobs timed with fresh and kept factorizations: (job, untimed warm-up steps, timed steps).
REUSE_JOBS = (("twisting", 1, 50), ("ball", 70, 20))


def reuse_comparison(jobs_dir: Path, comm: MPI.Comm = MPI.COMM_WORLD) -> list[dict]:
    """Time steps of :data:`REUSE_JOBS` with a fresh factorization per Newton iteration and with the
    refactor policy, one after the other in one run."""
    rows = []
    for job, warmup, steps in REUSE_JOBS:
        for factorization in ("fresh", "reuse"):
            overrides = {"solver": {"factorization": factorization}}
            row = scene_benchmark(jobs_dir / f"{job}.toml", steps, comm=comm, warmup=warmup, overrides=overrides)
            rows.append(row | {"job": job})
    return rows


def write_performance(docs: Path, jobs_dir: Path, steps: int = 5, comm: MPI.Comm = MPI.COMM_WORLD) -> Path:
    """Measure everything ``docs/performance.md`` shows, in one run, and write it with its rows
    (``docs/performance.json``): one Newton iteration on 10 x 10 to 30 x 30 sheets, ray-patch
    intersection (midpoint against Newton-guided splitting), and time steps of the paper's scenes."""
    rows = {
        "ranks": comm.size,
        "blas": openblas_core(),
        "newton": [benchmark(n, comm=comm) for n in (10, 20, 30)],
        # at (nearly) equal DoFs: N Hermite patches carry 12 (N + 1)^2, M degree-p spans 3 (M + p)^2
        "discretizations": [
            {
                **benchmark(spans, comm=comm, discretization=name, quadrature=quadrature),
                **sheet_step_benchmark(spans, name, quadrature, comm=comm),
            }
            for n in (10, 20)
            for name, spans, quadrature in (
                ("hermite", n, None),
                ("bspline2", 2 * n, None),
                ("bspline2", 2 * n, "reduced"),
                ("bspline3", 2 * n - 1, None),
            )
        ],  # fmt: skip
        "equal_accuracy": equal_accuracy_benchmarks(docs, comm),
        "rays": [ray_benchmark(n) for n in (10, 30)] if comm.rank == 0 else [],
        "scenes": paper_comparison(jobs_dir, steps, comm),
        "reuse": reuse_comparison(jobs_dir, comm),
        "steps": steps,
    }
    out = docs / "performance.md"
    if comm.rank == 0:
        docs.mkdir(parents=True, exist_ok=True)
        (docs / "performance.json").write_text(json.dumps(rows, indent=1) + "\n")
        out.write_text(performance_markdown(rows))
    comm.Barrier()
    return out


#: The accuracy targets of the equal-accuracy benchmark, on the clamped plate of the plate study.
EQUAL_ACCURACY_TARGETS = (1e-2, 1e-3)


def equal_accuracy_benchmarks(docs: Path, comm: MPI.Comm = MPI.COMM_WORLD) -> list[dict]:
    """Each method at the fewest knot spans (patches) that reach each of
    :data:`EQUAL_ACCURACY_TARGETS` on the clamped plate of the serial plate study in
    ``docs/studies`` (run first by ``make docs``), timed on the cloth sheet of :func:`benchmark`
    and :func:`sheet_step_benchmark`. A method that reaches no target within the study's sizes
    has no row."""
    from bhem_hpc.studies.report import read_rows

    path = docs / "studies" / "ranks-1" / "plate" / "plate.csv"
    if not path.exists():
        return []
    plate = [r for r in read_rows(path) if r["support"] == "clamped" and r["hessian"] == "exact"]
    rows = []
    for target in EQUAL_ACCURACY_TARGETS:
        for discretization, quadrature in METHOD_RULES:
            rule = quadrature or DEFAULT_QUADRATURE[discretization]
            reached = [
                r for r in plate
                if (r["discretization"], r["quadrature"], r["factorization"]) == (discretization, rule, "ldlt")
                and r["error"] <= target
            ]  # fmt: skip
            if not reached:
                continue
            spans = min(r["patches"] for r in reached)
            error = next(r["error"] for r in reached if r["patches"] == spans)
            timing = benchmark(spans, comm=comm, discretization=discretization, quadrature=quadrature)
            steps = sheet_step_benchmark(spans, discretization, quadrature, comm=comm)
            rows.append({**timing, **steps, "plate_target": target, "plate_error": error})
    return rows


def performance_markdown(rows: dict) -> str:
    """The performance page from the rows of :func:`write_performance`."""
    lines = [
        "# Performance",
        "",
        f"Generated by `bhem-hpc bench --docs docs` (`make docs`), {rows['ranks']} rank(s) on one 2-core machine "
        f"(BLAS: {blas_label(rows.get('blas'))}); every figure below comes from that one run.",
        "",
        "## One Newton iteration (`bhem-hpc bench --patches N`)",
        "",
        "A 1 m cloth sheet (Y 1e4 Pa, nu 0.3, h 1 mm) stretched 2 % with a two-wave bump, exact Hessian, "
        "MUMPS LDL^T; median of 3 iterations after a warm-up.",
        "",
        format_newton_table(rows["newton"], "exact", 3),
        "",
    ]
    lines[-2] = "```\n" + lines[-2] + "\n```"
    lines += _discretization_table(rows.get("discretizations", []), rows.get("equal_accuracy", []))
    if rows["rays"]:
        lines += ["## Ray-patch intersection (`bhem-hpc bench --rays`)", ""]
        lines += [f"- {format_ray_row(r)}" for r in rows["rays"]]
        lines += [""]
    lines += _scene_table(rows["scenes"], rows["steps"])
    lines += _reuse_table(rows.get("reuse", []))
    return "\n".join(lines) + "\n"


def _reuse_table(rows: list[dict]) -> list[str]:
    """Fresh factorizations against the refactor policy, per job."""
    if not rows:
        return []
    lines = [
        "",
        "## Factorization reuse (`bhem-hpc bench --scene JOB --factorization fresh|reuse`)",
        "",
        "Each job's warm-up steps untimed, then the mean over its timed steps, without output; `fresh` factors the "
        "Jacobian at every Newton iteration, `reuse` keeps factorizations while chord steps converge well.",
        "",
        "| job | warm-up + timed steps | factorization | s / step | Newton / step | refactorizations / step | "
        "assembly s / step | factorization s / step | speedup |",
        "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    fresh = {r["job"]: r for r in rows if r["factorization"] == "fresh"}
    for r in rows:
        speedup = fresh[r["job"]]["step_s"] / r["step_s"] if r["job"] in fresh else float("nan")
        lines.append(
            f"| `{r['job']}` | {r['warmup']} + {r['steps']} | {r['factorization']} | {r['step_s']:.3f} | "
            f"{r['newton_per_step']:.2f} | {r['refactorizations_per_step']:.2f} | {r['assembly_per_step_s']:.3f} | "
            f"{r['factor_per_step_s']:.3f} | {speedup:.2f}x |"
        )
    return lines


def _discretization_table(rows: list[dict], equal_accuracy: list[dict]) -> list[str]:
    """Hermite and B-splines on the same sheet at (nearly) equal DoFs and at equal accuracy."""
    if not rows:
        return []
    header = [
        "| method | patches / spans | DoFs | nonzeros / DoF | membrane / bending points | Jacobian [s] "
        "| factor [s] | Newton iteration [s] | time step [s] | Newton / step |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]

    def line(r: dict, extra: str = "") -> str:
        return (
            f"| {method_name(r['discretization'], r['quadrature'])} | {r['patches']} | {r['dofs']} | "
            f"{r['nnz'] / r['dofs']:.0f} | {r['membrane_points']} / {r['bending_points']} | "
            f"{r['assemble_jacobian_s']:.4f} | {r['factor_s']:.4f} | {r['newton_iteration_s']:.4f} | "
            f"{r['step_s']:.4f} | {r['newton_per_step']:.1f} |{extra}"
        )

    lines = [
        "## Hermite and B-splines at equal DoFs (`bhem-hpc bench --patches N --discretization D`)",
        "",
        "The same sheet and state; N Hermite patches against 2N quadratic and 2N - 1 cubic knot spans, each with "
        "its default Gauss rule, and the quadratic splines with the B-spline paper's reduced rule "
        "(`--quadrature reduced`). Time step: the sheet clamped along one edge falls from flat "
        "(implicit Euler, dt 10 ms), mean of 5 steps after one.",
        "",
        *header,
        *(line(r) for r in rows),
        "",
        *_paper_claims(rows),
    ]
    if equal_accuracy:
        lines += [
            "## Hermite and B-splines at equal accuracy",
            "",
            "Each method at the fewest patches / spans whose clamped-plate deflection (the plate study, serial) is "
            "within the target of the tabulated value, timed on the sheet above; a method that reaches a target "
            "at none of the study's sizes has no row for it.",
            "",
            header[0] + " target | plate error |",
            header[1] + " ---: | ---: |",
            *(line(r, f" {r['plate_target']:g} | {r['plate_error']:.2e} |") for r in equal_accuracy),
            "",
        ]
    return lines


def _paper_claims(rows: list[dict]) -> list[str]:
    """The B-spline paper's cost claims, checked against the equal-DoF rows (per sheet size)."""
    lines = []
    for hermite in (r for r in rows if r["discretization"] == "hermite"):
        by = {method_name(r["discretization"], r["quadrature"]): r for r in rows if r["dofs"] == hermite["dofs"]}
        if not {"bspline2", "bspline2 reduced"} <= set(by):
            continue
        full, reduced = by["bspline2"], by["bspline2 reduced"]
        iteration = full["newton_iteration_s"] / hermite["newton_iteration_s"]
        lines.append(
            f"- {hermite['dofs']} DoFs: quadratic B-splines against Hermite: nonzeros per DoF "
            f"{full['nnz'] / full['dofs']:.0f} against {hermite['nnz'] / hermite['dofs']:.0f} (the paper: a sparser "
            f"Hessian than Hermite's), Newton iteration {iteration:.2f} x, time step "
            f"{full['step_s'] / hermite['step_s']:.2f} x Hermite's; the reduced rule evaluates "
            f"{reduced['membrane_points'] + reduced['bending_points']} points against "
            f"{full['membrane_points'] + full['bending_points']} and assembles the Jacobian in "
            f"{reduced['assemble_jacobian_s'] / full['assemble_jacobian_s']:.2f} x the time of 3 x 3 Gauss."
        )
    return ["The B-spline paper's cost claims at equal DoFs, measured in this run:", "", *lines, ""] if lines else []


def _scene_table(rows: list[dict], steps: int) -> list[str]:
    def num(v, fmt="{:.3g}") -> str:
        return "-" if v is None else (v if isinstance(v, str) else fmt.format(v))

    lines = [
        "## Time steps beside the paper's Table 2 (`bhem-hpc bench --scene JOB`)",
        "",
        f"Each scene: its warm-up steps untimed, then the mean of {steps} steps without output. The paper's figures",
        "come from a 14-core desktop with its own scene sizes; ours are the `jobs/` scenes named in the first column.",
        "Collision = detection + response (impulses, friction, push-out) per step; the paper's t_obj is its CCD.",
        "",
        "| scene (job) | DoFs ours / paper | nonzeros ours / paper | sample points ours / paper | dt [ms] | "
        "s / step ours / paper | collision s / step ours / paper | of which detection | self-collision ours / paper |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for r in rows:
        dofs, nnz, samples, dt_ms, t_int, t_obj, sc = r["paper"]
        collision = r["collision_per_step_s"] if r["sample_points"] else None
        detection = r["detection_per_step_s"] if r["sample_points"] else None
        lines.append(
            f"| {r['label']} (`{Path(r['scene']).stem}`) | {r['dofs']} / {num(dofs)} | {r['nnz']:.3g} / {num(nnz)} | "
            f"{r['sample_points'] or '-'} / {samples} | {dt_ms} | {r['step_s']:.3g} / {num(t_int)} | "
            f"{num(collision)} / {num(t_obj)} | {num(detection)} | {'yes' if r['self_collision'] else 'no'} / {sc} |"
        )
    return lines


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
