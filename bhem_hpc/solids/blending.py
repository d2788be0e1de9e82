"""Ray-cast blending weights of parts (SEM paper §6.1): numpy and scipy, the closest points and the
secondary rays compiled (:mod:`bhem_hpc.compiled.projection`, :mod:`bhem_hpc.compiled.ray_hits`).

For a volume point ``X`` and a part ``b_i``: ``X*`` is the closest point of the part, the primary
distance ``d_p = |X - X*|``; a secondary ray from ``X*`` through ``X`` meets the next surface at
``X^h``, ``d_t = |X^h - X*|``. The distance weight (eq. 8) is
``theta_i = max(1 - d_p / min(d_t, alpha), 0)``, and 1 where ``X^h`` lies on the same part (inside
a closed part). The normalization QP of eq. (9), ``min w^T diag(1/theta) w`` on the simplex, has
the closed form ``w = theta / sum(theta)`` (its KKT point; parts with ``theta = 0`` get 0). A point
that no part reaches within ``alpha`` belongs to its nearest part alone. The cutoff ``alpha`` is
chosen for a sparsity target ``T``: the share of nonzero weights.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse

from bhem_hpc.compiled.blend_counts import nonzero_weights
from bhem_hpc.compiled.extraction import bezier_nets_by_degree
from bhem_hpc.compiled.projection import closest_points
from bhem_hpc.compiled.ray_hits import first_hits
from bhem_hpc.geometry.nurbs import NurbsSurface
from bhem_hpc.geometry.rational_bezier import flat_share
from bhem_hpc.geometry.surface import SurfaceError

#: Bisection steps of the cutoff search (the share of nonzeros is a step function of alpha).
ALPHA_BISECTIONS = 40
#: A secondary ray is searched from this far (relative to the model's size) beyond its point: a
#: boundary sample lies on its own part, whose crossing there Newton finds up to its tolerance
#: (1e-10 of the size) and which is not the next surface.
BEYOND_POINT = 1e-7


@dataclass(frozen=True)
class RayDistances:
    """Per point and part ``(Q, parts)``: primary distance (inf: not computed, the part lies too far
    to weigh, see :func:`ray_distances`), total distance (inf: no surface within ``reach``, or no
    ray cast), and whether the secondary ray met the same part; ``away (Q, parts, 3)`` the unit
    vector from the closest point to the point (the primary distance's gradient; 0 where not
    computed), ``feet (Q, parts, 3)`` the closest points (nan where not computed); ``reach`` bounds
    every cutoff."""

    primary: np.ndarray
    total: np.ndarray
    same_part: np.ndarray
    away: np.ndarray
    feet: np.ndarray
    reach: float
    seconds: float

    def with_rays(self, parts: Sequence[NurbsSurface], pairs: np.ndarray, reach: float) -> RayDistances:
        """These distances with the secondary rays of the point-part ``pairs (Q, parts)`` (a mask)
        cast from their feet through their points, each searched no farther than ``reach`` (which
        then bounds every cutoff): the total distances and same-part flags of those pairs."""
        control = np.concatenate([p.control.reshape(-1, 3) for p in parts])
        beyond = BEYOND_POINT * float(np.ptp(control, axis=0).max())
        point, part_of_ray = np.nonzero(pairs)
        origins, directions = self.feet[point, part_of_ray], self.away[point, part_of_ray]
        tau_min = self.primary[point, part_of_ray] + beyond
        best, owner = np.full(len(point), np.inf), np.full(len(point), -1)
        # flat groups first: their hits, found in one solve, shorten the curved groups' searches
        for nets, part_of_patch in sorted(bezier_nets_by_degree(parts), key=lambda group: -flat_share(group[0])):
            # searched no farther than the nearest hit so far
            hits = first_hits(nets, origins, directions, tau_min, np.minimum(best, reach))
            closer = hits.tau < best
            best[closer], owner[closer] = hits.tau[closer], part_of_patch[hits.patch[closer]]
        total, same = self.total.copy(), self.same_part.copy()
        total[point, part_of_ray] = best
        same[point, part_of_ray] = owner == part_of_ray
        return replace(self, total=total, same_part=same, reach=float(reach))

    def with_pairs(self, parts: Sequence[NurbsSurface], points: np.ndarray, pairs: np.ndarray, on_part: np.ndarray,
                   cast: np.ndarray) -> RayDistances:  # fmt: skip
        """These distances with those of the point-part ``pairs (Q, parts)`` (a mask of pairs not yet
        computed) to ``points (Q, 3)``: closest points (0 at the part each point lies on, ``on_part
        (Q,)``, -1: none), then the secondary rays of the ``cast (parts,)`` parts where the primary
        distance is below :attr:`reach` (see :meth:`with_rays`)."""
        if not pairs.any():
            return self
        primary, feet, away = self.primary.copy(), self.feet.copy(), self.away.copy()
        for i, part in enumerate(parts):
            rows = np.flatnonzero(pairs[:, i])
            if len(rows):
                _, feet[rows, i], distance = closest_points(part, points[rows])
                distance[on_part[rows] == i] = 0.0
                primary[rows, i] = distance
        inside = pairs & (primary > 0.0)
        away[inside] = (points[:, None] - feet)[inside] / primary[inside][:, None]
        same = self.same_part | (pairs & (primary == 0.0))
        distances = replace(self, primary=primary, feet=feet, away=away, same_part=same)
        return distances.with_rays(parts, inside & (primary < self.reach) & cast[None, :], self.reach)

    def theta(self, alpha: float) -> np.ndarray:
        """Distance weights ``(Q, parts)`` for the cutoff ``alpha <= reach``."""
        with np.errstate(divide="ignore", invalid="ignore"):
            theta = np.maximum(1.0 - self.primary / np.minimum(self.total, alpha), 0.0)
        return np.where(self.same_part, 1.0, theta)

    def weights(self, alpha: float) -> scipy.sparse.csr_matrix:
        """Blending weights ``(Q, parts)``: nonnegative, rows summing to one."""
        theta = self.theta(alpha)
        total = theta.sum(axis=1)
        alone = total <= 0.0
        theta[alone, np.argmin(self.primary[alone], axis=1)] = 1.0
        theta /= theta.sum(axis=1, keepdims=True)
        return scipy.sparse.csr_matrix(theta)

    def weight_gradients(self, alpha: float) -> np.ndarray:
        """``(Q, parts, 3)``: the gradients of :meth:`weights` in the point, the total distances held
        fixed (the secondary ray's far end moves little next to the point itself): ``theta_i``
        falls as ``-away_i / min(d_t, alpha)`` where it is positive and not set to 1, and the
        normalization's quotient rule keeps the gradients summing to zero."""
        theta = self.theta(alpha)
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = np.where((theta > 0.0) & ~self.same_part, -1.0 / np.minimum(self.total, alpha), 0.0)
        d_theta = slope[..., None] * self.away
        total = theta.sum(axis=1)
        alone = total <= 0.0
        total = np.where(alone, 1.0, total)
        gradients = d_theta / total[:, None, None] - theta[..., None] * d_theta.sum(axis=1, keepdims=True) / (
            total[:, None, None] ** 2
        )
        gradients[alone] = 0.0  # a point no part reaches belongs to its nearest part alone
        return gradients

    def nonzero_share(self, alpha: float) -> float:
        """The share of nonzero entries of :meth:`weights` (counted without building the matrix:
        the positive distance weights, and one for each point that no part reaches)."""
        return nonzero_weights(self.primary, self.total, self.same_part, float(alpha)) / self.primary.size

    def cutoff_for(self, target: float, name: str = "model") -> float:
        """The largest cutoff whose share of nonzero weights stays at most ``target`` in ``(0, 1]``
        (at least one weight per point is always nonzero)."""
        if not (isinstance(target, int | float) and 0.0 < target <= 1.0):
            raise SurfaceError(f"{name}: blending sparsity target must lie in (0, 1], got {target!r}")
        low, high = 0.0, self.reach
        if self.nonzero_share(high) <= target:
            return high
        for _ in range(ALPHA_BISECTIONS):
            middle = 0.5 * (low + high)
            low, high = (middle, high) if self.nonzero_share(middle) <= target else (low, middle)
        return max(low, 1e-12 * self.reach)


def _box_distances(parts: Sequence[NurbsSurface], points: np.ndarray) -> np.ndarray:
    """``(Q, parts)``: the distance of each point to each part's control point box (a lower bound
    of its distance to the part, 0 inside the box)."""
    boxes = [(part.control.reshape(-1, 3).min(axis=0), part.control.reshape(-1, 3).max(axis=0)) for part in parts]
    return np.stack([np.linalg.norm(np.maximum(np.maximum(low - points, points - high), 0.0), axis=1)
                     for low, high in boxes], axis=1)  # fmt: skip


def ray_distances(parts: Sequence[NurbsSurface], points: np.ndarray, reach: float, on_part: np.ndarray | None = None,
                  cast: np.ndarray | None = None, within: float | None = None) -> RayDistances:  # fmt: skip
    """Primary and secondary distances of ``points (Q, 3)`` to ``parts``; secondary rays are cast
    only where the primary distance is below ``reach`` and searched no farther than ``reach``.
    ``on_part (Q,)``: the part each point lies on (boundary samples; -1: none), at distance 0 from
    it. ``cast (parts,)``: the parts whose secondary rays are cast (default: all; the others' total
    distances stay inf, see :meth:`RayDistances.with_rays`). ``within`` (default ``reach``): the
    primary distance is inf, and no ray is cast, where the part's box lies that far from the point
    or farther (a point outside a part's box is not inside the part, so its weight there is 0 for
    every cutoff up to ``within``), except at points no part's box comes that near to (their
    nearest part takes them alone)."""
    clock = time.perf_counter()
    count = len(points)
    on_part = np.full(count, -1) if on_part is None else np.asarray(on_part)
    cast = np.ones(len(parts), dtype=bool) if cast is None else np.asarray(cast, dtype=bool)
    shape = (count, len(parts))
    distances = RayDistances(np.full(shape, np.inf), np.full(shape, np.inf), np.zeros(shape, dtype=bool),
                             np.zeros((*shape, 3)), np.full((*shape, 3), np.nan), float(reach), 0.0)  # fmt: skip
    within = reach if within is None else within
    near = _box_distances(parts, points) < within
    distances = distances.with_pairs(parts, points, near, on_part, cast)
    # where no part came nearer than within, all of them: the point's nearest part among all
    alone = (distances.primary.min(axis=1) >= within)[:, None] & ~near
    distances = distances.with_pairs(parts, points, alone, on_part, cast)
    return replace(distances, seconds=time.perf_counter() - clock)


def cutoff_distances(parts: Sequence[NurbsSurface], points: np.ndarray, reach: float, target: float,
                     name: str = "model") -> tuple[RayDistances, float]:  # fmt: skip
    """:func:`ray_distances` and :meth:`RayDistances.cutoff_for` the sparsity ``target``, each flat
    part's secondary rays cast only where they can matter. A ray leaving a flat part never meets it
    again, and its next surface lies beyond the point (the secondary distance exceeds the primary),
    so a flat part's weight is nonzero exactly where its primary distance is below the cutoff: the
    cutoff follows from the curved parts' rays alone, and the flat parts' rays are then cast where
    their primary distance is below it, no farther than it (beyond it only the cutoff counts). The
    weights at the cutoff are those of all rays at full reach."""
    flat = np.array([part.flat_frame is not None for part in parts])
    # first the pairs within half the reach: where the cutoff lies below that, the bisection over
    # [0, reach] halves to it in its first step and takes the same steps on these distances
    distances = ray_distances(parts, points, reach, cast=~flat, within=0.5 * reach)
    if distances.nonzero_share(0.5 * reach) <= target:  # then all of them
        missing = np.isinf(distances.primary)
        distances = distances.with_pairs(parts, points, missing, np.full(len(points), -1), ~flat)
    alpha = distances.cutoff_for(target, name)
    if not flat.any():
        return distances, alpha
    clock = time.perf_counter()
    within = (distances.primary < alpha) & (distances.primary > 0.0) & flat[None, :]
    distances = distances.with_rays(parts, within, alpha)
    return replace(distances, seconds=distances.seconds + time.perf_counter() - clock), alpha
