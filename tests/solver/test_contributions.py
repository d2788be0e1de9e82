"""Energy contributions from outside the library: a spring between two material points and a
barrier with a line-search bound, added to a solver without touching it."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import CouplingBeyondPattern, PointSpring, gather_matrix
from mpi4py import MPI
from petsc4py import PETSc

from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import Loads, PointLoad, ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.contributions import Contribution, ContributionState, StepBounded
from bhem_hpc.solver.problem import ShellProblem, stored_entries
from bhem_hpc.solver.report import SolveReport

STEEL = Material(young=2.1e11, poisson=0.3, thickness=1e-3, density=7850.0)  # sheet steel
SIZE = 0.2


def clamped_sheet(comm, loads: Loads | None = None, patches=6):
    rest = S.flat_rectangle(SIZE, SIZE, patches, patches)
    return ShellModel(rest, STEEL, loads or Loads(), [bcs.clamp(bcs.edge_nodes(rest.grid, "xi1_min"))], comm=comm)


def _gathered_point(model, xi):
    """A material point's basis on its owning rank, and its global blocks and values on every rank."""
    blocks, values = model.discretization.point_basis(*xi)
    shared = [part for part in model.comm.allgather((model.global_open_blocks[blocks], values)) if len(part[0])]
    return (blocks, values), shared[0]


class Spring(PointSpring):
    """The spring between two material points of one sheet."""

    name = "spring"

    def __init__(self, model, p, q, stiffness, rest_length):
        self.p, shared_p = _gathered_point(model, p)
        self.q, shared_q = _gathered_point(model, q)
        super().__init__(model.comm, (self.p, self.q), (shared_p, shared_q), stiffness, rest_length)


class Floor(Spring):
    """The log barrier ``-kappa log(z - z0)`` keeping a material point above the plane ``z = z0``,
    whose line-search bound keeps every trial state above it; it records the gaps it was asked for."""

    name = "floor"

    def __init__(self, model, p, kappa, z0):
        self.comm = model.comm
        self.kappa, self.z0 = kappa, z0
        self.p, (self.gp, self.vp) = _gathered_point(model, p)
        owned = len(self.p[0]) > 0
        count = len(self.gp)
        self._pattern = (np.repeat(self.gp, count), np.tile(self.gp, count)) if owned else (np.zeros(0, int),) * 2
        self.gaps = []

    def _gap(self, state):
        gap = float(state.point_positions([self.p])[0, 2]) - self.z0
        self.gaps.append(gap)
        return gap

    def energy(self, state):
        gap = self._gap(state)
        return (-self.kappa * np.log(gap) if gap > 0 else np.inf) if self.comm.rank == 0 else 0.0

    def add_gradient(self, state, gradient):
        blocks, values = self.p
        gradient[blocks, 2] += values * (-self.kappa / self._gap(state))

    def hessian(self, state):
        gap = self._gap(state)  # collective: every rank evaluates it
        if not len(self.p[0]):
            return np.zeros((0, 3, 3))
        ez = np.zeros((3, 3))
        ez[2, 2] = 1.0
        return (self.kappa / gap**2) * np.outer(self.vp, self.vp).ravel()[:, None, None] * ez


class BoundedFloor(Floor):
    def max_step(self, state, direction):
        blocks, values = self.p
        dz = self.comm.allreduce(float(values @ direction[blocks, 2]) if len(blocks) else 0.0)
        gap = self._gap(state)
        return 1.0 if dz >= 0 else min(1.0, 0.9 * gap / -dz)  # stop at a tenth of the gap, as IPC does


def test_the_protocols_recognize_the_contributions():
    assert isinstance(Spring.__new__(Spring), Contribution)
    assert not isinstance(Floor.__new__(Floor), StepBounded)
    assert isinstance(BoundedFloor.__new__(BoundedFloor), StepBounded)
    assert not isinstance(object(), Contribution)


def _problem_derivatives(model, spring):
    """The problem's potential, residual and Jacobian as functions of the closed DOFs."""
    problem = ShellProblem(model, "aij", SolveReport(), [spring])
    x = PETSc.Vec().createMPI((3 * model.discretization.num_owned_closed, 3 * model.discretization.num_closed),
                              comm=model.comm)  # fmt: skip
    problem.state_to_vector(x)
    return problem, x


