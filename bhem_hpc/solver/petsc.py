"""PETSc utilities shared by the solvers: options under a prefix, object lifetimes, reasons, MUMPS status."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager

from petsc4py import PETSc

from bhem_hpc.errors import UserError

SNES_REASONS = {v: k for k, v in vars(PETSc.SNES.ConvergedReason).items() if k.isupper()}
KSP_REASONS = {v: k for k, v in vars(PETSc.KSP.ConvergedReason).items() if k.isupper()}
#: PETSc error codes a bad option gives, in words.
PETSC_ERRORS = {
    56: "a type or option this PETSc build does not support",
    62: "an argument out of range",
    63: "an argument out of range",
    73: "an object in the wrong state",
    86: "an unknown type name: check the spelling",
    92: "no such factorization package: check the solver type's spelling",
}


class SolverError(UserError, RuntimeError):
    """A nonlinear or linear solve failed; the message names the solver and the reasons."""


class SolverSetupError(SolverError):
    """PETSc refused the solver's configuration (a bad option): no retry with a smaller step helps."""


@contextmanager
def negated(vector: PETSc.Vec) -> Iterator[PETSc.Vec]:
    """A copy of ``vector`` times -1, destroyed on leaving the context."""
    copy = vector.copy()
    copy.scale(-1.0)
    try:
        yield copy
    finally:
        copy.destroy()


def rejected_options(solver: str, exc: PETSc.Error, detail: str = "") -> SolverSetupError:
    """The error of a solver (``"SNES solver 'bhem_'"``) whose options PETSc rejected with ``exc``;
    ``detail``: what follows the explanation (e.g. the options given)."""
    return SolverSetupError(f"{solver}: PETSc rejected its options (error code {exc.ierr}: "
                            f"{PETSC_ERRORS.get(exc.ierr, 'see the PETSc message above')}){detail}")  # fmt: skip


def push_options(prefix: str, defaults: Mapping[str, str], overrides: Mapping[str, object]) -> list[str]:
    """Set ``overrides`` then ``defaults`` under ``prefix`` where the database has no value.

    Returns the names pushed, so the caller can remove them after ``setFromOptions`` and leave
    the database as the user made it.
    """
    opts = PETSc.Options()
    pushed = []
    for source in (overrides, defaults):
        for key, value in source.items():
            name = prefix + key.lstrip("-")
            if not opts.hasName(name):
                opts[name] = "" if value is None else str(value)
                pushed.append(name)
    return pushed


def unused_options(prefix: str) -> list[str]:
    """Names in the options database under ``prefix`` that no PETSc object has read (PETSc's
    "options left", asked through ``PetscOptionsUsed``, which petsc4py does not wrap)."""
    import ctypes

    query = ctypes.CDLL(PETSc.__file__).PetscOptionsUsed  # libpetsc, linked by petsc4py's module
    used = ctypes.c_int(0)
    unused = []
    for name in sorted(PETSc.Options().getAll()):
        if name.startswith(prefix) and query(None, name.encode(), ctypes.byref(used)) == 0 and not used.value:
            unused.append(name)
    return unused


class PetscOwner:
    """Owns PETSc objects: an explicit ``close()`` (idempotent), a context manager, a guarded ``__del__``."""

    def close(self) -> None:  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown may have torn PETSc down already
            pass


def mumps_infog(ksp: PETSc.KSP | None, entry: int = 1) -> int | None:
    """MUMPS INFOG(entry) of a KSP's factorization (None if there is none or it is not MUMPS')."""
    try:
        return int(ksp.getPC().getFactorMatrix().getMumpsInfog(entry))
    except (PETSc.Error, AttributeError):
        return None


def mumps_factor(ksp: PETSc.KSP) -> PETSc.Mat | None:
    """The MUMPS factor of a KSP's last factorization (for its INFOG/RINFOG figures); None otherwise."""
    pc = ksp.getPC()
    if pc.getType() not in ("cholesky", "lu") or pc.getFactorSolverType() != "mumps":
        return None
    try:
        return pc.getFactorMatrix()
    except PETSc.Error:
        return None


def negative_pivots(ksp: PETSc.KSP) -> int:
    """Negative pivots of a KSP's last LDL^T factorization (MUMPS INFOG(12)); -1 if unknown (no
    Cholesky, or not MUMPS')."""
    if ksp.getPC().getType() != "cholesky":
        return -1
    value = mumps_infog(ksp, 12)
    return -1 if value is None else value


def solve_stopped(prefix: str, exc: PETSc.Error) -> SolverSetupError:
    """The error of a SNES solve that PETSc stopped (not a divergence: e.g. a bad option)."""
    return SolverSetupError(
        f"SNES solver '{prefix}': PETSc stopped the solve with error code {exc.ierr} "
        f"({PETSC_ERRORS.get(exc.ierr, 'see the PETSc message above')})"
    )


def library_versions() -> dict[str, str]:
    """Versions of bhem-hpc and the FEniCSx/PETSc stack, for run summaries."""
    import basix
    import dolfinx
    import petsc4py
    import ufl

    from bhem_hpc import __version__

    return {
        "bhem_hpc": __version__,
        "dolfinx": dolfinx.__version__,
        "basix": basix.__version__,
        "ufl": ufl.__version__,
        "petsc4py": petsc4py.__version__,
    }


def stage_seconds(stage: PETSc.Log.Stage, event: str) -> float:
    """Cumulative seconds of a PETSc log ``event`` within ``stage`` on this process. For a solver's
    stage, ``PCSetUp`` is the factorization (MUMPS, or a Krylov preconditioner's incomplete one) and
    ``KSPSolve`` the solves (triangular solves, Krylov iterations): PETSc sets the preconditioner up
    before its ``KSPSolve`` event begins, so the two do not overlap."""
    return PETSc.Log.Event(event).getPerfInfo(stage.id)["time"]
