"""Several bodies' problems as one: a stacked residual, Jacobian, potential and constraint rows.

:class:`StackedProblem` joins the problem of each body (a shell's
:class:`~bhem_hpc.solver.problem.ShellProblem`, a solid's :class:`~bhem_hpc.solids.petsc.SolidProblem`)
into one problem on one stacked vector (:class:`~bhem_hpc.bodies.layout.StackedLayout`: each rank's
range holds the closed DOFs each body owns there, body after body). Each body assembles its own
UFL terms and contributions as it does alone; the stacked problem adds energy contributions that
couple bodies (a spring between material points of two bodies; contact between bodies), which
see every body's open blocks side by side:

- ``ContributionState.positions``: this rank's open blocks (owned and ghosts) of body 0, then of
  body 1, ..., shape ``(blocks, 3)``; :meth:`StackedProblem.point_basis` names a material point of a
  body in those rows;
- Hessian patterns name stacked global open blocks (:attr:`StackedProblem.global_open_blocks`).

The stacked Jacobian is AIJ with 3 x 3 blocks: each body's closed Jacobian (constrained rows and
columns already the identity) copied in at its offsets, plus the coupling Hessian ``P^T H P``
(``H`` on the stacked open blocks, ``P`` the bodies' prolongations side by side: seams, ties and
B-spline control points as each body has them; formed by :mod:`.coupling_product` from the blocks
the contributions give), every constrained row and column set to the identity again, then the
diagonal regularizer.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np
import scipy.sparse
from mpi4py import MPI
from petsc4py import PETSc

from bhem_hpc.bodies.coupling_product import CouplingProduct, PatternKeys, contribution_blocks
from bhem_hpc.bodies.layout import StackedLayout
from bhem_hpc.bodies.shared_dofs import SharedDofs
from bhem_hpc.bodies.shared_petsc import SharedDofProblem
from bhem_hpc.model.hessian import COMPOSED_HESSIANS
from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solids.model import SolidModel
from bhem_hpc.solids.petsc import SolidProblem
from bhem_hpc.solver.acceleration import BodiesAccelerationResidual
from bhem_hpc.solver.contributions import (
    Contribution,
    ContributionState,
    PointBasis,
    StepBounded,
    adapt_to_iterate,
    adapted_parameters,
    begin_lagged_step,
    carried_by_obstacles,
    moving_obstacles,
    place_obstacles_within_step,
    restore_adapted,
    step_bound,
    step_converged,
    step_testers,
)
from bhem_hpc.solver.model_group import BodyModel
from bhem_hpc.solver.petsc import PetscOwner
from bhem_hpc.solver.problem import ShellProblem, add_diagonal_regularization, stored_entries
from bhem_hpc.solver.report import SolveReport


def _pattern(contribution: Contribution) -> tuple[np.ndarray, np.ndarray]:
    rows, columns = (np.asarray(a).reshape(-1) for a in contribution.hessian_pattern())
    if rows.shape != columns.shape:
        raise ValueError(f"contribution {contribution.name!r}: a Hessian pattern needs as many rows as columns, "
                         f"got {rows.shape} and {columns.shape}")  # fmt: skip
    return rows.astype(PETSc.IntType)[:, None], columns.astype(PETSc.IntType)[:, None]


class StackedBlocks:
    """Where contributions that couple bodies see each body's open blocks (known from the models
    alone, before any problem is made: a contribution is made before the solver that takes it).

    Args:
        models: the bodies' models in the stacked order, on one communicator.

    Attributes:
        open: the stacked numbering of the bodies' open blocks (:class:`StackedLayout`).
        open_offsets: where each body's open blocks (owned, then ghosts) start in the rows of
            ``ContributionState.positions``, ``(bodies + 1,)``.
        global_open_blocks: the stacked global open block of each of those rows.
    """

    def __init__(self, models: Sequence[BodyModel]):
        self.models = list(models)
        self.comm = comm = self.models[0].comm
        counts = [m.open_blocks for m in self.models]  # (owned, ghosts) of each body
        self.open = StackedLayout(comm.allgather([owned for owned, _ in counts]), comm.rank)
        self.open_offsets = np.concatenate([[0], np.cumsum([owned + ghosts for owned, ghosts in counts])])
        self.global_open_blocks = np.concatenate(
            [self.open.to_stacked(b, m.global_open_blocks) for b, m in enumerate(self.models)])  # fmt: skip

    def point_basis(self, body: int, xi1: float, xi2: float) -> PointBasis:
        """A material point of ``body`` in the contributions' rows: ``(rows, basis values)`` on the rank
        that owns its patch (empty elsewhere)."""
        blocks, values = self.models[body].point_basis(xi1, xi2)
        return np.asarray(blocks, dtype=np.int64) + self.open_offsets[body], values

    def point_frame_basis(self, body: int, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        """A material point of shell ``body`` with its tangents: ``(rows, values (3, n))`` on the rank
        that owns its patch (empty elsewhere)."""
        model = self.models[body]
        if not isinstance(model, ShellModel):
            raise TypeError(f"body {body} is not a shell: it has no tangents to couple along an interface")
        blocks, values = model.point_frame_basis(xi1, xi2)
        return np.asarray(blocks, dtype=np.int64) + self.open_offsets[body], values


class StackedProblem(PetscOwner):
    """One problem of several bodies' :class:`ShellProblem` s and the contributions that couple them.

    Args:
        problems: one per body, in the stacked order, on one communicator, each with an AIJ
            Jacobian (``matrix_format = "aij"``); the stacked problem owns and closes them.
        contributions: energy contributions over all bodies' open blocks (see the module).

    Raises:
        ValueError: no body, or a body whose Jacobian is not AIJ.
        TypeError: an object that is not a :class:`Contribution`.
    """

    def __init__(self, problems: Sequence[ShellProblem | SolidProblem], contributions: Sequence[Contribution] = (),
                 names: Sequence[str] | None = None):  # fmt: skip
        if not problems:
            raise ValueError("a stacked problem needs at least one body")
        self.problems = list(problems)
        #: the bodies' names, for messages (default: "body 0", "body 1", ...)
        self.names = [f"body {k}" for k in range(len(self.problems))] if names is None else list(names)
        if len(self.names) != len(self.problems):
            raise ValueError(f"{len(self.problems)} bodies need as many names, got {self.names}")
        kinds = {p.hessian_kinds() for p in self.problems}
        if len(kinds) > 1:
            raise ValueError(f"the bodies of one problem must offer the same Hessian kinds (solver.hessian), got "
                             f"{sorted(kinds)}")  # fmt: skip
        self._closed = False
        comm = self.problems[0].model.comm
        self.comm = comm
        for k, problem in enumerate(self.problems):
            if problem.matrix_format != "aij":
                raise ValueError(f"body {k}: its Jacobian must be AIJ to be stacked, got {problem.matrix_format!r}")
        self.contributions: list[Contribution] = []
        self._patterns: list[tuple[np.ndarray, np.ndarray]] = []
        sizes = [p.model.closed_dofs for p in self.problems]  # (owned, all) DOFs of each body
        self.closed = StackedLayout(comm.allgather([owned for owned, _ in sizes]), comm.rank)
        #: the coupling contributions' rows and blocks
        self.blocks = StackedBlocks([p.model for p in self.problems])
        self.open, self.open_offsets = self.blocks.open, self.blocks.open_offsets
        self.global_open_blocks = self.blocks.global_open_blocks
        self._x = [PETSc.Vec().createMPI(size, comm=comm) for size in sizes]
        self._f = [v.duplicate() for v in self._x]
        self._rows = [self.closed.rank_start[comm.rank] + np.arange(s.start, s.stop, dtype=np.int64)
                      for s in map(self.closed.local_slice, range(len(self.problems)))]  # fmt: skip
        self.bc_local = np.concatenate([p.bc_local + self.closed.local_slice(b).start
                                        for b, p in enumerate(self.problems)]).astype(np.int64)  # fmt: skip
        self.bc_rows = np.concatenate([self.closed.to_stacked(b, p.bc_rows)
                                       for b, p in enumerate(self.problems)]).astype(PETSc.IntType)  # fmt: skip
        self._bc_counts = np.cumsum([0] + [len(p.bc_local) for p in self.problems])
        self.regularization = 0.0
        #: called when the Jacobian's pattern grew: a factorization must start again from its analysis
        self.on_pattern_growth: Callable[[], None] | None = None
        #: forms P^T H P of the coupling contributions (None: no coupling)
        self._coupling: CouplingProduct | None = None
        #: the stacked Jacobian's pattern on this rank's rows (grows with contact between bodies)
        self._pattern_keys: PatternKeys | None = None
        self.jacobian = self._create_jacobian()
        if contributions:
            self.add_contributions(contributions)

    def add_contributions(self, contributions: Sequence[Contribution]) -> None:
        """Collective: add coupling contributions (their Hessian patterns fix the Jacobian's, which is
        made again: before the problem is handed to a solver). They may name material points through
        :meth:`point_basis` and blocks through :attr:`global_open_blocks` of this problem."""
        for contribution in contributions:
            if not isinstance(contribution, Contribution):
                raise TypeError(f"{contribution!r} is not an energy contribution (bhem_hpc.solver.contributions)")
        self.contributions += list(contributions)
        self._patterns += [_pattern(c) for c in contributions]
        self.jacobian.destroy()
        self._coupling = self._create_coupling() if self.comm.allreduce(len(self.contributions)) else None
        self.jacobian = self._create_jacobian()

    # -- layout ---------------------------------------------------------------------------------
    def body_csr(self, body: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body ``body``'s closed Jacobian as it stands: row pointer, stacked global columns, values
        of this rank's rows."""
        row_pointer, columns, values = self.problems[body].jacobian.getValuesCSR()
        return row_pointer, self.closed.to_stacked(body, columns).astype(PETSc.IntType), values

    def _prolongation(self) -> scipy.sparse.csr_matrix:
        """Collective: the bodies' prolongations side by side, every rank's rows: stacked open DOFs
        ``3 * block + component`` (rows) from stacked closed DOFs (columns)."""
        rank = self.comm.rank
        pointers, columns, values = [np.zeros(1, np.int64)], [], []
        for body, problem in enumerate(self.problems):
            if problem.prolongation is not None:
                row_pointer, body_columns, body_values = problem.prolongation.getValuesCSR()
                body_columns = self.closed.to_stacked(body, body_columns)
            else:  # open DOFs are the closed ones
                count = self.closed.local_slice(body).stop - self.closed.local_slice(body).start
                row_pointer, body_values = np.arange(count + 1), np.ones(count)
                body_columns = self.closed.rank_start[rank] + np.arange(self.closed.local_slice(body).start,
                                                                        self.closed.local_slice(body).stop)  # fmt: skip
            pointers.append(np.asarray(row_pointer[1:], np.int64) + pointers[-1][-1])
            columns.append(np.asarray(body_columns, np.int64))
            values.append(np.asarray(body_values, dtype=float))
        row_pointer = np.concatenate(pointers)
        local = scipy.sparse.csr_matrix((np.concatenate(values), np.concatenate(columns), row_pointer),
                                        shape=(len(row_pointer) - 1, self.closed.size_global))  # fmt: skip
        return scipy.sparse.vstack(self.comm.allgather(local), format="csr")  # rank after rank: the open order

    def _create_coupling(self) -> CouplingProduct:
        """Collective: the product's prolongation and this rank's closed rows."""
        start = int(self.closed.rank_start[self.comm.rank])
        return CouplingProduct(self._prolongation(), slice(start, start + self.closed.size_local))

    def _gathered(self, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
        """Collective: every rank's ``arrays`` (block rows, columns and maybe values), concatenated
        rank after rank, on every rank."""
        if self.comm.size == 1:
            return arrays
        return tuple(np.concatenate(part) for part in zip(*self.comm.allgather(arrays), strict=True))

    def _create_jacobian(self) -> PETSc.Mat:
        """The stacked AIJ: every body's pattern at its offsets and the coupling's ``P^T H P``."""
        size = (self.closed.size_local, self.closed.size_global)
        local_rows, columns = [], []
        for body in range(len(self.problems)):
            row_pointer, body_columns, _ = self.body_csr(body)
            local_rows.append(self._rows[body][np.repeat(np.arange(len(row_pointer) - 1), np.diff(row_pointer))])
            columns.append(body_columns)
        if self._coupling is not None:  # room for every block of the contributions' fixed patterns
            pairs = self._gathered(*(np.concatenate([np.asarray(p, np.int64).reshape(-1) for p, _ in self._patterns]),
                                     np.concatenate([np.asarray(c, np.int64).reshape(-1) for _, c in self._patterns])))
            coupled = self._coupling.pattern(*pairs)
            start = self.closed.rank_start[self.comm.rank]
            local_rows.append(start + np.repeat(np.arange(coupled.shape[0]), np.diff(coupled.indptr)))
            columns.append(coupled.indices.astype(np.int64))
        rows, columns = np.concatenate(local_rows) - self.closed.rank_start[self.comm.rank], np.concatenate(columns)
        keys = np.unique(rows * self.closed.size_global + columns.astype(np.int64))  # sorted by row, then column
        rows, columns = keys // self.closed.size_global, keys % self.closed.size_global
        row_pointer = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=self.closed.size_local))])
        csr = (row_pointer.astype(PETSc.IntType), columns.astype(PETSc.IntType))
        jacobian = PETSc.Mat().createAIJ((size, size), bsize=3, csr=csr, comm=self.comm)
        jacobian.assemble()
        jacobian.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        jacobian.setOption(PETSc.Mat.Option.SYMMETRIC, all(p.model.symmetric for p in self.problems))
        self._pattern_keys = PatternKeys(row_pointer, columns, self.closed.size_global)
        return jacobian

    def create_vector(self) -> PETSc.Vec:
        """A stacked closed vector (the caller destroys it)."""
        return PETSc.Vec().createMPI((self.closed.size_local, self.closed.size_global), comm=self.comm)

    def point_basis(self, body: int, xi1: float, xi2: float) -> PointBasis:
        """A material point of ``body`` in the contributions' rows (:meth:`StackedBlocks.point_basis`)."""
        return self.blocks.point_basis(body, xi1, xi2)

    def point_frame_basis(self, body: int, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        """A material point of shell ``body`` with its tangents (:meth:`StackedBlocks.point_frame_basis`)."""
        return self.blocks.point_frame_basis(body, xi1, xi2)

    # -- state ----------------------------------------------------------------------------------
    @property
    def hessian(self) -> str:
        """The Hessian kind every body assembles next (they share one)."""
        return self.problems[0].hessian

    @hessian.setter
    def hessian(self, kind: str) -> None:
        for problem in self.problems:
            problem.hessian = kind

    def hessian_kinds(self) -> tuple[str, ...]:
        """The Hessian kinds :attr:`hessian` may name (every body's)."""
        return self.problems[0].hessian_kinds()

    @property
    def alm_multipliers(self) -> np.ndarray:
        """Every body's point-constraint multipliers, body after body, ``(points, 3)``."""
        return np.concatenate([p.alm_multipliers.reshape(-1, 3) for p in self.problems])

    def update_multipliers(self) -> bool:
        """After a converged solve: whether every body's held points are within tolerance (each body
        updates its multipliers where not; collective)."""
        return all([p.update_multipliers() for p in self.problems])  # a list: every body updates

    def begin_step(self, time: float, dt: float) -> None:
        """Collective, before a time step from ``time`` of ``dt`` [s]: every body's lagged
        contributions and the coupling ones take the step's start state."""
        for problem in self.problems:
            problem.begin_step(time, dt)
        begin_lagged_step(self.contributions, self.contribution_state(), time, dt)

    def adapt_to_iterate(self) -> bool:
        """Collective: every body's contributions and the coupling ones adapt at the current state
        (:class:`~bhem_hpc.solver.contributions.IterationAdapted`); returns whether some energy changed."""
        changed = [p.adapt_to_iterate() for p in self.problems]
        return adapt_to_iterate(self.contributions, self.contribution_state()) or any(changed)

    def adapted_parameters(self) -> dict[str, float]:
        """Every body's and the coupling contributions' adapted parameters, for a checkpoint."""
        return adapted_parameters(self.contributions) | {k: v for p in self.problems
                                                          for k, v in p.adapted_parameters().items()}  # fmt: skip

    def restore_adapted(self, parameters: dict[str, float]) -> None:
        """Take every contribution's adapted parameters from a checkpoint."""
        restore_adapted(self.contributions, parameters)
        for problem in self.problems:
            problem.restore_adapted(parameters)

    def set_point_targets(self, t: float, ramp: bool = False) -> None:
        """Every body's point-constraint targets at time (or load factor) ``t``."""
        for problem in self.problems:
            problem.set_point_targets(t, ramp)

    @property
    def bc_values(self) -> np.ndarray:
        """Values of the constrained DOFs, body after body (a copy)."""
        return np.concatenate([p.bc_values for p in self.problems])

    @bc_values.setter
    def bc_values(self, values: np.ndarray) -> None:
        values = np.asarray(values, dtype=float)
        if values.shape != (self._bc_counts[-1],):
            raise ValueError(f"the bodies have {self._bc_counts[-1]} constrained DOFs, got values of shape "
                             f"{values.shape}")  # fmt: skip
        for k, problem in enumerate(self.problems):
            problem.bc_values = values[self._bc_counts[k]:self._bc_counts[k + 1]].copy()

    def _split(self, x: PETSc.Vec) -> None:
        """Copy stacked ``x`` into the bodies' vectors."""
        values = x.array_r
        for body, vector in enumerate(self._x):
            vector.array[:] = values[self.closed.local_slice(body)]

    def update_state(self, x: PETSc.Vec) -> None:
        """Write stacked closed DOFs ``x`` into every body's position Function."""
        self._split(x)
        for problem, vector in zip(self.problems, self._x, strict=True):
            problem.update_state(vector)

    def state_to_vector(self, x: PETSc.Vec) -> None:
        """Copy every body's current position into stacked closed DOFs ``x``."""
        values = x.array
        for body, (problem, vector) in enumerate(zip(self.problems, self._x, strict=True)):
            problem.state_to_vector(vector)
            values[self.closed.local_slice(body)] = vector.array_r

    def contribution_state(self) -> ContributionState:
        """What the coupling contributions see: every body's open blocks, side by side."""
        positions = np.concatenate([p.model.open_positions for p in self.problems])
        return ContributionState(positions, float(self.problems[0].model.load_factor.value), self.point_positions)

    def point_positions(self, bases: Sequence[PointBasis]) -> np.ndarray:
        """Collective: positions ``(points, 3)`` of material points given by :meth:`point_basis`."""
        positions = np.concatenate([p.model.open_positions for p in self.problems])
        local = np.zeros((len(bases), 3))
        for k, (rows, values) in enumerate(bases):
            if len(rows):
                local[k] = values @ positions[rows]
        return self.comm.allreduce(local)

    # -- assembly -------------------------------------------------------------------------------
    def assemble_residual(self, x: PETSc.Vec, f: PETSc.Vec) -> None:
        """Every body's residual at its offsets, the coupling gradients added to its open blocks
        before its constrained rows are replaced by ``x - x_bc``."""
        report, t0 = self.problems[0].report, time.perf_counter()
        before = report.assemble_residual_s  # the bodies add their own shares: the whole is timed here
        gradient = np.zeros((self.open_offsets[-1], 3))
        state = self.contribution_state()
        for contribution in self.contributions:
            contribution.add_gradient(state, gradient)
        self._split(x)
        values = f.array
        for body, problem in enumerate(self.problems):
            share = gradient[self.open_offsets[body]:self.open_offsets[body + 1]]

            def add_share(local: np.ndarray, share: np.ndarray = share) -> None:
                local += share

            problem.assemble_residual(self._x[body], self._f[body], add_share)
            values[self.closed.local_slice(body)] = self._f[body].array_r
        report.assemble_residual_s = before + time.perf_counter() - t0

    def assemble_jacobian(self, jac: PETSc.Mat) -> None:
        """Every body's closed Jacobian at its offsets plus the coupling blocks ``P^T H P``; constrained
        rows and columns the identity; then ``J + r |diag J|``. Coupling blocks beyond the Jacobian's
        pattern (contact between bodies) grow it (:attr:`on_pattern_growth` is called)."""
        report, t0 = self.problems[0].report, time.perf_counter()
        before = report.assemble_jacobian_s  # the bodies add their own shares: the whole is timed here
        jac.zeroEntries()
        for body, problem in enumerate(self.problems):
            problem.regularization = 0.0  # applied once, to the stacked matrix
            problem.assemble_jacobian(problem.jacobian)
            row_pointer, columns, values = self.body_csr(body)
            jac.setValuesIJV(row_pointer, columns, values, addv=PETSc.InsertMode.ADD,
                             rowmap=self._rows[body].astype(PETSc.IntType))  # fmt: skip
        coupled = None
        if self._coupling is not None:
            blocks = contribution_blocks(self.contributions, self._patterns, self.contribution_state())
            coupled = self._coupling.product(self._gathered(*blocks))
        # (every rank has a coupling or none: it is made collectively)
        grows = coupled is not None and self.comm.allreduce(not self._pattern_keys.holds(coupled), op=MPI.LOR)
        if coupled is not None and not grows:  # within the pattern: added with the bodies' entries
            self._add_rows(jac, coupled)
        jac.assemble()
        if grows:
            self._grow(jac, coupled)
        if self._coupling is not None:
            jac.zeroRowsColumns(self.bc_rows, diag=1.0)
        add_diagonal_regularization(jac, self.regularization)
        report.assemble_jacobian_s = before + time.perf_counter() - t0

    def _add_rows(self, jac: PETSc.Mat, coupled: scipy.sparse.csr_matrix) -> None:
        """Add ``coupled`` (this rank's rows) into ``jac`` where its pattern has room."""
        rows = np.arange(self._coupling.rows.start, self._coupling.rows.stop, dtype=PETSc.IntType)
        jac.setValuesIJV(coupled.indptr.astype(PETSc.IntType), coupled.indices.astype(PETSc.IntType), coupled.data,
                         addv=PETSc.InsertMode.ADD, rowmap=rows)  # fmt: skip

    def _grow(self, jac: PETSc.Mat, coupled: scipy.sparse.csr_matrix) -> None:
        """Collective: ``jac += coupled`` with the pattern of both (new nonzeros: a factorization must
        start again from its analysis)."""
        size = (self.closed.size_local, self.closed.size_global)
        addition = PETSc.Mat().createAIJ((size, size), bsize=3, comm=self.comm, csr=(
            coupled.indptr.astype(PETSc.IntType), coupled.indices.astype(PETSc.IntType), coupled.data))
        try:
            jac.axpy(1.0, addition, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        finally:
            addition.destroy()
        row_pointer, columns, _ = jac.getValuesCSR()
        self._pattern_keys = PatternKeys(row_pointer, columns, self.closed.size_global)
        if self.on_pattern_growth is not None:
            self.on_pattern_growth()

    def potential_energy(self) -> float:
        """Collective: every body's potential plus the coupling contributions' energies."""
        state = self.contribution_state()
        coupling = self.comm.allreduce(sum(c.energy(state) for c in self.contributions))
        return sum(p.potential_energy() for p in self.problems) + coupling

    def term_residual_norms(self) -> dict[str, float]:
        """Collective: the 2-norm of each body's terms' part of the residual (named ``"<body>: <term>"``)
        and of each coupling contribution's, on the free DOFs, at the current state."""
        norms = {f"{name}: {term}": norm for name, problem in zip(self.names, self.problems, strict=True)
                 for term, norm in problem.term_residual_norms().items()}  # fmt: skip
        state = self.contribution_state()
        for contribution in self.contributions:
            gradient = np.zeros((self.open_offsets[-1], 3))
            contribution.add_gradient(state, gradient)
            squares = 0.0
            for body, problem in enumerate(self.problems):
                share = gradient[self.open_offsets[body]:self.open_offsets[body + 1]]

                def fill(local: np.ndarray, share: np.ndarray = share) -> None:
                    local += share.ravel()

                squares += problem.open_gradient_norm(fill) ** 2
            norms[contribution.name] = float(np.sqrt(squares))
        return norms

    @property
    def has_step_bounds(self) -> bool:
        return any(p.has_step_bounds for p in self.problems) or any(
            isinstance(c, StepBounded) for c in self.contributions)  # fmt: skip

    def max_step(self, direction: PETSc.Vec) -> float:
        """Collective: the largest fraction of the stacked step every bounded contribution admits."""
        if not self.has_step_bounds:
            return 1.0
        return self.max_open_step(np.concatenate(self._direction_blocks(direction)))

    def _direction_blocks(self, direction: PETSc.Vec) -> list[np.ndarray]:
        """Collective: a stacked closed-DOF direction on every body's open blocks, ``(blocks, 3)`` each."""
        self._split(direction)
        return [np.asarray(p.open_direction_blocks(v)).reshape(-1, 3)
                for p, v in zip(self.problems, self._x, strict=True)]  # fmt: skip

    @property
    def has_step_tests(self) -> bool:
        return any(p.has_step_tests for p in self.problems) or bool(step_testers(self.contributions))

    def step_converged(self, direction: PETSc.Vec) -> bool:
        """Collective: whether every body's and coupling step test lets the solve end with the
        stacked step (False: none tests steps)."""
        if not self.has_step_tests:
            return False
        blocks = self._direction_blocks(direction)
        tested = [p.open_step_converged(b) for p, b in zip(self.problems, blocks, strict=True) if p.has_step_tests]
        if step_testers(self.contributions):
            tested.append(step_converged(self.contributions, self.contribution_state(), np.concatenate(blocks)))
        return all(tested)

    def max_open_step(self, direction: np.ndarray, swept_from: float | None = None) -> float:
        """Collective: :meth:`max_step` of a direction on every body's open blocks side by side (the
        rows of :meth:`contribution_state`), ``(blocks, 3)`` or flat; ``swept_from``: a guess within a
        time step, moving obstacles moving along."""
        blocks = np.asarray(direction, dtype=float).reshape(-1, 3)
        offsets = self.open_offsets
        fraction = min(1.0, *(p.max_open_step(blocks[offsets[b]:offsets[b + 1]], swept_from)
                              for b, p in enumerate(self.problems)))  # fmt: skip
        if any(isinstance(c, StepBounded) for c in self.contributions):
            fraction = min(fraction, step_bound(self.contributions, self.contribution_state(), blocks, swept_from))
        return fraction

    @property
    def moves_obstacles(self) -> bool:
        """Whether a body's or a coupling contribution's obstacles move during a time step."""
        return any(p.moves_obstacles for p in self.problems) or moving_obstacles(self.contributions)

    def place_obstacles_within_step(self, fraction: float) -> None:
        """Every body's and coupling contribution's moving obstacles where they are at ``fraction`` of the time step."""
        for problem in self.problems:
            problem.place_obstacles_within_step(fraction)
        place_obstacles_within_step(self.contributions, fraction)

    def carried_by_obstacles(self, since: float) -> tuple[np.ndarray, np.ndarray]:
        """Collective: every body's open blocks side by side that moving obstacles reach from the
        fraction ``since`` of the time step to its end ``(blocks,)``, and their displacement ``(blocks, 3)``."""
        own = [p.carried_by_obstacles(since) for p in self.problems]
        reached, displacement = (np.concatenate(parts) for parts in zip(*own, strict=True))
        shared, moved = carried_by_obstacles(self.contributions, self.contribution_state(), since)
        displacement[shared] = moved[shared]
        return reached | shared, displacement

    def acceleration_residual(self, prefix: str, direct: bool) -> BodiesAccelerationResidual:
        """``a_rms`` of stacked residuals: each body's mass solve under ``<prefix><body>_``."""
        return BodiesAccelerationResidual(
            [body.acceleration_residual(f"{prefix}{k}_", direct) for k, body in enumerate(self.problems)],
            [self.closed.local_slice(k) for k in range(len(self.problems))])  # fmt: skip

    def matrix_nonzeros(self) -> int:
        """Nonzeros of the stacked Jacobian."""
        return stored_entries(self.jacobian)

    def close(self) -> None:
        """Destroy the stacked objects and close every body's problem (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for obj in (*self._x, *self._f, self.jacobian):
            obj.destroy()
        for problem in self.problems:
            problem.close()


def _solid_kinds(models: Sequence[BodyModel]) -> tuple[str, ...]:
    """The Hessian kinds a solid's problem names: its shells' (a solid assembles the exact Hessian
    for ``"exact"``, the projected one for every other kind), or its own kind's."""
    for model in models:
        if isinstance(model, ShellModel):
            return tuple(model.jacobian_forms)
    kind = models[0].hessian
    return COMPOSED_HESSIANS.get(kind, (kind,))


def _body_problem(model: BodyModel, matrix_format: str, report: SolveReport, kinds: tuple[str, ...],
                  contributions: Sequence[Contribution] = ()) -> ShellProblem | SolidProblem:  # fmt: skip
    if isinstance(model, SolidModel):
        return SolidProblem(model, report, kinds, contributions)
    return ShellProblem(model, matrix_format, report, contributions)


def make_problem(
    models: Sequence[BodyModel], matrix_format: str, report: SolveReport, contributions: Sequence[Contribution] = (),
    shared: SharedDofs | None = None,
) -> ShellProblem | SolidProblem | StackedProblem | SharedDofProblem:
    """The problem a Newton driver solves: one model's (a shell's :class:`ShellProblem` with its
    Jacobian in ``matrix_format``, ``contributions`` on its open blocks; a solid's
    :class:`SolidProblem`), or several models' problems stacked (AIJ; ``contributions`` couple the
    bodies), on the unknowns that remain where bodies ``shared`` DOFs (:class:`SharedDofProblem`).

    Raises:
        ValueError: shared DOFs in a solve of one body."""
    kinds = _solid_kinds(models)
    if len(models) == 1 and shared is not None and len(shared):
        raise ValueError("shared DOFs join several bodies; the solve has one")
    if len(models) == 1:
        return _body_problem(models[0], matrix_format, report, kinds, contributions)
    if matrix_format != "aij":
        raise ValueError(f"several bodies are assembled into one AIJ matrix, not {matrix_format!r}")
    problems: list[ShellProblem | SolidProblem] = []
    try:
        for model in models:
            problems.append(_body_problem(model, "aij", report, kinds))
        stacked = StackedProblem(problems, contributions)
    except Exception:
        for problem in problems:
            problem.close()
        raise
    if shared is None or not len(shared):
        return stacked
    try:
        return SharedDofProblem(stacked, shared)
    except Exception:
        stacked.close()
        raise
