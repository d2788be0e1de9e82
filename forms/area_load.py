"""Potential of a dead area load: force per unit rest area, fixed in direction."""

from __future__ import annotations

import ufl

from bhem_hpc.forms.kinematics import area_density


def area_load_potential(x, x_rest, load, dx: ufl.Measure) -> ufl.Form:
    """``-int q . x dOmega_rest``; ``load`` ``q`` is a UFL 3-vector expression (force per rest area,
    which may vary over the parameters)."""
    return -ufl.dot(load, x) * area_density(x_rest) * dx
