"""The refactor policy and the linear solver choice: pure decisions, no PETSc."""

from __future__ import annotations

import math

import pytest

from bhem_hpc.solver.linear import (
    ITERATIVE_MIN_DOFS,
    LinearSolverError,
    choose_linear_solver,
    direct_factor_bytes,
    mass_dominance,
)
from bhem_hpc.solver.reuse import FactorizationReuse, refactor_cost

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank

SIGNATURE = (0.002, 0.0)


def solve(policy: FactorizationReuse, norms: list[float], target: float = 1e-9) -> list[bool]:
    """The policy's decisions over one solve whose residual norms are ``norms``."""
    policy.start_solve()
    return [policy.refactor_now(k, norm, target, SIGNATURE) for k, norm in enumerate(norms)]


def test_the_first_iteration_factors_and_fast_chord_steps_keep_the_factorization():
    policy = FactorizationReuse(refactor_cost=15.0)
    assert solve(policy, [1.0, 1e-2, 1e-4, 1e-6, 1e-8]) == [True, False, False, False, False]
    assert solve(policy, [1.0, 1e-2, 1e-4, 1e-6, 1e-8]) == [False] * 5
    assert (policy.refactorizations, policy.chord_iterations) == (1, 9)


def test_a_residual_that_grows_or_contracts_too_slowly_refactors():
    policy = FactorizationReuse(refactor_cost=15.0)
    solve(policy, [1.0, 1e-3])
    # |F| grew: refactor at once
    assert solve(policy, [1.0, 2.0]) == [False, True]
    # ratio 0.5: log(1e-9 / 0.5) / log(0.5) = 29 more chord steps > 15: refactor
    assert solve(policy, [1.0, 0.5]) == [False, True]
    # ratio 0.1 from 1e-1: 8 more steps < 15: keep
    assert solve(policy, [1.0, 0.1]) == [False, False]
    # converged norms never trigger a refactorization
    assert solve(policy, [1.0, 1e-10], target=1e-9) == [False, False]


def test_the_contraction_is_judged_over_the_last_two_chord_steps():
    policy = FactorizationReuse(refactor_cost=15.0)
    solve(policy, [1.0, 1e-10])
    # 0.1 then 0.6: sqrt(0.06) = 0.245 per step, log(1e-9 / 0.06) / log(0.245) = 12.7 steps < 15: keep
    # (0.6 alone would predict 35)
    assert solve(policy, [1.0, 0.1, 0.06]) == [False, False, False]
    # 0.3 then 0.6: sqrt(0.18) = 0.42 per step, 20 steps from 0.036 > 15: refactor; the new
    # factorization's first contraction is then judged alone (0.1 from 0.0036: 6.6 steps)
    assert solve(policy, [1.0, 0.2, 0.06, 0.036, 0.0036]) == [False, False, False, True, False]


def test_a_solve_that_costs_more_than_the_cycle_average_ends_the_cycle():
    policy = FactorizationReuse(refactor_cost=10.0)
    solve(policy, [1.0, 1e-5, 1e-10])  # factor + 3 iterations: cycle cost 13 in 1 solve
    assert solve(policy, [1.0, 1e-5, 1e-10]) == [False] * 3  # 3 <= 13: the cycle goes on (16 / 2 = 8)
    six = [10.0 ** -(k * 2) for k in range(6)]  # a 6-iteration solve, contracting 1e-2 per step
    assert solve(policy, six) == [False] * 6  # 3 <= 16 / 2 before it: kept
    assert solve(policy, six + [1e-12, 1e-13]) == [False] * 8  # 6 <= 22 / 3 before it: kept
    assert solve(policy, [1.0])[0] is True  # 8 > 30 / 4: the last solve cost more than the average


def test_a_step_test_that_ends_solves_sooner_sets_the_end_the_contraction_is_judged_by():
    policy = FactorizationReuse(refactor_cost=15.0)
    solve(policy, [1.0, 1e-10])
    # ratio 0.3 from 0.3: log(1e-9 / 0.3) / log(0.3) = 16 more steps to the tolerance > 15: refactor
    assert solve(policy, [1.0, 0.3]) == [False, True]
    # two solves that a step test ended at 1e-3 and 2e-3 of their first residual
    for end in (1e-3, 2e-3):
        decisions = solve(policy, [1.0, 0.1, 1e-2, end])
        policy.ended_by_step_test(end)
    # the same contraction is now 4 steps from the smaller reduction reached (1e-3): keep
    assert solve(policy, [1.0, 0.3]) == [False, False]
    # a solve that ended after one chord step does not lift the end above 1e-2 of the first residual:
    # 0.8 per step from 0.8 is 20 steps from 1e-2: refactor
    for _ in range(2):
        solve(policy, [1.0, 0.5])
        policy.ended_by_step_test(0.5)
    assert solve(policy, [1.0, 0.8]) == [False, True]
    assert decisions == [False] * 4
    # what it learned goes into every checkpoint: a policy restored from it decides alike
    assert policy.learned() == {"reduction": 0.5, "reduction_before": 0.5}
    continued = FactorizationReuse(refactor_cost=15.0)
    continued.restore_learned(policy.learned())
    solve(continued, [1.0, 1e-10])
    assert solve(continued, [1.0, 0.8]) == [False, True] and solve(continued, [1.0, 0.3]) == [False, False]


