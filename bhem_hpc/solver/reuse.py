"""When to refactor: the Jacobian and its factorization kept across Newton iterations and solves.

A Newton iteration with a kept (lagged) factorization is a chord step: no Jacobian assembly and
no factorization, only a residual and two triangular solves. Near a converged state that changes
little per time step or load step (a mass-dominated step matrix, a small load increment) the
chord steps contract the residual almost as fast as Newton's; when they stop doing so the
Jacobian is assembled and factored again. No PETSc here: the driver asks :meth:`refactor_now`
before each Newton iteration and reports what happened.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

#: ``solver.factorization`` values: ``"reuse"`` keeps factorizations while they converge well,
#: ``"fresh"`` factors the Jacobian at every Newton iteration (full Newton).
FACTORIZATION_POLICIES = ("reuse", "fresh")
#: Whatever the last solves ended at, a solve is expected to reduce its residual by at least this
#: factor: one that a step test ended after a chord step or two says little about the next one.
LEAST_EXPECTED_REDUCTION = 1e-2


@dataclass
class FactorizationReuse:
    """Refactor policy of a Newton solver.

    A kept factorization is dropped (the next Newton iteration assembles and factors) when

    * a chord step did not reduce the residual norm, or the contraction of the last two
      (the geometric mean of ``|F_k| / |F_{k-1}|`` over the chord steps since the factorization,
      at most two) predicts more chord iterations to the solve's end than ``refactor_cost`` (a
      fresh Jacobian converges in a few Newton iterations from there). The end is the tolerance,
      or, where IPC's step test ends solves sooner (once a step moves no point by more than a
      velocity times dt), the smaller of the residual reductions at which it ended the last two
      (:meth:`ended_by_step_test`), but at least :data:`LEAST_EXPECTED_REDUCTION`. The driver
      reports those ends only with step-bounded contributions (IPC's barrier), whose iterations
      cost the most: on the cloth lying on the ball (``jobs/ball.toml``) chord steps then replace
      half the refactorizations; on the hanging cotton, with the step test and no barrier, the
      slower chord steps cost more Newton iterations than the refactorizations they save;
    * a solve has taken ``max_chord_iterations`` Newton iterations on it without converging;
    * at the start of a solve, when the last solve cost more than the average solve since the
      factorization was made, counting a refactorization as ``refactor_cost`` Newton iterations:
      the average cost per solve of the cycle would start to grow (a chord step slows down as
      the state drifts from the one factored; the policy balances that against refactoring);
    * the operator it was made from changed: the ``signature`` (time step, diagonal regularizer)
      differs from the one it was factored with;
    * a solve using it failed (:meth:`failed`): the driver retries once with a fresh one.

    Attributes:
        enabled: False: a fresh factorization at every Newton iteration.
        chord_within_solve: False: a kept factorization serves only the first iteration of a
            solve (static load steps: the solve then ends with Newton's quadratic steps, whose
            last one lands far inside the tolerance, as analysts' references expect).
        refactor_cost: the cost of assembling and factoring the Jacobian, in chord iterations
            (a residual and two triangular solves): see :func:`refactor_cost`.
        max_chord_iterations: chord iterations within one solve before refactoring.
        refactorizations: Jacobians assembled and factored while the policy ran.
        chord_iterations: Newton iterations that reused a factorization.
        retries: failed solves retried with a fresh factorization.
    """

    enabled: bool = True
    chord_within_solve: bool = True
    refactor_cost: float = 15.0
    max_chord_iterations: int = 30
    refactorizations: int = 0
    chord_iterations: int = 0
    retries: int = 0
    _valid: bool = field(default=False, repr=False)
    _signature: tuple = field(default=(), repr=False)
    _previous_norm: float = field(default=float("inf"), repr=False)
    _chord_in_solve: int = field(default=0, repr=False)
    _previous_ratio: float = field(default=0.0, repr=False)
    _cycle_cost: float = field(default=0.0, repr=False)  # since the factorization: refactor + iterations
    _cycle_solves: int = field(default=0, repr=False)
    _solve_cost: float = field(default=0.0, repr=False)  # the current solve's, since the cycle began
    _current_is_kept: bool = field(default=False, repr=False)
    _first_norm: float = field(default=float("inf"), repr=False)  # the current solve's first residual norm
    # |F_end| / |F_0| of the last two solves a step test ended, the latest first (0: none yet)
    _reductions: tuple[float, float] = field(default=(0.0, 0.0), repr=False)

    def __post_init__(self) -> None:
        if self.max_chord_iterations < 1:
            raise ValueError(f"max_chord_iterations must be >= 1, got {self.max_chord_iterations!r}")
        if not self.refactor_cost > 0:
            raise ValueError(f"refactor_cost must be > 0, got {self.refactor_cost!r}")

    def start_solve(self) -> None:
        """A nonlinear solve begins (its first residual norm is the reference)."""
        if self._valid and self._cycle_solves and self._solve_cost > self._cycle_cost / self._cycle_solves:
            self._valid = False  # the last solve cost more than the cycle's average
        self._previous_norm = float("inf")
        self._first_norm = float("inf")
        self._chord_in_solve = 0
        self._solve_cost = 0.0
        self._current_is_kept = False
        self._cycle_solves += 1

    def refactor_now(self, iteration: int, residual_norm: float, target_norm: float, signature: tuple) -> bool:
        """Whether Newton iteration ``iteration`` (0-based, within the solve) at residual norm
        ``residual_norm`` must assemble and factor the Jacobian, the solve converging at
        ``target_norm``; counts the decision."""
        slowed = False
        ratio = residual_norm / self._previous_norm if iteration > 0 else 0.0
        if iteration == 0:
            self._first_norm = residual_norm
        target_norm = self._expected_end(target_norm)
        if iteration > 0 and residual_norm > target_norm:
            # two contractions: Anderson-mixed chord steps contract unevenly from one to the next
            rate = math.sqrt(ratio * self._previous_ratio) if self._previous_ratio > 0 else ratio
            remaining = math.log(target_norm / residual_norm) / math.log(rate) if rate < 1.0 else math.inf
            slowed = ratio >= 1.0 or remaining > self.refactor_cost
        self._previous_norm = residual_norm
        self._previous_ratio = ratio
        fresh = (
            not self.enabled
            or (iteration > 0 and not self.chord_within_solve)
            or not self._valid
            or signature != self._signature
            or slowed
            or self._chord_in_solve >= self.max_chord_iterations
        )
        if fresh:
            self.refactored(signature)
        else:
            self.chord_iterations += 1
            self._chord_in_solve += 1
        self._solve_cost += 1.0
        self._cycle_cost += 1.0
        self._current_is_kept = not fresh
        return fresh

    def _expected_end(self, target_norm: float) -> float:
        """The residual norm at which the current solve is expected to end: ``target_norm``, or the
        reduction at which a step test ended the last solves (see the class)."""
        reached = [r for r in self._reductions if r > 0.0]
        if not reached or not math.isfinite(self._first_norm):
            return target_norm
        return max(target_norm, self._first_norm * min(min(reached), LEAST_EXPECTED_REDUCTION))

    def ended_by_step_test(self, final_norm: float) -> None:
        """A step test ended the current solve at the residual norm ``final_norm``: its reduction
        from the first norm is what the next solves expect to reach."""
        if math.isfinite(self._first_norm) and self._first_norm > 0.0 and math.isfinite(final_norm):
            self._reductions = (final_norm / self._first_norm, self._reductions[0])

    def refactored(self, signature: tuple) -> None:
        """The Jacobian was assembled and factored at the current iterate: a new cycle begins
        (the current solve's cost counts from here)."""
        self.refactorizations += 1
        self._valid, self._signature, self._chord_in_solve = True, signature, 0
        self._previous_ratio = 0.0  # the next contraction is the new factorization's first
        self._cycle_cost, self._cycle_solves, self._solve_cost = self.refactor_cost, 1, self.refactor_cost
        self._current_is_kept = False

    def on_kept_factorization(self) -> bool:
        """Whether the current Newton iteration's step came from a kept factorization."""
        return self._current_is_kept

    def used_chord_steps(self) -> bool:
        """Whether the current solve took a chord step (then a failure is worth a fresh retry)."""
        return self.enabled and self._chord_in_solve > 0

    @property
    def valid(self) -> bool:
        """Whether a kept factorization may serve the next Newton iteration."""
        return self._valid

    #: The keys of :meth:`state`.
    STATE_KEYS: ClassVar[tuple[str, ...]] = ("cycle_cost", "cycle_solves", "solve_cost")
    #: The keys of :meth:`learned`.
    LEARNED_KEYS: ClassVar[tuple[str, ...]] = ("reduction", "reduction_before")

    def state(self) -> dict[str, float]:
        """What the policy's next decisions on a kept factorization depend on, for a checkpoint (with
        the iterate it was made at, a run continued from it decides as an uninterrupted one)."""
        return dict(zip(self.STATE_KEYS, (self._cycle_cost, self._cycle_solves, self._solve_cost), strict=True))

    def learned(self) -> dict[str, float]:
        """What the policy learned from the solves (the reductions at which a step test ended them),
        for every checkpoint, a factorization kept or not (0: nothing learned)."""
        return dict(zip(self.LEARNED_KEYS, self._reductions, strict=True))

    def restore_learned(self, learned: dict[str, float]) -> None:
        """Continue from :meth:`learned` (a checkpoint without it: nothing learned)."""
        self._reductions = tuple(float(learned.get(key, 0.0)) for key in self.LEARNED_KEYS)

    def restore(self, state: dict[str, float], signature: tuple) -> None:
        """Continue from :meth:`state` with the factorization remade at ``signature``'s operator."""
        self._valid, self._signature = True, signature
        self._cycle_cost = float(state["cycle_cost"])
        self._cycle_solves = int(state["cycle_solves"])
        self._solve_cost = float(state["solve_cost"])

    def invalidate(self) -> None:
        """The kept factorization no longer belongs to the problem (e.g. the matrix was modified)."""
        self._valid = False
        self._current_is_kept = False

    def failed(self) -> None:
        """A solve that used chord steps failed: the next attempt starts from a fresh factorization."""
        self.retries += 1
        self._valid = False


#: A Newton iteration's cost with a step-bounded contribution (IPC's barrier: its energy at every
#: line-search trial and its gradient, the continuous collision detection of the step bound and of
#: the step test), in iterations without one: a chord iteration of the cloth lying on the ball
#: (``jobs/ball.toml``) takes about 0.034 s by IPC, 0.014 s by impulses (their collision
#: detection, once per step, apart).
BOUNDED_ITERATION_COST = 2.5


def refactor_cost(dofs: int, step_bounded: bool = False) -> float:
    """A refactorization's cost in chord iterations for a shell of ``dofs`` unknowns; with
    ``step_bounded`` contributions each iteration costs :data:`BOUNDED_ITERATION_COST` times more,
    and a refactorization as many fewer of them.

    Factoring a 2-D shell's matrix takes ~dofs^1.5 flops (nested-dissection-like orderings),
    its triangular solves and the residual ~dofs, so the ratio grows as sqrt(dofs). Calibrated
    on the 30x30-patch Hermite cloth (11,532 DoFs): a Jacobian assembly and an LDL^T cost about
    15 residual-and-solve iterations there. A count, not a timing: every rank decides alike.
    """
    cost = max(4.0, 15.0 * (dofs / 11532) ** 0.5)
    return cost / BOUNDED_ITERATION_COST if step_bounded else cost
