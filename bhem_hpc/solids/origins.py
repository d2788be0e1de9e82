"""Deformation origins by an integer min-cost network flow (SEM paper §6.2), numpy and scipy only.

Quadrature points are grouped by the set of parts with nonzero blending weight at them; each
group is a candidate origin. The flow runs source -> candidate -> part -> sink: a candidate has
an edge to every part of its set, costing the sum of that part's blending weights over the
group's points (heavily connected candidates cost more); every part passes one unit to the sink.
The parts that draw their unit through one candidate share one origin (placed by
:func:`~bhem_hpc.solids.shape_matching.shape_matching` at the centroid of their samples).

The integer program (eq. 10) is solved exactly without an LP solver: the source's edges have no
capacity and no cost, and the parts' edges to the sink capacity 1, so successive shortest paths
send each part's unit along its cheapest candidate edge, and no later path can reroute an
earlier one more cheaply (the paths share only the source). HiGHS (:func:`scipy.optimize.milp`)
found the same optimum in 2-5 ms a model, most of it the solver's setup; the tests check the two
against each other.

Symmetric models tie: a beam's four side faces each see several candidates of the same cost.
Among the optimal flows :func:`assign_candidates` takes one through few candidates (the one
cheapest for the most parts not yet assigned, first), so that tied parts share origins where
they can. On the twisted beam (756 DoFs, 360 degrees in steps of 30) this gave 12 origins, 153
Newton iterations and the midspan at 180.5 degrees, where the lowest candidate index gave 19,
330 and 173.7, and HiGHS's choice 17, 291 and 181.7.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

from bhem_hpc.geometry.surface import SurfaceError

#: Relative difference under which two candidates' costs for a part count as a tie.
TIE_TOLERANCE = 1e-9


def candidate_groups(weights: scipy.sparse.spmatrix) -> tuple[np.ndarray, np.ndarray]:
    """Groups of points by their set of parts: ``(patterns (G, parts) bool, group of each point (Q,))``."""
    pattern = scipy.sparse.csr_matrix(weights).toarray() > 0.0
    # one byte string per point (np.unique over rows sorts a structured view: 3 ms for 1328 points);
    # the bits' order keeps the rows' lexicographic order
    packed = np.ascontiguousarray(np.packbits(pattern, axis=1))
    keys = packed.view(np.dtype((np.void, packed.shape[1]))).ravel()
    _, first, group = np.unique(keys, return_index=True, return_inverse=True)
    return pattern[first], group.ravel()


def assign_candidates(weights: scipy.sparse.spmatrix, name: str = "model") -> tuple[np.ndarray, np.ndarray]:
    """The min-cost flow: the candidate group ``(parts,)`` each part draws its unit through, and the
    costs ``(G, parts)`` of the candidate -> part edges (inf: no edge).

    Args:
        weights: blending weights ``(Q, parts)`` at the quadrature points.
    """
    weights = scipy.sparse.csr_matrix(weights)
    patterns, group = candidate_groups(weights)
    # cost of candidate g -> part i: the part's weights summed over the group's points
    cost = np.asarray(
        scipy.sparse.csr_matrix(
            (np.ones(len(group)), (group, np.arange(len(group)))), shape=(len(patterns), len(group))
        )
        @ weights.toarray()
    )
    unreached = np.flatnonzero(~patterns.any(axis=0))
    if len(unreached):
        raise SurfaceError(f"{name}: part {int(unreached[0])} has no quadrature point with a nonzero blending weight")
    edge_cost = np.where(patterns, cost, np.inf)
    # each part's unit along one of its cheapest edges (the module docstring says why that is the
    # optimum, and how ties are broken); costs summed in another order differ by round-off
    cheapest = edge_cost.min(axis=0)
    tied = patterns & (edge_cost <= cheapest + TIE_TOLERANCE * np.abs(cheapest))
    candidate_of_part = np.full(len(cheapest), -1)
    while np.any(candidate_of_part < 0):  # each round assigns at least one part
        open_edges = tied & (candidate_of_part < 0)[None, :]
        chosen = int(np.argmax(open_edges.sum(axis=1)))
        candidate_of_part[open_edges[chosen]] = chosen
    return candidate_of_part, edge_cost


def deformation_origins(weights: scipy.sparse.spmatrix, name: str = "model") -> np.ndarray:
    """The origin index ``(parts,)`` of each part (:func:`assign_candidates`), origins numbered
    ``0 ..`` in order of their first part."""
    candidate_of_part, _ = assign_candidates(weights, name)
    _, first, origin = np.unique(candidate_of_part, return_index=True, return_inverse=True)
    # number origins in order of their first part
    rank = np.empty(len(first), dtype=int)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[origin.ravel()]
