"""Square plate under uniform load, simply supported and clamped, against series solutions."""

from __future__ import annotations

import itertools
from collections.abc import Iterable

import numpy as np
from mpi4py import MPI

from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import DEFAULT_QUADRATURE, Loads, ShellModel
from bhem_hpc.studies.references import CLAMPED_SQUARE_PLATE, simply_supported_square_plate
from bhem_hpc.studies.study import Study, StudyError, flat_sheet, spline_variants, study_result, timed_solve


def _plate_configurations() -> Iterable[dict]:
    hermite = {"discretization": "hermite", "hessian": "exact", "factorization": "ldlt"}
    for support, patches in itertools.product(("simply_supported", "clamped"), (2, 4, 8, 16, 24)):
        yield {"support": support, "patches": patches, "quadrature": 4, **hermite}
    for support, quadrature in itertools.product(("simply_supported", "clamped"), (2, 3, 5)):
        yield {"support": support, "patches": 8, "quadrature": quadrature, **hermite}
    for support in ("simply_supported", "clamped"):
        yield {"support": support, "patches": 16, "quadrature": 4, **hermite, "hessian": "pseudo"}
        yield {"support": support, "patches": 16, "quadrature": 4, **hermite, "factorization": "lu"}
    # the B-spline methods on the same knot spans
    for support, spline in itertools.product(("simply_supported", "clamped"), spline_variants((4, 8, 16, 24, 32, 48))):
        yield {"support": support, "patches": spline["size"], "quadrature": spline["quadrature"],
               "discretization": spline["discretization"], "hessian": "exact", "factorization": "ldlt"}  # fmt: skip


def run_plate(config: dict, comm: MPI.Comm) -> dict:
    """Square plate under uniform load, small deflection: centre deflection in q a^4 / D."""
    material = Material(young=1e6, poisson=0.3, thickness=0.01, density=1.0)
    n = config["patches"]
    if not (isinstance(n, int) and 1 <= n <= 128):
        raise StudyError(f"knob patches = {n!r} is out of range (1..128)")
    rest = flat_sheet(config.get("discretization", "hermite"), 1.0, 1.0, n, n)
    edges = ("xi1_min", "xi1_max", "xi2_min", "xi2_max")
    if config["support"] == "clamped":
        constraints = [bcs.clamp_edge(rest, e) for e in edges]
        reference = CLAMPED_SQUARE_PLATE
    else:
        constraints = [bcs.support_edge(rest, e) for e in edges]
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
    measured = timed_solve(model, 1, options, comm)
    value = -model.state_surface().evaluate(np.array(0.5), np.array(0.5)).x[2] * material.bending_stiffness / q
    return study_result(model, float(value), reference, measured)


STUDY = Study(
    "plate",
    "square plate under uniform load, simply supported and clamped, small deflection",
    ("support", "discretization", "patches", "quadrature", "hessian", "factorization"),
    _plate_configurations,
    run_plate,
    ("support", "discretization"),
    {"quadrature": DEFAULT_QUADRATURE, "hessian": "exact", "factorization": "ldlt"},
    "support",
    note=(
        "`patches` counts knot spans in each direction for every discretization; `quadrature` is Gauss points per "
        "direction (the defaults: Hermite 4, quadratic B-splines 3, cubic 4) or the B-spline paper's reduced rule. "
        "On B-splines a clamped edge holds the two outer rows of control points, a simply supported one the "
        "boundary row."
    ),
)
