"""The record of a run that ``summary.json`` holds (no numpy, no PETSc).

:class:`RunSummary` is filled as the run goes: what it solves (scene, physics hash, DoFs, the
linear solver), per step a record, and at the end its status, where it stopped and the solver's
totals. :meth:`RunSummary.as_dict` is the JSON object, its keys in the order of the fields, those
not (yet) known left out.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields
from pathlib import Path

from bhem_hpc.io.run_directory import write_replacing

#: The states of a run: written first as running, last as one of the others.
RUN_STATUSES = ("running", "completed", "failed", "interrupted")


@dataclass
class RunSummary:
    """``summary.json``: a run's identity and settings, its step records and its outcome.

    Attributes:
        scene: the scene file.
        status: one of :data:`RUN_STATUSES`.
        physics_hash: the identity of the scene's physics (restarts must match it).
        solution_method: the scene's ``[solver]`` keys that choose how, not what, it solves.
        dofs, nonzeros, ranks: the problem's size and the MPI ranks.
        versions: the libraries' versions.
        static: a path of equilibria (True) or time steps.
        linear_solver: the linear solver chosen, and why.
        factorization: the factorization policy.
        velocity_tolerance_m_s: the solver's step test's tolerance (``solver.velocity_tolerance``,
            ``"auto"`` resolved), or None without one.
        steps: one record per time step or path point (the step's row of ``steps.jsonl``).
        contact: colliders and contact samples (contact by impulses), or the barrier's settings (by IPC).
        time: the simulated time (dynamic), or the last frame's time value (static).
        load_factor, path_method: where a path ended and how it was followed (static).
        error: why the run failed or stopped.
        unused_petsc_options: options under the run's prefix PETSc never read.
        linear_solver_fallbacks: fallbacks of the linear solver during the run.
        solver_totals: the solver's counters over the run.
        bodies: a scene of several bodies: each body's name, DoFs and discretization.
        interfaces: where its shell bodies are joined or sewn (each interface's type, bodies,
            edges, penalty, quadrature points and the rest gap between its edges).
        cad_models: each shell read from a CAD model: its parts, the joints found, its free edges
            and how far its patches are from its parts.
    """

    scene: str
    physics_hash: str
    solution_method: dict
    dofs: int
    nonzeros: int
    ranks: int
    versions: dict
    static: bool
    linear_solver: dict
    factorization: str
    steps: list[dict] = field(default_factory=list)
    velocity_tolerance_m_s: float | None = None
    status: str = "running"
    contact: dict | None = None
    time: float | None = None
    load_factor: float | None = None
    path_method: str | None = None
    error: str | None = None
    unused_petsc_options: list[str] | None = None
    linear_solver_fallbacks: list | None = None
    solver_totals: dict | None = None
    bodies: list[dict] | None = None
    interfaces: list[dict] | None = None
    cad_models: list[dict] | None = None

    #: The JSON object's first keys (the run's identity), then the others in field order.
    LEADING = ("scene", "status")

    def as_dict(self) -> dict:
        """The JSON object of ``summary.json`` (fields not yet known left out)."""
        names = [*self.LEADING, *(f.name for f in fields(self) if f.name not in self.LEADING)]
        return {name: getattr(self, name) for name in names if getattr(self, name) is not None}

    def write(self, out: Path) -> None:
        """Write ``out/summary.json`` (replaced whole, by rename)."""
        write_replacing(out / "summary.json", (json.dumps(self.as_dict(), indent=1) + "\n").encode())