def test_a_spring_between_two_points_has_consistent_energy_gradient_and_hessian(comm):
    model = clamped_sheet(comm)
    spring = Spring(model, (0.9 * SIZE, 0.1 * SIZE), (0.45 * SIZE, 0.95 * SIZE), 5e3, 0.1 * SIZE)
    problem, x = _problem_derivatives(model, spring)
    rng = np.random.default_rng(7)
    x.array[:] += 1e-3 * SIZE * rng.standard_normal(x.array.shape)  # away from the rest state (tension)
    f, dx, f_plus = x.duplicate(), x.duplicate(), x.duplicate()
    dx.array[:] = rng.standard_normal(x.array.shape)
    dx.array[problem.bc_local] = 0.0
    problem.update_state(x)
    problem.assemble_residual(x, f)
    problem.assemble_jacobian(problem.jacobian)

    def energy_along(t):
        y = x.copy()
        y.axpy(t, dx)
        problem.update_state(y)
        return problem.potential_energy()

    h = 1e-6
    slope = (energy_along(h) - energy_along(-h)) / (2 * h)
    assert abs(f.dot(dx) - slope) <= 1e-6 * abs(slope)
    # the Jacobian times dx against the residual's central difference
    y = x.copy()
    y.axpy(h, dx)
    problem.update_state(y)
    problem.assemble_residual(y, f_plus)
    y.axpy(-2 * h, dx)
    problem.update_state(y)
    f_minus = x.duplicate()
    problem.assemble_residual(y, f_minus)
    difference = (f_plus - f_minus) / (2 * h)
    product = x.duplicate()
    problem.jacobian.mult(dx, product)
    product.array[problem.bc_local] = 0.0
    difference.array[problem.bc_local] = 0.0
    assert (product - difference).norm() <= 1e-5 * difference.norm()
    # the spring's share of the residual is the term named after it
    problem.update_state(x)
    assert problem.term_residual_norms()["spring"] > 0
    problem.close()


def test_a_spring_pulls_as_the_point_loads_of_its_tension(comm):
    """The spring's equilibrium is the equilibrium under its own end forces as point loads: a
    compressed spring pushes two points of the free edge apart (stretching the edge between them)."""
    p, q, k, length = (SIZE, 0.2 * SIZE), (SIZE, 0.8 * SIZE), 1e5, 0.65 * SIZE
    model = clamped_sheet(comm)
    spring = Spring(model, p, q, k, length)
    rest = model.x.x.array.copy()
    with ShellSolver(model, contributions=[spring]) as solver:
        solver.solve(load_steps=2)
        assert solver.report.newton_iterations[-1] <= 8
    state = ContributionState(model.x.x.array.reshape(-1, 3), 1.0, model.point_positions)
    d = spring._d(state)
    force = k * (np.linalg.norm(d) - length) * d / np.linalg.norm(d)
    assert 0.6 * SIZE + 1e-6 < np.linalg.norm(d) < length  # pushed apart, held back by the sheet
    sprung = model.x.x.array.copy()
    loaded = clamped_sheet(comm, Loads(point_loads=(PointLoad(*p, tuple(-force)), PointLoad(*q, tuple(force)))))
    with ShellSolver(loaded) as solver:
        solver.solve(load_steps=2)
    assert np.abs(loaded.x.x.array - sprung).max() <= 1e-6 * np.abs(sprung - rest).max()


@pytest.mark.parametrize("bounded", [True, False])
def test_a_barrier_with_a_step_bound_is_never_crossed(comm, bounded):
    """A free corner of a clamped steel sheet sags under its weight onto a floor 0.4 mm below it (the
    free sag is about 0.8 mm): with the bound no trial state of the line search is below the floor."""
    model = clamped_sheet(comm, Loads(gravity=(0.0, 0.0, -9.81)))
    floor = (BoundedFloor if bounded else Floor)(model, (SIZE, SIZE), kappa=1e-5, z0=-4e-4)
    with ShellSolver(model, contributions=[floor]) as solver:
        solver.solve()
        bounded_steps = solver.report.bounded_steps
    gap = floor.gaps[-1]
    assert 0 < gap < 1e-4  # resting on the floor, held by the barrier
    if bounded:
        assert min(floor.gaps) > 0 and bounded_steps >= 1
    else:
        assert min(floor.gaps) <= 0  # a trial went through the floor (the energy rejected it)


