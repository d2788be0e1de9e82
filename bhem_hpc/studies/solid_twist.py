"""The SEM paper's twisted beam (its Fig. 12): a beam of 22 NURBS parts (756 DoFs, as the paper's),
one end held, the other turned about the beam's axis up to 360 degrees in static increments.
Serial, numpy and scipy."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bhem_hpc.geometry import nurbs
from bhem_hpc.io.solid_output import tessellate_parts
from bhem_hpc.solids.equilibrium import solve_static
from bhem_hpc.solids.sem import ShapeMatchingSolid, SolidMaterial, SolidOptions

#: Length and square side of the beam [m]; rubber as the paper's twisted beam (Table 1).
LENGTH, SIDE = 2.0, 0.2
RUBBER = SolidMaterial(density=1000.0, young=1e6, poisson=0.45)
#: Sections of 4 biquadratic side parts (3 x 3 control points), plus the two ends refined to 6 x 6
#: control points: 22 parts, 756 DoFs, the paper's count.
SECTIONS = 5
END_REFINEMENT = (3, 3)
#: Saint-Venant's torsion constant of a square section, ``J = k b^4`` (Timoshenko and Goodier).
SQUARE_TORSION = 0.1406


@dataclass(frozen=True)
class TwistIncrement:
    """One static increment: the end's angle [deg], Newton iterations, seconds, the elastic energy
    [J], Saint-Venant's linear energy at that angle [J] and the midspan section's angle [deg]."""

    angle: float
    iterations: int
    seconds: float
    energy: float
    saint_venant: float
    midspan_angle: float


def _turned(points: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """``points (n, 3)`` turned about the x axis by ``angles (n,)`` [rad]."""
    c, s = np.cos(angles), np.sin(angles)
    out = points.copy()
    out[:, 1] = c * points[:, 1] - s * points[:, 2]
    out[:, 2] = s * points[:, 1] + c * points[:, 2]
    return out


def twist_parts() -> list[nurbs.NurbsSurface]:
    """The beam's parts along x from 0 to :data:`LENGTH`, its axis the x axis."""
    half = SIDE / 2
    parts = nurbs.beam_faces([0.0, -half, -half], [LENGTH, half, half], SECTIONS, degree=2)
    parts[-2:] = [nurbs.refine(end, END_REFINEMENT) for end in parts[-2:]]  # beam_faces puts the ends last
    return parts


def twist_solid(alpha: float = 0.12, lines: int = 60) -> ShapeMatchingSolid:
    """The beam of :func:`twist_parts`."""
    options = SolidOptions(degree=2, lines_per_side=lines, alpha=alpha)
    return ShapeMatchingSolid(twist_parts(), RUBBER, options, name="beam")


def _midspan_angle(solid: ShapeMatchingSolid, q: np.ndarray, previous: float) -> float:
    """The mean angle [deg] by which the control points at midspan turned about the axis, unwrapped
    next to ``previous``."""
    middle = np.isclose(solid.reference[:, 0], LENGTH / 2)
    before = np.arctan2(solid.reference[middle, 2], solid.reference[middle, 1])
    after = np.arctan2(q[middle, 2], q[middle, 1])
    turn = np.degrees(np.angle(np.mean(np.exp(1j * (after - before)))))
    return turn + 360.0 * np.round((previous - turn) / 360.0)


def twist(solid: ShapeMatchingSolid, increment: float = 30.0, total: float = 360.0):
    """Turn the end at x = :data:`LENGTH` by ``total`` degrees in ``increment`` steps, each solved
    to static equilibrium from a first guess that turns every control point by the increment in
    proportion to its x. Returns the increments and the control points ``(n_q, 3)`` after each."""
    reference = solid.reference
    held, turned = np.isclose(reference[:, 0], 0.0), np.isclose(reference[:, 0], LENGTH)
    fixed = np.zeros(reference.shape, dtype=bool)
    fixed[held | turned] = True
    shear = RUBBER.young / (2.0 * (1.0 + RUBBER.poisson))
    q, angle, midspan = reference.copy(), 0.0, 0.0
    rows, states = [], []
    for _ in range(int(round(total / increment))):
        angle += increment
        guess = _turned(q, np.radians(increment) * reference[:, 0] / LENGTH)
        guess[held] = reference[held]
        guess[turned] = _turned(reference[turned], np.full(np.count_nonzero(turned), np.radians(angle)))
        clock = time.perf_counter()
        state = solve_static(solid, guess, fixed)
        q = state.q
        midspan = _midspan_angle(solid, q, midspan + increment / 2)
        linear = 0.5 * SQUARE_TORSION * shear * SIDE**4 / LENGTH * np.radians(angle) ** 2
        rows.append(
            TwistIncrement(angle, state.iterations, time.perf_counter() - clock, solid.energy(q), linear, midspan)
        )
        states.append(q.copy())
    return rows, states


def plot_twist(path: Path, solid: ShapeMatchingSolid, states: list[np.ndarray], labels: list[str]) -> None:
    """The beam's parts in each of ``states`` (its control points), side by side, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    samples = 9
    fig = plt.figure(figsize=(4.5 * len(states), 2.6))
    for k, (q, label) in enumerate(zip(states, labels, strict=True)):
        axis = fig.add_subplot(1, len(states), k + 1, projection="3d")
        points = tessellate_parts(solid.deformed_parts(q), samples)[0].reshape(len(solid.parts), samples, samples, 3)
        for i, grid in enumerate(points):
            axis.plot_surface(*grid.transpose(2, 0, 1), color=f"C{i % 4}", alpha=0.9, linewidth=0.2, edgecolor="k")
        reach = 1.5 * SIDE
        axis.set(title=label, xlim=(0, LENGTH), ylim=(-reach, reach), zlim=(-reach, reach))
        axis.set_box_aspect((LENGTH, 2 * reach, 2 * reach))
        axis.view_init(elev=25, azim=-70)
        axis.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
