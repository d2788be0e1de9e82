"""Accuracy-versus-cost studies: every configuration of a study's knobs, its error and its time.

``bhem-hpc study NAME --out DIR`` (or :func:`run_study`) writes ``DIR/NAME.csv`` row by row (an
interrupted study keeps the rows it finished), then ``DIR/NAME.md`` (a table) and ``DIR/NAME.png``
(error against wall time and against DoFs). Wall time is the solve (assembly, factorization,
Newton), not the one-off JIT compilation. Collective: all ranks compute, rank 0 writes.
"""

from __future__ import annotations

import csv
import itertools
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from bhem_hpc import bcs
from bhem_hpc import surface as S
from bhem_hpc.material import Material
from bhem_hpc.references import CLAMPED_SQUARE_PLATE, simply_supported_square_plate
from bhem_hpc.shell import Loads, ShellModel
from bhem_hpc.solver import ShellSolver

COLUMNS = (
    "study",
    "support",
    "patches",
    "quadrature",
    "hessian",
    "factorization",
    "ranks",
    "dofs",
    "nonzeros",
    "value",
    "reference",
    "error",
    "wall_s",
    "newton_iterations",
)


class StudyError(ValueError):
    """Unknown study, knob value out of range, or an output directory that exists."""


@dataclass(frozen=True)
class Study:
    name: str
    description: str
    configurations: Callable[[], Iterable[dict]]
    run: Callable[[dict, MPI.Comm], dict]


def _plate_configurations() -> Iterable[dict]:
    for support, patches in itertools.product(("simply_supported", "clamped"), (2, 4, 8, 16, 24)):
        yield {"support": support, "patches": patches, "quadrature": 4, "hessian": "exact", "factorization": "ldlt"}
    for support, quadrature in itertools.product(("simply_supported", "clamped"), (2, 3, 5)):
        yield {"support": support, "patches": 8, "quadrature": quadrature, "hessian": "exact", "factorization": "ldlt"}
    for support in ("simply_supported", "clamped"):
        yield {"support": support, "patches": 16, "quadrature": 4, "hessian": "pseudo", "factorization": "ldlt"}
        yield {"support": support, "patches": 16, "quadrature": 4, "hessian": "exact", "factorization": "lu"}


def run_plate(config: dict, comm: MPI.Comm) -> dict:
    """Square plate under uniform load, small deflection: centre deflection in q a^4 / D."""
    material = Material(young=1e6, poisson=0.3, thickness=0.01, density=1.0)
    n = config["patches"]
    if not (isinstance(n, int) and 1 <= n <= 128):
        raise StudyError(f"knob patches = {n!r} is out of range (1..128)")
    rest = S.flat_rectangle(1.0, 1.0, n, n)
    edges = ("xi1_min", "xi1_max", "xi2_min", "xi2_max")
    if config["support"] == "clamped":
        constraints = [bcs.clamp(bcs.edge_nodes(rest.grid, e)) for e in edges]
        reference = CLAMPED_SQUARE_PLATE
    else:
        constraints = [bcs.simply_supported(rest.grid, e) for e in edges]
        reference = simply_supported_square_plate()
    q = 1e-6 * material.bending_stiffness
    model = ShellModel(
        rest,
        material,
        Loads(gravity=(0.0, 0.0, -q / (material.density * material.thickness))),
        constraints,
        hessian=config["hessian"],
        quadrature_points=config["quadrature"],
        comm=comm,
    )
    options = {"pc_type": "cholesky" if config["factorization"] == "ldlt" else "lu"}
    with ShellSolver(model, prefix="bhem_study_", options=options) as solver:
        start = time.perf_counter()  # the solve only: form compilation is a one-off, cached cost
        report = solver.solve()
        wall = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
        nonzeros = solver.matrix_nonzeros()
    value = -model.state_surface().evaluate(np.array(0.5), np.array(0.5)).x[2] * material.bending_stiffness / q
    return {
        "dofs": 3 * model.discretization.num_closed,
        "nonzeros": nonzeros,
        "value": float(value),
        "reference": reference,
        "error": abs(float(value) / reference - 1),
        "wall_s": wall,
        "newton_iterations": sum(report.newton_iterations),
    }


STUDIES = {
    "plate": Study(
        "plate",
        "square plate under uniform load, simply supported and clamped, small deflection",
        _plate_configurations,
        run_plate,
    ),
}


def run_study(name: str, out: Path, comm: MPI.Comm = MPI.COMM_WORLD, limit: int | None = None) -> list[dict]:
    """Run every configuration of study ``name`` (the first ``limit`` only, if given)."""
    if name not in STUDIES:
        raise StudyError(f"study {name!r} does not exist; known: {sorted(STUDIES)}")
    error = None
    if comm.rank == 0:
        if out.exists() and any(out.iterdir()):
            error = f"output directory {out} exists and is not empty"
        else:
            out.mkdir(parents=True, exist_ok=True)
    error = comm.bcast(error)
    if error:
        raise StudyError(error)
    study = STUDIES[name]
    rows: list[dict] = []
    csv_path = out / f"{name}.csv"
    handle = open(csv_path, "w", newline="") if comm.rank == 0 else None  # noqa: SIM115 - kept open across rows
    try:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS) if handle else None
        if writer:
            writer.writeheader()
        for k, config in enumerate(study.configurations()):
            if limit is not None and k >= limit:
                break
            row = {"study": name, "ranks": comm.size, **config, **study.run(config, comm)}
            rows.append(row)
            if writer:
                writer.writerow({c: row.get(c, "") for c in COLUMNS})
                handle.flush()  # an interrupted study keeps the rows it finished
    finally:
        if handle:
            handle.close()
    if comm.rank == 0:
        _write_table(out / f"{name}.md", study, rows)
        _plot(out / f"{name}.png", study, rows)
    return rows


def _write_table(path: Path, study: Study, rows: list[dict]) -> None:
    header = "| support | patches | quadrature | Hessian | factorization | DoFs | error | wall s |\n"
    header += "| --- | ---: | ---: | --- | --- | ---: | ---: | ---: |\n"
    body = "".join(
        f"| {r['support']} | {r['patches']} | {r['quadrature']}x{r['quadrature']} | {r['hessian']} | "
        f"{r['factorization']} | {r['dofs']} | {r['error']:.2e} | {r['wall_s']:.3f} |\n"
        for r in rows
    )
    path.write_text(f"# Study `{study.name}`: {study.description}\n\n{header}{body}")


def _plot(path: Path, study: Study, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), dpi=110)
    for support in sorted({r["support"] for r in rows}):
        series = sorted(
            (
                r
                for r in rows
                if r["support"] == support
                and r["quadrature"] == 4
                and r["hessian"] == "exact"
                and r["factorization"] == "ldlt"
            ),
            key=lambda r: r["dofs"],
        )
        if not series:
            continue
        errors = [max(r["error"], 1e-16) for r in series]
        axes[0].loglog([r["wall_s"] for r in series], errors, "o-", label=support)
        axes[1].loglog([r["dofs"] for r in series], errors, "o-", label=support)
    axes[0].set_xlabel("wall time [s]")
    axes[1].set_xlabel("DoFs")
    for ax in axes:
        ax.set_ylabel("relative error")
        ax.grid(alpha=0.3, which="both")
        ax.legend()
    fig.suptitle(f"{study.name}: {study.description}")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
