"""Rational Bezier extraction of NURBS parts, compiled: the nets of
:attr:`bhem_hpc.geometry.nurbs.NurbsSurface.bezier_patches` (the same extraction operators of the
parts' knot directions, applied span by span in one compiled loop instead of a dozen numpy calls
per part), grouped by degree as :func:`bhem_hpc.geometry.nurbs.bezier_nets_by_degree` groups them.
A solid's quadrature extracts every part afresh: the numpy calls' overhead, about 25 us a part,
was most of a many-part model's ray casting."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit

from bhem_hpc.geometry.nurbs import NurbsSurface


@njit(cache=True, error_model="numpy")
def _extract(control, weights, spans_u, spans_v, extraction_u, extraction_v, nets, first) -> None:  # noqa: PLR0913
    """The Bezier nets of one part into ``nets[first:first + S_u S_v]`` ``(p + 1, q + 1, 4)``, in
    order ``span_u * S_v + span_v``: ``net[k, l] = sum_ij E_u[a, i, k] E_v[b, j, l] H[i, j]`` over
    the homogeneous points ``H = (w x, w y, w z, w)`` of the span pair ``(a, b)`` (control ``(n, m,
    3)``, weights ``(n, m)``, knot indices ``spans_u (S_u,)``, ``spans_v (S_v,)`` of the spans,
    extraction operators ``(S_u, p + 1, p + 1)``, ``(S_v, q + 1, q + 1)``)."""
    p, q = extraction_u.shape[1] - 1, extraction_v.shape[1] - 1
    along_v = np.empty((p + 1, q + 1, 4))  # the span pair's points summed along v
    for a in range(len(spans_u)):
        row = spans_u[a] - p
        for b in range(len(spans_v)):
            column = spans_v[b] - q
            for i in range(p + 1):
                for l in range(q + 1):  # noqa: E741
                    x = y = z = w = 0.0
                    for j in range(q + 1):
                        e = extraction_v[b, j, l] * weights[row + i, column + j]
                        x += e * control[row + i, column + j, 0]
                        y += e * control[row + i, column + j, 1]
                        z += e * control[row + i, column + j, 2]
                        w += e
                    along_v[i, l, 0], along_v[i, l, 1], along_v[i, l, 2], along_v[i, l, 3] = x, y, z, w
            net = nets[first + a * len(spans_v) + b]
            for k in range(p + 1):
                for l in range(q + 1):  # noqa: E741
                    for c in range(4):
                        total = 0.0
                        for i in range(p + 1):
                            total += extraction_u[a, i, k] * along_v[i, l, c]
                        net[k, l, c] = total


def bezier_nets_by_degree(parts: Sequence[NurbsSurface]) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`bhem_hpc.geometry.nurbs.bezier_nets_by_degree`, compiled: the parts' nets in one array
    per degree, with the part of each patch: ``[(nets (P, p + 1, q + 1, 4), part (P,)), ...]``."""
    by_degree: dict[tuple[int, int], list[int]] = {}
    for k, part in enumerate(parts):
        by_degree.setdefault(part.degrees, []).append(k)
    groups = []
    for (p, q), members in by_degree.items():
        counts = [len(parts[k].u.spans) * len(parts[k].v.spans) for k in members]
        nets = np.empty((sum(counts), p + 1, q + 1, 4))
        first = 0
        for k, count in zip(members, counts, strict=True):
            u, v = parts[k].u, parts[k].v
            _extract(parts[k].control, parts[k].weights, u.spans, v.spans, u.extraction, v.extraction, nets, first)
            first += count
        groups.append((nets, np.repeat(np.asarray(members), counts)))
    return groups
