"""The path-following page: the static jobs run through ``bhem-hpc run`` and their load-displacement
paths compared with their references (``bhem-hpc paths --docs DIR`` writes ``DIR/path-following.md``
and a PNG per case)."""

from __future__ import annotations

import csv
import functools
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from bhem_hpc.studies.paths import CompressedStrip, CylindricalPanel, ShallowArch, snap_landmarks
from bhem_hpc.studies.references import pinned_elastica, shallow_arch_load

JOBS = Path(__file__).resolve().parents[2] / "jobs"


@dataclass(frozen=True)
class PathCase:
    """A static job and how its path is checked: ``check(rows) -> (error, what the error is)``, and
    ``curves() -> {label: (displacements, load factors)}`` of its reference for the plot, with the
    path.csv columns ``plotted`` against the load factor."""

    job: str
    title: str
    reference: str
    check: object
    curves: object
    plotted: tuple[str, ...]


def _floats(rows: list[dict], key: str) -> np.ndarray:
    return np.array([float(r[key]) for r in rows])


def _arch(rows: list[dict]) -> tuple[float, str]:
    arch = ShallowArch()
    rises = (arch.rise + _floats(rows, "mid_uz")) / arch.gyration_radius
    peak = shallow_arch_load(math.sqrt((arch.initial_rise**2 - 4) / 3), arch.initial_rise)
    error = np.abs(_floats(rows, "load_factor") - shallow_arch_load(rises, arch.initial_rise)).max() / peak
    return float(error), "largest load-factor error along the path / limit load"


def _strip(rows: list[dict]) -> tuple[float, str]:
    bow = 1e-4 * CompressedStrip().length
    errors = []
    for row in rows[1:]:
        deflection = float(row["mid_uz"]) + bow
        if deflection >= 0.1:  # far enough from the bifurcation for the bow's w0 / w to be small
            load, _ = pinned_elastica(deflection)
            errors.append(abs(float(row["load_factor"]) / load - 1))
    return float(max(errors)), (
        "largest relative load error against the elastica for w / L >= 0.1 (the bow of 1e-4 L lowers the load "
        "by about w0 / w <= 1e-3)"
    )


def _arch_curve() -> dict:
    arch = ShallowArch()
    rises = np.linspace(arch.initial_rise, -1.35 * arch.initial_rise, 400)
    return {"closed form": (rises * arch.gyration_radius - arch.rise, shallow_arch_load(rises, arch.initial_rise))}


def _elastica_curve() -> dict:
    deflections = np.linspace(1e-4, 0.3, 200)
    loads = [pinned_elastica(w)[0] for w in deflections]
    return {"elastica": (np.concatenate([[0.0], deflections]) - 1e-4, np.concatenate([[0.0], loads]))}


def _circle_curve() -> dict:
    factors = np.linspace(1e-3, 1.0, 200)
    radii = 1.0 / (2 * np.pi * factors)
    return {
        "exact ux": (radii * np.sin(1 / radii) - 1.0, factors),
        "exact uz": (radii * (1 - np.cos(1 / radii)), factors),
    }


@functools.cache
def _panel_reference(patches: int = 16) -> tuple[dict, ...]:
    """The cylindrical panel's path on ``patches`` (the job's arc-length settings), as path.csv rows."""
    from bhem_hpc.scene import load_scene

    settings = load_scene(JOBS / "cylindrical-panel.toml").path_plan.arc_length
    points = CylindricalPanel().follow(patches, settings, MPI.COMM_SELF)
    return tuple({"load_factor": p.load_factor, "centre_uy": p.probes["centre"]["displacement"][1]} for p in points)


def _panel_landmarks(rows) -> dict[str, float]:
    return snap_landmarks(list(_floats(rows, "load_factor")), list(-_floats(rows, "centre_uy")))


def _panel(rows: list[dict]) -> tuple[float, str]:
    coarse, fine = _panel_landmarks(rows), _panel_landmarks(_panel_reference())
    error = max(abs(coarse[k] / fine[k] - 1) for k in coarse)
    detail = ", ".join(f"{k} {coarse[k]:.5g} ({fine[k]:.5g})" for k in coarse)
    return float(error), f"largest relative difference of the landmarks from 16 x 16 patches: {detail}"


def _panel_curve() -> dict:
    rows = _panel_reference()
    return {"16 x 16 patches": (_floats(rows, "centre_uy"), _floats(rows, "load_factor"))}


