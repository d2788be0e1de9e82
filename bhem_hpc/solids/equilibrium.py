"""Serial solves of one SEM solid by direct solvers (LAPACK's dense Cholesky where the system is
full, else scipy's sparse LU, :func:`solve_symmetric`): static equilibrium by projected
Newton with an energy line search, and the paper's linearly implicit Euler step (Table 1 times
one such step per frame).

The DOFs are interleaved control-point coordinates ``(3 n_q,)``; ``fixed`` is a boolean mask of
the same shape whose entries keep their values in ``q`` (prescribed control points). The
potential is the solid's energy minus ``forces @ q`` (dead loads: gravity, point forces).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from bhem_hpc.errors import UserError
from bhem_hpc.solids.sem import ShapeMatchingSolid

#: Newton iterations of a static solve.
MAX_ITERATIONS = 100
#: Step halvings of one line search.
MAX_HALVINGS = 40
#: Armijo's sufficient decrease.
ARMIJO = 1e-4


class EquilibriumError(UserError, RuntimeError):
    """A static solve of a solid did not converge."""


#: A symmetric system with at least this share of nonzeros, and at most :data:`DENSE_ROWS` rows, is
#: solved by LAPACK's dense Cholesky factorization: solids whose parts blend everywhere have full
#: stiffness matrices, on which a sparse LU only adds bookkeeping (1872 DoFs: 0.37 s against 0.1 s).
DENSE_SHARE = 0.25
DENSE_ROWS = 8000


def solve_symmetric(matrix: scipy.sparse.spmatrix, rhs: np.ndarray) -> np.ndarray:
    """``matrix^-1 rhs`` for a symmetric ``matrix (n, n)``: dense Cholesky where the matrix is full
    enough (:data:`DENSE_SHARE`) and positive definite, else scipy's sparse direct solver."""
    size = matrix.shape[0]
    if size <= DENSE_ROWS and matrix.nnz >= DENSE_SHARE * size**2:
        try:
            factor = scipy.linalg.cho_factor(matrix.toarray(), check_finite=False)
        except np.linalg.LinAlgError:  # semi-definite (a projected Hessian's null direction)
            pass
        else:
            return scipy.linalg.cho_solve(factor, rhs, check_finite=False)
    return scipy.sparse.linalg.spsolve(scipy.sparse.csc_matrix(matrix), rhs)


@dataclass(frozen=True)
class Equilibrium:
    """A converged static state: control points ``(n_q, 3)``, Newton iterations, final gradient norm."""

    q: np.ndarray
    iterations: int
    residual: float


#: Diagonal shift of the static Hessian, relative to its largest diagonal entry: SEM's kinematics
#: leave control-point motions that no quadrature point sees (coefficients of parts whose weights
#: vanish in the volume), and the shift keeps Newton's steps finite along them.
STATIC_SHIFT = 1e-9


def _free_system(solid: ShapeMatchingSolid, q: np.ndarray, free: np.ndarray, forces: np.ndarray):
    gradient = solid.gradient(q)[free] - forces[free]
    hessian = solid.hessian(q).tocsc()[free][:, free]
    shift = STATIC_SHIFT * float(hessian.diagonal().max())
    return gradient, (hessian + shift * scipy.sparse.identity(hessian.shape[0], format="csc")).tocsc()


def solve_static(
    solid: ShapeMatchingSolid,
    q: np.ndarray,
    fixed: np.ndarray,
    forces: np.ndarray | None = None,
    tolerance: float = 1e-8,
) -> Equilibrium:
    """Minimize ``energy(q) - forces @ q`` over the free DOFs from ``q (n_q, 3)``.

    Converged when the free gradient's norm is at most ``tolerance`` times the norm of the free
    forces plus the solid's stiffness scale (Young's modulus times the model's squared size).
    """
    q = np.asarray(q, dtype=float).reshape(-1).copy()
    free = ~np.asarray(fixed, dtype=bool).reshape(-1)
    forces = np.zeros_like(q) if forces is None else np.asarray(forces, dtype=float).reshape(-1)
    size = float(np.ptp(solid.reference, axis=0).max())
    scale = np.linalg.norm(forces[free]) + max(m.young for m in solid.materials) * size**2
    potential = solid.energy(q) - forces @ q
    if not np.isfinite(potential):
        raise EquilibriumError(f"{solid.name}: the starting state inverts the solid (det F <= 0 somewhere)")
    for iteration in range(MAX_ITERATIONS + 1):
        gradient, hessian = _free_system(solid, q, free, forces)
        norm = float(np.linalg.norm(gradient))
        if norm <= tolerance * scale:
            return Equilibrium(q.reshape(-1, 3), iteration, norm)
        if iteration == MAX_ITERATIONS:
            break
        step = -solve_symmetric(hessian, gradient)
        slope = float(gradient @ step)
        if not slope < 0.0:  # the projected Hessian is PSD; a null direction gives no descent
            step, slope = -gradient, -(norm**2)
        length = 1.0
        for _ in range(MAX_HALVINGS):
            trial = q.copy()
            trial[free] += length * step
            trial_potential = solid.energy(trial) - forces @ trial
            if trial_potential <= potential + ARMIJO * length * slope:
                break
            length *= 0.5
        else:
            raise EquilibriumError(
                f"{solid.name}: the line search found no decrease at Newton iteration {iteration} "
                f"(gradient norm {norm:.3g}); lower the load or refine the quadrature"
            )
        q, potential = trial, trial_potential
    raise EquilibriumError(
        f"{solid.name}: no equilibrium after {MAX_ITERATIONS} Newton iterations (gradient norm {norm:.3g}, "
        f"target {tolerance * scale:.3g})"
    )


def linearly_implicit_step(
    solid: ShapeMatchingSolid,
    q: np.ndarray,
    velocity: np.ndarray,
    dt: float,
    fixed: np.ndarray,
    forces: np.ndarray,
    mass: scipy.sparse.spmatrix | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One linearly implicit Euler step (Baraff-Witkin): ``(M + dt^2 K) dv = dt (f(q) - dt K v)``
    with ``f = forces - grad E``; fixed DOFs keep their values and zero velocity. Returns ``q`` and
    the velocity, both ``(n_q, 3)``."""
    q, velocity = np.asarray(q, dtype=float).reshape(-1), np.asarray(velocity, dtype=float).reshape(-1)
    free = ~np.asarray(fixed, dtype=bool).reshape(-1)
    mass = solid.mass_matrix() if mass is None else mass
    stiffness = solid.hessian(q)
    force = np.asarray(forces, dtype=float).reshape(-1) - solid.gradient(q)
    matrix = (mass + dt**2 * stiffness).tocsc()[free][:, free]
    rhs = dt * (force - dt * (stiffness @ velocity))[free]
    new_velocity = np.where(free, velocity, 0.0)
    new_velocity[free] += solve_symmetric(matrix, rhs)
    return (q + dt * new_velocity).reshape(-1, 3), new_velocity.reshape(-1, 3)
