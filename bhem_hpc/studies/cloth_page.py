"""The B-spline cloth paper's comparison tests timed against its table: the cotton jobs run through
``bhem-hpc run`` at the paper's resolutions (``bhem-hpc cloth --docs DIR`` writes
``DIR/cloth-comparison.md``, its JSON rows and a PNG of seconds per step against DoFs).

Each case is a shipped job whose ``[surface]`` (resolution, discretization) and ``[solver]``
(quadrature) and ``[material]`` (membrane) keys are replaced; the quality figure is the number of
wrinkles along a line of the final state, so that runs are paired by measurement, not by eye.
"""

from __future__ import annotations

import json
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

JOBS = Path(__file__).resolve().parents[2] / "jobs"
#: The paper's seconds per step as the issue reads its supplemental table: (job, discretization,
#: knot spans or patches) -> s/step; its own text (§5) names a 24-core Xeon w7-3345 for its figures.
PAPER_SECONDS = {
    ("hanging", "hermite", 25): 116.67,
    ("drape-cotton", "hermite", 25): 13.92,
    ("hanging", "bspline2", 75): 1.43,
    ("drape-cotton", "bspline2", 100): 2.11,
}
PAPER_MACHINE = "the paper's figures: its BHEM re-implementation and its B-spline FEM, C++ with CHOLMOD and TBB"
#: Per job: the line of parameters (xi1, xi2) from, to along which wrinkles are counted, and the
#: coordinate that is out of the sheet's initial plane.
WRINKLE_LINES = {
    "hanging": (((0.05, 0.85), (0.95, 0.85)), 2),
    "drape-cotton": (((0.05, 0.5), (0.95, 0.5)), 1),  # it hangs in a vertical plane: wrinkles along y
    "shear": (((0.05, 0.5), (0.95, 0.5)), 2),
}
#: A wrinkle is counted where the detrended height crosses +-this [m] alternately.
WRINKLE_AMPLITUDE = 5e-4
#: The paper's resolutions: Hermite patches, B-spline knot spans.
PAPER_SIZES = {"hermite": (25, 35), "bspline2": (75, 100, 125), "bspline3": (75, 100, 125)}


@dataclass(frozen=True)
class ClothCase:
    """One run: a job at a resolution, discretization, quadrature and membrane."""

    job: str
    discretization: str
    patches: int
    quadrature: int | str | None = None
    membrane: str = "svk"
    young: float | None = None  # Young's modulus replacing the job's (the locking sweep)

    @property
    def name(self) -> str:
        parts = [self.job, self.discretization, str(self.patches)]
        parts += [] if self.quadrature is None else [str(self.quadrature)]
        parts += [] if self.membrane == "svk" else [self.membrane]
        return "-".join(parts + ([] if self.young is None else [f"Y{self.young:g}"]))

    def scene_text(self) -> str:
        """The job's TOML with this case's keys replaced (the jobs keep each key on a line of its own)."""
        lines = []
        table = ""
        for line in (JOBS / f"{self.job}.toml").read_text().splitlines():
            stripped = line.split("#")[0].strip()
            if stripped.startswith("["):
                table = stripped
            key = stripped.split("=")[0].strip()
            if table == "[surface]" and key in ("patches", "discretization"):
                continue
            if (table, key) in (("[solver]", "quadrature"), ("[material]", "young")) and (
                key != "young" or self.young is not None
            ):
                continue
            lines.append(line)
            if stripped == "[surface]":
                lines += [f"patches = [{self.patches}, {self.patches}]", f'discretization = "{self.discretization}"']
            if stripped == "[solver]" and self.quadrature is not None:
                value = f'"{self.quadrature}"' if isinstance(self.quadrature, str) else str(self.quadrature)
                lines.append(f"quadrature = {value}")
            if stripped == "[material]" and self.membrane == "fbw":
                lines += ['membrane = "fbw"', "shear_ratio = 1.0"]
            if stripped == "[material]" and self.young is not None:
                lines.append(f"young = {self.young!r}")
        return "\n".join(lines) + "\n"


#: The locking test's membrane stiffness sweep: Young's moduli [Pa] (cotton's 2 MPa among them).
LOCKING_YOUNG = (2e4, 2e5, 2e6)


CLOTH_JOBS = (*WRINKLE_LINES, "locking-cotton")


