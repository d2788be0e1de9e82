"""The count of nonzero blending weights at a cutoff, compiled: the cutoff's bisection counts them
forty times over every point-part pair, where numpy's temporaries cost more than the arithmetic."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def nonzero_weights(primary: np.ndarray, total: np.ndarray, same_part: np.ndarray, alpha: float) -> int:
    """The nonzero entries of the blending weights ``(Q, parts)`` at the cutoff ``alpha`` from the
    primary and total distances and same-part flags ``(Q, parts)``: the positive distance weights
    ``max(1 - primary / min(total, alpha), 0)`` (1 on the same part), evaluated as
    :meth:`bhem_hpc.solids.blending.RayDistances.theta` evaluates them, and one for each point
    with none (its nearest part takes it)."""
    count = 0
    for q in range(primary.shape[0]):
        positive = 0
        for i in range(primary.shape[1]):
            if same_part[q, i] or 1.0 - primary[q, i] / min(total[q, i], alpha) > 0.0:
                positive += 1
        count += max(positive, 1)
    return count
