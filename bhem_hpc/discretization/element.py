"""The C1 bicubic Hermite element on quadrilaterals as a custom Basix element.

DOFs per vertex, in this order, all taken with respect to the *reference* cell coordinates
(X, Y): value, d/dX, d/dY, d2/dXdY. The map is the identity: dolfinx never transforms these
DOFs, so the field is C1 only on a grid where every cell has the same Jacobian. Conversion to
and from parametric derivatives lives in :mod:`bhem_hpc.discretization`.
"""

from __future__ import annotations

import basix
import basix.ufl_wrapper
import numpy as np

# Local order of the four DOFs of one vertex and the Basix derivative slot of each.
VERTEX_DOF_DERIVATIVES = ((0, 0), (1, 0), (0, 1), (1, 1))
DOFS_PER_VERTEX = len(VERTEX_DOF_DERIVATIVES)


def create_hermite_element() -> basix.finite_element.FiniteElement:
    """The scalar bicubic Hermite (Bogner-Fox-Schmit) element: 16 DOFs, degree 3."""
    cell = basix.CellType.quadrilateral
    nderivs = basix.index(0, 2) + 1  # derivatives up to order 2 in 2-D: 6 slots
    vertices = basix.geometry(cell)
    points: list[list[np.ndarray]] = [
        [v.reshape(1, 2) for v in vertices],
        [np.zeros((0, 2)) for _ in range(4)],
        [np.zeros((0, 2))],
        [],
    ]
    matrices: list[list[np.ndarray]] = [
        [],
        [np.zeros((0, 1, 0, nderivs)) for _ in range(4)],
        [np.zeros((0, 1, 0, nderivs))],
        [],
    ]
    for _ in vertices:
        m = np.zeros((DOFS_PER_VERTEX, 1, 1, nderivs))
        for k, (dx, dy) in enumerate(VERTEX_DOF_DERIVATIVES):
            m[k, 0, 0, basix.index(dx, dy)] = 1.0
        matrices[0].append(m)
    # The polyset of degree 3 on a quadrilateral is Q3 (16 functions): take all of it.
    return basix.create_custom_element(cell, [], np.eye(16), points, matrices, 2, basix.MapType.identity, False, 3, 3)


def hermite_ufl_element(value_size: int = 3) -> basix.ufl_wrapper._BasixElementBase:
    """UFL element of the position field: ``value_size`` copies of the Hermite element."""
    scalar = basix.ufl_wrapper.BasixElement(create_hermite_element())
    if value_size == 1:
        return scalar
    return basix.ufl_wrapper.VectorElement(scalar, value_size)
