"""Several bodies as one problem: the stacked layout is a bijection that keeps each body's numbering,
two bodies stacked give their own residuals, Jacobians and energies, and a spring between material
points of two bodies (a contribution from outside the library) has consistent energy, gradient and
Hessian and is solved by an unmodified PETSc Newton."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import CLAMPED, RUBBER, SHEET, STEEL, GrowingTwoBodySpring, TwoBodySpring, gather, gather_matrix
from petsc4py import PETSc

from bhem_hpc.bodies.layout import StackedLayout
from bhem_hpc.bodies.petsc import StackedProblem
from bhem_hpc.run import build_model
from bhem_hpc.scene.loader import load_scene
from bhem_hpc.solver.problem import ShellProblem, stored_entries
from bhem_hpc.solver.report import SolveReport

SIZE = 0.2


@pytest.mark.parametrize("seed", range(6))
def test_the_stacked_layout_is_a_bijection_that_keeps_each_bodys_numbering(seed):
    rng = np.random.default_rng(seed)
    ranks, bodies = int(rng.integers(1, 5)), int(rng.integers(1, 5))
    owned = rng.integers(0, 7, size=(ranks, bodies))
    layouts = [StackedLayout(owned, r) for r in range(ranks)]
    total = int(owned.sum())
    seen = []
    for b in range(bodies):
        indices = np.arange(layouts[0].body_size_global(b))
        stacked = layouts[0].to_stacked(b, indices)
        body, back = layouts[0].to_body(stacked)
        assert (body == b).all() and (back == indices).all()
        seen.append(stacked)
        for r, layout in enumerate(layouts):  # a body's owned entries are one slice of the rank's range
            mine = indices[layout.body_start[b, r]:layout.body_start[b, r + 1]]
            piece = layout.local_slice(b)
            assert (layout.to_stacked(b, mine) == layout.rank_start[r] + np.arange(piece.start, piece.stop)).all()
    assert np.array_equal(np.sort(np.concatenate(seen)), np.arange(total))
    for layout in layouts:
        sizes = [layout.local_slice(b).stop - layout.local_slice(b).start for b in range(bodies)]
        assert sum(sizes) == layout.size_local and layout.size_global == total
    with pytest.raises(IndexError, match="indices span"):
        layouts[0].to_stacked(0, [layouts[0].body_size_global(0)])
    with pytest.raises(ValueError, match="counts >= 0"):
        StackedLayout([[1, -1]], 0)
    with pytest.raises(ValueError, match="rank 3 is not one of"):
        StackedLayout([[1, 2]], 3)


def _models(comm, tmp_path, point_loads=((), ()), upper=RUBBER):
    """A steel Hermite sheet and a quadratic B-spline sheet of ``upper`` 5 cm above it."""
    models = []
    for k, (discretization, material, z) in enumerate((("hermite", STEEL, 0.0), ("bspline2", upper, 0.05))):
        path = tmp_path / f"body{k}.toml"
        text = SHEET.format(size=SIZE, discretization=discretization, origin=[0.0, 0.0, z], time="static = true",
                            rest=CLAMPED, **material)  # fmt: skip
        if point_loads[k]:
            loads = ", ".join(f"{{ at = [{a}, {b}], force = [{fx!r}, {fy!r}, {fz!r}] }}"
                              for (a, b), (fx, fy, fz) in point_loads[k])  # fmt: skip
            text = text.replace("[effects]", f"[effects]\npoint_loads = [{loads}]")
        if comm.rank == 0:
            path.write_text(text)
        comm.Barrier()
        models.append(build_model(load_scene(path), comm))
    return models


def _stacked(models):
    return StackedProblem([ShellProblem(m, "aij", SolveReport()) for m in models])


def test_two_bodies_stacked_give_their_own_residuals_jacobians_and_energies(comm, shared_tmp_path):
    models = _models(comm, shared_tmp_path)
    alone = [ShellProblem(m, "aij", SolveReport()) for m in models]
    with _stacked(models) as stacked:
        x, f = stacked.create_vector(), stacked.create_vector()
        stacked.state_to_vector(x)
        x.array[:] += 1e-4 * np.random.default_rng(comm.rank).standard_normal(x.array.shape)
        stacked.update_state(x)
        stacked.assemble_residual(x, f)
        stacked.assemble_jacobian(stacked.jacobian)
        residual, jacobian = gather(f), gather_matrix(stacked.jacobian)
        expected_energy, parts, blocks = 0.0, [], []
        for body, problem in enumerate(alone):
            disc = problem.model.discretization
            xb = PETSc.Vec().createMPI((3 * disc.num_owned_closed, 3 * disc.num_closed), comm=comm)
            xb.array[:] = x.array_r[stacked.closed.local_slice(body)]
            problem.update_state(xb)
            fb = xb.duplicate()
            problem.assemble_residual(xb, fb)
            problem.assemble_jacobian(problem.jacobian)
            parts.append(gather(fb))
            blocks.append(gather_matrix(problem.jacobian))
            expected_energy += problem.potential_energy()
            for v in (xb, fb):
                v.destroy()
        energy = stacked.potential_energy()
        # stacked order: rank by rank, body by body; each body's own numbering within
        rows = [stacked.closed.to_stacked(b, np.arange(len(parts[b]))) for b in range(2)]
        for b in range(2):
            np.testing.assert_array_equal(residual[rows[b]], parts[b])
            np.testing.assert_array_equal(jacobian[np.ix_(rows[b], rows[b])], blocks[b])
        assert np.abs(jacobian[np.ix_(rows[0], rows[1])]).max() == 0.0
        assert energy == pytest.approx(expected_energy, rel=1e-14)
        assert stacked.matrix_nonzeros() == sum(int(p.jacobian.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"])
                                                 for p in alone)  # fmt: skip
        for v in (x, f):
            v.destroy()
    for problem in alone:
        problem.close()


def test_a_spring_between_two_bodies_has_consistent_energy_gradient_and_hessian(comm, shared_tmp_path):
    models = _models(comm, shared_tmp_path)
    stacked = _stacked(models)
    spring = TwoBodySpring(stacked, (SIZE, SIZE), (0.8 * SIZE, 0.5 * SIZE), 5e3, 0.01)
    stacked.add_contributions([spring])
    stacked.hessian = "exact"
    x = stacked.create_vector()
    stacked.state_to_vector(x)
    rng = np.random.default_rng(11 + comm.rank)
    x.array[:] += 1e-4 * SIZE * rng.standard_normal(x.array.shape)
    dx = x.duplicate()
    dx.array[:] = rng.standard_normal(x.array.shape)
    dx.array[stacked.bc_local] = 0.0

    def at(t, f=None):
        y = x.copy()
        y.axpy(t, dx)
        stacked.update_state(y)
        if f is not None:
            stacked.assemble_residual(y, f)
        y.destroy()
        return stacked.potential_energy()

    f, f_plus, f_minus, product = (x.duplicate() for _ in range(4))
    h = 1e-7
    slope = (at(h) - at(-h)) / (2 * h)
    at(0.0, f)
    stacked.assemble_jacobian(stacked.jacobian)
    assert abs(f.dot(dx) - slope) <= 1e-6 * abs(slope)
    at(h, f_plus)
    at(-h, f_minus)
    difference = (f_plus - f_minus) / (2 * h)
    stacked.jacobian.mult(dx, product)
    for v in (product, difference):
        v.array[stacked.bc_local] = 0.0
    assert (product - difference).norm() <= 1e-5 * difference.norm()
    # the spring couples the bodies: nonzero blocks between them
    rows = [stacked.closed.to_stacked(b, np.arange(3 * m.discretization.num_closed)) for b, m in enumerate(models)]
    assert np.abs(gather_matrix(stacked.jacobian)[np.ix_(rows[0], rows[1])]).max() > 0.1 * spring.k
    for v in (x, dx, f, f_plus, f_minus, product, difference):
        v.destroy()
    stacked.close()


def _newton(comm, prefix, problem, jacobian, x, f) -> None:
    """PETSc's plain Newton (MUMPS LU) on a problem's public callbacks, from ``x``; asserts it converged.
    Plain: the residual norm rises on the way, where a backtracking line search on it stalls."""
    options = PETSc.Options()
    options.setValue(f"{prefix}snes_linesearch_type", "basic")
    snes = PETSc.SNES().create(comm)
    snes.setOptionsPrefix(prefix)

    def residual(snes, y, g):
        problem.update_state(y)
        problem.assemble_residual(y, g)

    def tangent(snes, y, jac, pmat):
        problem.update_state(y)
        problem.assemble_jacobian(jac)

    snes.setFunction(residual, f)
    snes.setJacobian(tangent, jacobian, jacobian)
    snes.setTolerances(rtol=1e-12, atol=1e-6, max_it=30)  # round-off of steel's residual: about 4e-8 N
    snes.getKSP().setType("preonly")
    snes.getKSP().getPC().setType("lu")
    snes.getKSP().getPC().setFactorSolverType("mumps")
    snes.setFromOptions()
    options.delValue(f"{prefix}snes_linesearch_type")
    snes.solve(None, x)
    reason = snes.getConvergedReason()
    snes.destroy()
    assert reason > 0, reason


def test_an_unmodified_petsc_newton_solves_two_sprung_bodies_as_their_spring_forces_would(comm, shared_tmp_path):
    """PETSc SNES on the stacked problem's callbacks: two steel sheets (Hermite and quadratic
    B-splines) under gravity pulled together by the spring; their equilibrium is each sheet's
    equilibrium under the spring's end forces as point loads."""
    p, q = (SIZE, SIZE), (0.8 * SIZE, 0.5 * SIZE)
    models = _models(comm, shared_tmp_path, upper=STEEL)
    stacked = _stacked(models)
    spring = TwoBodySpring(stacked, p, q, 2e2, 0.01)
    stacked.add_contributions([spring])
    stacked.hessian = "exact"
    x, f = stacked.create_vector(), stacked.create_vector()
    stacked.state_to_vector(x)
    _newton(comm, "two_bodies_", stacked, stacked.jacobian, x, f)
    stacked.update_state(x)
    force = spring.force(stacked.contribution_state())
    assert np.linalg.norm(force) > 0.05  # the spring pulls (N), against gravity and the sheets' stiffness
    sprung = [m.x.x.array.copy() for m in models]
    for v in (x, f):
        v.destroy()
    stacked.close()
    loaded = _models(comm, shared_tmp_path, (((p, tuple(-force)),), ((q, tuple(force)),)), upper=STEEL)
    for model, expected in zip(loaded, sprung, strict=True):
        with ShellProblem(model, "aij", SolveReport()) as problem:
            xb = PETSc.Vec().createMPI((3 * model.discretization.num_owned_closed, 3 * model.discretization.num_closed),
                                       comm=comm)  # fmt: skip
            problem.state_to_vector(xb)
            start = model.x.x.array.copy()
            fb = xb.duplicate()
            _newton(comm, "one_body_", problem, problem.jacobian, xb, fb)
            problem.update_state(xb)
            assert np.abs(model.x.x.array - expected).max() <= 1e-6 * np.abs(expected - start).max()
            xb.destroy()
            fb.destroy()


