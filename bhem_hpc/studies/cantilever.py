"""Heavy cantilever strip: tip drop against the heavy elastica (master curve)."""

from __future__ import annotations

import itertools
import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from mpi4py import MPI

from bhem_hpc.errors import InputError
from bhem_hpc.geometry import surface as S
from bhem_hpc.io import render_surface_png, write_surface_xdmf
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import DEFAULT_QUADRATURE, Loads, ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.studies.references import heavy_cantilever
from bhem_hpc.studies.study import Study, StudyError, flat_sheet, spline_variants, study_result, timed_solve

CANTILEVER_SIZE = (1.0, 0.1)  # length, width [m]


def cantilever_model(
    gamma: float,
    patches: int,
    hessian: str = "exact",
    comm: MPI.Comm = MPI.COMM_WORLD,
    discretization: str = "hermite",
    quadrature: int | str | None = None,
) -> ShellModel:
    """The strip of :func:`cantilever`: nu = 0, clamped at xi1 = 0, gravity set by ``Gamma*``."""
    length, width = CANTILEVER_SIZE
    material = Material(young=1e6, poisson=0.0, thickness=0.01, density=1000.0)
    gravity = gamma * material.young * material.thickness**2 / (12 * material.density * length**3)
    rest = flat_sheet(discretization, length, width, patches, 1)
    return ShellModel(
        rest,
        material,
        Loads(gravity=(0.0, 0.0, -gravity)),
        [bcs.clamp_edge(rest, "xi1_min")],
        hessian=hessian,
        quadrature_points=quadrature,
        comm=comm,
    )


