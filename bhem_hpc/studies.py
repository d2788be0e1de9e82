"""Accuracy-versus-cost studies: every configuration of a study's knobs, its error and its time.

``bhem-hpc study NAME --out DIR`` (or :func:`run_study`) writes ``DIR/NAME.csv`` row by row (an
interrupted study keeps the rows it finished), then ``DIR/NAME.md`` (a table) and ``DIR/NAME.png``
(error against wall time and against DoFs). Wall time is the solve (assembly, factorization,
Newton), not the one-off JIT compilation. Collective: all ranks compute, rank 0 writes.
"""

from __future__ import annotations

import csv
import itertools
import math
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

RESULT_COLUMNS = ("ranks", "dofs", "nonzeros", "value", "reference", "error", "wall_s", "newton_iterations")


class StudyError(ValueError):
    """Unknown study, knob value out of range, or an output directory that exists."""


@dataclass(frozen=True)
class Study:
    """A named set of knob configurations and how to run one.

    ``knobs`` are the configuration keys (CSV/table columns); the plot draws one error curve per
    value of ``series`` over the configurations whose other knobs equal ``baseline``.
    """

    name: str
    description: str
    knobs: tuple[str, ...]
    configurations: Callable[[], Iterable[dict]]
    run: Callable[[dict, MPI.Comm], dict]
    series: str
    baseline: dict
    problem: str  # the knob that changes the problem itself (not its discretization)
    extra: tuple[str, ...] = ()  # result columns beyond RESULT_COLUMNS
    note: str = ""  # how to read the errors (written under the study's heading in the docs)
    figure: Callable[[Path, list[dict]], None] | None = None  # draws DIR/NAME-shapes.png from the rows

    @property
    def columns(self) -> tuple[str, ...]:
        return ("study", *self.knobs, *RESULT_COLUMNS, *self.extra)


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
    measured = _timed_solve(model, 1, options, comm)
    value = -model.state_surface().evaluate(np.array(0.5), np.array(0.5)).x[2] * material.bending_stiffness / q
    return _result(model, float(value), reference, measured)


def _timed_solve(model: ShellModel, load_steps: int, options: dict, comm: MPI.Comm) -> tuple[float, int, int]:
    """Solve; ``(wall seconds of the solve only, nonzeros, Newton iterations)``.

    Form compilation (a one-off, cached cost) happens when the model is built, outside the timing.
    """
    with ShellSolver(model, prefix="bhem_study_", options=options) as solver:
        start = time.perf_counter()
        report = solver.solve(load_steps)
        wall = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
        return wall, solver.matrix_nonzeros(), sum(report.newton_iterations)


def _result(model: ShellModel, value: float, reference: float, measured: tuple[float, int, int]) -> dict:
    wall, nonzeros, iterations = measured
    return {
        "dofs": 3 * model.discretization.num_closed,
        "nonzeros": nonzeros,
        "value": value,
        "reference": reference,
        "error": abs(value / reference - 1),
        "wall_s": wall,
        "newton_iterations": iterations,
    }


def _cantilever_configurations() -> Iterable[dict]:
    gammas = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0)
    for patches, gamma in itertools.product((8, 16, 32), gammas):
        yield {"gamma": gamma, "patches": patches, "hessian": "exact", "newton_rtol": 1e-9}
    for gamma in gammas:
        yield {"gamma": gamma, "patches": 16, "hessian": "pseudo", "newton_rtol": 1e-9}
    for rtol, gamma in itertools.product((1e-3, 1e-6), (1.0, 30.0, 300.0)):
        yield {"gamma": gamma, "patches": 16, "hessian": "exact", "newton_rtol": rtol}


def run_cantilever(config: dict, comm: MPI.Comm) -> dict:
    """Strip under self-weight (nu = 0): tip drop H/L against the heavy elastica (paper Fig. 19)."""
    from bhem_hpc.jobs import CANTILEVER_SIZE, cantilever_model
    from bhem_hpc.references import heavy_cantilever_tip

    gamma, patches = config["gamma"], config["patches"]
    if not (0 < gamma <= 1e4) or not (1 <= patches <= 512):
        raise StudyError(f"knobs gamma = {gamma!r} (0, 1e4] and patches = {patches!r} (1..512) out of range")
    rtol = config.get("newton_rtol", 1e-9)
    if not (1e-14 <= rtol <= 0.1):
        raise StudyError(f"knob newton_rtol = {rtol!r} is out of range [1e-14, 0.1]")
    model = cantilever_model(gamma, patches, config["hessian"], comm)
    load_steps = max(1, int(np.ceil(2 * np.sqrt(gamma))))
    measured = _timed_solve(model, load_steps, {"snes_rtol": rtol}, comm)
    length, width = CANTILEVER_SIZE
    drop = -model.state_surface().evaluate(np.array(length), np.array(width / 2)).x[2] / length
    return _result(model, float(drop), heavy_cantilever_tip(gamma)[1], measured)


