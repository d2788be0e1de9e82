"""Command line: ``bhem-hpc {run,render,study,bench,cantilever,states,intersections,...} ...``.

Trailing ``-prefix_option value`` pairs go to PETSc.

PETSc options must reach ``petsc4py.init`` before dolfinx is imported, so every command imports
the solver lazily, after parsing.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import traceback
from pathlib import Path

from bhem_hpc.blas import use_best_kernels
from bhem_hpc.errors import InputError
from bhem_hpc.model.hessian import HESSIAN_KINDS

BENCH_DEFAULT_PATCHES = [10, 20, 30]
#: Patches per side a benchmark sheet may have (a scene's limit: 10^6 patches).
MAX_BENCH_PATCHES = 1000
#: Memory one Newton iteration with MUMPS takes per Hermite patch, about (measured: 68 kB per patch
#: between 30 x 30 and 60 x 60; the factor's fill grows with the size).
NEWTON_BYTES_PER_PATCH = 100_000


def _add_cloth(sub) -> None:
    """``bhem-hpc cloth``: the cotton jobs at the B-spline cloth paper's resolutions."""
    cloth = sub.add_parser("cloth", help="the cotton jobs at the B-spline cloth paper's resolutions against its table")
    cloth.add_argument("--docs", type=Path, default=Path("docs"), help="write DOCS/cloth-comparison.md, .json, .png")
    cloth.add_argument("--out", type=Path, default=Path("out/cloth"), help="the runs' output directories")
    cloth.add_argument("--steps", type=int, default=200, help="time steps per case (from the start)")
    cloth.add_argument("--hermite", type=int, nargs="*", default=[25, 35], help="Hermite patches per side")
    cloth.add_argument("--bspline2", type=int, nargs="*", default=[75, 100, 125], help="knot spans per side")
    cloth.add_argument("--bspline3", type=int, nargs="*", default=[75, 100, 125], help="knot spans per side")
    cloth.add_argument("--jobs", nargs="+", default=None, help="jobs (default: hanging, drape-cotton, shear, "
                       "locking-cotton)")  # fmt: skip
    cloth.add_argument("--whole", nargs="+", default=[], metavar="CASE",
                       help="cases (by the page's names, e.g. shear-hermite-25) run to their job's end instead")


def _add_solids(sub) -> None:
    """``bhem-hpc solids``: the SEM solids page."""
    solids = sub.add_parser("solids", help="SEM solids: quadrature convergence, cost as parts are added, a cantilever "
                            "against tetrahedral FEM (serial)")  # fmt: skip
    solids.add_argument("--docs", type=Path, default=Path("docs"), help="write DOCS/solids.md, .json, .png")


def _add_paths(sub) -> None:
    """``bhem-hpc paths``: the path-following page."""
    paths = sub.add_parser("paths", help="run the static path-following jobs against their references")
    paths.add_argument("--docs", type=Path, default=Path("docs"), help="write DOCS/path-following.md and its PNGs")
    paths.add_argument("--out", type=Path, default=Path("out/paths"), help="the runs' output directories")


def _add_interfaces(sub) -> None:
    """``bhem-hpc interfaces``: joined patches by the penalty against shared edge data."""
    page = sub.add_parser("interfaces", help="patches joined by the penalty coupling against patches sharing their "
                          "edge data: static cases against one patch over the penalty factor, the patch test, the "
                          "hood job")  # fmt: skip
    page.add_argument("--docs", type=Path, default=Path("docs"), help="write DOCS/interfaces.md, .json, .png")
    page.add_argument("--out", type=Path, default=Path("out/interfaces"), help="the hood runs' output directories")


def _add_contact_page(sub) -> None:
    """``bhem-hpc contact-page``: the contact jobs by impulses and by IPC, head to head."""
    page = sub.add_parser("contact-page", help="the contact jobs by impulses and by IPC over windows where contact "
                          "happens (serial, one run after the other)")  # fmt: skip
    page.add_argument("--docs", type=Path, default=Path("docs"), help="write DOCS/contact-comparison.md, .json")
    page.add_argument("--out", type=Path, default=Path("out/contact"), help="the runs' scenes and output directories")
    page.add_argument("--jobs", nargs="+", default=None, help="jobs (default: every contact job with a window)")
    page.add_argument("--timeout", type=float, default=1800.0, help="seconds each run may take before it is stopped")


