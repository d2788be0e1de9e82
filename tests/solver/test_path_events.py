"""Events between two path points (numpy only): limit points at the interpolated extremum of the load
factor, two limits between the same points, no limit at a sharp knee, bifurcations from inertia."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.solver.path_events import PathSample, events_between, hermite_extrema

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def sample(f, df, s: float, pivots: int = 0) -> PathSample:
    return PathSample(s, float(f(s)), float(df(s)), pivots)


def test_a_cubic_path_has_its_extremum_found_exactly():
    """lambda = s^3 - 3 s has a maximum at s = -1 (lambda 2) and a minimum at s = 1 (-2); the cubic
    Hermite interpolant of a cubic is the cubic, so both are found to round-off, although the two
    samples at s = -1.5 and 1.5 have the same slope's sign (3.75)."""
    f, df = (lambda s: s**3 - 3 * s), (lambda s: 3 * s**2 - 3)
    events = events_between(sample(f, df, -1.5, 0), sample(f, df, 1.5, 0))
    assert [e.kind for e in events] == ["limit", "limit"]
    assert [e.arc_length for e in events] == pytest.approx([-1.0, 1.0], abs=1e-12)
    assert [e.load_factor for e in events] == pytest.approx([2.0, -2.0], abs=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_a_smooth_limit_is_located_far_closer_than_the_next_point(seed):
    """lambda = sin(s) sampled on a random segment around its maximum at pi/2: the located maximum
    is within 1e-3 of 1 where the segment's endpoints are up to 0.1 below it."""
    rng = np.random.default_rng(seed)
    s0, s1 = np.pi / 2 - rng.uniform(0.1, 0.45), np.pi / 2 + rng.uniform(0.1, 0.45)
    (event,) = events_between(sample(np.sin, np.cos, s0), sample(np.sin, np.cos, s1, 1))
    assert event.kind == "limit" and abs(event.load_factor - 1.0) < 1e-3 and abs(event.arc_length - np.pi / 2) < 2e-2
    assert 1.0 - max(np.sin(s0), np.sin(s1)) > 1e-3


def test_a_sharp_knee_without_a_turn_is_no_limit():
    """A stiff path (slope 50) meeting a flat one (slope 0.01): the interpolant overshoots, but the
    samples show no turn, so no limit is invented; an inertia change there is a bifurcation."""
    start, end = PathSample(0.0, 0.0, 50.0, 0), PathSample(1.0, 1.0, 0.01, 0)
    assert hermite_extrema(start, end)  # the overshoot
    assert events_between(start, end) == ()
    (event,) = events_between(start, PathSample(1.0, 1.0, 0.01, 1))
    assert event.kind == "bifurcation" and event.load_factor == 1.0


def test_an_inertia_change_beyond_the_limits_passed_is_also_a_bifurcation():
    f, df = np.sin, np.cos
    events = events_between(sample(f, df, 1.2, 0), sample(f, df, 1.9, 2))
    assert [e.kind for e in events] == ["limit", "bifurcation"]