def _buckling_configurations() -> Iterable[dict]:
    # nu = 0: a strip's out-of-plane bending stiffness is then Y h^3 w / 12 whether its section bends
    # anticlastically (beam) or is held (plate); for nu > 0 the reference would have to choose.
    for aspect, patches in itertools.product((0.02, 0.05, 0.1, 0.2), (10, 20, 40)):
        yield {"aspect": aspect, "patches_per_m": patches, "poisson": 0.0}


def _buckling_gravity(gamma: float, material: Material) -> float:
    """``g`` of ``Gamma* = 12 (1 - nu^2) rho g L^3 / (Y h^2)`` for L = 1 m."""
    return gamma * material.young * material.thickness**2 / (12 * (1 - material.poisson**2) * material.density)


def buckling_model(
    aspect: float, patches_per_m: int, poisson: float, comm: MPI.Comm, planar: bool = False
) -> ShellModel:
    """A 1 m plate hanging on edge from a clamp: width ``aspect`` m vertical (in the x-z plane),
    thickness ``aspect / 50``, gravity along -z at the beam-theory threshold (the solver's force
    scale comes from it; change it through ``model.gravity``). ``planar`` holds every DOF's y
    component at 0: the plate's planar equilibrium, stable or not."""
    from bhem_hpc.references import lateral_buckling_gamma

    if not (0.005 <= aspect <= 0.5) or not (isinstance(patches_per_m, int) and 2 <= patches_per_m <= 200):
        raise StudyError(
            f"knobs aspect = {aspect!r} [0.005, 0.5] and patches_per_m = {patches_per_m!r} (2..200) out of range"
        )
    if not (0.0 <= poisson < 0.5):
        raise StudyError(f"knob poisson = {poisson!r} is out of range [0, 0.5)")
    material = Material(young=1e6, poisson=poisson, thickness=aspect / 50, density=1000.0)
    across = max(1, round(patches_per_m * aspect))
    upright = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # the width along z
    rest = S.flat_rectangle(1.0, aspect, patches_per_m, across).transformed(upright, np.zeros(3))
    constraints = [bcs.clamp(bcs.edge_nodes(rest.grid, "xi1_min"))]
    if planar:
        others = np.argwhere(np.ones(rest.grid.node_shape, dtype=bool))
        others = others[others[:, 0] > 0]  # the clamp holds the first column already
        constraints.append(bcs.NodalConstraint(others, (0, 1, 2, 3), (1,), None))
    return ShellModel(
        rest,
        material,
        Loads(gravity=(0.0, 0.0, -_buckling_gravity(lateral_buckling_gamma(poisson), material))),
        constraints,
        comm=comm,
    )


def run_buckling(config: dict, comm: MPI.Comm) -> dict:
    """Lateral buckling of a plate hanging on edge (paper Fig. 20): the ``Gamma*`` at which its
    planar equilibrium stops being stable, found by bisection to 0.1 %: the planar equilibrium is
    solved with the out-of-plane DOFs held (near the threshold the free problem's Hessian is
    singular), then the inertia of the free plate's exact Hessian there (MUMPS LDL^T negative
    pivots) tells whether it is stable."""
    from bhem_hpc.references import lateral_buckling_gamma

    knobs = (config["aspect"], config["patches_per_m"], config["poisson"], comm)
    planar, free = buckling_model(*knobs, planar=True), buckling_model(*knobs)
    material = free.material
    reference = lateral_buckling_gamma(material.poisson)
    low, high = 0.25 * reference, 4.0 * reference
    wall, iterations = 0.0, 0
    with ShellSolver(planar, prefix="bhem_study_") as planar_solver, ShellSolver(free, prefix="bhem_free_") as solver:
        nonzeros = solver.matrix_nonzeros()
        for _ in range(64):
            if high / low - 1 < 1e-3:
                break
            gamma = math.sqrt(low * high)
            for model in (planar, free):
                model.gravity.value[:] = (0.0, 0.0, -_buckling_gravity(gamma, material))
            start = time.perf_counter()
            report = planar_solver.solve(1)
            iterations += report.newton_iterations[-1]
            free.set_state(planar.state_surface())
            buckled = solver.time_newton_iteration()["negative_pivots"] > 0
            wall += comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
            low, high = (low, gamma) if buckled else (gamma, high)
    return _result(free, math.sqrt(low * high), reference, (wall, nonzeros, iterations))


DRAPE_SIDE = 0.5  # m
DRAPE_INSET = 0.05  # corners moved inward along the diagonals by this fraction of the side
DRAPE_LATTICE = np.linspace(0.0, DRAPE_SIDE, 21)