class GrowingSpring(CouplingBeyondPattern, Spring):
    """The spring between two points of one sheet whose coupling blocks come beyond its pattern."""

    def __init__(self, model, p, q, stiffness, rest_length):
        super().__init__(model, p, q, stiffness, rest_length)
        self._split_pattern(_gathered_point(model, p)[1][0])


#: where a Jacobian's pattern grows (MPISBAIJ cannot zero constrained rows and columns: symmetric
#: storage is a serial format; a grown MPIBAIJ came out wrong)
GROWING = ("aij", "baij", "sbaij") if MPI.COMM_WORLD.size == 1 else ("aij",)


@pytest.mark.parametrize("matrix_format", GROWING)
def test_blocks_beyond_a_pattern_grow_the_jacobian_to_the_full_hessian(comm, matrix_format):
    """A stretched spring between two far corners of a clamped steel sheet whose pattern holds only
    each corner's own blocks: the Jacobian's pattern grows to take the coupling blocks (and keeps
    them), and at three assemblies in a row the Jacobian equals that of the spring with the whole
    pattern fixed (MPI's AIJ is then assembled in place: a conversion into a grown pattern loses
    entries there)."""
    from bhem_hpc.solver.contributions import GrowingPattern

    p, q = (0.02, 0.03), (0.19, 0.18)
    jacobians, grown = {}, []
    for kind in (Spring, GrowingSpring):
        model = clamped_sheet(comm)
        spring = kind(model, p, q, 1e6, 0.05)  # 0.05 m rest length: stretched
        problem = ShellProblem(model, matrix_format, SolveReport(), [spring])
        growths = []
        problem.on_pattern_growth = lambda growths=growths: growths.append(1)
        stored = stored_entries(problem.jacobian)
        for _ in range(3):
            problem.assemble_jacobian(problem.jacobian)
            full = PETSc.Mat()
            problem.jacobian.convert("aij", full)  # SBAIJ keeps one triangle
            jacobians.setdefault(kind.__name__, []).append(gather_matrix(full))
            full.destroy()
        if kind is GrowingSpring:
            assert isinstance(spring, GrowingPattern) and comm.allreduce(len(spring.hessian_beyond_pattern()[0])) > 0
            grown.append(stored_entries(problem.jacobian) - stored)
            assert not growths  # it grew at the first assembly, before any factorization, and no more
        problem.close()
    assert grown[0] > 0
    scale = np.abs(jacobians["Spring"][0]).max()
    for fixed, growing in zip(jacobians["Spring"], jacobians["GrowingSpring"], strict=True):
        np.testing.assert_allclose(growing, fixed, rtol=0, atol=1e-12 * scale)


@pytest.mark.parallel
def test_where_the_pattern_cannot_grow_the_blocks_go_onto_the_diagonal(comm):
    """MPIBAIJ (the Krylov path on several ranks) keeps its pattern: the spring's coupling blocks
    are replaced by their diagonal compensation, so the Jacobian differs from that of the spring
    with the whole pattern by a positive semi-definite matrix, and its pattern is as it was."""
    p, q = (0.02, 0.03), (0.19, 0.18)
    jacobians = {}
    for kind in (Spring, GrowingSpring):
        model = clamped_sheet(comm)
        problem = ShellProblem(model, "baij", SolveReport(), [kind(model, p, q, 1e6, 0.05)])
        stored = stored_entries(problem.jacobian)
        problem.assemble_jacobian(problem.jacobian)
        assert stored_entries(problem.jacobian) == stored
        jacobians[kind.__name__] = gather_matrix(problem.jacobian)
        problem.close()
    change = jacobians["GrowingSpring"] - jacobians["Spring"]
    scale = np.abs(jacobians["Spring"]).max()
    assert np.abs(change).max() > 1e-3 * 1e6  # the spring's coupling moved (k = 1e6 N/m)
    np.testing.assert_allclose(change, change.T, atol=1e-12 * scale)
    assert np.linalg.eigvalsh(change).min() >= -1e-12 * scale
