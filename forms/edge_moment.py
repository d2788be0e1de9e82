"""Virtual work of a distributed moment on boundary edges, conjugate to the rotation of the edge."""

from __future__ import annotations

import ufl

from bhem_hpc.forms.kinematics import metric, unit_normal


def edge_moment_work(x, x_rest, moment, test, ds: ufl.Measure) -> ufl.Form:
    """``int_Gamma m t . (dn[v] x n) dGamma_rest``: ``moment`` ``m`` per rest length about the
    edge's current unit tangent ``t`` (counterclockwise around the parameter domain).

    The rotation of the edge about ``t`` under a variation ``v`` is ``t . (n x dn[v])`` (``n`` the
    unit normal); ``m > 0`` turns the edge's outward direction towards ``+n``, i.e. curls it up.
    The axis follows the edge, so the load has no potential in general (it has one when the edge
    keeps its direction, as in a strip rolled up about its end).
    """
    outward = ufl.FacetNormal(x_rest.ufl_domain())
    along = ufl.as_vector([-outward[1], outward[0]])  # counterclockwise tangent in parameter space
    tangent = x.dx(0) * along[0] + x.dx(1) * along[1]
    tangent = tangent / ufl.sqrt(ufl.dot(tangent, tangent))
    n = unit_normal(x)
    rotation = ufl.dot(tangent, ufl.cross(ufl.derivative(n, x, test), n))
    length_density = ufl.sqrt(ufl.dot(along, metric(x_rest) * along))
    return moment * rotation * length_density * ds