def _circle(radius_of_factor) -> object:
    def check(rows: list[dict]) -> tuple[float, str]:
        errors = []
        for row in rows[1:]:
            radius = radius_of_factor(float(row["load_factor"]))
            angle = 1.0 / radius
            exact = np.array([radius * math.sin(angle), radius * (1 - math.cos(angle))])
            tip = np.array([float(row["tip_x"]), float(row["tip_z"])])
            errors.append(np.linalg.norm(tip - exact))
        return float(max(errors)), "largest distance of the tip from its place on the exact circle, / L"

    return check


CASES = (
    PathCase("shallow-arch", "Shallow arch: snap-through by arc length", "Marguerre's closed form", _arch,
             _arch_curve, ("mid_uz",)),  # fmt: skip
    PathCase("compressed-strip", "Compressed strip: past Euler's load by displacement control",
             "the pinned elastica", _strip, _elastica_curve, ("mid_uz",)),  # fmt: skip
    PathCase("cylindrical-panel", "Cylindrical panel: snap-through and snap-back by arc length",
             "the same path on 16 x 16 patches", _panel, _panel_curve, ("centre_uy",)),  # fmt: skip
    PathCase("roll-up", "Roll-up by a prescribed end rotation", "the circle of radius L / (2 pi lambda)",
             _circle(lambda factor: 1.0 / (2 * math.pi * factor)), _circle_curve, ("tip_ux", "tip_uz")),  # fmt: skip
    PathCase("moment-roll-up", "Roll-up by an end moment", "the circle of radius D / m",
             _circle(lambda factor: 1.0 / (2 * math.pi * factor)), _circle_curve, ("tip_ux", "tip_uz")),  # fmt: skip
)


def _plot(case: PathCase, rows: list[dict], png: Path) -> None:
    """The path's points over the reference curves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=100)
    for label, (x, y) in case.curves().items():
        ax.plot(x, y, "-", color="0.6", linewidth=1.5, label=label)
    factors = _floats(rows, "load_factor")
    for column in case.plotted:
        ax.plot(_floats(rows, column), factors, "o", markersize=4, fillstyle="none", label=f"computed {column}")
    events = [r for r in rows if r["event"]]
    if events:
        ax.plot(_floats(events, case.plotted[0]), _floats(events, "load_factor"), "^", color="red", markersize=8,
                label="flagged event")  # fmt: skip
    ax.set_xlabel("displacement (in the job's length unit)")
    ax.set_ylabel("load factor")
    ax.set_title(case.title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)


def write_path_following(docs: Path, runs: Path, comm: MPI.Comm = MPI.COMM_WORLD) -> Path:
    """Run every case into ``runs/<job>`` and write ``docs/path-following.md`` with a table and each
    case's load-displacement plot (``docs/path-<job>.png``). Collective."""
    from bhem_hpc.run import RunOptions, run_scene

    lines = [
        "# Path following",
        "",
        "Generated by `bhem-hpc paths --docs docs` from the static jobs in `jobs/`, each run as "
        "`bhem-hpc run jobs/JOB.toml --out out/paths/JOB`. Every point of a path is a converged equilibrium; "
        "a `limit` is where the load factor turned between two points, given at the extremum of its "
        "cubic interpolant in the arc length (from the points' tangents), a `bifurcation` where the "
        f"tangent's inertia (negative pivots of its LDL^T) changed otherwise. Ranks: {comm.size}.",
        "",
        "| case | method | points | Newton iterations | events | reference | error | measure | seconds |",
        "| --- | --- | ---: | ---: | --- | --- | ---: | --- | ---: |",
    ]
    figures = []
    if comm.rank == 0:
        docs.mkdir(parents=True, exist_ok=True)
    for case in CASES:
        out = runs / case.job
        start = time.perf_counter()
        summary = run_scene(RunOptions(JOBS / f"{case.job}.toml", out, force=True, progress=False), comm)
        seconds = time.perf_counter() - start
        if comm.rank != 0:
            continue
        with open(out / "path.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        error, measure = case.check(rows)
        events = ", ".join(f"{r['event']} at {float(r.get('event_load_factor') or r['load_factor']):.4g}"
                           for r in rows if r["event"]) or "none"  # fmt: skip
        method = summary.get("path_method", "")
        iterations = sum(int(r["newton_iterations"]) for r in rows)
        lines.append(f"| {case.title} | {method} | {len(rows) - 1} | {iterations} | {events} | {case.reference} "
                     f"| {error:.2e} | {measure} | {seconds:.1f} |")  # fmt: skip
        figure = docs / f"path-{case.job}.png"
        _plot(case, rows, figure)
        figures += ["", f"## {case.title}", "", f"![{case.title}]({figure.name})"]
    if comm.rank == 0:
        page = docs / "path-following.md"
        page.write_text("\n".join(lines + figures) + "\n")
        return page
    return docs / "path-following.md"
