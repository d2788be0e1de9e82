"""The Hessian kinds a model's Jacobian can be built with (importable without dolfinx).

- ``"exact"``: the UFL derivative of the residual; indefinite wherever a membrane is compressed or
  a shell buckles, which is what statics and path following read their stability from.
- ``"pseudo"``: the BHEM paper's: bending drops the second derivative of its curvature strain.
- ``"projected"``: positive semi-definite for every term (bending as ``"pseudo"``, the membrane's
  geometric stiffness from the tensile part of its stress only), so that every Newton step of an
  incremental potential goes downhill.
- ``"adaptive"``, the default for time steps: a ladder of three. Each time step starts with the
  exact Hessian, which converges quadratically wherever inertia keeps it positive definite (stiff
  shells: the mandrel job's can 6.7 Newton iterations and 0.19 s per step, against 13.3 and 1.4 s
  with ``"projected"``). Where its LDL^T shows negative pivots, the step goes on with the
  membrane's compressive stress dropped only from its stiffness out of the plane (where it makes
  cloth wrinkle) and kept in the plane; where that one still has negative pivots (in-plane
  compression of order one), the iteration is recomputed with the projected one. A step that left
  the exact Hessian is followed by steps that start one rung lower, more of them each time it is
  left again (:class:`HessianLadder`: compressed cloth stays compressed; hanging cotton, 20 steps:
  20 factorizations, 28 where every step tries the exact Hessian first, 14 from the rung below).
  Descent steps as ``"projected"``, in far fewer Newton iterations on compressed cloth (cotton
  hanging from moving corners, 25 x 25 Hermite patches, the sheet in its plane: 7.6 per step
  against 32 for ``"projected"``, whose linear convergence when the corners stop needed dt
  halvings). Where wrinkles grow out of the plane, both still converge linearly. The iterative
  linear path, whose Krylov solves tell no inertia, takes ``"projected"`` instead.
- ``"trust_region"``: time steps minimize the incremental potential by a Newton trust region whose
  quadratic model has the exact Hessian, its conjugate gradients preconditioned by the projected
  one (:mod:`bhem_hpc.solver.energy_trust_region`); steps it cannot take go on as ``"projected"``.
  Where cotton is compressed at once it converges without recovery where line-search Newton halves
  dt (25 x 25 Hermite patches, first 10 steps, against ``"adaptive"``: the shear job 1.18 s/step and
  21.5 iterations against 4.31 s/step, 39.6 and 10 recoveries; the locking test 0.40 s/step, 8.4
  against 3.76, 19.0 and 5 dt halvings); where ``"adaptive"`` converges, its chord steps on a kept
  factorization are cheaper (hanging 0.27 against 0.10 s/step). The drape's first 20 steps: 0.67
  s/step, 10.5 iterations, no recovery against 1.05, 22.3 and 1 dt halving. The default for the
  cotton drape, shear and locking jobs; with the direct linear solver only.
"""

from __future__ import annotations

from typing import Literal

HessianKind = Literal["exact", "pseudo", "projected", "adaptive", "trust_region"]
HESSIAN_KINDS: tuple[str, ...] = ("exact", "pseudo", "projected", "adaptive", "trust_region")
#: The Jacobians a composed kind is made of, the one Newton iterates with first.
COMPOSED_HESSIANS: dict[str, tuple[str, ...]] = {
    "adaptive": ("exact", "out_of_plane", "projected"),
    "trust_region": ("projected", "exact"),
}


#: The most time steps the adaptive ladder starts one rung lower before it tries the exact Hessian again.
MAX_EXACT_WAIT = 16


class HessianLadder:
    """Where each time step of the adaptive Hessian starts its ladder: at the exact Hessian, unless a
    step that started there left it; then the next steps start at the one projected out of the plane,
    one step after the first such step, twice as many after each further one in a row (at most
    :data:`MAX_EXACT_WAIT`), none once a step ends at the exact Hessian again."""

    def __init__(self):
        self._started_at = "exact"
        self._wait = 0  # steps left that start one rung lower
        self._backoff = 1  # the wait after the next step that leaves the exact Hessian

    def start(self, ended_at: str) -> str:
        """The kind the next step starts with, given the kind the last one ended with."""
        if self._started_at == "exact":
            if ended_at == "exact":
                self._backoff = 1
            else:
                self._wait, self._backoff = self._backoff, min(2 * self._backoff, MAX_EXACT_WAIT)
        self._started_at = "exact" if self._wait == 0 else "out_of_plane"
        self._wait = max(self._wait - 1, 0)
        return self._started_at
