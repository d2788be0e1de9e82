"""The SEM paper's Table 1 beside ours: models built like the paper's (:mod:`.sem_models`, the
twisted beam of :mod:`.solid_twist`) at the paper's DoF counts, each stage of the solid's
construction and a linearly implicit step timed on this machine, next to the paper's figures
(MATLAB and C++ on a MacBook Pro, Intel i5 2.3 GHz). Serial, numpy and scipy."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np

from bhem_hpc.solids.equilibrium import linearly_implicit_step
from bhem_hpc.solids.sem import ShapeMatchingSolid, SolidMaterial, SolidOptions
from bhem_hpc.studies import sem_models
from bhem_hpc.studies.solid_twist import twist_solid

#: The paper's Table 1 rows: DoFs q, then seconds of Sample, Quad, Weights, Build Pi and Step, and Nnz [%].
PAPER = {
    "rocket (soft)": (648, 2.83e-2, 5.62e-3, 5.58e-1, 6.83e-2, 1.26, 100.0),
    "beam (twist)": (756, 1.97e-1, 2.25e-2, 1.35, 5.16e-1, 3.95, 46.94),
    "coffee mug (soft)": (1800, 4.18e-1, 2.87e-2, 3.77, 2.08, 11.9, 100.0),
    "castle": (1872, 4.84e-1, 1.44e-2, 1.52, 5.78e-1, 8.02, 100.0),
}
#: Our stages in the paper's columns: Sample, Quad, Weights, Build Pi (origins and the projection).
STAGES = ("sample", "quadrature", "weights", ("origins", "projection"))
OPTIONS = SolidOptions(degree=2, lines_per_side=24, sparsity=0.5)
#: Builds of each model; a stage's seconds are their median (the rocket's samples take 3 ms: one
#: build's figure moves with the first calls' caches and the machine's load).
BUILDS = 3


#: Control points added to each part of the mug (the cup, the handle) and of the castle (6 base
#: faces, 6 keep faces, 4 towers) by knot insertion, the shapes unchanged: the paper's DoF counts.
MUG_REFINEMENT = [(10, 16), (3, 3)]
CASTLE_REFINEMENT = [(3, 3)] * 6 + [(2, 2)] * 6 + [(0, 4)] * 4


def _models() -> dict[str, Callable[[], ShapeMatchingSolid]]:
    return {
        "rocket (soft)": lambda: ShapeMatchingSolid(
            sem_models.rocket(), SolidMaterial(1.27e3, 7e6, 0.40), OPTIONS, name="rocket"
        ),
        "beam (twist)": twist_solid,
        "coffee mug (soft)": lambda: ShapeMatchingSolid(
            sem_models.refined(sem_models.mug(), MUG_REFINEMENT), SolidMaterial(1e3, 1e4, 0.47), OPTIONS, name="mug"
        ),
        "castle": lambda: ShapeMatchingSolid(
            sem_models.refined(sem_models.castle(), CASTLE_REFINEMENT),
            SolidMaterial(1.27e3, 2e3, 0.45),
            OPTIONS,
            name="castle",
        ),
    }


def step_cost(solid: ShapeMatchingSolid, fixed: np.ndarray, steps: int = 3) -> tuple[float, float]:
    """The mean seconds of ``steps`` linearly implicit Euler steps of ``solid`` under gravity (dt =
    10 ms, ``fixed (n_q, 3)`` held) and the stiffness's share of nonzeros at the reference state."""
    forces, mass = solid.gravity_force(np.array([0.0, 0.0, -9.81])), solid.mass_matrix()
    q, velocity = solid.reference, np.zeros_like(solid.reference)
    clock = time.perf_counter()
    for _ in range(steps):
        q, velocity = linearly_implicit_step(solid, q, velocity, 0.01, fixed, forces, mass)
    step = (time.perf_counter() - clock) / steps
    stiffness = solid.hessian(solid.reference)
    stiffness.eliminate_zeros()
    return step, stiffness.nnz / stiffness.shape[0] ** 2


def _median_seconds(builds: Sequence[ShapeMatchingSolid], stages: Sequence[str]) -> float:
    """The median over ``builds`` of the seconds their ``stages`` took together."""
    return float(np.median([sum(b.seconds[s] for s in stages) for b in builds]))


def table_rows(steps: int = 3) -> list[dict]:
    """Per model: parts, DoFs, quadrature points, each stage's seconds (the median of
    :data:`BUILDS` builds), the mean seconds of ``steps`` linearly implicit Euler steps under
    gravity (nothing held), Nnz, and the paper's row."""
    rows = []
    for name, build in _models().items():
        builds = [build() for _ in range(BUILDS)]
        solid = builds[-1]
        step, nonzero = step_cost(solid, np.zeros(solid.reference.shape, dtype=bool), steps)
        stages = [_median_seconds(builds, (stage,) if isinstance(stage, str) else stage) for stage in STAGES]
        rows.append({"model": name, "parts": len(solid.parts), "dofs": solid.dof_count,
                     "points": len(solid.quadrature.weights), "stages": stages,
                     "operators": _median_seconds(builds, ("operators",)), "step": step,
                     "nnz": 100.0 * nonzero, "paper": PAPER[name]})  # fmt: skip
    return rows


def table_lines(rows: list[dict]) -> list[str]:
    """The page's section: ours and the paper's seconds per stage, and the paper's over ours."""
    header = ("| model | parts | DoFs (paper) | points | Sample | Quad | Weights | Build Pi | Operators | Step "
              "| Nnz [%] (paper) |")  # fmt: skip
    lines = [header, "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        paper = r["paper"]
        ours = [*r["stages"], r["step"]]
        cells = [f"{o:.3g} ({p:.3g}, {p / o:.2g}x)" for o, p in zip(ours, paper[1:6], strict=True)]
        cells.insert(4, f"{r['operators']:.3g} (-)")
        lines.append(f"| {r['model']} | {r['parts']} | {r['dofs']} ({paper[0]}) | {r['points']} | "
                     + " | ".join(cells) + f" | {r['nnz']:.1f} ({paper[6]:g}) |")  # fmt: skip
    return lines
