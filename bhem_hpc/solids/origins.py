"""Deformation origins by an integer min-cost network flow (SEM paper §6.2), numpy and scipy only.

Quadrature points are grouped by the set of parts with nonzero blending weight at them; each
group is a candidate origin. The flow runs source -> candidate -> part -> sink: a candidate has
an edge to every part of its set, costing the sum of that part's blending weights over the
group's points (heavily connected candidates cost more); every part passes one unit to the sink.
The parts that draw their unit through one candidate share one origin (placed by
:func:`~bhem_hpc.solids.shape_matching.shape_matching` at the centroid of their samples). The
integer program (eq. 10) goes to HiGHS through :func:`scipy.optimize.milp`.
"""

from __future__ import annotations

import numpy as np
import scipy.optimize
import scipy.sparse

from bhem_hpc.geometry.surface import SurfaceError


def candidate_groups(weights: scipy.sparse.spmatrix) -> tuple[np.ndarray, np.ndarray]:
    """Groups of points by their set of parts: ``(patterns (G, parts) bool, group of each point (Q,))``."""
    pattern = scipy.sparse.csr_matrix(weights).toarray() > 0.0
    patterns, group = np.unique(pattern, axis=0, return_inverse=True)
    return patterns, group.ravel()


def assign_candidates(weights: scipy.sparse.spmatrix, name: str = "model") -> tuple[np.ndarray, np.ndarray]:
    """The min-cost flow: the candidate group ``(parts,)`` each part draws its unit through, and the
    costs ``(G, parts)`` of the candidate -> part edges (inf: no edge).

    Args:
        weights: blending weights ``(Q, parts)`` at the quadrature points.
    """
    weights = scipy.sparse.csr_matrix(weights)
    parts = weights.shape[1]
    patterns, group = candidate_groups(weights)
    # cost of candidate g -> part i: the part's weights summed over the group's points
    cost = np.asarray(
        scipy.sparse.csr_matrix(
            (np.ones(len(group)), (group, np.arange(len(group)))), shape=(len(patterns), len(group))
        )
        @ weights.toarray()
    )
    edges = np.argwhere(patterns)  # (E, 2): candidate, part
    unreached = np.setdiff1d(np.arange(parts), edges[:, 1])
    if len(unreached):
        raise SurfaceError(f"{name}: part {int(unreached[0])} has no quadrature point with a nonzero blending weight")
    count = len(edges)
    # variables: one flow per candidate -> part edge (source and sink flows follow from them)
    # each part receives exactly one unit; flows are 0 or 1
    receive = scipy.sparse.csr_matrix((np.ones(count), (edges[:, 1], np.arange(count))), shape=(parts, count))
    result = scipy.optimize.milp(
        c=cost[edges[:, 0], edges[:, 1]],
        constraints=scipy.optimize.LinearConstraint(receive, np.ones(parts), np.ones(parts)),
        integrality=np.ones(count),
        bounds=scipy.optimize.Bounds(np.zeros(count), np.ones(count)),
    )
    if not result.success:
        raise SurfaceError(f"{name}: the deformation-origin flow has no solution ({result.message})")
    chosen = edges[np.round(result.x).astype(bool)]
    candidate_of_part = np.empty(parts, dtype=int)
    candidate_of_part[chosen[:, 1]] = chosen[:, 0]
    return candidate_of_part, np.where(patterns, cost, np.inf)


def deformation_origins(weights: scipy.sparse.spmatrix, name: str = "model") -> np.ndarray:
    """The origin index ``(parts,)`` of each part (:func:`assign_candidates`), origins numbered
    ``0 ..`` in order of their first part."""
    candidate_of_part, _ = assign_candidates(weights, name)
    _, first, origin = np.unique(candidate_of_part, return_index=True, return_inverse=True)
    # number origins in order of their first part
    rank = np.empty(len(first), dtype=int)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[origin.ravel()]
