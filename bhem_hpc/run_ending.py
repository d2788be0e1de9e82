"""How a run's files are written and how a run ends: file operations on rank 0 whose failure every
rank sees, and the summary a run leaves however it ends (completed, failed or interrupted), with
its solver's totals and unused options."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from mpi4py import MPI

from bhem_hpc.errors import RunError
from bhem_hpc.io.interruption import RunInterrupted
from bhem_hpc.io.run_summary import RunSummary
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.newton import LINEAR_COUNTERS, RECOVERY_COUNTERS

if TYPE_CHECKING:
    from bhem_hpc.contact.ipc_contribution import IpcBarrier

log = logging.getLogger(__name__)


def on_rank0(comm: MPI.Comm, action, what: str):
    """Run a file operation on rank 0 and raise :class:`RunError` on every rank if it fails (so no
    rank waits for a collective that rank 0 never reaches). Returns the action's result on rank 0,
    None elsewhere."""
    error = result = None
    if comm.rank == 0:
        try:
            result = action()
        except (OSError, ValueError, RuntimeError) as exc:  # h5py reports failed writes as RuntimeError
            detail = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            error = f"cannot write {what}: {detail}"
    error = comm.bcast(error)
    if error:
        raise RunError(error)
    return result


@contextmanager
def summarized(summary: RunSummary, barrier: IpcBarrier | None, solver: ShellSolver, out: Path, comm: MPI.Comm,
               close_output: Callable[[], object]) -> Iterator[None]:  # fmt: skip
    """The end of a run's body, however it ends: the output (``close_output``) and the solver are
    closed, the contact barrier's figures (the stiffness it grew to; ``barrier`` None: none) join
    the summary, and ``summary.json`` is written: ``completed``, or why the run stopped."""
    try:
        yield
    except Exception as exc:
        if barrier is not None:
            summary.contact |= barrier.summary()
        record_failure(summary, exc, out, comm)
        raise
    finally:
        close_output()
        close_solver(solver, summary, comm)
    if barrier is not None:
        summary.contact |= barrier.summary()
    summary.status = "completed"
    on_rank0(comm, lambda: summary.write(out), "summary.json")


def record_failure(summary: RunSummary, exc: Exception, out: Path, comm: MPI.Comm) -> None:
    """``summary.json`` says why the run stopped (``interrupted`` by a signal, else ``failed``), if
    its output directory was started (rank 0 writes)."""
    summary.status, summary.error = "interrupted" if isinstance(exc, RunInterrupted) else "failed", str(exc)
    if comm.rank == 0 and out.is_dir():
        try:
            summary.write(out)
        except OSError:
            log.error("could not record the failure in %s/summary.json", out)


def close_solver(solver: ShellSolver, summary: RunSummary, comm: MPI.Comm) -> None:
    """The solver's unused options, fallbacks and totals into the summary; then close it."""
    report_unused_options(solver, summary, comm)
    summary.linear_solver_fallbacks = solver.fallbacks
    summary.solver_totals = {k: v for k, v in solver.counters().items() if k in (*LINEAR_COUNTERS, *RECOVERY_COUNTERS)}
    solver.close()


def report_unused_options(solver: ShellSolver, summary: RunSummary, comm: MPI.Comm) -> None:
    """Options under the run's prefix that PETSc never read (a misspelling, or an option that does
    not apply): a warning and ``summary.json``'s ``unused_petsc_options``."""
    unused = solver.unused_options()
    summary.unused_petsc_options = unused
    if unused and comm.rank == 0:
        log.warning("PETSc options never used (misspelled or not applicable): %s", ", ".join(unused))
