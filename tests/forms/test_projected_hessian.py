"""The projected (positive semi-definite) Hessian: the 2 x 2 positive part, positivity on compressed
states, and exactness where the membrane is in tension."""

from __future__ import annotations

import numpy as np
import ufl
from helpers import jacobian_dense

from bhem_hpc.forms.kinematics import positive_part_2x2
from bhem_hpc.geometry import surface as S
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import Loads, ShellModel

#: cotton (the B-spline cloth paper's §5): a stiff membrane under a tiny bending stiffness
COTTON = Material(young=2e6, poisson=0.243, thickness=3.18e-4, density=472.6)


def test_positive_part_clamps_the_eigenvalues_of_symmetric_2x2_matrices(rng):
    for _ in range(20):
        a = rng.normal(size=(2, 2)) * 10 ** rng.uniform(-6, 6)
        a = a + a.T
        values, vectors = np.linalg.eigh(a)
        expected = (vectors * np.maximum(values, 0)) @ vectors.T
        part = positive_part_2x2(ufl.as_matrix(a.tolist()))
        got = np.array([[part[i, j](()) for j in range(2)] for i in range(2)])
        np.testing.assert_allclose(got, expected, atol=1e-13 * np.abs(a).max())
    zero = positive_part_2x2(ufl.as_matrix([[0.0, 0.0], [0.0, 0.0]]))
    assert [[zero[i, j](()) for j in range(2)] for i in range(2)] == [[0.0, 0.0], [0.0, 0.0]]


def _compressed(rest: S.HermiteSurface, rng) -> S.HermiteSurface:
    """The rest sheet squeezed by 10 % along xi1 and roughened: compressed and wrinkled."""
    nodal = rest.nodal.copy()
    nodal[..., 0, 0] *= 0.9
    nodal[..., 1, :] *= 0.9  # d/dxi1 scales with the squeeze
    return S.HermiteSurface(rest.grid, nodal + 1e-3 * rng.normal(size=nodal.shape))


def test_projected_hessian_of_a_compressed_cotton_sheet_is_positive_semidefinite(comm, rng):
    rest = S.flat_rectangle(0.2, 0.2, 3, 3)
    state = _compressed(rest, rng)
    dynamics_free = {"loads": Loads(gravity=(0.0, -9.81, 0.0)), "comm": comm, "initial": state}
    spectra = {}
    for kind in ("exact", "pseudo", "projected"):
        hessian = jacobian_dense(ShellModel(rest, COTTON, hessian=kind, **dynamics_free))
        spectra[kind] = np.linalg.eigvalsh(0.5 * (hessian + hessian.T))
    scale = spectra["exact"].max()
    assert spectra["exact"].min() < -1e-4 * scale  # compression makes the exact Hessian indefinite
    assert spectra["pseudo"].min() < -1e-4 * scale  # dropping bending's second derivative does not help
    assert spectra["projected"].min() > -1e-12 * scale


def test_projected_hessian_is_the_pseudo_hessian_where_the_membrane_is_stretched(comm, rng):
    """In tension (the stress resultant positive definite at every quadrature point) nothing is
    clamped: the membrane's Hessian is exact and bending's is the pseudo Hessian."""
    rest = S.flat_rectangle(0.2, 0.2, 3, 3)
    nodal = rest.nodal.copy()
    nodal[..., 0, :2] *= 1.05
    nodal[..., 1:3, :2] *= 1.05
    state = S.HermiteSurface(rest.grid, nodal + 1e-5 * rng.normal(size=nodal.shape))
    pseudo = jacobian_dense(ShellModel(rest, COTTON, hessian="pseudo", comm=comm, initial=state))
    projected = jacobian_dense(ShellModel(rest, COTTON, hessian="projected", comm=comm, initial=state))
    np.testing.assert_allclose(projected, pseudo, atol=1e-11 * np.abs(pseudo).max())