def test_bad_bodies_and_contributions_are_refused_by_name(comm, shared_tmp_path):
    models = _models(comm, shared_tmp_path)
    with pytest.raises(ValueError, match="at least one body"):
        StackedProblem([])
    with ShellProblem(models[0], "baij", SolveReport()) as blocked, pytest.raises(ValueError, match="body 0: .*'baij'"):
        StackedProblem([blocked])
    with _stacked(models) as stacked:
        with pytest.raises(TypeError, match="is not an energy contribution"):
            stacked.add_contributions([object()])
        with pytest.raises(ValueError, match=r"constrained DOFs, got values of shape \(3,\)"):
            stacked.bc_values = np.zeros(3)
        values = stacked.bc_values
        stacked.bc_values = values + 1.0  # split back to the bodies in order
        assert np.array_equal(np.concatenate([p.bc_values for p in stacked.problems]), values + 1.0)


def test_coupling_blocks_beyond_a_pattern_grow_the_stacked_jacobian_to_the_full_one(comm, shared_tmp_path):
    """A spring between the two bodies whose pattern holds only each point's own blocks (as contact
    between bodies has it): the stacked Jacobian grows to take the coupling (the growth reported
    once) and equals, at three assemblies in a row, the one of the spring with its whole pattern."""
    jacobians = {}
    for kind in (TwoBodySpring, GrowingTwoBodySpring):
        stacked = _stacked(_models(comm, shared_tmp_path))
        stacked.add_contributions([kind(stacked, (SIZE, SIZE), (0.8 * SIZE, 0.5 * SIZE), 5e3, 0.01)])
        growths = []
        stacked.on_pattern_growth = lambda growths=growths: growths.append(1)
        stored = stored_entries(stacked.jacobian)
        for _ in range(3):
            stacked.assemble_jacobian(stacked.jacobian)
            jacobians.setdefault(kind.__name__, []).append(gather_matrix(stacked.jacobian))
        grown = stored_entries(stacked.jacobian) - stored
        assert (grown > 0, len(growths)) == ((True, 1) if kind is GrowingTwoBodySpring else (False, 0))
        stacked.close()
    scale = np.abs(jacobians["TwoBodySpring"][0]).max()
    for fixed, growing in zip(jacobians["TwoBodySpring"], jacobians["GrowingTwoBodySpring"], strict=True):
        np.testing.assert_allclose(growing, fixed, rtol=0, atol=1e-12 * scale)
