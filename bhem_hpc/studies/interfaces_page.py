"""The interfaces page: patches joined by the penalty coupling against patches that share their
edge data (``bhem-hpc interfaces --docs DIR`` writes ``DIR/interfaces.md``, ``.json`` and ``.png``).

Every case is solved once per joining method and penalty factor alpha: ``coupled`` (the penalty
on the displacement jump and on the angle, :mod:`bhem_hpc.bodies.coupling`) and ``shared`` (the
edge's data one unknown, :mod:`bhem_hpc.bodies.shared_dofs`, the penalty on the angle only). The
statics compare with the same structure as one patch; the hood job is time-stepped by each method.
The page is serial: every solve runs on ``COMM_SELF``; the cases take a communicator (tests run
them on 2 ranks too).
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from bhem_hpc.bodies.coupling import DEFAULT_PENALTY, InterfaceCoupling, penalty_stiffness, rest_frames
from bhem_hpc.bodies.petsc import StackedBlocks
from bhem_hpc.bodies.shared_dofs import SharedDofs, conforming_edge_dofs
from bhem_hpc.geometry import bspline as B
from bhem_hpc.geometry import surface as S
from bhem_hpc.geometry.grid import ParameterGrid
from bhem_hpc.geometry.interfaces import edge_line, element_across, pair_edges
from bhem_hpc.geometry.nurbs import cylinder_panel
from bhem_hpc.geometry.rational_bspline import on_uniform_knots
from bhem_hpc.model import bcs
from bhem_hpc.model.loads import AreaLoad, LineLoad, Loads
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.petsc import SolverError

JOBS = Path(__file__).resolve().parents[2] / "jobs"
#: The joining methods, as a joint's ``dofs`` names them.
METHODS = ("coupled", "shared")
#: The penalty factors swept.
FACTORS = (1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6)
DISCRETIZATIONS = ("bspline3", "hermite")
DEG = np.pi / 180

Joint = tuple[int, int, tuple[str, str]]


Ranges = tuple[tuple[float, float], tuple[float, float]]


def patch_grid(position: Callable, ranges: Ranges, splits: tuple[int, int], spans: tuple[int, int],
               discretization: str) -> tuple[list, list[tuple[int, int]], list[Joint]]:  # fmt: skip
    """``position`` over ``ranges`` as ``splits[0] x splits[1]`` patches of ``spans`` in all, each a
    cubic B-spline or a Hermite surface: the rest surfaces, their ``(i, j)`` places and the joints
    between neighbours ``(a, b, (edge of a, edge of b))``."""
    b1, b2 = (np.linspace(*r, n + 1) for r, n in zip(ranges, splits, strict=True))
    keys, joints = neighbours(splits)
    grids = [ParameterGrid(spans[0] // splits[0], spans[1] // splits[1], (b1[i], b1[i + 1]), (b2[j], b2[j + 1]),
                           False, False) for i, j in keys]  # fmt: skip
    rests = [S.from_callable(position, g) if discretization == "hermite" else B.from_callable(position, g, degree=3)
             for g in grids]  # fmt: skip
    return rests, keys, joints


def neighbours(splits: tuple[int, int]) -> tuple[list[tuple[int, int]], list[Joint]]:
    """The ``(i, j)`` places of ``splits[0] x splits[1]`` patches and the joints between neighbours."""
    keys = [(i, j) for i in range(splits[0]) for j in range(splits[1])]
    joints = [(keys.index((i, j)), keys.index((i + 1, j)), ("xi1_max", "xi1_min"))
              for i, j in keys if i + 1 < splits[0]]  # fmt: skip
    joints += [(keys.index((i, j)), keys.index((i, j + 1)), ("xi2_max", "xi2_min"))
               for i, j in keys if j + 1 < splits[1]]  # fmt: skip
    return keys, joints


@dataclass
class Solve:
    """One static solve of joined patches: its unknowns, Newton iterations, seconds, and why it
    failed (empty: it converged)."""

    unknowns: int = 0
    newton: int = 0
    seconds: float = 0.0
    failure: str = ""


def solve_joined(models: list[ShellModel], rests: list, joints: list[Joint], material: Material, method: str,
                 factor: float) -> Solve:  # fmt: skip
    """The statics of ``models`` joined at ``joints`` by ``method`` with penalty factor ``factor``
    (the narrower side's element across each joint)."""
    blocks, couplings, shared = StackedBlocks(models), [], []
    for a, b, edges in joints:
        quadrature = pair_edges(rests[a], edges[0], rests[b], edges[1], 1e-8)
        element = min(element_across(rests[a], edges[0]), element_across(rests[b], edges[1]))
        a_d, a_r = penalty_stiffness(material.young, material.poisson, material.thickness, element, factor)
        if method == "shared":
            shared.append(conforming_edge_dofs((rests[a], rests[b]), (a, b), edges, 1e-9))
        couplings.append(InterfaceCoupling(blocks, (a, b), quadrature, rest_frames(rests[a], rests[b], quadrature),
                                           (0.0 if method == "shared" else a_d, a_r)))  # fmt: skip
    result, start = Solve(), time.perf_counter()
    with ShellSolver(models, prefix="bhem_interfaces_", contributions=couplings,
                     shared_dofs=SharedDofs.join(shared) if shared else None) as solver:  # fmt: skip
        result.unknowns = solver.x.getSize()
        try:
            report = solver.solve()
            result.newton = int(sum(report.newton_iterations))
        except SolverError as exc:  # where the load stepping gave up, and the term that dominated there
            text = str(exc)
            where = re.search(r"failed at load factor ([0-9.e+-]+)", text)
            term = re.search(r"the (\w+) term dominates", text)
            result.failure = (f"at load factor {where.group(1)}" if where else text[:60]) + (
                f", the {term.group(1)} term dominating" if term else "")
    result.seconds = time.perf_counter() - start
    return result


def _gap(first, second, on_first, on_second) -> float:
    return float(np.abs(first.evaluate(*on_first).x - second.evaluate(*on_second).x).max())


STEEL = Material(2.0e11, 0.3, 0.01, 7800.0)


def cantilever(discretization: str, method: str | None, factor: float,
               comm: MPI.Comm = MPI.COMM_SELF) -> tuple[float, float, Solve]:  # fmt: skip
    """A steel strip 1 m x 0.2 m x 1 cm clamped at x = 0 under an end load of 5 N/m (``method``
    None: one patch of 8 x 2 spans; else cut at midspan into two of 4 x 2): the tip deflection [m],
    the largest gap across the cut [m] and the solve."""
    length, width = 1.0, 0.2
    load = Loads(line_loads=(LineLoad("xi1_max", (0.0, 0.0, -5.0)),))
    splits = (1, 1) if method is None else (2, 1)
    rests, _, joints = patch_grid(lambda u, v: np.stack([u, v, 0 * u], -1), ((0.0, length), (0.0, width)), splits,
                                  (8, 2), discretization)  # fmt: skip
    models = [ShellModel(r, STEEL, load if k == len(rests) - 1 else Loads(),
                         [bcs.clamp_edge(r, "xi1_min")] if k == 0 else [], comm=comm)
              for k, r in enumerate(rests)]  # fmt: skip
    solve = solve_joined(models, rests, joints, STEEL, method or "coupled", factor)
    states = [m.state_surface() for m in models]
    along = np.linspace(0.0, width, 9)
    gap = 0.0 if method is None else _gap(states[0], states[1], (np.full(9, length / 2), along),
                                          (np.full(9, length / 2), along))  # fmt: skip
    return float(states[-1].evaluate(np.array(length), np.array(width / 2)).x[2]), gap, solve


ROOF_MATERIAL = Material(4.32e8, 0.0, 0.25, 1.0)


def roof(discretization: str, method: str | None, factor: float, splits: tuple[int, int] = (2, 2),
         comm: MPI.Comm = MPI.COMM_SELF, spans: int = 12) -> tuple[float, float, Solve]:  # fmt: skip
    """The Scordelis-Lo roof (R 25, L 50, 80 degrees, h 0.25, E 4.32e8, nu 0, self-weight 90 per
    area, diaphragms at its ends) of ``spans`` x ``spans`` in all, as one patch (``method`` None) or ``splits``
    patches (2 x 2: four meeting at one point): the free edge's midside deflection scaled to the
    load 90, the largest gap across the joints [m] and the solve. ``discretization`` "nurbs2" or
    "nurbs3": the exact cylinder in rational patches; else interpolated (cubic B-splines or Hermite)."""
    radius, load = 25.0, 0.09
    splits = (1, 1) if method is None else splits

    def position(z, angle):
        return np.stack([radius * np.cos(angle), radius * np.sin(angle), z], -1)

    if discretization.startswith("nurbs"):  # the exact cylinder: each patch a rational panel
        keys, joints = neighbours(splits)
        z, angle = np.linspace(0.0, 50.0, splits[0] + 1), np.linspace(50 * DEG, 130 * DEG, splits[1] + 1)
        rests = [on_uniform_knots(cylinder_panel(radius, (z[i], z[i + 1]), (angle[j], angle[j + 1])),
                                  (spans // splits[0], spans // splits[1]), int(discretization[-1]))
                 for i, j in keys]  # fmt: skip
    else:
        rests, keys, joints = patch_grid(position, ((0.0, 50.0), (50 * DEG, 130 * DEG)), splits, (spans, spans),
                                         discretization)  # fmt: skip
    weight = Loads(area_loads=(AreaLoad((0.0, -load, 0.0)),))

    def supports(i: int, rest) -> list:
        ends = [edge for edge, end in (("xi1_min", 0), ("xi1_max", splits[0] - 1)) if i == end]
        return [bcs.diaphragm_edge(rest, edge, "z") for edge in ends]

    models = [ShellModel(rest, ROOF_MATERIAL, weight, supports(i, rest), comm=comm)
              for (i, _), rest in zip(keys, rests, strict=True)]  # fmt: skip
    solve = solve_joined(models, rests, joints, ROOF_MATERIAL, method or "coupled", factor)
    states = [m.state_surface() for m in models]
    k = keys.index((splits[0] // 2, 0))
    at = (np.array(25.0), np.array(rests[k].grid.xi2_range[0]))  # the free edge's middle
    deflection = float(states[k].evaluate(*at).x[1] - rests[k].evaluate(*at).x[1]) * 90.0 / load
    gap = 0.0
    for a, b, edges in joints:
        along, value_a, (low, high), _ = edge_line(rests[a].grid, edges[0])
        t = np.linspace(low, high, 9)
        on_a = (np.full(9, value_a), t) if along == 1 else (t, np.full(9, value_a))
        _, value_b, _, _ = edge_line(rests[b].grid, edges[1])
        on_b = (np.full(9, value_b), t) if along == 1 else (t, np.full(9, value_b))
        gap = max(gap, _gap(states[a], states[b], on_a, on_b))
    return deflection, gap, solve


def patch_test(discretization: str, method: str | None, comm: MPI.Comm = MPI.COMM_SELF) -> tuple[float, Solve]:
    """A steel strip of two halves (3 x 2 spans each; ``method`` None: one patch of 6 x 2) pulled
    by a uniform traction of 2 kN/m at x = 1 m, held along the pull at x = 0: the largest departure
    of either half from the uniform stretch, over the stretch at the end."""
    length, width, traction = 1.0, 0.2, 2.0e3
    splits = (1, 1) if method is None else (2, 1)
    rests, _, joints = patch_grid(lambda u, v: np.stack([u, v, 0 * u], -1), ((0.0, length), (0.0, width)), splits,
                                  (6, 2), discretization)  # fmt: skip
    edge_nodes = bcs.edge_nodes(rests[0].grid, "xi1_min", rests[0].node_shape)
    kinds = (0, 2) if discretization == "hermite" else (0,)  # Hermite: the slopes along the edge too
    supports = [bcs.NodalConstraint(edge_nodes, kinds, (0, 2)), bcs.NodalConstraint(edge_nodes[:1], (0,), (1,))]
    pull = Loads(line_loads=(LineLoad("xi1_max", (traction, 0.0, 0.0)),))
    models = [ShellModel(r, STEEL, pull if k == len(rests) - 1 else Loads(), supports if k == 0 else [],
                         comm=comm) for k, r in enumerate(rests)]  # fmt: skip
    solve = solve_joined(models, rests, joints, STEEL, method or "coupled", DEFAULT_PENALTY)
    strain = traction / (STEEL.young * STEEL.thickness)
    worst = 0.0
    for model, rest in zip(models, rests, strict=True):
        x1, x2 = np.meshgrid(np.linspace(*rest.grid.xi1_range, 5), np.linspace(0.0, width, 4), indexing="ij")
        moved = model.state_surface().evaluate(x1, x2).x - rest.evaluate(x1, x2).x
        expected = np.stack([strain * x1, -STEEL.poisson * strain * x2, 0 * x1], -1)
        worst = max(worst, float(np.abs(moved - expected).max()))
    return worst / (strain * length), solve


def hood_job(method: str, out: Path, steps: int | None = None) -> dict:
    """``jobs/hood.toml`` (four bicubic CAD parts, steel, 3 kPa) with its seams joined by
    ``method``: unknowns, Newton iterations per step (mean, largest), recoveries, dt halvings and
    seconds per step."""
    from bhem_hpc.run import RunOptions, run_scene

    text = (JOBS / "hood.toml").read_text().replace("tolerance = 1e-6\n", f'tolerance = 1e-6\ndofs = "{method}"\n', 1)
    out.mkdir(parents=True, exist_ok=True)
    scene = out / f"hood-{method}.toml"
    scene.write_text(text.replace('file = "models/', f'file = "{JOBS / "models"}/'))
    options = RunOptions(scene, out / f"hood-{method}", steps=steps, force=True, progress=False)
    summary = run_scene(options, MPI.COMM_SELF)
    rows = [json.loads(line) for line in (out / f"hood-{method}" / "steps.jsonl").read_text().splitlines()]
    newton = [r["newton_iterations"] for r in rows]
    return {"method": method, "unknowns": summary["dofs"], "steps": len(rows), "newton_mean": float(np.mean(newton)),
            "newton_max": int(max(newton)), "recoveries": sum(r["recoveries"] for r in rows),
            "dt_halvings": sum(r["dt_halvings"] for r in rows),
            "seconds_per_step": float(np.mean([r["wall_s"] for r in rows])), "status": summary["status"]}  # fmt: skip


CASES = {"cantilever": cantilever, "roof": roof}


def static_rows(factors=FACTORS, discretizations=DISCRETIZATIONS) -> list[dict]:
    """Every static case, discretization, method and factor against the case's one patch."""
    rows = []
    for case, build in CASES.items():
        for discretization in discretizations:
            one, _, _ = build(discretization, None, DEFAULT_PENALTY)
            for method in METHODS:
                for factor in factors:
                    value, gap, solve = build(discretization, method, factor)
                    rows.append({"case": case, "discretization": discretization, "method": method, "factor": factor,
                                 "one_patch": one, "value": value, "difference": value / one - 1, "gap_m": gap,
                                 **asdict(solve)})  # fmt: skip
    return rows


def _plot(path: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, len(CASES), figsize=(5.5 * len(CASES), 4.2))
    for ax, case in zip(np.atleast_1d(axes), CASES, strict=True):
        for discretization in DISCRETIZATIONS:
            for method, style in zip(METHODS, ("--", "-"), strict=True):
                chosen = [r for r in rows if (r["case"], r["discretization"], r["method"]) == (case, discretization,
                                                                                               method)]  # fmt: skip
                solved = [r for r in chosen if not r["failure"]]
                ax.loglog([r["factor"] for r in solved], [max(abs(r["difference"]), 1e-12) for r in solved], style,
                          marker="o", label=f"{discretization}, {method}")  # fmt: skip
                failed = [r["factor"] for r in chosen if r["failure"]]
                ax.plot(failed, [1e-1] * len(failed), "x", color="red")
        ax.set(title=f"{case}: |joined / one patch - 1|", xlabel="penalty factor alpha", ylabel="relative difference")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def _static_table(rows: list[dict], case: str) -> list[str]:
    lines = ["| discretization | method | alpha | unknowns | Newton iterations | seconds | joined / one patch - 1 | "
             "largest gap [m] |", "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for r in (r for r in rows if r["case"] == case):
        if r["failure"]:
            lines.append(f"| {r['discretization']} | {r['method']} | {r['factor']:.0e} | {r['unknowns']} | failed "
                         f"{r['failure']} | {r['seconds']:.2f} | | |")  # fmt: skip
        else:
            lines.append(f"| {r['discretization']} | {r['method']} | {r['factor']:.0e} | {r['unknowns']} | "
                         f"{r['newton']} | {r['seconds']:.2f} | {r['difference']:.2e} | "
                         f"{r['gap_m']:.1e} |")  # fmt: skip
    return lines


def write_interfaces_page(docs: Path, out: Path, command: str, factors=FACTORS, hood_steps: int | None = None,
                          roof_spans: tuple[int, ...] | None = None) -> Path:  # fmt: skip
    """Measure every case and write ``docs/interfaces.md``, ``.json`` and ``.png``; returns the page
    (``roof_spans``: the rational section's convergence rows, default its own)."""
    from bhem_hpc.studies.rational_cases import ROOF_SPANS, rational_rows, rational_section  # builds on this module

    docs.mkdir(parents=True, exist_ok=True)
    rows = static_rows(tuple(factors))
    rational = rational_rows(roof_spans or ROOF_SPANS)
    patches = []
    for discretization in DISCRETIZATIONS:
        for method in (None, *METHODS):
            departure, solve = patch_test(discretization, method)
            patches.append({"discretization": discretization, "method": method or "one patch",
                            "departure": departure, **asdict(solve)})  # fmt: skip
    hood = [hood_job(method, out, hood_steps) for method in METHODS]
    (docs / "interfaces.json").write_text(json.dumps({"static": rows, "patch_test": patches, "hood": hood,
                                                      "rational": rational}, indent=1))  # fmt: skip
    _plot(docs / "interfaces.png", rows)
    ones = {(r["case"], r["discretization"]): r["one_patch"] for r in rows}
    at_default = max((abs(r["difference"]) for r in rows if r["factor"] == DEFAULT_PENALTY and not r["failure"]),
                     default=float("nan"))  # fmt: skip
    lines = [
        "# Joined patches: the penalty coupling against shared edge data",
        "",
        f"Generated by `{command}` (serial, this machine; one run). Patches of one shell are joined along",
        "an edge by one of two methods, a joint's `dofs`:",
        "",
        "- `coupled`: the penalty energy on the displacement jump and on the change of the angle",
        "  between the patches (`bhem_hpc.bodies.coupling`), stiffness `alpha E t / ((1 - nu^2) h)` and",
        "  `alpha E t^3 / (12 (1 - nu^2) h)` over the narrower side's element `h`;",
        "- `shared`: the edge's data one unknown (B-spline control points; Hermite positions and slopes",
        "  along the edge), the penalty on the angle only (`bhem_hpc.bodies.shared_dofs`).",
        "",
        "Each static case is solved as one patch and as joined patches for every alpha; the difference is",
        "the joined value over the one patch's, less 1 (the one patch is smoother across the cut, so the",
        "difference falls to the two spaces' difference, not to zero). A red cross marks a failed solve.",
        "",
        "![difference from one patch against alpha](interfaces.png)",
        "",
        "What decides between them: a shared edge has no gap and no consistency error at any alpha (the",
        "patch test's departure is the one patch's) and fewer unknowns, so scenes share the data of every",
        "joint that conforms (`dofs = \"auto\"`); the penalty joins the rest (non-matching edges, partial",
        "and trim-curve joints, seams). What is left of a joint's error is the angle term's compliance,",
        "falling as 1/alpha to the difference between the joined and the one patch's spaces; it does not",
        "grow again as alpha does (no locking), and the default alpha = 1e3 puts it within "
        f"{at_default:.1e} of one patch here.",
        "Above about 1e5 the Newton systems lose their digits to the penalty (failed rows).",
        "",
        "## A steel cantilever cut at midspan",
        "",
        "1 m x 0.2 m x 1 cm, clamped at x = 0, 5 N/m along its free end; one patch of 8 x 2 spans, or two",
        "of 4 x 2. Tip deflection of one patch: "
        + ", ".join(f"{d} {ones[('cantilever', d)]:.6e} m" for d in DISCRETIZATIONS) + ".",
        "",
        *_static_table(rows, "cantilever"),
        "",
        "## The Scordelis-Lo roof in 2 x 2 patches",
        "",
        "12 x 12 spans in all, four patches meeting at one point; midside deflection of one patch: "
        + ", ".join(f"{d} {ones[('roof', d)]:.6f}" for d in DISCRETIZATIONS) + " (reference 0.3006).",
        "",
        *_static_table(rows, "roof"),
        "",
        *rational_section(rational),
        "## Patch test across the joint",
        "",
        "A strip of two halves (3 x 2 spans each) pulled by a uniform traction, alpha = 1e3: the largest",
        "departure of either half from the uniform stretch, over the stretch at the end; one patch of 6 x 2",
        "spans departs as far as the finite strain of the large-deformation model takes it. A penalty",
        "joint is not variationally consistent: it shifts the far half by its compliance.",
        "",
        "| discretization | method | departure / stretch | unknowns |",
        "| --- | --- | ---: | ---: |",
        *(f"| {p['discretization']} | {p['method']} | {p['departure']:.2e} | {p['unknowns']} |" for p in patches),
        "",
        "## The hood job, time-stepped",
        "",
        f"`jobs/hood.toml` ({hood[0]['steps']} steps): four bicubic CAD parts with matching knots, clamped",
        "front and back, pressed by 3 kPa; its four seams joined by each method at alpha = 1e3.",
        "",
        "| method | unknowns | Newton iterations per step | largest | recoveries | dt halvings | seconds per step |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
        *(f"| {h['method']} | {h['unknowns']} | {h['newton_mean']:.2f} | {h['newton_max']} | {h['recoveries']} | "
          f"{h['dt_halvings']} | {h['seconds_per_step']:.3f} |" for h in hood),  # fmt: skip
        "",
    ]
    page = docs / "interfaces.md"
    page.write_text("\n".join(lines))
    return page
