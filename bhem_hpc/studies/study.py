"""The study record: knobs, configurations, how to run one, and the shared timing of a solve."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from mpi4py import MPI

from bhem_hpc.errors import UserError
from bhem_hpc.model.shell import DEFAULT_QUADRATURE, ShellModel
from bhem_hpc.solver import ShellSolver

RESULT_COLUMNS = ("ranks", "dofs", "nonzeros", "value", "reference", "error", "wall_s", "newton_iterations")


class StudyError(UserError, ValueError):
    """Unknown study, knob value out of range, or an output directory that exists."""


@dataclass(frozen=True)
class Study:
    """A named set of knob configurations and how to run one.

    ``knobs`` are the configuration keys (CSV/table columns); the plot draws one error curve per
    value of ``series`` (a knob or a tuple of knobs) over the configurations whose other knobs equal
    ``baseline`` (a value, or a dict of values by discretization).
    """

    name: str
    description: str
    knobs: tuple[str, ...]
    configurations: Callable[[], Iterable[dict]]
    run: Callable[[dict, MPI.Comm], dict]
    series: str | tuple[str, ...]
    baseline: dict
    problem: str  # the knob that changes the problem itself (not its discretization)
    extra: tuple[str, ...] = ()  # result columns beyond RESULT_COLUMNS
    note: str = ""  # how to read the errors (written under the study's heading in the docs)
    figure: Callable[[Path, list[dict]], None] | None = None  # draws DIR/NAME-shapes.png from the rows

    @property
    def columns(self) -> tuple[str, ...]:
        return ("study", *self.knobs, *RESULT_COLUMNS, *self.extra)

    def baseline_value(self, knob: str, row: dict) -> object:
        """The baseline value of ``knob`` for ``row`` (a dict baseline is keyed by the row's discretization)."""
        value = self.baseline[knob]
        return value[row.get("discretization", "hermite")] if isinstance(value, dict) else value

    def in_baseline(self, row: dict) -> bool:
        return all(row[k] == self.baseline_value(k, row) for k in self.baseline)

    def in_plot(self, row: dict) -> bool:
        """Baseline rows, and rows of the reduced quadrature rule that are baseline otherwise."""
        if row.get("quadrature") == "reduced":
            return all(row[k] == self.baseline_value(k, row) for k in self.baseline if k != "quadrature")
        return self.in_baseline(row)

    def series_label(self, row: dict) -> str:
        keys = (self.series,) if isinstance(self.series, str) else self.series
        label = ", ".join(f"{k} = {row[k]}" for k in keys)
        return f"{label} (reduced)" if row.get("quadrature") == "reduced" else label


def timed_solve(model: ShellModel, load_steps: int, options: dict, comm: MPI.Comm) -> tuple[float, int, int]:
    """Solve; ``(wall seconds of the solve only, nonzeros, Newton iterations)``.

    Form compilation (a one-off, cached cost) happens when the model is built, outside the timing.
    """
    with ShellSolver(model, prefix="bhem_study_", options=options) as solver:
        start = time.perf_counter()
        report = solver.solve(load_steps)
        wall = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
        return wall, solver.problem.matrix_nonzeros(), sum(report.newton_iterations)


def study_result(model: ShellModel, value: float, reference: float, measured: tuple[float, int, int]) -> dict:
    wall, nonzeros, iterations = measured
    return {
        "dofs": 3 * model.discretization.num_closed,
        "nonzeros": nonzeros,
        "value": value,
        "reference": reference,
        "error": abs(value / reference - 1),
        "wall_s": wall,
        "newton_iterations": iterations,
    }


#: The C1 methods of the head-to-head: a discretization and its quadrature rule (None: the
#: discretization's default Gauss rule, :data:`DEFAULT_QUADRATURE`).
METHOD_RULES = (("hermite", None), ("bspline2", None), ("bspline2", "reduced"), ("bspline3", None))


def method_name(discretization: str, quadrature: object) -> str:
    """``hermite``, ``bspline2``, ``bspline2 reduced`` or ``bspline3``."""
    return f"{discretization} reduced" if quadrature == "reduced" else discretization


#: The methods' names, in the order of :data:`METHOD_RULES`.
METHODS = tuple(method_name(d, q) for d, q in METHOD_RULES)


def row_method(row: dict) -> str:
    """The method of a study row (rows of studies without a discretization knob are Hermite)."""
    return method_name(row.get("discretization", "hermite"), row.get("quadrature"))


def spline_variants(sizes: tuple[int, ...], cubic_sizes: tuple[int, ...] | None = None) -> Iterable[dict]:
    """The B-spline methods of a head-to-head, each with its sizes: quadratic splines with 3 x 3
    Gauss and with the reduced rule, cubic splines with 4 x 4 Gauss (on ``cubic_sizes``, default
    ``sizes``)."""
    for discretization, rule in METHOD_RULES:
        if discretization == "hermite":
            continue
        quadrature = rule or DEFAULT_QUADRATURE[discretization]
        for size in cubic_sizes or sizes if discretization == "bspline3" else sizes:
            yield {"discretization": discretization, "quadrature": quadrature, "size": size}


def flat_sheet(discretization: str, length1: float, length2: float, n1: int, n2: int):
    """A flat sheet of ``n1 x n2`` patches (knot spans) for a discretization name."""
    from bhem_hpc.geometry import bspline
    from bhem_hpc.geometry import surface as S

    if discretization == "hermite":
        return S.flat_rectangle(length1, length2, n1, n2)
    if discretization not in bspline.DISCRETIZATIONS:
        raise StudyError(f"knob discretization = {discretization!r}; expected one of {bspline.DISCRETIZATIONS}")
    return bspline.flat_rectangle(length1, length2, n1, n2, degree=int(discretization[-1]))