def _add_states(sub) -> None:
    """``bhem-hpc states``: the shipped jobs' final states recorded, or compared with a record."""
    states = sub.add_parser("states", help="record the shipped jobs' final states, or compare with a record")
    states.add_argument("--record", type=Path, default=None, help="write the states to FILE (.npz)")
    states.add_argument("--compare", type=Path, default=None, help="compare with FILE (exit 1 if not equal)")
    states.add_argument("--steps", type=int, default=3, help="time steps (static jobs: path points) per job")
    states.add_argument("--jobs", nargs="+", default=None, help="job names of jobs/ (default: every TOML scene)")
    states.add_argument("--out", type=Path, default=Path("out/states"), help="the runs' output directories")
    states.add_argument("--tolerance", type=float, default=1e-12, help="largest relative difference that passes")


def _add_intersections(sub) -> None:
    """``bhem-hpc intersections``: whether a run's output meshes ever intersect."""
    audit = sub.add_parser("intersections", help="test every frame of a run's output meshes for intersections "
                           "(ipc-toolkit); exit 1 if one intersects")  # fmt: skip
    audit.add_argument("directory", type=Path, help="output directory of `bhem-hpc run`")
    audit.add_argument("--within", type=float, default=1e-3,
                       help="report the smallest distance between triangles closer than this [m]")  # fmt: skip


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bhem-hpc",
        description="Thin shells with C1 bicubic Hermite elements on FEniCSx/PETSc. "
        "Unrecognized -options are passed to PETSc (e.g. -bhem_static_snes_monitor).",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log solver progress")
    parser.add_argument("--debug", action="store_true", help="on an error, show the traceback too")
    sub = parser.add_subparsers(dest="command", required=True)
    cant = sub.add_parser("cantilever", help="static cantilever under self-weight vs the heavy elastica")
    cant.add_argument("--gamma", type=float, default=20.0, help="Gamma* = 12 (1-nu^2) rho g L^3 / (Y h^2)")
    cant.add_argument("--patches", type=int, default=32, help="patches along the strip")
    cant.add_argument("--load-steps", type=int, default=None, help="maximum load increment = 1/steps")
    cant.add_argument("--hessian", choices=HESSIAN_KINDS, default="exact")
    cant.add_argument("--out", type=Path, default=Path("out/cantilever"), help="output directory")
    run = sub.add_parser("run", help="run a scene file (TOML), writing XDMF, checkpoints and a summary")
    run.add_argument("scene", type=Path)
    run.add_argument("--out", type=Path, required=True, help="output directory")
    run.add_argument("--steps", type=int, default=None, help="number of time steps (overrides the scene)")
    run.add_argument("--restart", type=Path, default=None, help="continue from DIR/checkpoint.h5")
    run.add_argument("--force", action="store_true", help="overwrite a non-empty output directory")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    study = sub.add_parser("study", help="an accuracy-versus-cost study: CSV, Markdown table and PNG plot")
    study.add_argument("name", nargs="?", help="study name (plate, cantilever)")
    study.add_argument("--out", type=Path, help="output directory (must not exist or be empty)")
    study.add_argument("--docs", type=Path, help="run every study and write DOCS/accuracy-cost.md")
    _add_paths(sub)
    _add_cloth(sub)
    _add_solids(sub)
    _add_interfaces(sub)
    _add_states(sub)
    _add_contact_page(sub)
    _add_intersections(sub)
    render = sub.add_parser("render", help="ray-trace a saved frame's patches to PNG")
    render.add_argument("directory", type=Path,
                        help="output directory of `bhem-hpc run` (a shell's surface.h5, a solid's IGES frames)")
    render.add_argument("--frame", type=int, default=-1, help="frame index (default: the last)")
    render.add_argument("--size", default="320x240", help="WIDTHxHEIGHT in pixels")
    render.add_argument("--out", type=Path, default=None, help="PNG path (default: DIR/frame_K.png)")
    summary = sub.add_parser("summary", help="rewrite README.md's generated summary from the docs pages' rows")
    summary.add_argument("--docs", type=Path, default=Path("docs"), help="the docs directory")
    summary.add_argument("--readme", type=Path, default=Path("README.md"), help="the README to update")
    bench = sub.add_parser("bench", help="time one Newton iteration on an N x N sheet")
    bench.add_argument("--patches", type=int, nargs="+", default=BENCH_DEFAULT_PATCHES)
    bench.add_argument("--hessian", choices=HESSIAN_KINDS, default=None,
                       help="the Jacobian (default: exact for one iteration, the scene's with --scene)")
    bench.add_argument(
        "--discretization", choices=("hermite", "bspline2", "bspline3"), default="hermite", help="with --patches"
    )
    bench.add_argument(
        "--quadrature", type=_quadrature, default=None,
        help="with --patches: Gauss points per direction (2-5) or 'reduced' (bspline2); default: the discretization's",
    )  # fmt: skip
    bench.add_argument("--repeats", type=int, default=3)
    bench.add_argument("--json", action="store_true", help="print one JSON object per size")
    bench.add_argument("--scene", type=Path, default=None, help="time steps of this scene instead of one iteration")
    bench.add_argument("--steps", type=int, default=None, help="steps to time (--scene: 20, --docs: 5 per scene)")
    bench.add_argument("--warmup", type=int, default=1, help="with --scene: untimed steps first (e.g. a fall)")
    bench.add_argument("--samples", type=int, default=None, help="with --scene: contact samples per patch side")
    bench.add_argument("--docs", type=Path, default=None, help="measure everything and write DOCS/performance.md")
    bench.add_argument("--rays", action="store_true", help="ray-patch intersection: midpoint vs Newton-guided")
    bench.add_argument("--linear", choices=("auto", "direct", "iterative"), default=None,
                       help="with --scene: the linear solver (default: the scene's)")  # fmt: skip
    bench.add_argument(
        "--factorization", choices=("reuse", "fresh"), default=None,
        help="with --scene: keep factorizations across Newton iterations or not (default: the scene's)",
    )  # fmt: skip
    bench.add_argument(
        "--scaling", action="store_true",
        help="time steps of --scene (default jobs/million-cloth.toml) for every --ranks count, --patches size and "
        "linear solver, each in its own mpirun; writes CSV, Markdown, PNG",
    )  # fmt: skip
    bench.add_argument("--ranks", type=int, nargs="+", default=[1, 2], help="with --scaling: MPI rank counts")
    bench.add_argument("--dt", type=float, nargs="+", default=None,
                       help="with --scene: the time step; with --scaling: Krylov iterations against these time steps "
                            "(iterative solver, the first size, 1 rank)")  # fmt: skip
    bench.add_argument(
        "--fresh", type=int, nargs="+", default=None,
        help="with --scaling: also MUMPS factoring the Jacobian at every Newton iteration, one rank, these sizes",
    )  # fmt: skip
    bench.add_argument(
        "--weak", type=int, default=None,
        help="with --scaling: weak scaling too, patches per side for one rank (N sqrt(ranks) for more)",
    )  # fmt: skip
    bench.add_argument("--out", type=Path, default=Path("out/scaling"), help="with --scaling: the output folder")
    bench.add_argument("--mpirun", default=None, help="with --scaling: the MPI launcher (default: mpirun)")
    bench.add_argument("--timeout", type=float, default=3600.0, help="with --scaling: seconds per case")
    return parser


