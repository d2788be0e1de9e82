"""The study record: knobs, configurations, how to run one, and the shared timing of a solve."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from mpi4py import MPI

from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solver import ShellSolver

RESULT_COLUMNS = ("ranks", "dofs", "nonzeros", "value", "reference", "error", "wall_s", "newton_iterations")


class StudyError(ValueError):
    """Unknown study, knob value out of range, or an output directory that exists."""


@dataclass(frozen=True)
class Study:
    """A named set of knob configurations and how to run one.

    ``knobs`` are the configuration keys (CSV/table columns); the plot draws one error curve per
    value of ``series`` over the configurations whose other knobs equal ``baseline``.
    """

    name: str
    description: str
    knobs: tuple[str, ...]
    configurations: Callable[[], Iterable[dict]]
    run: Callable[[dict, MPI.Comm], dict]
    series: str
    baseline: dict
    problem: str  # the knob that changes the problem itself (not its discretization)
    extra: tuple[str, ...] = ()  # result columns beyond RESULT_COLUMNS
    note: str = ""  # how to read the errors (written under the study's heading in the docs)
    figure: Callable[[Path, list[dict]], None] | None = None  # draws DIR/NAME-shapes.png from the rows

    @property
    def columns(self) -> tuple[str, ...]:
        return ("study", *self.knobs, *RESULT_COLUMNS, *self.extra)


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
