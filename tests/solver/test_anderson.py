"""Anderson mixing of chord steps: pure numpy, checked on seeded linear problems."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from bhem_hpc.solver.anderson import AndersonMixing

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def linear_problem(seed: int, n: int = 40, perturbation: float = 0.01, condition: float = 1e3):
    """``F(x) = A x - b`` with SPD ``A`` and a kept factorization of ``P = A + E`` (``E`` SPD):
    the chord steps ``P^{-1} F`` contract at a rate set by ``perturbation``."""
    rng = np.random.default_rng(seed)
    q = np.linalg.qr(rng.standard_normal((n, n)))[0]
    a = q @ np.diag(np.geomspace(1.0, condition, n)) @ q.T
    g = rng.standard_normal((n, 4))  # the kept Jacobian is off in a few directions (a few slow modes)
    p = a + perturbation * condition * g @ g.T / n
    b = rng.standard_normal(n)
    return a, np.linalg.inv(p), b


def iterations_to(a, p_inverse, b, depth: int, reduction: float = 1e-10, limit: int = 500) -> int:
    mixing = AndersonMixing(depth)
    x = np.zeros_like(b)
    first = np.linalg.norm(a @ x - b)
    for k in range(limit):
        residual = a @ x - b
        if np.linalg.norm(residual) <= reduction * first:
            return k
        step = p_inverse @ residual
        mixed = mixing.mixed_step(x, step)
        x = x - (step if mixed is None else mixed)
    return limit


@pytest.mark.parametrize("seed", range(6))
def test_mixing_removes_the_slow_modes_of_chord_steps(seed):
    a, p_inverse, b = linear_problem(seed)
    plain = iterations_to(a, p_inverse, b, depth=0)
    mixed = iterations_to(a, p_inverse, b, depth=5)
    assert plain > 40  # four modes contract slowly
    assert mixed <= 8  # depth 5 > four slow modes: they are gone after a few steps


@pytest.mark.parametrize("seed", range(4))
def test_with_the_whole_history_mixing_ends_like_gmres_within_n_plus_one_steps(seed):
    n = 8
    a, p_inverse, b = linear_problem(seed, n=n, perturbation=2.0, condition=10.0)
    assert iterations_to(a, p_inverse, b, depth=n, reduction=1e-8) <= n + 1


def test_split_over_two_ranks_the_mixed_step_is_that_of_the_whole_vectors():
    """Two threads stand for two ranks, each holding part of every vector; ``reduce`` sums their
    small arrays as MPI's allreduce would."""
    rng = np.random.default_rng(7)
    iterates, steps = rng.standard_normal((5, 10)), rng.standard_normal((5, 10))
    whole = AndersonMixing(3)
    expected = [whole.mixed_step(x, s) for x, s in zip(iterates, steps, strict=True)]
    parts = (slice(0, 4), slice(4, 10))
    barrier, posted = threading.Barrier(2), [None, None]
    results: list[list] = [[], []]

    def rank(r: int) -> None:
        def allreduce(local: np.ndarray) -> np.ndarray:
            posted[r] = local
            barrier.wait()
            total = posted[0] + posted[1]
            barrier.wait()  # both have read before either posts again
            return total

        mixing = AndersonMixing(3, reduce=allreduce)
        results[r] = [mixing.mixed_step(x[parts[r]], s[parts[r]]) for x, s in zip(iterates, steps, strict=True)]

    threads = [threading.Thread(target=rank, args=(r,)) for r in (0, 1)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=30)
    assert expected[0] is None and results[0][0] is None and results[1][0] is None
    for k in range(1, 5):
        np.testing.assert_allclose(np.concatenate([results[0][k], results[1][k]]), expected[k], rtol=1e-12)


def test_no_history_no_depth_or_a_degenerate_history_gives_no_mixed_step():
    mixing = AndersonMixing(3)
    x, s = np.ones(5), np.full(5, 0.5)
    assert mixing.mixed_step(x, s) is None  # nothing to mix with yet
    assert mixing.mixed_step(x, s) is None  # the same pair again: all differences vanish
    mixing.reset()
    assert mixing.mixed_step(x + 1, s) is None  # reset: a new history
    plain = AndersonMixing(0)
    assert plain.mixed_step(x, s) is None and plain.mixed_step(x + 1, s + 1) is None
    with np.errstate(invalid="ignore"):
        broken = AndersonMixing(2)
        broken.mixed_step(x, s)
        assert broken.mixed_step(x, np.full(5, np.nan)) is None


@pytest.mark.parametrize("depth", [-1, 2.5, True, "5"])
def test_a_bad_depth_is_refused(depth):
    with pytest.raises(ValueError, match="Anderson depth"):
        AndersonMixing(depth)