def _render(args: argparse.Namespace, comm) -> None:
    from bhem_hpc.io import read_frame
    from bhem_hpc.io.render import TrimmedSurface, render, write_png
    from bhem_hpc.io.run_directory import run_series
    from bhem_hpc.io.solid_output import read_solid_frame
    from bhem_hpc.io.xdmf import read_trim_loops

    if comm.rank != 0:  # serial: one rank renders
        return
    try:
        width, height = (int(v) for v in args.size.lower().split("x"))
    except ValueError as exc:
        raise InputError(f"--size must be WIDTHxHEIGHT, got {args.size!r}") from exc
    if not (1 <= width <= 4096 and 1 <= height <= 4096):
        raise InputError(f"--size must be between 1x1 and 4096x4096, got {args.size!r}")
    series = run_series(args.directory)  # a run of one body's, or each body's of a run of several
    if args.out is not None and not args.out.parent.is_dir():
        raise InputError(f"--out {args.out}: the folder {args.out.parent} does not exist")
    surfaces = []
    for h5 in series:
        if h5.suffix == ".pvd":  # a solid's frames: its deformed model as IGES
            surface, time = read_solid_frame(h5, args.frame)
            surfaces.append(surface)
            continue
        try:
            surface, time = read_frame(h5, args.frame)
            loops = read_trim_loops(h5)
        except (OSError, KeyError, TypeError) as exc:
            raise InputError(f"{h5}: not a readable surface series ({exc})") from None
        surfaces.append(surface if loops is None else TrimmedSurface(surface, tuple(loops)))
    image, mask = render(surfaces, width, height)
    out = args.out or args.directory / f"frame_{args.frame if args.frame >= 0 else 'last'}.png"
    write_png(out, image)
    print(f"rendered t = {time:.6g} s, {width}x{height}, {int(mask.sum())} pixels on the surface: {out}")


