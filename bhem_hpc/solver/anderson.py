"""Anderson acceleration of chord steps (Walker & Ni, SIAM J. Numer. Anal. 49, 2011); no PETSc here.

A chord step on a kept factorization ``J0`` is the fixed-point iteration
``x_{k+1} = x_k - s_k`` with ``s_k = J0^{-1} F(x_k)``. It contracts the residual linearly, at the
rate of the slowest mode of ``I - J0^{-1} J(x)``; once the state has drifted from the factored one
a few such modes dominate and the rate stays far from Newton's for many iterations. Anderson mixing
(type II, mixing parameter 1) combines the last ``depth`` steps so that the combination of their
chord steps is smallest in the least-squares sense,

    gamma = argmin_g || s_k - sum_i g_i (s_k - s_i) ||_2,
    x_{k+1} = x_k - s_k - sum_i gamma_i ((x_k - x_i) - (s_k - s_i)),

which removes those modes as a Krylov method would, using only vectors the chord steps computed
anyway (no extra residual, no extra triangular solve). On a linear problem it is equivalent to
GMRES on ``J0^{-1} J`` (Walker & Ni, section 2).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

#: Chord steps combined by Anderson mixing in problems with a potential, whose energy line search
#: applies it (option ``chord_anderson_depth`` under the solver's prefix; 0: plain chord steps);
#: of 3, 5 and 8, 5 took the fewest Newton iterations on the ball scene in contact.
CHORD_ANDERSON_DEPTH = 5
#: Relative Tikhonov term of the least-squares problem's normal equations (Gram matrix): steps
#: that have become nearly parallel get small, not huge, coefficients.
GRAM_REGULARIZATION = 1e-12


def anderson_depth(value: str, prefix: str) -> int:
    """The depth option's ``value`` under a solver's ``prefix`` (the default: :data:`CHORD_ANDERSON_DEPTH`).

    Raises:
        ValueError: not an integer >= 0 (naming the option and the value).
    """
    try:
        depth = int(value)
    except ValueError:
        depth = -1
    if depth < 0:
        raise ValueError(f"option {prefix}chord_anderson_depth must be an integer >= 0, got {value!r}")
    return depth


def _no_reduction(local: np.ndarray) -> np.ndarray:
    return local


@dataclass
class AndersonMixing:
    """Anderson mixing of the chord steps taken with one kept factorization.

    Attributes:
        depth: how many earlier steps are combined (0: no mixing, plain chord steps).
        reduce: sums a small array over the ranks that hold parts of the vectors (an MPI
            allreduce; the default suits one process). Every rank gets the same coefficients.
    """

    depth: int = 5
    reduce: Callable[[np.ndarray], np.ndarray] = _no_reduction
    _iterates: list[np.ndarray] = field(default_factory=list, repr=False)
    _steps: list[np.ndarray] = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        if isinstance(self.depth, bool) or not isinstance(self.depth, int) or self.depth < 0:
            raise ValueError(f"Anderson depth must be an integer >= 0, got {self.depth!r}")

    def reset(self) -> None:
        """Forget the history: the factorization (the fixed-point map) or the problem changed."""
        self._iterates.clear()
        self._steps.clear()

    def mixed_step(self, iterate: np.ndarray, step: np.ndarray) -> np.ndarray | None:
        """The mixed step at ``iterate`` for the chord step ``step`` (next iterate: ``iterate - step``).

        Args:
            iterate: this process's part of ``x_k``, shape ``(n,)``.
            step: this process's part of ``s_k = J0^{-1} F(x_k)``, shape ``(n,)``.

        Returns:
            This process's part of the mixed step, shape ``(n,)``, or None when there is no
            history yet or the least-squares problem has no finite solution. The pair is recorded
            for the next call either way.
        """
        mixed = None
        if self.depth and self._iterates:
            d_iterates = np.array([iterate - earlier for earlier in self._iterates])  # (m, n)
            d_steps = np.array([step - earlier for earlier in self._steps])  # (m, n)
            m = len(d_steps)
            local = np.concatenate([(d_steps @ d_steps.T).ravel(), d_steps @ step])
            summed = self.reduce(local)
            gram, right = summed[: m * m].reshape(m, m), summed[m * m :]
            scale = np.trace(gram) / m
            if np.isfinite(scale) and scale > 0:
                gamma = np.linalg.solve(gram + GRAM_REGULARIZATION * scale * np.eye(m), right)
                if np.all(np.isfinite(gamma)):
                    mixed = step + gamma @ (d_iterates - d_steps)
        self._iterates.append(iterate.copy())
        self._steps.append(step.copy())
        if len(self._iterates) > self.depth:
            del self._iterates[0], self._steps[0]
        return mixed
