"""The tables every body of a scene reads alike (numpy + stdlib only): the clock (``[time]``), the
output's pace and density (``[output]``) and the solver's linear strategy and PETSc options
(``[solver]``). A shell's and a solid's parsers both read them here, so a key means the same for
every body type."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from bhem_hpc.scene.petsc_options import option_problem
from bhem_hpc.scene.table import SceneError, Table
from bhem_hpc.solver.linear import LINEAR_SOLVERS
from bhem_hpc.solver.reuse import FACTORIZATION_POLICIES

#: Bounds checked before anything is allocated: time steps of one run.
MAX_STEPS = 10_000_000
MIN_DT, MAX_DT = 1e-12, 1e3  # s


@dataclass(frozen=True)
class Clock:
    """``[time]``: static (with its load steps), or ``dt`` [s] and ``steps``."""

    static: bool
    dt: float
    steps: int
    load_steps: int


def _whole_steps(duration: float, dt: float) -> bool:
    """``duration`` is a whole number of steps ``dt`` (to 1e-6 of a step), at least one, bounded."""
    steps = duration / dt
    return bool(np.isfinite(steps)) and 1 <= round(steps) <= MAX_STEPS and abs(steps - round(steps)) <= 1e-6


def parse_clock(top: Table) -> Clock:
    """``[time]``: ``static = true`` (and ``load_steps``), or ``dt`` and exactly one of ``steps`` and
    ``duration`` (a whole number of steps)."""
    time_table = top.table("time")
    static = time_table.get("static", "a boolean", False)
    if static:
        load_steps = time_table.get("load_steps", "an integer", 1, lambda v: v >= 1, "an integer >= 1")
        time_table.done()
        return Clock(True, 0.0, 0, load_steps)
    expected_dt = f"a number in [{MIN_DT:g}, {MAX_DT:g}] (time step [s])"
    dt = time_table.get("dt", "a number", check=lambda v: MIN_DT <= v <= MAX_DT, expected=expected_dt)
    has_steps, has_duration = "steps" in time_table.data, "duration" in time_table.data
    if has_steps == has_duration:
        raise SceneError(f"{top.path}: table 'time' needs exactly one of 'steps' and 'duration'")
    if has_steps:
        steps = time_table.get(
            "steps", "an integer", check=lambda v: 1 <= v <= MAX_STEPS, expected=f"an integer in 1..{MAX_STEPS}"
        )
    else:
        whole = f"a number > 0 [s], a whole number (1..{MAX_STEPS}) of time steps dt = {dt!r}"
        duration = time_table.get("duration", "a number", check=lambda v: _whole_steps(v, dt), expected=whole)
        steps = round(duration / dt)
    time_table.done()
    return Clock(False, dt, steps, 1)


def parse_output(top: Table) -> tuple[int, int]:
    """``[output]``: a frame ``every`` so many steps, ``density`` samples per patch side."""
    output = top.table("output", None)
    if output is None:
        return 1, 4
    every = output.get("every", "an integer", 1, lambda v: v >= 1, "an integer >= 1")
    density = output.get("density", "an integer", 4, lambda v: 1 <= v <= 32, "an integer in 1..32")
    output.done()
    return every, density


def parse_linear_strategy(solver: Table) -> tuple[str, str | None]:
    """``solver.linear`` and ``solver.factorization`` (None: the scene's default)."""
    linear = solver.get("linear", "a string", "auto", lambda v: v in LINEAR_SOLVERS,
                        "'auto', 'direct' or 'iterative'")  # fmt: skip
    factorization = solver.get("factorization", "a string", None, lambda v: v in FACTORIZATION_POLICIES,
                               "'reuse' or 'fresh'")  # fmt: skip
    return linear, factorization


def parse_petsc_options(t: Table) -> dict[str, Any]:
    """``options``: PETSc options (without prefix) of the table's solver, their values checked."""
    options = t.get("options", "a table", {})
    for k, v in options.items():
        if not isinstance(v, str | int | float | bool):
            t.fail(f"options.{k}", "a string, number or boolean", v)
        if (problem := option_problem(k, v)) is not None:
            t.fail(f"options.{k}", problem, v)
    return options
