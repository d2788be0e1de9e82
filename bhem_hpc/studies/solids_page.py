"""The SEM solids page: ray-cast quadrature convergence, the cost of each preprocessing stage and
of a time step as parts are added (the paper's Fig. 13), and a cantilever against a tetrahedral
FEM reference computed with dolfinx (the paper's Fig. 10). ``bhem-hpc solids --docs DOCS`` writes
``DOCS/solids.md``, ``.json`` and ``.png``; serial.
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

import numpy as np

from bhem_hpc.compiled.warm import load_all
from bhem_hpc.geometry import nurbs
from bhem_hpc.solids.equilibrium import solve_static
from bhem_hpc.solids.quadrature import ray_cast_quadrature
from bhem_hpc.solids.sem import ShapeMatchingSolid, SolidMaterial, SolidOptions
from bhem_hpc.studies.petsc import fem_tip_deflection
from bhem_hpc.studies.sem_table import step_cost, table_lines, table_rows
from bhem_hpc.studies.solid_twist import LENGTH, RUBBER, SECTIONS, SIDE, plot_twist, twist, twist_solid

#: The cantilever: length, width, height [m]; rubber-like, stiff enough for a moderate sag.
BEAM = (1.0, 0.2, 0.2)
BEAM_MATERIAL = SolidMaterial(density=1000.0, young=1e7, poisson=0.45)
GRAVITY = np.array([0.0, 0.0, -9.81])
STAGES = ("sample", "quadrature", "weights", "origins", "projection", "operators")


def quadrature_rows(resolutions: tuple[int, ...] = (16, 32, 64, 128)) -> list[dict]:
    """Relative volume errors of the exact NURBS sphere, torus and box against lines per side."""
    models = {
        "sphere r=1": ([nurbs.sphere(1.0)], 4.0 / 3.0 * math.pi),
        "torus R=1, r=0.3": ([nurbs.torus(1.0, 0.3)], 2.0 * math.pi**2 * 0.09),
        "box 2 x 1 x 0.5": (nurbs.box_faces([0, 0, 0], [2.0, 1.0, 0.5]), 1.0),
    }
    rows = []
    for name, (parts, volume) in models.items():
        for lines in resolutions:
            clock = time.perf_counter()
            rule = ray_cast_quadrature(parts, lines)
            seconds = time.perf_counter() - clock
            error = abs(rule.volume - volume) / volume
            rows.append(
                {"model": name, "lines": lines, "points": len(rule.weights), "error": error, "seconds": seconds}
            )
    return rows


def _clamped(solid: ShapeMatchingSolid) -> np.ndarray:
    fixed = np.zeros(solid.reference.shape, dtype=bool)
    fixed[np.isclose(solid.reference[:, 0], 0.0)] = True
    return fixed


#: Fig. 13's growing beam: unit cubes of 4 side parts each, the blending cutoff fixed at half a
#: cube [m], and the quadrature lines per cube side.
SCALING_CUTOFF = 0.5
SCALING_LINES_PER_CUBE = 12


def scaling_rows(sections: tuple[int, ...], steps: int = 3) -> list[dict]:
    """Stage seconds, stiffness nonzeros and linearly implicit step seconds of the paper's Fig. 13
    beam: a unit cube of 6 bilinear parts extended by 4 parts per unit of length, clamped at x = 0
    under gravity (dt = 10 ms), with quadrature of a fixed density and a fixed blending cutoff."""
    rows = []
    for count in sections:
        parts = nurbs.beam_faces([0.0, 0.0, 0.0], [float(count), 1.0, 1.0], count)
        options = SolidOptions(degree=2, lines_per_side=SCALING_LINES_PER_CUBE * count, alpha=SCALING_CUTOFF)
        solid = ShapeMatchingSolid(parts, BEAM_MATERIAL, options, name="beam")
        step, nonzero = step_cost(solid, _clamped(solid), steps)
        rows.append(
            {"sections": count, "parts": len(solid.parts), "dofs": solid.dof_count,
             "points": len(solid.quadrature.weights), "alpha": solid.alpha,
             **{stage: solid.seconds[stage] for stage in STAGES}, "nnz": nonzero,
             "step": step}
        )  # fmt: skip
    return rows


#: The cantilever's blending cutoffs: a fixed distance (0.6 of the beam's height) and the paper's
#: sparsity target, whose cutoff grows with the parts (a point sees 30 % of all of them).
CANTILEVER_CUTOFFS = ({"alpha": 0.12}, {"sparsity": 0.3})


def _cutoff_label(cutoff: dict) -> str:
    return f"alpha = {cutoff['alpha']} m" if "alpha" in cutoff else f"T = {cutoff['sparsity']}"


def cantilever_rows(
    sections: tuple[int, ...], cutoffs: tuple[dict, ...] = CANTILEVER_CUTOFFS, lines: int = 40, face_degree: int = 3
) -> list[dict]:
    """SEM tip sag (the end part's centre) against sections for each blending cutoff (``alpha`` or
    ``sparsity`` of :class:`SolidOptions`), bicubic parts."""
    rows = []
    for cutoff in cutoffs:
        for count in sections:
            clock = time.perf_counter()
            parts = nurbs.beam_faces([0.0, 0.0, 0.0], BEAM, count, face_degree)
            options = SolidOptions(degree=2, lines_per_side=lines, **cutoff)
            solid = ShapeMatchingSolid(parts, BEAM_MATERIAL, options, name="beam")
            built = time.perf_counter() - clock
            clock = time.perf_counter()
            state = solve_static(solid, solid.reference, _clamped(solid), solid.gravity_force(GRAVITY))
            seconds = time.perf_counter() - clock
            end, moved = solid.parts[-1], solid.deformed_parts(state.q)[-1]
            centre = (np.array([0.5]), np.array([0.5]))
            sag = float(moved.evaluate(*centre)[0][0, 2] - end.evaluate(*centre)[0][0, 2])
            rows.append({"cutoff": _cutoff_label(cutoff), "alpha": solid.alpha, "sections": count,
                         "parts": len(solid.parts), "dofs": solid.dof_count, "iterations": state.iterations,
                         "build": built, "seconds": seconds, "sag": sag})  # fmt: skip
    return rows


def _plot(path: Path, scaling: list[dict], cantilever: list[dict], reference: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    dofs = [r["dofs"] for r in scaling]
    axes[0].plot(dofs, [100 * r["nnz"] for r in scaling], "o-")
    axes[0].set(xlabel="DoFs", ylabel="stiffness nonzeros [%]", title="sparsity as parts are added")
    axes[1].plot(dofs, [r["step"] for r in scaling], "o-")
    axes[1].set(xlabel="DoFs", ylabel="seconds", title="linearly implicit step")
    for label in dict.fromkeys(r["cutoff"] for r in cantilever):
        rows = [r for r in cantilever if r["cutoff"] == label]
        axes[2].plot([r["parts"] for r in rows], [100 * r["sag"] / reference for r in rows], "o-", label=label)
    axes[2].legend()
    axes[2].axhline(100.0, color="gray", lw=0.8)
    axes[2].set(xlabel="parts", ylabel="tip sag, % of FEM", title="cantilever under gravity")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_solids_page(
    docs: Path, command: str, scaling_sections=(1, 2, 4, 8, 16), cantilever_sections=(1, 2, 4, 6, 8)
) -> Path:
    """Measure everything and write ``docs/solids.md``, ``.json`` and ``.png``; returns the page."""
    docs.mkdir(parents=True, exist_ok=True)
    load_all()  # numba's cached machine code, loaded once per process: not a stage's time
    quadrature = quadrature_rows()
    scaling = scaling_rows(tuple(scaling_sections))
    cantilever = cantilever_rows(tuple(cantilever_sections))
    reference = fem_tip_deflection(BEAM, BEAM_MATERIAL, GRAVITY)
    solid = twist_solid()
    twisted, states = twist(solid, increment=30.0, total=360.0)
    shown = [3, 7, 11]  # 120, 240 and 360 degrees
    plot_twist(docs / "solids-twist.png", solid, [solid.reference] + [states[k] for k in shown],
               ["0 deg"] + [f"{twisted[k].angle:.0f} deg" for k in shown])  # fmt: skip
    table = table_rows()
    record = {"table": table, "quadrature": quadrature, "scaling": scaling, "cantilever": cantilever,
              "fem_sag": reference, "twist": [vars(r) for r in twisted]}  # fmt: skip
    (docs / "solids.json").write_text(json.dumps(record, indent=1))
    _plot(docs / "solids.png", scaling, cantilever, reference)
    lines = [
        "# SEM solids: measured",
        "",
        f"Generated by `{command}` (serial, this machine). The Shape Matching Element Method's pipeline",
        "on NURBS parts (`bhem_hpc.solids`); times in seconds.",
        "",
        "![sparsity, step time and cantilever sag](solids.png)",
        "",
        "## Ray-cast volume quadrature",
        "",
        "| model | lines per side | points | relative volume error | seconds |",
        "| --- | ---: | ---: | ---: | ---: |",
        *(
            f"| {r['model']} | {r['lines']} | {r['points']} | {r['error']:.2e} | {r['seconds']:.3f} |"
            for r in quadrature
        ),
        "",
        "## Cost as parts are added (the paper's Fig. 13)",
        "",
        "A unit cube of 6 bilinear parts, extended along x by 4 parts per unit cube; quadratic matching,",
        f"blending cutoff {SCALING_CUTOFF} m, {SCALING_LINES_PER_CUBE} quadrature lines per cube side, clamped at",
        "x = 0 under gravity; step: one linearly implicit Euler step (dt = 10 ms), a direct solver (dense",
        "Cholesky where the matrix is full, else sparse LU).",
        "",
        "| sections | parts | DoFs | points | alpha [m] | " + " | ".join(STAGES) + " | Nnz [%] | step |",
        "| ---: | ---: | ---: | ---: | ---: | " + " | ".join("---:" for _ in STAGES) + " | ---: | ---: |",
        *(
            f"| {r['sections']} | {r['parts']} | {r['dofs']} | {r['points']} | {r['alpha']:.3f} | "
            + " | ".join(f"{r[s]:.3f}" for s in STAGES)
            + f" | {100 * r['nnz']:.1f} | {r['step']:.3f} |"
            for r in scaling
        ),
        "",
        "## Cantilever under gravity against tetrahedral FEM",
        "",
        f"{BEAM[0]} x {BEAM[1]} x {BEAM[2]} m, density {BEAM_MATERIAL.density:g} kg/m^3, "
        f"Young {BEAM_MATERIAL.young:g} Pa,",
        f"Poisson {BEAM_MATERIAL.poisson}, clamped at x = 0. FEM: P2 tetrahedra (40 x 4 x 4 boxes), the same",
        f"Neo-Hookean energy, dolfinx: tip sag {reference:.5f} m. SEM: bicubic flat parts (4 x 4 control",
        "points), quadratic matching, 40 lines per side, each cutoff as labelled. With a fixed cutoff the",
        "sag converges to the FEM one as sections are added, slowly at first: the error energy (eq. 16),",
        "which ties each part's boundary to the blended map there, stiffens beams of few sections. With",
        "the paper's sparsity target the cutoff grows with the parts (each point blends 30 % of them).",
        "Setup is the solid's construction (samples, quadrature, weights, origins, projection).",
        "",
        "| cutoff | alpha [m] | sections | parts | DoFs | Newton iterations | setup [s] | solve [s] | tip sag [m] "
        "| % of FEM |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
        *(
            f"| {r['cutoff']} | {r['alpha']:.3f} | {r['sections']} | {r['parts']} | {r['dofs']} | {r['iterations']} | "
            f"{r['build']:.1f} | {r['seconds']:.1f} | {r['sag']:.5f} | {100 * r['sag'] / reference:.1f} |"
            for r in cantilever
        ),
        "",
    ]
    lines += [
        "## A beam twisted 360 degrees (the paper's Fig. 12)",
        "",
        f"{LENGTH} x {SIDE} x {SIDE} m, {len(solid.parts)} biquadratic parts ({SECTIONS} sections of 3 x 3 "
        f"control points, the ends 6 x 6), {solid.dof_count} DoFs,",
        f"rubber (Young {RUBBER.young:g} Pa, Poisson {RUBBER.poisson}), quadratic matching, cutoff {solid.alpha} m. "
        "The end",
        "at x = 0 is held, the one at x = L turned about the axis in static increments of 30 degrees, each",
        "solved by projected Newton from a first guess turned in proportion to x. Saint-Venant: the",
        "linear torsion energy of the square section (k = 0.1406) with free warping; the ends here hold",
        "the warping, and the fixed length stretches the twisted fibres, so the energy grows faster.",
        "The midspan section turns by half the end's angle. Newton needs more iterations as the twist",
        "grows; each part's boundary is tied to the blended map there by the error energy (eq. 16, gamma",
        "= Young's modulus).",
        "",
        "![the twisted beam](solids-twist.png)",
        "",
        "| end angle [deg] | Newton iterations | seconds | energy [J] | Saint-Venant [J] | midspan angle [deg] |",
        "| ---: | ---: | ---: | ---: | ---: | ---: |",
        *(
            f"| {r.angle:.0f} | {r.iterations} | {r.seconds:.1f} | {r.energy:.4g} | {r.saint_venant:.4g} | "
            f"{r.midspan_angle:.1f} |"
            for r in twisted
        ),
        "",
    ]
    lines += [
        "## The paper's Table 1 beside ours",
        "",
        "Models built like the paper's from overlapping NURBS parts (`bhem_hpc/studies/sem_models.py`):",
        "a rocket (a body of revolution and four fins through it), the twisted beam above, a mug (a cup",
        "of revolution and a torus handle through its wall) and a castle (blocks and four round towers),",
        "each with the paper's DoFs (three per control point, as the paper's q): the mug's and the",
        "castle's parts refined by knot insertion, which leaves their shapes as they are;",
        "the paper's materials; quadratic matching, 24 lines per side, T = 0.5 (the beam: its own",
        "settings above). Step: one linearly implicit Euler step under gravity (dt = 10 ms), a direct",
        "solver as above. Each cell: our seconds, a stage's the median of three builds of the model (the",
        "paper's, the paper's over ours). The paper: MATLAB",
        "and C++ on a MacBook Pro (Intel i5, 2.3 GHz), Embree on triangulated parts; ours: numpy and",
        f"scipy serially on this machine (OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}: "
        "1 is one core), rays and closest points on the exact rational patches, compiled by numba",
        "(`bhem_hpc/compiled`; loaded from numba's cache before any timing). Quad includes the",
        "extraction of the parts' rational Bezier patches (compiled; Weights extracts them again). Lines and",
        "rays meet ruled patches (degree 1 along one parameter: the rocket's body, the cup, the towers) at",
        "the roots of one polynomial each, other curved patches by subdivision and Newton's method. Operators",
        "(no column in the paper's table): the kinematic",
        "maps, the mass and the error energy, whose boundary samples need blending weights of their own.",
        "",
        *table_lines(table),
        "",
    ]
    page = docs / "solids.md"
    page.write_text("\n".join(lines))
    return page
