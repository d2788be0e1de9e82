"""Virtual work of a dead line load on boundary edges (paper eq. 10, second right-hand term)."""

from __future__ import annotations

import ufl

from bhem_hpc.forms.kinematics import metric


def line_load_work(x_rest, traction, test, ds: ufl.Measure) -> ufl.Form:
    """``int_Gamma t . v dGamma_rest``: ``traction`` is force per rest length (a UFL 3-vector).

    ``ds`` is a facet measure of the parameter mesh (restricted by the caller to the loaded
    edges); the rest arc length is ``sqrt(t_p . a_rest t_p) dxi`` with ``t_p`` the unit
    tangent of the edge in parameter space.
    """
    n = ufl.FacetNormal(x_rest.ufl_domain())
    tangent = ufl.as_vector([-n[1], n[0]])
    length_density = ufl.sqrt(ufl.dot(tangent, metric(x_rest) * tangent))
    return ufl.dot(traction, test) * length_density * ds