def _drape_configurations() -> Iterable[dict]:
    # the finest configuration first: it is the reference of the others
    yield {"patches": 24, "hessian": "exact", "dt": 0.01}
    for patches in (4, 8, 12, 16):
        yield {"patches": patches, "hessian": "exact", "dt": 0.01}
    for patches in (8, 16, 24):
        yield {"patches": patches, "hessian": "pseudo", "dt": 0.01}
    for dt in (0.02, 0.04):
        yield {"patches": 16, "hessian": "exact", "dt": dt}


def drape_to_rest(patches: int, hessian: str, dt: float, comm: MPI.Comm) -> tuple[np.ndarray, dict]:
    """A square cloth (paper Fig. 15-16) pinned at its four corners, moved inward along the
    diagonals, drapes from flat under gravity (implicit Euler, mass damping 4/s) until every node is
    slower than 1 mm/s (at most 1000 steps).

    Returns:
        Positions ``(21, 21, 3)`` on a parameter lattice at rest, and ``{"wall_s",
        "newton_iterations", "steps", "dofs", "nonzeros"}`` of the run.
    """
    from bhem_hpc.dynamics import TimeStepper
    from bhem_hpc.shell import Dynamics

    if not (isinstance(patches, int) and 2 <= patches <= 64) or hessian not in ("exact", "pseudo"):
        raise StudyError(f"knobs patches = {patches!r} (2..64) and hessian = {hessian!r} (exact|pseudo) out of range")
    if not (0.001 <= dt <= 0.1):
        raise StudyError(f"knob dt = {dt!r} is out of range [0.001, 0.1] s")
    rest = S.flat_rectangle(DRAPE_SIDE, DRAPE_SIDE, patches, patches)
    corners = np.array([[0, 0], [0, patches], [patches, 0], [patches, patches]])
    inward = DRAPE_INSET * DRAPE_SIDE * np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], dtype=float)
    targets = rest.nodal[corners[:, 0], corners[:, 1], 0, :].copy()
    targets[:, :2] += inward
    model = ShellModel(
        rest,
        Material(young=1e5, poisson=0.3, thickness=1e-3, density=200.0),
        Loads(gravity=(0.0, 0.0, -9.81)),
        [bcs.NodalConstraint(corners, (0,), (0, 1, 2), targets[:, None, :])],
        hessian=hessian,
        comm=comm,
        dynamics=Dynamics(dt, mass_damping=4.0),
    )
    with ShellSolver(model, prefix="bhem_study_") as solver:
        stepper = TimeStepper(model, solver)
        start = time.perf_counter()
        for step in range(1, 1001):
            stepper.advance()
            speed = comm.allreduce(float(np.abs(model.velocity.x.array).max(initial=0.0)), op=MPI.MAX)
            # parametric velocity DOFs: positions' rates are in m/s, derivative rates smaller
            if step >= 10 and speed < 1e-3:
                break
        wall = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
        nonzeros = solver.matrix_nonzeros()
    a, b = np.meshgrid(DRAPE_LATTICE, DRAPE_LATTICE, indexing="ij")
    positions = model.state_surface().evaluate(a, b).x
    iterations = sum(r.newton_iterations for r in stepper.history)
    return positions, {
        "wall_s": wall,
        "newton_iterations": iterations,
        "steps": step,
        "dofs": 3 * model.discretization.num_closed,
        "nonzeros": nonzeros,
    }


_DRAPE_REFERENCE: dict[int, np.ndarray] = {}  # finest rest shape per rank count, within one process


def run_drape(config: dict, comm: MPI.Comm) -> dict:
    """Drape to rest; error = largest distance to the finest configuration's rest shape on a
    21 x 21 lattice, relative to the side. The finest configuration is computed first (and once)."""
    positions, run = drape_to_rest(config["patches"], config["hessian"], config["dt"], comm)
    if comm.size not in _DRAPE_REFERENCE:
        finest = next(iter(_drape_configurations()))
        if config == finest:
            _DRAPE_REFERENCE[comm.size] = positions
        else:
            _DRAPE_REFERENCE[comm.size] = drape_to_rest(finest["patches"], finest["hessian"], finest["dt"], comm)[0]
    deviation = float(np.linalg.norm(positions - _DRAPE_REFERENCE[comm.size], axis=-1).max()) / DRAPE_SIDE
    sag = float(-positions[..., 2].min())
    return {
        "dofs": run["dofs"],
        "nonzeros": run["nonzeros"],
        "value": sag,
        "reference": float(-_DRAPE_REFERENCE[comm.size][..., 2].min()),
        "error": deviation,
        "wall_s": run["wall_s"],
        "newton_iterations": run["newton_iterations"],
        "steps": run["steps"],
    }


