"""Runs stopped by a signal at a step boundary: SIGTERM (``kill``, ``timeout``, a scheduler's
cancel), SIGINT (Ctrl-C) and SIGUSR1 (SLURM's warning before a time limit) set a flag that the
step loop reads after each step, on every rank at the same step; the run then writes its state as
a frame and a checkpoint and ends with status ``interrupted``. A second signal of the same kind
acts as it would without the handler (Ctrl-C twice: ``KeyboardInterrupt`` at once).
"""

from __future__ import annotations

import signal
import threading
from types import FrameType

from mpi4py import MPI

from bhem_hpc.errors import UserError

#: The signals that ask a run to stop at the next step boundary.
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGUSR1)


class RunInterrupted(UserError, RuntimeError):
    """A signal stopped the run at a step boundary (its state is written)."""


class Interruption:
    """Context manager: while active, :data:`STOP_SIGNALS` only set :attr:`received`.

    Handlers are installed only in the main thread (Python's rule); elsewhere the manager does
    nothing and :meth:`requested` stays False.
    """

    def __init__(self) -> None:
        self.received: int | None = None
        self._previous: dict[int, object] = {}

    def _handle(self, number: int, frame: FrameType | None) -> None:
        if self.received == number:  # the second time: as without the handler
            previous = self._previous.get(number)
            signal.signal(number, previous if previous is not None else signal.SIG_DFL)
            signal.raise_signal(number)
            return
        self.received = number

    def __enter__(self) -> Interruption:
        if threading.current_thread() is threading.main_thread():
            for number in STOP_SIGNALS:
                self._previous[number] = signal.signal(number, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for number, previous in self._previous.items():
            signal.signal(number, previous if previous is not None else signal.SIG_DFL)
        self._previous.clear()

    def requested(self, comm: MPI.Comm) -> str | None:
        """Collective: the name of a stop signal any rank received (None: go on)."""
        number = comm.allreduce(self.received or 0, op=MPI.MAX)
        return signal.Signals(number).name if number else None
