"""Virtual work of a follower pressure ``p n`` on the deformed surface (paper §4.3)."""

from __future__ import annotations

import ufl

from bhem_hpc.forms.kinematics import area_normal


def pressure_work(x, pressure, test, dx: ufl.Measure) -> ufl.Form:
    """``int p n . v dOmega = int p (a1 x a2) . v dxi``: a rank-1 form.

    A follower load has no potential on an open surface; its Jacobian is not symmetric in
    general, so a problem with pressure factorizes with LU.
    """
    return pressure * ufl.dot(area_normal(x), test) * dx