def _study(args: argparse.Namespace, comm) -> None:
    from bhem_hpc.studies.report import run_study, write_accuracy_cost

    if args.docs is not None:
        path = write_accuracy_cost(args.docs, comm)
        if comm.rank == 0:
            print(f"wrote {path}")
        return
    if args.name is None or args.out is None:
        raise InputError("study needs NAME and --out DIR, or --docs DIR")
    rows = run_study(args.name, args.out, comm)
    if comm.rank == 0:
        print(f"study {args.name}: {len(rows)} configurations -> {args.out}/{args.name}.csv, .md, .png")


def _run(args: argparse.Namespace, comm) -> None:
    from bhem_hpc.run import RunOptions, run_scene

    options = RunOptions(args.scene, args.out, args.steps, args.restart, args.force, not args.no_progress)
    summary = run_scene(options, comm)
    if comm.rank == 0:
        steps = summary["steps"]
        newton = sum(s["newton_iterations"] for s in steps)
        if summary["static"]:
            events = [f"{e['kind']} point at load factor {e['load_factor']:.6g} (between path points {s['step'] - 1} "
                      f"and {s['step']})" for s in steps for e in s.get("events", ())]  # fmt: skip
            print(
                f"{args.scene}: {len(steps)} path point(s) to load factor {summary['load_factor']:.6g}, "
                f"{summary['dofs']} DoFs, {comm.size} rank(s), {newton} Newton iterations"
                + "".join(f"\n  {e}" for e in events)
                + f"\n  output: {args.out}/path.csv, path.png, surface.xdmf and surface.pvd (ParaView), last.png, "
                "summary.json, checkpoint.h5"
            )
            return
        output = f"{args.out}/surface.xdmf and surface.pvd (ParaView), last.png, summary.json, checkpoint.h5"
        if "bodies" in summary:
            folders = ", ".join(f"{body['name']}/" for body in summary["bodies"])
            models = "".join(f", {m['body']}/" for m in summary.get("cad_models") or [])
            output = (f"{args.out}/bodies.pvd (ParaView: every body), {folders} (a shell's surface.xdmf and "
                      "surface.pvd, a solid's surface.pvd and surface_points.pvd)"
                      + (f"{models} (a CAD shell's deformed model at each frame, IGES)" if models else "")
                      + ", last.png, summary.json")  # fmt: skip
        print(
            f"{args.scene}: {len(steps)} step(s) to t = {summary['time']:.6g} s, {summary['dofs']} DoFs, "
            f"{comm.size} rank(s), {newton} Newton iterations, "
            f"{sum(s.get('recoveries', 0) for s in steps)} recoveries\n  output: {output}"
        )


def _cantilever(args: argparse.Namespace, comm) -> None:
    from bhem_hpc.studies.cantilever import cantilever

    summary = cantilever(args.gamma, args.out, args.patches, args.load_steps, args.hessian, comm)
    if comm.rank == 0:
        print(
            f"cantilever Gamma* = {args.gamma:g}, {summary['patches'][0]} patches, {summary['dofs']} DoFs, "
            f"{comm.size} rank(s): {summary['load_steps']} load steps, "
            f"{sum(summary['newton_iterations'])} Newton iterations, {summary['solve_s']:.2f} s\n"
            f"  tip drop H/L  = {summary['tip_H_over_L']:.6f}  "
            f"heavy elastica {summary['reference_H_over_L']:.6f}"
            f"  ({100 * summary['relative_error_H']:+.4f} %)\n"
            f"  tip reach W/L = {summary['tip_W_over_L']:.6f}  "
            f"heavy elastica {summary['reference_W_over_L']:.6f}"
            f"  ({100 * summary['relative_error_W']:+.4f} %)\n"
            f"  output: {args.out}/cantilever.xdmf (ParaView), cantilever.png, cantilever-3d.png, summary.json"
        )


