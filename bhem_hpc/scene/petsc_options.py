"""Values of well-known PETSc options checked before PETSc reads them (numpy-free, PETSc-free).

PETSc refuses a bad value of a solver's option (``-bhem_snes_max_it -5``) only when the solver is
set up, with an error code and no message through petsc4py; these checks name the option and value
first. Options are matched by the end of their name, so they apply under any prefix.
"""

from __future__ import annotations

from collections.abc import Iterable

#: Option name endings whose value is a count (an integer >= 0).
COUNTS = ("_max_it", "_max_funcs", "_gmres_restart", "_factor_levels", "_max_fail", "_max_linear_solve_fail")
#: Option name endings whose value is a tolerance or a length (a number >= 0).
TOLERANCES = ("_rtol", "_atol", "_stol", "_trtol", "_linesearch_minlambda", "_linesearch_maxstep")


def option_problem(name: str, value: object) -> str | None:
    """What is wrong with ``value`` for the PETSc option ``name`` (None: nothing this module knows)."""
    name = name.lstrip("-")
    if name.endswith(COUNTS):
        try:
            number = int(str(value))
        except ValueError:
            return "an integer >= 0"
        return None if number >= 0 else "an integer >= 0"
    if name.endswith(TOLERANCES):
        try:
            number = float(str(value))
        except ValueError:
            return "a number >= 0"
        return None if number >= 0 and number == number and number != float("inf") else "a finite number >= 0"
    return None


def command_line_options(arguments: Iterable[str]) -> list[tuple[str, str | None]]:
    """``-name value`` pairs of a command line's PETSc arguments (a flag without a value: None)."""
    arguments = list(arguments)
    pairs = []
    for k, argument in enumerate(arguments):
        if argument.startswith("-") and not _is_number(argument):
            following = arguments[k + 1] if k + 1 < len(arguments) else None
            is_value = following is not None and (not following.startswith("-") or _is_number(following))
            pairs.append((argument.lstrip("-"), following if is_value else None))
    return pairs


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