WRINKLE_SIZE = (0.25, 0.1)  # m, pulled along the first side (paper Fig. 13, 17; Cerda & Mahadevan's sheet)
WRINKLE_STRAIN = 0.1  # nominal strain of the pull
WRINKLE_MEASURED = 0.35e-3  # m, the measured peak amplitude the paper compares with (Wang et al. 2019)
WRINKLE_RAMP = 0.2  # s, the pull's duration (smooth start and stop)


def _wrinkle_configurations() -> Iterable[dict]:
    for patches in (5, 10, 15, 20, 30, 40):
        yield {"patches": patches, "quadrature": 4, "hessian": "exact", "dt": 0.01}
    for patches in (20, 30):
        yield {"patches": patches, "quadrature": 3, "hessian": "exact", "dt": 0.01}
    yield {"patches": 20, "quadrature": 4, "hessian": "pseudo", "dt": 0.01}
    yield {"patches": 20, "quadrature": 4, "hessian": "exact", "dt": 0.02}


def wrinkle_model(patches: int, quadrature: int, hessian: str, dt: float, comm: MPI.Comm) -> tuple[ShellModel, object]:
    """The stretched sheet (paper Fig. 13): 0.25 m x 0.1 m, h 0.1 mm, nu 0.5, Y 1 MPa, rho 930 kg/m^3,
    ``patches x patches``, no gravity. Both short ends are held in grips: position, the derivative
    along the end and the out-of-plane slope across it; the grip at xi1 = L moves by
    ``WRINKLE_STRAIN * L`` along x over ``WRINKLE_RAMP`` s. Flat initial state with a seeded
    random out-of-plane imperfection of 1 um (1 % of h) at the interior nodes; without one the
    flat, laterally compressed state is an equilibrium the sheet never leaves.

    Returns:
        The dynamic model (mass damping 10/s) and the :class:`~bhem_hpc.dynamics.PrescribedMotion`
        of the moving grip.
    """
    from bhem_hpc.dynamics import PrescribedMotion
    from bhem_hpc.shell import Dynamics

    if not (isinstance(patches, int) and 2 <= patches <= 80):
        raise StudyError(f"knob patches = {patches!r} is out of range (2..80)")
    if quadrature not in (2, 3, 4, 5) or hessian not in ("exact", "pseudo"):
        raise StudyError(f"knobs quadrature = {quadrature!r} (2..5) and hessian = {hessian!r} (exact|pseudo) invalid")
    if not (0.001 <= dt <= 0.05):
        raise StudyError(f"knob dt = {dt!r} is out of range [0.001, 0.05] s")
    length, width = WRINKLE_SIZE
    rest = S.flat_rectangle(length, width, patches, patches)
    grips = []
    for edge in ("xi1_min", "xi1_max"):
        nodes = bcs.edge_nodes(rest.grid, edge)
        # the grip holds the end line (x, d2, all components) and its out-of-plane slope (d1, d12
        # along z); the in-plane d1, d12 stay free so the sheet's stretch is not forced to 0 there
        grips += [bcs.NodalConstraint(nodes, (0, 2), (0, 1, 2)), bcs.NodalConstraint(nodes, (1, 3), (2,))]
    held = rest.nodal[-1, :, :, :][:, [0, 2], :]

    def grip_values(t: float) -> np.ndarray:
        s = min(1.0, t / WRINKLE_RAMP)
        values = held.copy()
        values[:, 0, 0] += WRINKLE_STRAIN * length * s * s * (3 - 2 * s)
        return values

    nodal = rest.nodal.copy()
    imperfection = np.random.default_rng(2019).standard_normal(nodal[1:-1, :, 0, 2].shape)
    nodal[1:-1, :, 0, 2] = 1e-6 * imperfection
    model = ShellModel(
        rest,
        Material(young=1e6, poisson=0.5, thickness=1e-4, density=930.0),
        Loads(),
        grips,
        initial=S.HermiteSurface(rest.grid, nodal),
        hessian=hessian,
        quadrature_points=quadrature,
        comm=comm,
        dynamics=Dynamics(dt, mass_damping=10.0),
    )
    return model, PrescribedMotion(grips[2], grip_values)


def wrinkle_profile(surface: S.HermiteSurface, samples: int = 401) -> tuple[float, int]:
    """``(peak amplitude [m], wrinkle count)``: the largest |z| on a lattice of 8 x 8 points per
    patch, and the number of half-waves across the width at mid-length (sign changes of z among
    the points where |z| exceeds 10 % of the peak, plus one)."""
    n1, n2 = surface.grid.n1, surface.grid.n2
    (a1, b1), (a2, b2) = surface.grid.xi1_range, surface.grid.xi2_range
    xi1, xi2 = np.meshgrid(np.linspace(a1, b1, 8 * n1 + 1), np.linspace(a2, b2, 8 * n2 + 1), indexing="ij")
    peak = float(np.abs(surface.evaluate(xi1, xi2).x[..., 2]).max())
    across = surface.evaluate(np.full(samples, (a1 + b1) / 2), np.linspace(a2, b2, samples)).x[:, 2]
    significant = np.sign(across[np.abs(across) > 0.1 * peak])
    return peak, int(np.count_nonzero(np.diff(significant))) + 1 if len(significant) else 0


