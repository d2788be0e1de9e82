"""Where the adaptive Hessian starts each time step (:class:`bhem_hpc.model.hessian.HessianLadder`)."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.model.hessian import MAX_EXACT_WAIT, HessianLadder

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def starts(needs: list[str]) -> list[str]:
    """The kinds the steps start with when step k needs the rung ``needs[k]``: a step that starts at the
    exact Hessian ends there or at the rung it needs; one that starts lower stays there."""
    ladder, kinds, ended = HessianLadder(), [], "exact"
    for k in range(len(needs) + 1):
        kind = ladder.start(ended)
        kinds.append(kind)
        ended = needs[k] if k < len(needs) and kind == "exact" else kind
    return kinds


def test_a_stiff_shell_always_starts_at_the_exact_hessian():
    assert starts(["exact"] * 30) == ["exact"] * 31


def test_one_step_that_leaves_the_exact_hessian_costs_one_step_below_it():
    """A buckling event: the step after it starts one rung lower, the next at the exact Hessian again."""
    kinds = starts(["exact", "out_of_plane", "out_of_plane", "exact", "exact"])
    assert kinds == ["exact", "exact", "out_of_plane", "exact", "exact", "exact"]


def test_compressed_cloth_tries_the_exact_hessian_ever_more_rarely():
    """Every step that tries the exact Hessian leaves it: the waits double (1, 2, 4, ...) up to the cap,
    so 200 steps try it about 200 / MAX_EXACT_WAIT times, not 200."""
    ends = ["out_of_plane"] * 200
    kinds = starts(ends)
    tries = [k for k, kind in enumerate(kinds) if kind == "exact"]
    waits = np.diff(tries) - 1
    assert list(waits[:5]) == [1, 2, 4, 8, 16] and waits.max() == MAX_EXACT_WAIT
    assert len(tries) <= 200 / MAX_EXACT_WAIT + 6


def test_the_wait_starts_over_once_the_exact_hessian_holds_a_step():
    """Cloth that comes to rest in tension: once the exact Hessian held a step, the next step that
    leaves it is followed by one step below it, not by the long wait of before."""
    kinds = starts(["out_of_plane"] * 8 + ["exact"] * 20 + ["out_of_plane"] * 3)
    exact = "exact"
    low = "out_of_plane"
    assert kinds[:11] == [exact, low, exact, low, low, exact, low, low, low, low, exact]
    assert kinds[-4:] == [exact, low, exact, low]
