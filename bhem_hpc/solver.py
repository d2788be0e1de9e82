"""PETSc solvers for the shell problem. All petsc4py code of the project lives in this module.

:class:`ShellSolver` owns a SNES (Newton + line search) whose linear solves are MUMPS direct
factorizations (LDL^T by default, LU when the Jacobian is not symmetric). Options live under the
solver's own prefix; defaults are pushed only where nothing is set yet, so the command line
(``-bhem_static_snes_rtol 1e-12``, ...) and a scene's ``options`` table override them.

On a surface with periodic directions the solver iterates on the closed DOFs ``x_c`` and
assembles on the open grid: ``F_c = P^T F(P x_c)``, ``J_c = P^T J P`` (PETSc ``PtAP``, whose
symbolic product is reused).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import dolfinx.fem.petsc as fem_petsc
import numpy as np
from petsc4py import PETSc

from bhem_hpc.shell import ShellModel

log = logging.getLogger(__name__)

SNES_REASONS = {v: k for k, v in vars(PETSc.SNES.ConvergedReason).items() if k.isupper()}
KSP_REASONS = {v: k for k, v in vars(PETSc.KSP.ConvergedReason).items() if k.isupper()}


class SolverError(RuntimeError):
    """A nonlinear or linear solve failed; the message names the solver and the reasons."""


def default_options(model: ShellModel) -> dict[str, str]:
    """Solver defaults for a model (all overridable under the prefix)."""
    m = model.material
    grid = model.rest_surface.grid
    # Absolute residual floor: round-off of the internal force is ~eps * Y h * patch size.
    force_scale = m.young * m.thickness * max(grid.h1, grid.h2)
    return {
        "snes_type": "newtonls",
        "snes_linesearch_type": "bt",
        "snes_rtol": "1e-9",
        "snes_atol": f"{1e-13 * force_scale:.3e}",
        "snes_stol": "1e-14",
        "snes_max_it": "50",
        "ksp_type": "preonly",
        "pc_type": "cholesky" if model.symmetric else "lu",
        "pc_factor_mat_solver_type": "mumps",
        # Debian's MUMPS has no METIS: AMF (2) was the fastest of the built-in orderings here.
        "mat_mumps_icntl_7": "2",
    }


def _push_options(prefix: str, defaults: Mapping[str, str], overrides: Mapping[str, object]) -> list[str]:
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


def _residual_callback(snes: PETSc.SNES, x: PETSc.Vec, f: PETSc.Vec, solver: ShellSolver) -> None:
    solver.update_state(x)
    solver.assemble_residual(x, f)


def _jacobian_callback(snes: PETSc.SNES, x: PETSc.Vec, jac: PETSc.Mat, pmat: PETSc.Mat, solver: ShellSolver) -> None:
    solver.assemble_jacobian(pmat)


@dataclass
class SolveReport:
    """What a solve did: per load step Newton iterations and timings."""

    load_steps: int = 0
    newton_iterations: list[int] = field(default_factory=list)
    residual_norms: list[float] = field(default_factory=list)
    negative_pivots: list[int] = field(default_factory=list)
    assemble_residual_s: float = 0.0
    assemble_jacobian_s: float = 0.0
    wall_s: float = 0.0


class ShellSolver:
    """Newton solver for the static equilibrium of a :class:`ShellModel`.

    Args:
        model: the shell problem (forms, constraints, loads).
        prefix: PETSc options prefix of this solver.
        options: PETSc options (without prefix) that override the defaults, e.g. from a scene.
    """

    def __init__(self, model: ShellModel, prefix: str = "bhem_static_", options: Mapping[str, object] | None = None):
        self.model = model
        self.prefix = prefix
        self._closed = False
        disc = model.discretization
        comm = model.comm
        n_local, n_global = 3 * disc.num_owned_closed, 3 * disc.num_closed
        self.x = PETSc.Vec().createMPI((n_local, n_global), comm=comm)
        self.f = self.x.duplicate()
        self.f_open = fem_petsc.create_vector(model.residual_form)
        self.point_loads = self.f_open.duplicate()
        with self.point_loads.localForm() as local:
            local.array[:] = model.point_load_open
        self.point_loads.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.jacobian_open = fem_petsc.create_matrix(model.jacobian_form)
        self.prolongation: PETSc.Mat | None = None
        if disc.is_periodic:
            blocks = disc.open_blocks
            rows = 3 * blocks.size
            cols = (3 * disc.closed_of_open[blocks][:, None] + np.arange(3)).ravel().astype(PETSc.IntType)
            indptr = np.arange(rows + 1, dtype=PETSc.IntType)
            self.prolongation = PETSc.Mat().createAIJ(
                ((rows, 3 * disc.function_space.dofmap.index_map.size_global), (n_local, n_global)),
                csr=(indptr, cols, np.ones(rows)),
                comm=comm,
            )
            self._assemble_open_jacobian()
            self.jacobian = self.jacobian_open.PtAP(self.prolongation)
        else:
            self.jacobian = self.jacobian_open
        self.jacobian.setOption(PETSc.Mat.Option.SYMMETRIC, model.symmetric)
        self.bc_local = model.constrained.local.astype(np.int64)
        self.bc_rows = model.constrained.rows.astype(PETSc.IntType)
        self.bc_values = model.constrained_initial.copy()
        self.report = SolveReport()

        self.snes = PETSc.SNES().create(comm)
        self.snes.setOptionsPrefix(prefix)
        self.snes.setFunction(_residual_callback, self.f, kargs={"solver": self})
        self.snes.setJacobian(_jacobian_callback, self.jacobian, self.jacobian, kargs={"solver": self})
        pushed = _push_options(prefix, default_options(model), options or {})
        self.snes.setFromOptions()
        opts = PETSc.Options()
        for name in pushed:
            opts.delValue(name)

    # -- assembly --------------------------------------------------------------------------------
    def update_state(self, x: PETSc.Vec) -> None:
        """Write closed DOFs ``x`` into the model's position Function (with ghosts)."""
        target = self.model.x.vector
        if self.prolongation is not None:
            self.prolongation.mult(x, target)
        else:
            x.copy(target)
        target.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)

    def state_to_vector(self, x: PETSc.Vec) -> None:
        """Copy the model's current position into closed DOFs ``x``."""
        disc = self.model.discretization
        x.array[:] = self.model.x.x.array.reshape(-1, 3)[disc.owned_closed_open_block].ravel()

    def assemble_residual(self, x: PETSc.Vec, f: PETSc.Vec) -> None:
        """``f = P^T (F_int - F_ext)`` with constrained rows replaced by ``x - x_bc``."""
        t0 = time.perf_counter()
        with self.f_open.localForm() as local:
            local.set(0.0)
        fem_petsc.assemble_vector(self.f_open, self.model.residual_form)
        self.f_open.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self.f_open.axpy(-float(self.model.load_factor.value), self.point_loads)
        if self.prolongation is not None:
            self.prolongation.multTranspose(self.f_open, f)
        else:
            self.f_open.copy(f)
        if len(self.bc_local):
            values = f.array
            values[self.bc_local] = x.array_r[self.bc_local] - self.bc_values
        self.report.assemble_residual_s += time.perf_counter() - t0

    def _assemble_open_jacobian(self) -> None:
        self.jacobian_open.zeroEntries()
        fem_petsc.assemble_matrix(self.jacobian_open, self.model.jacobian_form)
        self.jacobian_open.assemble()

    def assemble_jacobian(self, jac: PETSc.Mat) -> None:
        """``J = P^T J_open P`` with constrained rows and columns replaced by the identity."""
        t0 = time.perf_counter()
        self._assemble_open_jacobian()
        if self.prolongation is not None:
            self.jacobian_open.PtAP(self.prolongation, result=jac)
        jac.zeroRowsColumns(self.bc_rows, diag=1.0)
        self.report.assemble_jacobian_s += time.perf_counter() - t0

    # -- solves ---------------------------------------------------------------------------------
    def solve(self, load_steps: int = 1) -> SolveReport:
        """Solve for equilibrium, ramping loads and prescribed values over ``load_steps`` steps.

        Raises:
            SolverError: naming the solver, the load step and the SNES/KSP reasons.
        """
        if int(load_steps) < 1:
            raise SolverError(f"solver '{self.prefix}': load_steps must be >= 1, got {load_steps!r}")
        model = self.model
        start = time.perf_counter()
        self.state_to_vector(self.x)
        for step in range(1, load_steps + 1):
            factor = step / load_steps
            model.load_factor.value = factor
            self.bc_values = model.constrained_initial + factor * (model.constrained_target - model.constrained_initial)
            if len(self.bc_local):
                self.x.array[self.bc_local] = self.bc_values
            self.snes.solve(None, self.x)
            self._check(step, load_steps, factor)
            self.report.newton_iterations.append(self.snes.getIterationNumber())
            self.report.residual_norms.append(self.snes.getFunctionNorm())
            self.report.negative_pivots.append(self.negative_pivots())
            log.info(
                "%s load step %d/%d: %d Newton iterations, |F| = %.3e",
                self.prefix, step, load_steps, self.snes.getIterationNumber(), self.snes.getFunctionNorm(),
            )
        self.update_state(self.x)
        self.report.load_steps += load_steps
        self.report.wall_s += time.perf_counter() - start
        return self.report

    def _check(self, step: int, steps: int, factor: float) -> None:
        reason = self.snes.getConvergedReason()
        norm = self.snes.getFunctionNorm()
        if reason > 0 and np.isfinite(norm):
            return
        ksp = self.snes.getKSP()
        ksp_reason = ksp.getConvergedReason()
        mumps = ""
        factor_matrix = self._factor_matrix()
        if factor_matrix is not None:
            mumps = f", MUMPS INFOG(1) = {factor_matrix.getMumpsInfog(1)}"
        raise SolverError(
            f"SNES solver '{self.prefix}' failed at load step {step}/{steps} (load factor {factor:.4g}): "
            f"{SNES_REASONS.get(reason, reason)} after {self.snes.getIterationNumber()} Newton iterations, "
            f"|F| = {norm:.3e}; last linear solve: KSP {KSP_REASONS.get(ksp_reason, ksp_reason)}{mumps}"
        )

    def _factor_matrix(self) -> PETSc.Mat | None:
        pc = self.snes.getKSP().getPC()
        if pc.getType() not in ("cholesky", "lu") or pc.getFactorSolverType() != "mumps":
            return None
        try:
            return pc.getFactorMatrix()
        except PETSc.Error:
            return None

    def negative_pivots(self) -> int:
        """Negative pivots of the last LDL^T factorization (MUMPS INFOG(12)); -1 if unknown."""
        factor_matrix = self._factor_matrix()
        if factor_matrix is None or self.snes.getKSP().getPC().getType() != "cholesky":
            return -1
        return int(factor_matrix.getMumpsInfog(12))

    # -- lifetime -------------------------------------------------------------------------------
    def close(self) -> None:
        """Destroy the PETSc objects this solver owns (idempotent)."""
        if self._closed:
            return
        self._closed = True
        objects = [self.snes, self.x, self.f, self.f_open, self.point_loads, self.jacobian_open]
        if self.prolongation is not None:
            objects += [self.prolongation, self.jacobian]
        for obj in objects:
            obj.destroy()

    def __enter__(self) -> ShellSolver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown may have torn PETSc down already
            pass