def cloth_cases(sizes: dict[str, tuple[int, ...]] | None = None, jobs: tuple[str, ...] = CLOTH_JOBS) -> list[ClothCase]:
    """Every job with Hermite patches, quadratic B-splines (3 x 3 Gauss and the reduced rule) and
    cubic B-splines at ``sizes`` (default: the paper's); hanging and drape also with the FBW
    membrane at each discretization's smallest size; the locking test's stiffness sweep there."""
    sizes = sizes or PAPER_SIZES
    cases = []
    for job in jobs:
        if job == "locking-cotton":  # the sweep, at each discretization's smallest size
            for discretization, ns in sizes.items():
                cases += [ClothCase(job, discretization, ns[0], young=y) for y in LOCKING_YOUNG if ns]
            continue
        for n in sizes.get("hermite", ()):
            cases.append(ClothCase(job, "hermite", n))
        for n in sizes.get("bspline2", ()):
            cases += [ClothCase(job, "bspline2", n), ClothCase(job, "bspline2", n, "reduced")]
        for n in sizes.get("bspline3", ()):
            cases.append(ClothCase(job, "bspline3", n))
        if job in ("hanging", "drape-cotton"):
            for discretization in ("hermite", "bspline2"):
                if sizes.get(discretization):
                    cases.append(ClothCase(job, discretization, sizes[discretization][0], membrane="fbw"))
    return cases


def count_wrinkles(surface, job: str, samples: int = 400) -> int:
    """Wrinkles along the job's line of ``surface`` (a Hermite or B-spline surface): the height out of
    the initial plane, less its best quadratic fit (the sag), crosses +- :data:`WRINKLE_AMPLITUDE`
    alternately; each pair of crossings is a wrinkle."""
    (start, end), axis = WRINKLE_LINES[job]
    s = np.linspace(0.0, 1.0, samples)
    xi1 = start[0] + s * (end[0] - start[0])
    xi2 = start[1] + s * (end[1] - start[1])
    height = surface.evaluate(xi1, xi2).x[:, axis]
    residual = height - np.polyval(np.polyfit(s, height, 2), s)
    crossings, side = 0, 0
    for value in residual:
        now = 1 if value > WRINKLE_AMPLITUDE else -1 if value < -WRINKLE_AMPLITUDE else 0
        if now and now != side:
            crossings += side != 0
            side = now
    return (crossings + 1) // 2


def free_corner_drop(surface) -> float:
    """The locking test's figure: how far the two free corners (xi = (1, 0), (0, 1)) hang below the
    held ones (xi = (0, 0), (1, 1)), in z [m]; membrane locking makes it smaller."""
    held = surface.evaluate(np.array([0.0, 1.0]), np.array([0.0, 1.0])).x[:, 2].mean()
    free = surface.evaluate(np.array([1.0, 0.0]), np.array([0.0, 1.0])).x[:, 2].mean()
    return float(held - free)


def quality(surface, job: str) -> tuple[str, float]:
    """The job's measured quality figure of a final state: its name and value."""
    if job in WRINKLE_LINES:
        return "wrinkles", float(count_wrinkles(surface, job))
    return "free-corner drop [m]", free_corner_drop(surface)


def run_case(case: ClothCase, runs: Path, steps: int | None, comm: MPI.Comm) -> dict:
    """Run ``case`` for ``steps`` steps (None: to its job's end) into ``runs/<name>``; its figures
    (rank 0; {} elsewhere)."""
    from bhem_hpc.io import read_checkpoint
    from bhem_hpc.run import RunOptions, run_scene
    from bhem_hpc.scene import load_scene

    out = runs / case.name
    scene_file = runs / f"{case.name}.toml"
    if comm.rank == 0:
        runs.mkdir(parents=True, exist_ok=True)
        scene_file.write_text(case.scene_text())
    comm.Barrier()
    start = time.perf_counter()
    summary = run_scene(RunOptions(scene_file, out, steps=steps, force=True, progress=False), comm)
    seconds = time.perf_counter() - start
    if comm.rank != 0:
        return {}
    records = summary["steps"]
    scene = load_scene(scene_file)
    arrays, _ = read_checkpoint(out / "checkpoint.h5")
    final = scene.surface.with_nodal(arrays["position_nodal"])
    count = len(records)
    return {
        "case": case.name, "job": case.job, "discretization": case.discretization, "patches": case.patches,
        "quadrature": case.quadrature, "membrane": case.membrane, "hessian": scene.hessian, "dofs": summary["dofs"],
        "nonzeros": summary["nonzeros"], "steps": count, "status": summary["status"],
        "step_s": sum(r["wall_s"] for r in records) / count,
        "newton_per_step": sum(r["newton_iterations"] for r in records) / count,
        "newton_max": max(r["newton_iterations"] for r in records), "whole": steps is None,
        "dt_halvings": sum(r["dt_halvings"] for r in records),
        "recoveries": sum(r["recoveries"] for r in records),
        "quality": quality(final, case.job), "run_s": seconds,
        "paper_step_s": PAPER_SECONDS.get((case.job, case.discretization, case.patches)),
    }  # fmt: skip