def _quadrature(text: str) -> int | str:
    """``--quadrature``: an integer number of Gauss points per direction, or ``reduced``."""
    return text if text == "reduced" else int(text)


def _check_bench(args: argparse.Namespace) -> None:
    """Counts and sizes of ``bench`` refused before anything is allocated."""
    for name, value, low in (("--repeats", args.repeats, 1), ("--steps", args.steps, 1), ("--warmup", args.warmup, 0),
                             ("--samples", args.samples, 1)):  # fmt: skip
        if value is not None and not low <= value <= 100_000:
            raise InputError(f"{name} must be an integer in {low}..100000, got {value}")
    if any(not 1 <= n <= MAX_BENCH_PATCHES for n in args.patches):
        raise InputError(f"--patches takes sizes in 1..{MAX_BENCH_PATCHES} (patches per side), got {args.patches}")
    direct = not (args.scaling or args.rays or args.scene is not None or args.docs is not None)
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    needed = NEWTON_BYTES_PER_PATCH * max(args.patches) ** 2
    if direct and needed > memory:
        raise InputError(f"--patches {max(args.patches)} needs about {needed / 2**30:.0f} GiB for one Newton "
                         f"iteration with MUMPS; this machine has {memory / 2**30:.0f} GiB")  # fmt: skip


def _bench(args: argparse.Namespace, comm) -> None:
    from bhem_hpc.benchmarks import performance, timing

    _check_bench(args)

    if args.scaling:
        from bhem_hpc.benchmarks import scaling

        scaling.run_scaling_command(args, comm)
    elif args.rays:
        rows = [timing.ray_benchmark(n) for n in args.patches] if comm.rank == 0 else []
        for row in rows:
            print(json.dumps(row) if args.json else timing.format_ray_row(row))
    elif args.docs is not None:
        jobs = Path(__file__).resolve().parents[1] / "jobs"
        path = performance.write_performance(args.docs, jobs, args.steps or 5, comm)
        if comm.rank == 0:
            print(f"wrote {path}")
    elif args.scene is not None:
        row = timing.scene_benchmark(args.scene, args.steps or 20, args.hessian, comm, args.warmup, args.samples,
                                         _scene_overrides(args))  # fmt: skip
        if comm.rank == 0:
            print(json.dumps(row) if args.json else timing.format_scene_row(row))
    else:
        hessian = args.hessian or "exact"
        rows = [
            timing.benchmark(
                n, hessian, args.repeats, comm, discretization=args.discretization, quadrature=args.quadrature
            )
            for n in args.patches
        ]
        if comm.rank == 0:
            table = timing.format_newton_table(rows, hessian, args.repeats)
            print("\n".join(json.dumps(row) for row in rows) if args.json else table)


def _scene_overrides(args: argparse.Namespace) -> dict[str, dict]:
    """The scene keys ``bench --scene`` replaces: linear solver, factorization, patches, dt."""
    overrides = {"solver": {k: v for k, v in (("linear", args.linear), ("factorization", args.factorization)) if v}}
    if args.patches != BENCH_DEFAULT_PATCHES:
        if len(args.patches) != 1:
            raise InputError(f"--scene takes one --patches size, got {args.patches}")
        overrides["surface"] = {"patches": [args.patches[0]] * 2}
    if args.dt:
        if len(args.dt) != 1:
            raise InputError(f"--scene takes one --dt, got {args.dt}")
        overrides["time"] = {"dt": args.dt[0], "steps": 1000, "duration": None}
    return overrides