def cantilever(
    gamma: float,
    out: Path,
    patches: int = 32,
    load_steps: int | None = None,
    hessian: str = "exact",
    comm: MPI.Comm = MPI.COMM_WORLD,
    options: dict | None = None,
) -> dict:
    """A 1 m x 0.1 m strip (nu = 0) clamped at one end, bending under its own weight.

    ``Gamma* = 12 (1 - nu^2) rho g L^3 / (Y h^2)`` sets gravity. Writes ``cantilever.xdmf/.h5``,
    ``cantilever.png`` (centreline vs elastica), ``cantilever-3d.png``, ``cantilever.npz`` (nodal
    data) and ``summary.json`` to ``out``.

    Returns:
        The summary: tip position against the heavy elastica, Newton iterations, timings.
    """
    if not (np.isfinite(gamma) and 0 < gamma <= 1e4):
        raise InputError(f"--gamma must be in (0, 1e4], got {gamma!r}")
    if patches < 1:
        raise InputError(f"--patches must be >= 1, got {patches!r}")
    steps = load_steps or max(1, int(np.ceil(2 * np.sqrt(gamma))))
    model = cantilever_model(gamma, patches, hessian, comm)
    length, width = CANTILEVER_SIZE
    with ShellSolver(model, options=options) as solver:
        report = solver.solve(steps)
    deformed = model.state_surface()
    tip = deformed.evaluate(np.array(length), np.array(width / 2)).x
    ref_w, ref_h, shape = heavy_cantilever(gamma)
    summary = {
        "gamma": gamma,
        "patches": [patches, 1],
        "dofs": 3 * model.discretization.num_closed,
        "ranks": comm.size,
        "hessian": hessian,
        "tip_W_over_L": float(tip[0] / length),
        "tip_H_over_L": float(-tip[2] / length),
        "reference_W_over_L": ref_w,
        "reference_H_over_L": ref_h,
        "relative_error_H": float(-tip[2] / length / ref_h - 1),
        "relative_error_W": float(tip[0] / length / ref_w - 1),
        "load_steps": report.load_steps,
        "load_step_cuts": report.cuts,
        "newton_iterations": report.newton_iterations,
        "solve_s": report.wall_s,
    }
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        deformed.save(out / "cantilever.npz")
        write_surface_xdmf(out / "cantilever.xdmf", deformed, 4, "cantilever", model.rest_surface, model.material)
        _plot_cantilever(out / "cantilever.png", deformed, shape, summary)
        render_surface_png(out / "cantilever-3d.png", deformed, f"Γ* = {gamma:g}, {patches} patches")
        (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def _plot_cantilever(path: Path, surface: S.HermiteSurface, shape: np.ndarray, summary: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xi = np.linspace(0.0, 1.0, 201)
    centre = surface.evaluate(xi, np.full_like(xi, 0.05)).x
    fig, ax = plt.subplots(figsize=(6, 4.5), dpi=120)
    ax.plot(shape[:, 0], shape[:, 1], "k-", lw=2.5, label="heavy elastica (reference)")
    ax.plot(centre[:, 0], centre[:, 2], "r--", lw=1.5, label=f"BHEM, {summary['patches'][0]} patches")
    ax.set_aspect("equal")
    ax.set_xlabel("x / L")
    ax.set_ylabel("z / L")
    ax.set_title(
        f"Cantilever under self-weight, Γ* = {summary['gamma']:g}: "
        f"H/L error {100 * summary['relative_error_H']:+.3f} %"
    )
    ax.legend(loc="upper right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _cantilever_configurations() -> Iterable[dict]:
    gammas = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0)
    hermite = {"discretization": "hermite", "quadrature": 4, "hessian": "exact", "newton_rtol": 1e-9}
    for patches, gamma in itertools.product((8, 16, 32), gammas):
        yield {"gamma": gamma, "patches": patches, **hermite}
    for gamma in gammas:
        yield {"gamma": gamma, "patches": 16, **hermite, "hessian": "pseudo"}
    for rtol, gamma in itertools.product((1e-3, 1e-6), (1.0, 30.0, 300.0)):
        yield {"gamma": gamma, "patches": 16, **hermite, "newton_rtol": rtol}
    for spline, gamma in itertools.product(spline_variants((8, 16, 32, 64)), gammas):
        yield {"gamma": gamma, "patches": spline["size"], **hermite, "discretization": spline["discretization"],
               "quadrature": spline["quadrature"]}  # fmt: skip


def run_cantilever(config: dict, comm: MPI.Comm) -> dict:
    """Strip under self-weight (nu = 0): tip drop H/L against the heavy elastica (paper Fig. 19)."""
    from bhem_hpc.studies.references import heavy_cantilever_tip

    gamma, patches = config["gamma"], config["patches"]
    if not (0 < gamma <= 1e4) or not (1 <= patches <= 512):
        raise StudyError(f"knobs gamma = {gamma!r} (0, 1e4] and patches = {patches!r} (1..512) out of range")
    rtol = config.get("newton_rtol", 1e-9)
    if not (1e-14 <= rtol <= 0.1):
        raise StudyError(f"knob newton_rtol = {rtol!r} is out of range [1e-14, 0.1]")
    model = cantilever_model(
        gamma, patches, config["hessian"], comm, config.get("discretization", "hermite"), config.get("quadrature")
    )
    load_steps = max(1, int(np.ceil(2 * np.sqrt(gamma))))
    measured = timed_solve(model, load_steps, {"snes_rtol": rtol}, comm)
    length, width = CANTILEVER_SIZE
    drop = -model.state_surface().evaluate(np.array(length), np.array(width / 2)).x[2] / length
    return study_result(model, float(drop), heavy_cantilever_tip(gamma)[1], measured)


STUDY = Study(
    "cantilever",
    "heavy cantilever strip, tip drop against the heavy elastica (master curve)",
    ("gamma", "discretization", "patches", "quadrature", "hessian", "newton_rtol"),
    _cantilever_configurations,
    run_cantilever,
    "discretization",
    {"quadrature": DEFAULT_QUADRATURE, "hessian": "exact", "newton_rtol": 1e-9},
    "gamma",
)