def cloth_markdown(rows: list[dict], steps: int, command: str = "") -> str:
    """The page: how it was made, the machine, and a row per case (``*`` on the steps of a whole run)."""
    cpu = machine_label()
    whole = [r["case"] for r in rows if r.get("whole")]
    whole_runs = (f" The cases marked * ({', '.join(whole)}) ran to their job's end instead, as the paper's "
                  "figures do." if whole else "")  # fmt: skip
    lines = [
        "# Cotton cloth against the B-spline cloth paper's table",
        "",
        f"Generated by `{command or f'bhem-hpc cloth --docs docs --steps {steps}'}` in one run on {cpu}. "
        "Each case is a job of `jobs/` (cotton: 472.6 kg/m³, 0.318 mm, ν 0.243, Y 2 MPa; dt 10 ms) at the "
        f"given resolution, run for its first {steps} steps by `bhem-hpc run`; s/step is the mean wall time "
        f"of those steps (the paper averages whole runs).{whole_runs} Newton/step: the mean over the steps, "
        "and the most any one step took. Wrinkles: along the job's line of the final state, "
        f"the height out of the initial plane less its quadratic fit crosses ±{WRINKLE_AMPLITUDE * 1e3:g} mm "
        "alternately; the locking test's figure is how far its free corners hang below the held ones (membrane "
        "locking makes it smaller). FBW rows use the FEM Baraff–Witkin membrane with shear_ratio = 1. Hessian: "
        "the job's `solver.hessian` (`trust_region`: TAO's Newton trust region on the energy). Newton stops by the "
        "job's `[solver]` tests: an RMS acceleration residual of 1e-2 m/s², or a step that leaves less than 1e-2 of "
        "the sheet's diagonal per second to correct (`velocity_tolerance = \"auto\"`, IPC's test, which the paper's "
        f"solver uses). Paper s/step: {PAPER_MACHINE}.",
        "",
        "| case | Hessian | DoFs | nonzeros | steps | s/step | Newton/step | most | dt halvings | recoveries | "
        "quality | paper s/step |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        paper = "" if r["paper_step_s"] is None else f"{r['paper_step_s']:.2f}"
        status = "" if r["status"] == "completed" else f" ({r['status']})"
        lines.append(f"| {r['case']}{status} | {r.get('hessian', '')} | {r['dofs']} | {r['nonzeros']} | "
                     f"{r['steps']}{'*' if r.get('whole') else ''} | {r['step_s']:.3g} | "
                     f"{r['newton_per_step']:.2f} | {r.get('newton_max', '')} | {r['dt_halvings']} | "
                     f"{r['recoveries']} | "
                     f"{r['quality'][0]} {r['quality'][1]:.4g} | "
                     f"{paper} |")  # fmt: skip
    return "\n".join(lines + ["", "![seconds per step against DoFs](cloth-comparison.png)"]) + "\n"


def machine_label() -> str:
    """The CPU model and how many ranks of how many cores ran (a page names the machine it measured)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return f"{line.split(':', 1)[1].strip()}, {MPI.COMM_WORLD.size} rank(s) of a {_cores()}-core machine"
    except OSError:
        pass
    return platform.processor() or "this machine"


def _cores() -> int:
    import os

    return os.cpu_count() or 1


def _plot(rows: list[dict], png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=100)
    for job in sorted({r["job"] for r in rows}):
        for discretization in sorted({r["discretization"] for r in rows}):
            chosen = [r for r in rows if r["job"] == job and r["discretization"] == discretization]
            if chosen:
                ax.loglog([r["dofs"] for r in chosen], [r["step_s"] for r in chosen], "o-",
                          label=f"{job}, {discretization}")  # fmt: skip
    for (job, discretization, _), seconds in PAPER_SECONDS.items():
        ax.axhline(seconds, color="0.7", linewidth=0.8, linestyle=":")
        ax.annotate(f"paper: {job}, {discretization}", (ax.get_xlim()[0], seconds), fontsize=6, color="0.4")
    ax.set_xlabel("DoFs")
    ax.set_ylabel("seconds per time step")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)


def write_cloth_comparison(docs: Path, runs: Path, steps: int, cases: list[ClothCase],
                           comm: MPI.Comm = MPI.COMM_WORLD, command: str = "",
                           whole: frozenset[str] = frozenset()) -> Path:  # fmt: skip
    """Run every case, for ``steps`` steps or, if its name is in ``whole``, to its job's end, and write
    ``docs/cloth-comparison.md``, ``.json`` and ``.png`` (``command``: the command line the page names
    as its origin). Collective."""
    rows = [run_case(case, runs, None if case.name in whole else steps, comm) for case in cases]
    page = docs / "cloth-comparison.md"
    if comm.rank == 0:
        docs.mkdir(parents=True, exist_ok=True)
        (docs / "cloth-comparison.json").write_text(json.dumps(rows, indent=1) + "\n")
        _plot(rows, docs / "cloth-comparison.png")
        page.write_text(cloth_markdown(rows, steps, command))
    return page