WRINKLE_REST_DT = 2.0  # s, the largest time step of the relaxation after the pull


def stretch_to_rest(
    patches: int, quadrature: int, hessian: str, dt: float, comm: MPI.Comm, max_steps: int = 200
) -> tuple[S.HermiteSurface, dict]:
    """Pull the sheet of :func:`wrinkle_model` (time step ``dt``), then relax it to equilibrium:
    after the pull the time step doubles every step up to ``WRINKLE_REST_DT`` (implicit Euler with
    a large step is a proximal step on the energy: it settles slow wrinkle rearrangements that
    small steps take a second of simulated time to finish); stop at the first step of the largest
    dt that needs at most one Newton iteration, i.e. the state is an equilibrium to the solver's
    tolerance.

    Returns:
        The final surface and ``{"wall_s", "newton_iterations", "steps", "dofs", "nonzeros"}``.
    """
    from bhem_hpc.dynamics import TimeStepper

    model, grip = wrinkle_model(patches, quadrature, hessian, dt, comm)
    with ShellSolver(model, prefix="bhem_study_") as solver:
        stepper = TimeStepper(model, solver, motions=[grip])
        start = time.perf_counter()
        for _ in range(max_steps):
            if stepper.time >= WRINKLE_RAMP - 1e-9 * dt:
                stepper.dt = min(2 * stepper.dt, WRINKLE_REST_DT)
            report = stepper.advance()
            if stepper.dt == WRINKLE_REST_DT and report.newton_iterations <= 1:
                break
        else:
            raise StudyError(f"wrinkle study: the {patches}x{patches} sheet did not come to rest in {max_steps} steps")
        wall = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
        nonzeros = solver.matrix_nonzeros()
    iterations = sum(r.newton_iterations for r in stepper.history)
    return model.state_surface(), {
        "wall_s": wall,
        "newton_iterations": iterations,
        "steps": stepper.step,
        "dofs": 3 * model.discretization.num_closed,
        "nonzeros": nonzeros,
    }


_WRINKLE_SHAPES: dict[tuple, S.HermiteSurface] = {}  # final surface per configuration, within one process


