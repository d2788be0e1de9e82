"""Shells of exact rational patches (a CAD model's own NURBS) on the interfaces page: the
Scordelis-Lo roof converging on its exact cylinder against interpolated B-splines, and the roof and
the pinched hemisphere in several rational patches sharing their edges against one patch."""

from __future__ import annotations

import time

import numpy as np
from mpi4py import MPI

from bhem_hpc.geometry.nurbs import revolved_arc_panel
from bhem_hpc.geometry.rational_bspline import on_uniform_knots
from bhem_hpc.model import bcs
from bhem_hpc.model.loads import Loads, PointLoad
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import ShellModel
from bhem_hpc.studies.interfaces_page import DEG, Solve, neighbours, roof, solve_joined
from bhem_hpc.studies.references import ROOF_DEFLECTION

HEMISPHERE = Material(6.825e7, 0.3, 0.04, 1.0)
#: Spans per side of the roof's convergence rows.
ROOF_SPANS = (6, 12, 24)
#: The patch splits compared with one patch.
ROOF_SPLITS, HEMISPHERE_SPLITS = ((2, 2), (1, 3), (3, 1)), ((1, 2), (3, 1), (2, 2))


def hemisphere(splits: tuple[int, int], spans: int = 16, comm: MPI.Comm = MPI.COMM_SELF) -> tuple[float, Solve]:
    """The quarter of the pinched hemisphere with an 18-degree hole (R 10, h 0.04, E 6.825e7,
    nu 0.3) in ``splits`` exact cubic rational patches of ``spans`` per side in all (polar angle
    along xi1, azimuth along xi2; symmetry planes; unit loads in and out at the equator), joined
    by shared control points: the loaded point's radial displacement per unit load, and the solve."""
    radius, force = 10.0, 1e-3
    keys, joints = neighbours(splits)
    polar, azimuth = np.linspace(18 * DEG, 90 * DEG, splits[0] + 1), np.linspace(0.0, 90 * DEG, splits[1] + 1)
    per_patch = (spans // splits[0], spans // splits[1])
    rests = [on_uniform_knots(revolved_arc_panel((0.0, 0.0), radius, (polar[i], polar[i + 1]),
                                                 (azimuth[j], azimuth[j + 1])), per_patch, 3)
             for i, j in keys]  # fmt: skip
    last1, last2 = splits[0] - 1, splits[1] - 1

    def supports(key: tuple[int, int], rest) -> list:
        held = [*bcs.symmetry_edge(rest, "xi2_min", "y")] if key[1] == 0 else []
        held += [*bcs.symmetry_edge(rest, "xi2_max", "x")] if key[1] == last2 else []
        if key == (0, 0):  # the one free rigid motion: along the axis
            held.append(bcs.NodalConstraint(np.array([[0, 0]]), (0,), (2,)))
        return held

    def loads(key: tuple[int, int]) -> Loads:
        out = [PointLoad(1.0, 0.0, (force, 0.0, 0.0))] if key == (last1, 0) else []
        out += [PointLoad(1.0, 1.0, (0.0, -force, 0.0))] if key == (last1, last2) else []
        return Loads(point_loads=tuple(out))

    models = [ShellModel(rest, HEMISPHERE, loads(key), supports(key, rest), comm=comm)
              for key, rest in zip(keys, rests, strict=True)]  # fmt: skip
    solve = solve_joined(models, rests, joints, HEMISPHERE, "shared", 1e3)
    k, at = keys.index((last1, 0)), (np.array(1.0), np.array(0.0))
    return float(models[k].state_surface().evaluate(*at).x[0] - rests[k].evaluate(*at).x[0]) / force, solve


def rational_rows(roof_spans: tuple[int, ...] = ROOF_SPANS) -> dict[str, list[dict]]:
    """The page's measurements (serial): the roof's convergence rows (``roof_spans`` per side), its
    joined rows and the hemisphere's joined rows."""
    convergence = []
    for spans in roof_spans:
        for discretization in ("nurbs2", "nurbs3", "bspline3"):
            start = time.perf_counter()
            value, _, solve = roof(discretization, None, 1e3, spans=spans)
            convergence.append({"discretization": discretization, "spans": spans, "value": value,
                                "error": -value / ROOF_DEFLECTION - 1, "unknowns": solve.unknowns,
                                "seconds": time.perf_counter() - start})  # fmt: skip
    one, _, _ = roof("nurbs3", None, 1e3)
    joined = []
    for splits in ROOF_SPLITS:
        value, gap, solve = roof("nurbs3", "shared", 1e3, splits)
        joined.append({"case": "roof", "splits": list(splits), "one_patch": one, "value": value,
                       "difference": value / one - 1, "gap_m": gap, "unknowns": solve.unknowns,
                       "failure": solve.failure})  # fmt: skip
    single, _ = hemisphere((1, 1))
    for splits in HEMISPHERE_SPLITS:
        value, solve = hemisphere(splits)
        joined.append({"case": "hemisphere", "splits": list(splits), "one_patch": single, "value": value,
                       "difference": value / single - 1, "gap_m": None, "unknowns": solve.unknowns,
                       "failure": solve.failure})  # fmt: skip
    return {"roof_convergence": convergence, "joined": joined}


def rational_section(rows: dict[str, list[dict]]) -> list[str]:
    """The page's section on exact rational patches."""
    lines = [
        "## Exact rational patches",
        "",
        "A CAD model's parts kept as they are (`discretization = \"nurbs\"`: rational B-splines, the",
        "weights fixed, the control points the unknowns). The Scordelis-Lo roof's cylinder is one",
        "rational quadratic arc, exact in `nurbs2` and `nurbs3` (degree raised); `bspline3` interpolates",
        "it. One patch of n x n spans, the midside deflection against the reference 0.3006:",
        "",
        "| spans | discretization | deflection | / 0.3006 - 1 | unknowns | seconds |",
        "| ---: | --- | ---: | ---: | ---: | ---: |",
        *(f"| {r['spans']} | {r['discretization']} | {-r['value']:.6f} | {r['error']:.2e} | {r['unknowns']} | "
          f"{r['seconds']:.2f} |" for r in rows["roof_convergence"]),  # fmt: skip
        "",
        "On this roof the interpolated bicubic cylinder is as good as the exact one once the spans resolve",
        "the deformation: its geometry error is far below the discretization error. What the exact",
        "patches bring is the model itself, with no interpolation to choose or report: a CAD part's",
        "coarse spans are its own, and its circles stay circles. Quadratic patches lock at coarse spans",
        "(the membrane locking of C1 quadratics in bending-dominated shells).",
        "",
        "The roof (cubic, 12 x 12 spans in all) and the pinched hemisphere's exact sphere zone (cubic, 16 x 16",
        "spans; 3 x 1: 15 x 16) in several rational patches sharing their edges' control points (the angle",
        "penalty at alpha = 1e3), against one patch (hemisphere: the loaded point's radial displacement per",
        "unit load):",
        "",
        "| case | patches | one patch | joined | joined / one patch - 1 | unknowns |",
        "| --- | --- | ---: | ---: | ---: | ---: |",
        *(f"| {r['case']} | {r['splits'][0]} x {r['splits'][1]} | {r['one_patch']:.6f} | "
          + (f"failed {r['failure']} | | |" if r["failure"] else f"{r['value']:.6f} | {r['difference']:.2e} | "
             f"{r['unknowns']} |") for r in rows["joined"]),  # fmt: skip
        "",
    ]
    return lines