def test_a_changed_operator_a_failure_or_an_invalidation_refactors():
    policy = FactorizationReuse(refactor_cost=15.0)
    solve(policy, [1.0, 1e-10])
    policy.start_solve()
    assert policy.refactor_now(0, 1.0, 1e-9, (0.001, 0.0)) is True  # dt halved
    assert policy.refactor_now(1, 1e-3, 1e-9, (0.001, 0.0)) is False
    assert policy.used_chord_steps()
    policy.failed()
    assert policy.retries == 1 and solve(policy, [1.0])[0] is True
    policy.invalidate()
    assert solve(policy, [1.0])[0] is True


def test_fresh_policy_factors_at_every_iteration():
    policy = FactorizationReuse(enabled=False)
    assert solve(policy, [1.0, 1e-3, 1e-6]) == [True, True, True]
    assert not policy.used_chord_steps()


def test_static_policy_keeps_factorizations_for_the_first_iteration_of_a_solve_only():
    policy = FactorizationReuse(chord_within_solve=False)
    assert solve(policy, [1.0, 1e-3, 1e-7]) == [True, True, True]
    assert solve(policy, [1.0, 1e-3, 1e-7]) == [False, True, True]


def test_refactor_cost_grows_like_the_square_root_of_the_size():
    assert refactor_cost(11532) == pytest.approx(15.0)
    assert refactor_cost(4 * 11532) == pytest.approx(30.0)
    assert refactor_cost(10) == 4.0
    assert refactor_cost(11532, step_bounded=True) == pytest.approx(15.0 / 2.5)  # IPC's dearer iterations
    with pytest.raises(ValueError, match="refactor_cost"):
        FactorizationReuse(refactor_cost=0.0)
    with pytest.raises(ValueError, match="max_chord_iterations"):
        FactorizationReuse(max_chord_iterations=0)


def test_mass_dominance_of_the_paper_cloth():
    # rho l^2 (1 - nu^2) / (Y dt^2) for 1/30 m patches, dt 2 ms
    value = mass_dominance(200.0, 1e4, 0.3, 1 / 30, 0.002)
    assert value == pytest.approx(200.0 / 900 * 0.91 / (1e4 * 4e-6))
    assert mass_dominance(200.0, 1e4, 0.3, 1 / 30, None) == 0.0


@pytest.mark.parametrize(
    ("dofs", "dominance", "dynamic", "kind"),
    [
        (11532, 5.0, True, "direct"),  # small: a kept factorization is cheaper
        (ITERATIVE_MIN_DOFS, 0.5, True, "iterative"),  # large and mass-dominated
        (ITERATIVE_MIN_DOFS * 4, 1e-4, True, "direct"),  # large but stiff
        (ITERATIVE_MIN_DOFS * 4, 0.0, False, "direct"),  # statics
    ],
)
def test_auto_chooses_by_size_and_mass_dominance(dofs, dominance, dynamic, kind):
    choice = choose_linear_solver("auto", dofs, 100 * dofs, dominance, 1e12, dynamic)
    assert choice.kind == kind and choice.requested == "auto" and choice.reason
    assert choice.as_dict()["direct_gb_estimate"] == pytest.approx(direct_factor_bytes(dofs, 100 * dofs) / 1e9)


def test_a_factorization_that_does_not_fit_goes_iterative_or_is_refused():
    dofs = 1_000_000
    need = direct_factor_bytes(dofs, 100 * dofs)
    assert 1e9 < need < 2e10  # a few GB for a million DoFs (measured ~5.5 kB per DoF)
    choice = choose_linear_solver("auto", dofs, 100 * dofs, 0.0, need / 2, False)
    assert choice.kind == "iterative" and "GB" in choice.reason
    with pytest.raises(LinearSolverError, match=r"needs about \d+\.\d GB, \d+\.\d GB are available"):
        choose_linear_solver("direct", dofs, 100 * dofs, 0.0, need / 2, False)
    assert choose_linear_solver("direct", dofs, 100 * dofs, 0.0, math.inf, False).kind == "direct"
    with pytest.raises(LinearSolverError, match="one of"):
        choose_linear_solver("cholesky", dofs, 100 * dofs, 0.0, math.inf, False)
