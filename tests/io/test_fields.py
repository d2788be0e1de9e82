"""Output fields' small-matrix algebra (numpy only)."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.io.fields import inverse_2x2

pytestmark = pytest.mark.rank_free


def test_the_closed_form_2x2_inverse_is_lapacks(rng):
    """On 2000 seeded metrics (symmetric positive definite, condition numbers up to about 1e4) the
    adjugate inverse agrees with numpy's LAPACK inverse to 1e-10 relative, and undoes each matrix."""
    factors = rng.normal(size=(2000, 2, 2))
    metrics = factors @ factors.transpose(0, 2, 1) + 1e-4 * np.eye(2)
    inverse = inverse_2x2(metrics)
    np.testing.assert_allclose(inverse, np.linalg.inv(metrics), rtol=1e-10, atol=1e-10 * np.abs(inverse).max())
    np.testing.assert_allclose(inverse @ metrics, np.broadcast_to(np.eye(2), metrics.shape), atol=1e-8)