def plot_wrinkles(path: Path, rows: list[dict]) -> None:
    """Profiles across the width at mid-length for each resolution (exact Hessian, 4 x 4 Gauss,
    dt 0.01), and the out-of-plane displacement of the finest sheet (paper Fig. 13)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    length, width = WRINKLE_SIZE
    series = [
        r
        for r in rows
        if (r["quadrature"], r["hessian"], r["dt"]) == (4, "exact", 0.01) and tuple(_config(r)) in _WRINKLE_SHAPES
    ]
    if not series:
        return
    fig, axes = plt.subplots(1, 2, figsize=(12, 4), dpi=110, gridspec_kw={"width_ratios": [1, 1.4]})
    across = np.linspace(0.0, width, 401)
    for r in series:
        z = _WRINKLE_SHAPES[tuple(_config(r))].evaluate(np.full_like(across, length / 2), across).x[:, 2]
        axes[0].plot(across * 1e3, z * 1e3, label=f"{r['patches']} x {r['patches']}")
    axes[0].axhline(WRINKLE_MEASURED * 1e3, color="k", lw=0.8, ls="--", label="measured peak 0.35 mm")
    axes[0].axhline(-WRINKLE_MEASURED * 1e3, color="k", lw=0.8, ls="--")
    axes[0].set_xlabel("position across the width at mid-length [mm]")
    axes[0].set_ylabel("out-of-plane displacement [mm]")
    axes[0].legend(fontsize=7)
    axes[0].grid(alpha=0.3)
    finest = max(series, key=lambda r: r["patches"])
    surface = _WRINKLE_SHAPES[tuple(_config(finest))]
    a, b = np.meshgrid(np.linspace(0.0, length, 401), np.linspace(0.0, width, 161), indexing="ij")
    points = surface.evaluate(a, b).x
    limit = np.abs(points[..., 2]).max() * 1e3
    image = axes[1].pcolormesh(
        points[..., 0] * 1e3, points[..., 1] * 1e3, points[..., 2] * 1e3, cmap="RdBu_r", vmin=-limit, vmax=limit
    )
    axes[1].set_aspect("equal")
    axes[1].set_xlabel("x [mm] (pulled)")
    axes[1].set_ylabel("y [mm]")
    axes[1].set_title(f"{finest['patches']} x {finest['patches']} patches, stretched 10 %", fontsize=9)
    fig.colorbar(image, ax=axes[1], label="z [mm]", shrink=0.8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _config(row: dict) -> list[tuple]:
    """A wrinkle row's configuration items, in the configurations' key order."""
    return [(k, row[k]) for k in ("patches", "quadrature", "hessian", "dt")]


def run_wrinkle(config: dict, comm: MPI.Comm) -> dict:
    """Stretched-sheet wrinkles (paper Fig. 13, 17): peak amplitude against the measured 0.35 mm."""
    surface, run = stretch_to_rest(config["patches"], config["quadrature"], config["hessian"], config["dt"], comm)
    peak, count = wrinkle_profile(surface)
    _WRINKLE_SHAPES[tuple(config.items())] = surface
    return {
        "dofs": run["dofs"],
        "nonzeros": run["nonzeros"],
        "value": peak,
        "reference": WRINKLE_MEASURED,
        "error": abs(peak / WRINKLE_MEASURED - 1),
        "wall_s": run["wall_s"],
        "newton_iterations": run["newton_iterations"],
        "wrinkles": count,
        "steps": run["steps"],
    }


STUDIES = {
    "plate": Study(
        "plate",
        "square plate under uniform load, simply supported and clamped, small deflection",
        ("support", "patches", "quadrature", "hessian", "factorization"),
        _plate_configurations,
        run_plate,
        "support",
        {"quadrature": 4, "hessian": "exact", "factorization": "ldlt"},
        "support",
    ),
    "buckling": Study(
        "buckling",
        "plate hanging on edge from a clamp, Gamma* of lateral buckling against Michell-Prandtl beam theory",
        ("aspect", "patches_per_m", "poisson"),
        _buckling_configurations,
        run_buckling,
        "aspect",
        {"poisson": 0.0},
        "aspect",
        note=(
            "The reference is beam theory, exact only as w/L -> 0: the errors at a given w/L are mostly the plate's "
            "own stiffening near the clamp (the threshold rises about linearly with w/L; extrapolated to w/L = 0 it "
            "is the beam's within 1 %, asserted by `make study`), not discretization error: 20 and 40 patches per "
            "metre agree within 0.7 % at every w/L."
        ),
    ),
    "drape": Study(
        "drape",
        "cloth pinned at four corners moved inward, draped from flat to rest: shape against the finest run",
        ("patches", "hessian", "dt"),
        _drape_configurations,
        run_drape,
        "hessian",
        {"dt": 0.01},
        "hessian",
        ("steps",),
        note=(
            "The reference is the 24 x 24 exact-Hessian run at dt = 0.01 s (its own row has error 0 and is left "
            "out of the targets below). A run stops when every nodal velocity is below 1 mm/s, which leaves "
            "differences of a few 1e-4 between runs that reach the same rest shape. The first step, where the "
            "moved corners distort their patches, needs regularized retries and a dt halving."
        ),
    ),
    "wrinkle": Study(
        "wrinkle",
        "sheet stretched 10 % between grips: peak wrinkle amplitude against the measured 0.35 mm",
        ("patches", "quadrature", "hessian", "dt"),
        _wrinkle_configurations,
        run_wrinkle,
        "hessian",
        {"quadrature": 4, "dt": 0.01},
        "hessian",
        ("wrinkles", "steps"),
        figure=plot_wrinkles,
        note=(
            "The reference is a physical measurement (0.35 mm, Wang et al. 2019, as in the paper's Fig. 17), not an "
            "exact solution: the error of the finest runs is the model's (Kirchhoff-Love, St. Venant-Kirchhoff, "
            "10 % nominal strain assumed - our copy of the paper does not state the stretch) as much as the "
            "discretization's, and the cheapest row below is misleading: 3 x 3 Gauss under-integrates the bicubic "
            "energy and lands nearer the measurement by accident (4.5 % above the 40 x 40, 4 x 4 run at 20 x 20, "
            "3.3 % at 30 x 30); with 4 x 4 Gauss the amplitude settles from 30 x 30 on (30 and 40 within 0.6 %). "
            "`wrinkles` counts half-waves across the width at mid-length. Each run pulls the "
            "grip over 0.2 s (dt as configured), then relaxes to equilibrium with a time step doubling up to 2 s; "
            "the wrinkles appear within one step, midway through the pull, which costs that step regularized retries."
        ),
    ),
    "cantilever": Study(
        "cantilever",
        "heavy cantilever strip, tip drop against the heavy elastica (master curve)",
        ("gamma", "patches", "hessian", "newton_rtol"),
        _cantilever_configurations,
        run_cantilever,
        "patches",
        {"hessian": "exact", "newton_rtol": 1e-9},
        "gamma",
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
        writer = csv.DictWriter(handle, fieldnames=study.columns) if handle else None
        if writer:
            writer.writeheader()
        for k, config in enumerate(study.configurations()):
            if limit is not None and k >= limit:
                break
            row = {"study": name, "ranks": comm.size, **config, **study.run(config, comm)}
            rows.append(row)
            if writer:
                writer.writerow({c: row.get(c, "") for c in study.columns})
                handle.flush()  # an interrupted study keeps the rows it finished
    finally:
        if handle:
            handle.close()
    if comm.rank == 0:
        _write_table(out / f"{name}.md", study, rows)
        _plot(out / f"{name}.png", study, rows)
        if study.figure is not None:
            study.figure(out / f"{name}-shapes.png", rows)
    return rows


def _write_table(path: Path, study: Study, rows: list[dict]) -> None:
    columns = (*study.knobs, "dofs", "error", "wall_s", "newton_iterations", *study.extra)
    header = "| " + " | ".join(columns) + " |\n|" + " --- |" * len(columns) + "\n"

    def cell(value: object) -> str:
        return f"{value:.3g}" if isinstance(value, float) else str(value)

    body = "".join("| " + " | ".join(cell(r[c]) for c in columns) + " |\n" for r in rows)
    path.write_text(f"# Study `{study.name}`: {study.description}\n\n{header}{body}")


def _plot(path: Path, study: Study, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), dpi=110)
    rows = _results(rows)
    baseline = [r for r in rows if all(r[k] == v for k, v in study.baseline.items())]
    for label in sorted({r[study.series] for r in baseline}, key=str):
        series = sorted((r for r in baseline if r[study.series] == label), key=lambda r: (r["dofs"], r["wall_s"]))
        errors = [max(r["error"], 1e-16) for r in series]
        axes[0].loglog([r["wall_s"] for r in series], errors, "o", label=f"{study.series} = {label}")
        axes[1].loglog([r["dofs"] for r in series], errors, "o", label=f"{study.series} = {label}")
    axes[0].set_xlabel("wall time of the solve [s]")
    axes[1].set_xlabel("DoFs")
    for ax in axes:
        ax.set_ylabel("relative error")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.suptitle(f"{study.name}: {study.description}")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _results(rows: list[dict]) -> list[dict]:
    """The rows without a study's own reference row (measured against its finest run: error 0)."""
    return [r for r in rows if r["error"] > 0.0 or r["value"] != r["reference"]]


