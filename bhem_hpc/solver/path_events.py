"""Events between two converged points of an equilibrium path (numpy only): limit points located at
the load factor's extrema, bifurcations where the tangent's inertia changes without one.

Between the points ``0`` and ``1`` the load factor is interpolated as the cubic Hermite polynomial of
the arc length that has the points' load factors ``lambda_0, lambda_1`` and slopes ``m = dlambda/ds``
(from each point's tangent ``t = K^-1 q``: ``m = sign * sqrt(n) / |t|``, which vanishes at a limit
point). Every zero of its derivative inside the segment where the derivative changes sign is a limit
point, located at that extremum rather than at the next recorded point. Extrema are sought only where
the samples show a turn: a change of the slope's sign (one limit), or a change of the load factor
against both slopes (a maximum and a minimum between the two points); elsewhere the interpolant's
overshoot at a sharp knee would invent one. An inertia change that the limits do not account for (more
negative pivots gained or lost than limits passed) is a bifurcation, reported at the point after it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Relative size below which a derivative coefficient of the interpolant counts as zero.
ROOT_EPSILON = 1e-14


@dataclass(frozen=True)
class PathEvent:
    """A limit point or bifurcation between two path points.

    Attributes:
        kind: ``"limit"`` or ``"bifurcation"``.
        load_factor: lambda at the event (a limit: the interpolated extremum; a bifurcation: the
            point after it).
        arc_length: the path's arc length there.
    """

    kind: str
    load_factor: float
    arc_length: float

    def as_dict(self) -> dict[str, float | str]:
        return {"kind": self.kind, "load_factor": self.load_factor, "arc_length": self.arc_length}


@dataclass(frozen=True)
class PathSample:
    """What the event search needs of one converged point.

    Attributes:
        arc_length: s.
        load_factor: lambda.
        slope: dlambda/ds along the path's direction (0 at a limit point).
        negative_pivots: negative eigenvalues of the tangent (-1: unknown).
    """

    arc_length: float
    load_factor: float
    slope: float
    negative_pivots: int


def hermite_extrema(start: PathSample, end: PathSample) -> list[tuple[float, float]]:
    """``(arc_length, load_factor)`` of every extremum of the cubic Hermite interpolant of lambda(s)
    strictly between the two samples, in order of arc length (empty for a zero-length segment)."""
    h = end.arc_length - start.arc_length
    if not h > 0:
        return []
    l0, l1, m0, m1 = start.load_factor, end.load_factor, h * start.slope, h * end.slope
    # p(u) = l0 h00 + m0 h10 + l1 h01 + m1 h11 on u in [0, 1]; p'(u) = a u^2 + b u + c
    a = 6 * l0 + 3 * m0 - 6 * l1 + 3 * m1
    b = -6 * l0 - 4 * m0 + 6 * l1 - 2 * m1
    c = m0
    scale = max(abs(a), abs(b), abs(c), 1e-300)
    if abs(a) <= ROOT_EPSILON * scale:
        roots = [] if abs(b) <= ROOT_EPSILON * scale else [-c / b]
    else:
        discriminant = b * b - 4 * a * c
        if discriminant <= 0:  # no sign change of p' (a double root is an inflection, not an extremum)
            return []
        root = np.sqrt(discriminant)
        roots = sorted([(-b - root) / (2 * a), (-b + root) / (2 * a)])
    found = []
    for u in roots:
        if 0.0 < u < 1.0:
            value = l0 * (2 * u**3 - 3 * u**2 + 1) + m0 * (u**3 - 2 * u**2 + u) + l1 * (-2 * u**3 + 3 * u**2) + m1 * (
                u**3 - u**2
            )
            found.append((start.arc_length + u * h, float(value)))
    return found


def events_between(start: PathSample, end: PathSample) -> tuple[PathEvent, ...]:
    """The limit points and bifurcations between two consecutive path points (see the module)."""
    change = end.load_factor - start.load_factor
    turned = start.slope * end.slope < 0
    # only where the samples show a turn: the interpolant of a sharp knee (a stiff path meeting a
    # flat one) overshoots, and its extremum there is not the path's
    shown = turned or (change * start.slope < 0 and change * end.slope < 0)
    limits = [PathEvent("limit", factor, s) for s, factor in hermite_extrema(start, end)] if shown else []
    if not limits and turned:  # a sign change the interpolant misses (round-off)
        s, factor = max((start.arc_length, start.load_factor), (end.arc_length, end.load_factor),
                        key=lambda sample: np.sign(start.slope) * sample[1])  # fmt: skip
        limits.append(PathEvent("limit", factor, s))
    known = start.negative_pivots >= 0 and end.negative_pivots >= 0
    inertia_change = abs(end.negative_pivots - start.negative_pivots) if known else 0
    if inertia_change > len(limits):
        return (*limits, PathEvent("bifurcation", end.load_factor, end.arc_length))
    return tuple(limits)
