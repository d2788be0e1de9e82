"""The compiled count of nonzero blending weights against the weights it counts."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.compiled.blend_counts import nonzero_weights
from bhem_hpc.solids.blending import RayDistances

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def test_nonzero_weights_counts_the_weights_matrix_entries(rng):
    """Seeded random distances with the cases the weights treat apart: points on a part (0), pairs
    not computed (inf), rays that met nothing (inf), the same part, and points no part reaches."""
    shape = (400, 7)
    primary = rng.uniform(0.0, 1.0, shape)
    primary[rng.random(shape) < 0.1] = 0.0
    primary[rng.random(shape) < 0.2] = np.inf
    total = primary + rng.uniform(0.0, 1.0, shape)
    total[rng.random(shape) < 0.3] = np.inf
    same = rng.random(shape) < 0.05
    primary[:20] = np.inf  # far from every part
    primary[:20, 0] = 2.0
    distances = RayDistances(primary, total, same, np.zeros((*shape, 3)), np.zeros((*shape, 3)), 1.0, 0.0)
    for alpha in (1e-3, 0.1, 0.37, 0.8, 1.0):
        expected = distances.weights(alpha).nnz
        assert nonzero_weights(primary, total, same, alpha) == expected
        assert distances.nonzero_share(alpha) == expected / primary.size