def cheapest(rows: list[dict], tolerance: float) -> dict | None:
    """The fastest configuration whose error is at most ``tolerance`` (None if none reaches it)."""
    good = [r for r in rows if r["error"] <= tolerance]
    return min(good, key=lambda r: r["wall_s"]) if good else None


def read_rows(path: Path) -> list[dict]:
    """The rows of a study CSV, numbers parsed back (int where they are integral, else float)."""

    def parse(text: str) -> object:
        for kind in (int, float):
            try:
                return kind(text)
            except ValueError:
                pass
        return text

    with open(path, newline="") as handle:
        return [{k: parse(v) for k, v in row.items()} for row in csv.DictReader(handle)]


def write_accuracy_cost(docs: Path, comm: MPI.Comm = MPI.COMM_WORLD) -> Path:
    """Run every study into ``docs/studies/ranks-N/NAME`` (N = this run's rank count) and write
    ``docs/accuracy-cost.md`` from the rows of every rank count found there: a serial run and one
    under ``mpirun -n 2`` (``make docs`` runs both) give the 1- and 2-rank rows side by side."""
    import shutil

    target = docs / "studies" / f"ranks-{comm.size}"
    if comm.rank == 0 and target.exists():
        shutil.rmtree(target)
    comm.Barrier()
    for name in STUDIES:
        run_study(name, target / name, comm)
    out = docs / "accuracy-cost.md"
    if comm.rank == 0:
        out.write_text(_accuracy_cost_markdown(docs))
    comm.Barrier()
    return out


