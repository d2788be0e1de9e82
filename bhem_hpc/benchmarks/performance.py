"""The performance page (``bhem-hpc bench --docs``): the paper's Table 2 scenes, factorization
reuse, discretizations at equal DoFs and at equal accuracy, measured in one run.

Collective functions: call them on every rank of ``comm``; rank 0 writes files.
"""

from __future__ import annotations

import json
from pathlib import Path

from mpi4py import MPI

from bhem_hpc.benchmarks.contact_page import CONTACT_WINDOWS, METHODS
from bhem_hpc.benchmarks.timing import (
    benchmark,
    format_newton_table,
    format_ray_row,
    ray_benchmark,
    scene_benchmark,
    sheet_step_benchmark,
)
from bhem_hpc.blas import blas_label, openblas_core
from bhem_hpc.model.shell import DEFAULT_QUADRATURE
from bhem_hpc.studies.study import METHOD_RULES, method_name

#: Untimed steps before a contact job is timed: the start of its contact page window that both
#: methods share (where contact happens).
CONTACT_WARMUP = {window.job: window.start for window in CONTACT_WINDOWS if window.methods == METHODS}
#: The paper's Table 2 (DoFs, nonzeros, collider sample points, dt [ms], t_int and t_obj [s] per step,
#: self-collision) for the scenes that exist in jobs/, with the warm-up steps that reach the
#: interesting phase (contact, twisting) before timing.
PAPER_TABLE_2 = (
    ("twisting", "Twisting (Fig. 18)", 1.15e4, 1.19e6, "-", 2, 0.20, None, "-", 1),
    ("ball", "Ball (Fig. 2)", 1.15e4, 1.17e6, "-", 2, 4.80, 0.0023, "no", CONTACT_WARMUP["ball"]),
    ("mesh-obstacle", "Armadillo (Fig. 3)", 1.15e4, 1.19e6, "2.8k", 1, 2.90, 1.84, "no",
     CONTACT_WARMUP["mesh-obstacle"]),
    ("needles", "Needles (Fig. 4)", 1.15e4, 1.19e6, "3.6k", 2, 5.05, 26.66, "yes", CONTACT_WARMUP["needles"]),
    ("parasol", "Umbrella (Fig. 5)", 2.02e4, 1.76e6, "-", 2, 12.47, None, "-", 1),
    ("crushed-can", "Can (Fig. 8)", 5.3e3, 4.97e5, "-", 2, 4.55, None, "-", CONTACT_WARMUP["crushed-can"]),
    ("mandrel", "Cans (Fig. 22)", 1.15e4, 1.13e6, "-", 0.04, 5.29, 0.0024, "no", CONTACT_WARMUP["mandrel"]),
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
REUSE_JOBS = (("twisting", 1, 50), ("ball", CONTACT_WARMUP["ball"], 20))


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
        f"Each scene: its warm-up steps untimed, then the mean of {steps} steps without output (timed steps: the",
        "column after the job); a contact job is timed in contact, from the start of its window of",
        "[docs/contact-comparison.md](contact-comparison.md). The paper's figures",
        "come from a 14-core desktop with its own scene sizes; ours are the `jobs/` scenes named in the first column.",
        "Collision = detection + response (impulses, friction, push-out) per step; the paper's t_obj is its CCD.",
        "",
        "| scene (job) | timed steps | DoFs ours / paper | nonzeros ours / paper | sample points ours / paper | "
        "dt [ms] | s / step ours / paper | collision s / step ours / paper | of which detection | "
        "self-collision ours / paper |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for r in rows:
        dofs, nnz, samples, dt_ms, t_int, t_obj, sc = r["paper"]
        collision = r["collision_per_step_s"] if r["sample_points"] else None
        detection = r["detection_per_step_s"] if r["sample_points"] else None
        lines.append(
            f"| {r['label']} (`{Path(r['scene']).stem}`) | {r['warmup'] + 1}–{r['warmup'] + steps} | "
            f"{r['dofs']} / {num(dofs)} | {r['nnz']:.3g} / {num(nnz)} | "
            f"{r['sample_points'] or '-'} / {samples} | {dt_ms} | {r['step_s']:.3g} / {num(t_int)} | "
            f"{num(collision)} / {num(t_obj)} | {num(detection)} | {'yes' if r['self_collision'] else 'no'} / {sc} |"
        )
    return lines
