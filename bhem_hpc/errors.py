"""The base of every error a user can act on (no numpy, no PETSc: every package may import it).

An error of this family means the input, the options or the problem cannot be run as given: the
command line prints its message on one line and exits with status 2. Every other exception is a
bug in bhem-hpc, reported with its traceback.
"""

from __future__ import annotations


class UserError(Exception):
    """Bad input, options or settings, or a problem the solver cannot solve as posed; the message
    names the file, key or option and the value, and what to change."""


class InputError(UserError, ValueError):
    """A command-line argument, a file or a value outside what it may be (no more specific family)."""


class RunError(UserError, RuntimeError):
    """A run cannot start or continue (output directory, restart, failed step)."""