def _cloth(args: argparse.Namespace, comm) -> None:
    from bhem_hpc.studies.cloth_page import CLOTH_JOBS, cloth_cases, write_cloth_comparison

    if args.steps < 1:
        raise InputError(f"--steps must be >= 1, got {args.steps}")
    sizes = {"hermite": tuple(args.hermite), "bspline2": tuple(args.bspline2), "bspline3": tuple(args.bspline3)}
    for name, values in sizes.items():
        if any(n < 2 or n > 400 for n in values):
            raise InputError(f"--{name} takes sizes in 2..400, got {list(values)}")
    jobs = tuple(args.jobs) if args.jobs else None
    if jobs is not None and not set(jobs) <= set(CLOTH_JOBS):
        raise InputError(f"--jobs takes {CLOTH_JOBS}, got {list(jobs)}")
    cases = cloth_cases(sizes, jobs) if jobs else cloth_cases(sizes)
    unknown = sorted(set(args.whole) - {case.name for case in cases})
    if unknown:
        raise InputError(f"--whole names cases the page does not run: {unknown} (its cases: "
                         f"{[case.name for case in cases]})")  # fmt: skip
    flags = " ".join(f"--{name} {' '.join(map(str, values))}".rstrip() for name, values in sizes.items())
    command = f"bhem-hpc cloth --docs {args.docs} --steps {args.steps} {flags}" + (
        f" --jobs {' '.join(jobs)}" if jobs else "") + (f" --whole {' '.join(args.whole)}" if args.whole else "")
    page = write_cloth_comparison(args.docs, args.out, args.steps, cases, comm, command, frozenset(args.whole))
    if comm.rank == 0:
        print(f"wrote {page} ({len(cases)} cases, {args.steps} steps each)")


def _contact_page(args: argparse.Namespace, comm) -> None:
    from bhem_hpc.benchmarks.contact_page import CONTACT_WINDOWS, write_contact_page
    from bhem_hpc.studies.cloth_page import machine_label

    if comm.size > 1:
        raise InputError("bhem-hpc contact-page runs its jobs one after the other itself: run it without mpirun")
    known = [w.job for w in CONTACT_WINDOWS]
    if args.jobs is not None and not set(args.jobs) <= set(known):
        raise InputError(f"--jobs takes {known}, got {args.jobs}")
    if not args.timeout > 0:
        raise InputError(f"--timeout must be a positive number of seconds, got {args.timeout}")
    windows = tuple(w for w in CONTACT_WINDOWS if args.jobs is None or w.job in args.jobs)
    command = f"bhem-hpc contact-page --docs {args.docs}" + (f" --jobs {' '.join(args.jobs)}" if args.jobs else "")
    page = write_contact_page(args.docs, args.out, windows, args.timeout, command, machine_label())
    print(f"wrote {page} ({len(windows)} jobs, 2 methods each)")


def _solids(args: argparse.Namespace, comm) -> None:
    from bhem_hpc.studies.solids_page import write_solids_page

    if comm.size > 1:
        raise InputError("bhem-hpc solids runs serially (the SEM solids are serial); run it without mpirun")
    page = write_solids_page(args.docs, f"bhem-hpc solids --docs {args.docs}")
    print(f"wrote {page}")


def _interfaces(args: argparse.Namespace, comm) -> None:
    from bhem_hpc.studies.interfaces_page import write_interfaces_page

    if comm.size > 1:
        raise InputError("bhem-hpc interfaces runs serially (its times are one core's); run it without mpirun")
    page = write_interfaces_page(args.docs, args.out, f"bhem-hpc interfaces --docs {args.docs}")
    print(f"wrote {page}")


def _paths(args: argparse.Namespace, comm) -> None:
    from bhem_hpc.studies.path_page import write_path_following

    page = write_path_following(args.docs, args.out, comm)
    if comm.rank == 0:
        print(f"wrote {page}")


def _states(args: argparse.Namespace, comm) -> int:
    from bhem_hpc.benchmarks.reference_states import reference_states

    return reference_states(args.record, args.compare, args.jobs, args.steps, args.out, args.tolerance, comm)


def _intersections(args: argparse.Namespace, comm) -> int:
    from bhem_hpc.contact.audit import audit_run

    if comm.rank != 0:  # serial: one rank reads and tests
        return 0
    audits = audit_run(args.directory, args.within)
    crossing = [a for a in audits if a.intersecting]
    closest = min(audits, key=lambda a: a.min_distance)
    for a in crossing:
        print(f"frame {a.index} (t = {a.time:.6g}): intersecting")
    nearest = f"{closest.min_distance:.3g} m at frame {closest.index} (t = {closest.time:.6g})" \
        if math.isfinite(closest.min_distance) else f"none closer than {args.within:g} m"
    print(f"{len(audits)} frames, {len(crossing)} intersecting; smallest distance between triangles: {nearest}")
    return 1 if crossing else 0