def _accuracy_cost_markdown(docs: Path) -> str:
    runs = sorted(int(p.name.split("-")[1]) for p in (docs / "studies").glob("ranks-*") if p.is_dir())
    sections = []
    for name, study in STUDIES.items():
        by_ranks = {
            n: read_rows(docs / "studies" / f"ranks-{n}" / name / f"{name}.csv")
            for n in runs
            if (docs / "studies" / f"ranks-{n}" / name / f"{name}.csv").exists()
        }
        if not by_ranks:
            continue
        first = min(by_ranks)
        picture = f"studies/ranks-{first}/{name}/{name}.png"
        lines = [f"## `{name}`: {study.description}", "", f"![{name}]({picture})", ""]
        if (docs / picture.replace(".png", "-shapes.png")).exists():
            lines += [f"![{name} shapes]({picture.replace('.png', '-shapes.png')})", ""]
        if study.note:
            lines += [study.note, ""]
        rows = _results([r for n in sorted(by_ranks) for r in by_ranks[n]])
        lines += [
            f"| {study.problem} | target error | cheapest configuration | ranks | error | solve time [s] | DoFs |",
            "| --- | --- | --- | ---: | ---: | ---: | ---: |",
        ]
        for problem in sorted({r[study.problem] for r in rows}, key=str):
            subset = [r for r in rows if r[study.problem] == problem]
            best = min(subset, key=lambda r: r["error"])
            for tolerance in (1e-2, 1e-3):
                row = cheapest(subset, tolerance)
                if row is None:
                    lines.append(f"| {problem} | {tolerance:g} | not reached; best {best['error']:.2e} | | | | |")
                    continue
                knobs = ", ".join(f"{k} = {row[k]}" for k in study.knobs if k != study.problem)
                lines.append(
                    f"| {problem} | {tolerance:g} | {knobs} | {row['ranks']} | {row['error']:.2e} | "
                    f"{row['wall_s']:.4f} | {row['dofs']} |"
                )
        lines += ["", _knob_effects(study, _results(by_ranks[first])), ""]
        if len(by_ranks) > 1:
            lines += [_rank_comparison(study, by_ranks), ""]
        links = ", ".join(
            f"[{n} rank{'s' if n > 1 else ''}](studies/ranks-{n}/{name}/{name}.csv)" for n in sorted(by_ranks)
        )
        lines += [f"All rows: {links} (CSV; tables beside them).", ""]
        sections.append("\n".join(lines))
    counts = " and ".join(str(n) for n in runs)
    header = (
        "# What accuracy costs in time\n\n"
        "Generated by `make docs` (`bhem-hpc study --docs docs`, serially and under `mpirun -n 2`); every number "
        f"below was measured in those runs, on {counts} rank(s), on one 2-core machine. Errors are relative to "
        "independent references (Navier series, tabulated clamped-plate value, heavy elastica, Michell-Prandtl "
        "lateral buckling, a measured wrinkle amplitude) or, for the drape, to the finest run; times are the "
        "solve only (assembly, factorization, Newton; for the drape and the wrinkles every time step), without "
        "the one-off JIT compilation.\n\n"
    )
    return header + "\n".join(sections)


def _rank_comparison(study: Study, by_ranks: dict[int, list[dict]]) -> str:
    """The configurations run on every rank count: value and time per rank count."""
    counts = sorted(by_ranks)
    first = by_ranks[counts[0]]
    header = (
        "| "
        + " | ".join(study.knobs)
        + " | "
        + " | ".join(f"value ({n})" for n in counts)
        + " | "
        + " | ".join(f"time ({n}) [s]" for n in counts)
        + f" | time {counts[-1]} / {counts[0]} |"
    )
    lines = [
        "Rank counts (same configuration, value and solve time per rank count):",
        "",
        header,
        "|" + " --- |" * len(study.knobs) + " ---: |" * (2 * len(counts) + 1),
    ]
    for row in first:
        twins = [next((r for r in by_ranks[n] if all(r[k] == row[k] for k in study.knobs)), None) for n in counts]
        if any(t is None for t in twins):
            continue
        lines.append(
            "| "
            + " | ".join(str(row[k]) for k in study.knobs)
            + " | "
            + " | ".join(f"{t['value']:.6g}" for t in twins)
            + " | "
            + " | ".join(f"{t['wall_s']:.3f}" for t in twins)
            + f" | {twins[-1]['wall_s'] / twins[0]['wall_s']:.2f} |"
        )
    return "\n".join(lines)


def _knob_effects(study: Study, rows: list[dict]) -> str:
    """One sentence per knob: how error and time change against the baseline configuration."""
    sentences = []
    base = [r for r in rows if all(r[k] == v for k, v in study.baseline.items())]
    for knob in study.knobs:
        if knob in study.baseline:
            others = [r for r in rows if r[knob] != study.baseline[knob]]
            for r in others:
                twin = next((b for b in base if all(b[k] == r[k] for k in study.knobs if k != knob)), None)
                if twin is None:
                    continue
                sentences.append(
                    f"{knob} = {r[knob]} instead of {study.baseline[knob]} "
                    f"({', '.join(f'{k} = {r[k]}' for k in study.knobs if k != knob)}): error "
                    f"{twin['error']:.2e} -> {r['error']:.2e}, time {twin['wall_s']:.4f} -> {r['wall_s']:.4f} s."
                )
    return "What the knobs buy:\n\n" + "\n".join(f"- {s}" for s in sentences) if sentences else ""