def _summary(args: argparse.Namespace, comm) -> None:
    from bhem_hpc.studies.summary import update_readme

    if comm.rank == 0:
        update_readme(args.readme, args.docs)
        print(f"updated the summary in {args.readme}")


#: One handler per subcommand: ``handler(args, comm)``, which may return an exit status.
HANDLERS = {
    "run": _run,
    "render": _render,
    "study": _study,
    "bench": _bench,
    "summary": _summary,
    "paths": _paths,
    "cloth": _cloth,
    "solids": _solids,
    "interfaces": _interfaces,
    "contact-page": _contact_page,
    "states": _states,
    "intersections": _intersections,
    "cantilever": _cantilever,
}


def _configure_logging(verbose: bool, rank: int) -> None:
    """Warnings only unless ``--verbose``; the form compiler's command lines only with ``--verbose``."""
    level = logging.INFO if verbose and rank == 0 else logging.WARNING
    logging.basicConfig(level=level, format=f"[rank {rank}] %(levelname)s %(name)s: %(message)s", force=True)
    # setuptools, which compiles the finite elements' code on a first run, sets the root logger's
    # level to INFO: below the chosen level only this package's loggers (at their own levels) print
    logging.getLogger("bhem_hpc").setLevel(level)
    for handler in logging.getLogger().handlers:
        handler.addFilter(lambda record: record.levelno >= level or record.name.startswith("bhem_hpc"))
    for noisy in ("ffcx", "UFL"):
        logging.getLogger(noisy).setLevel(logging.INFO if verbose else logging.ERROR)
    # the one line that says forms were compiled, and how long it took (with --verbose, the compiler's too)
    jit_level = (logging.DEBUG if verbose else logging.INFO) if rank == 0 else logging.WARNING
    logging.getLogger("bhem_hpc.jit").setLevel(jit_level)


def main(argv: list[str] | None = None) -> int:
    use_best_kernels()  # before numpy or PETSc load OpenBLAS, which reads its kernel choice once
    argv = list(sys.argv[1:] if argv is None else argv)
    for arg in argv:  # bytes that are not UTF-8 arrive as surrogates, which MPI and PETSc cannot take
        try:
            arg.encode("utf-8")
        except UnicodeEncodeError:
            shown = arg.encode("utf-8", "replace").decode()
            print(f"bhem-hpc: error: argument {shown!r} is not UTF-8 text", file=sys.stderr)
            return 2
    args, petsc_args = _parser().parse_known_args(argv)
    bad = [a for a in petsc_args if a.startswith("--")]
    if bad:
        _parser().error(f"unrecognized arguments: {' '.join(bad)}")
    import petsc4py

    if "petsc4py.PETSc" not in sys.modules:  # a second init (main called in-process) would unbalance PETSc's finalize
        petsc4py.init([sys.argv[0], *petsc_args])
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    _configure_logging(args.verbose, comm.rank)
    from bhem_hpc.scene.petsc_options import command_line_options, option_problem

    for name, value in command_line_options(petsc_args):  # before any solver reads them
        if (problem := option_problem(name, value)) is not None:
            if comm.rank == 0:
                print(f"bhem-hpc: error: PETSc option -{name} must be {problem}, got {value!r}", file=sys.stderr)
            return 2

    from bhem_hpc.errors import UserError

    try:
        status = HANDLERS[args.command](args, comm)
    except UserError as exc:
        if comm.rank == 0:
            if args.debug:
                traceback.print_exc()
            print(f"bhem-hpc: error: {exc}", file=sys.stderr)
        _exit_past_failed_hdf5_files()
        return 2
    except Exception:
        # not the input's fault: a bug, reported with its traceback (Python prints it)
        print(f"bhem-hpc: internal error on rank {comm.rank} (a bug in bhem-hpc; please report it with "
              "the traceback below)", file=sys.stderr)  # fmt: skip
        raise
    return status or 0


def _exit_past_failed_hdf5_files() -> None:
    """After a failed HDF5 write (disk full): end the process without freeing that file, which
    would crash HDF5; MPI is finalized first, so mpirun sees an ordinary exit with code 2."""
    from bhem_hpc.io.xdmf import abandoned_files

    if abandoned_files():
        sys.stdout.flush()
        sys.stderr.flush()
        from mpi4py import MPI

        MPI.Finalize()
        os._exit(2)


if __name__ == "__main__":
    sys.exit(main())
