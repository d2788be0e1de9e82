"""The exact Hessian applied matrix-free (:mod:`bhem_hpc.solver.hessian_action`) against the assembled
exact Jacobian, on the shear job's cotton crumpled at random (compressed: the exact Hessian is
indefinite), with a point constraint (a contribution's Hessian blocks) and held edges (identity rows)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import REPO

from bhem_hpc.run import build_model
from bhem_hpc.scene.loader import load_scene
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.hessian_action import ExactHessianAction


@pytest.mark.parametrize("discretization, patches", [("hermite", 4), ("bspline2", 6)])
def test_the_matrix_free_exact_hessian_is_the_assembled_one(comm, shared_tmp_path, discretization, patches):
    path = shared_tmp_path / f"shear-{discretization}.toml"
    if comm.rank == 0:
        path.write_text((REPO / "jobs" / "shear.toml").read_text() + "\n[[point_constraints]]\nat = [0.37, 0.61]\n")
    comm.Barrier()
    scene = load_scene(path, {"surface": {"patches": [patches, patches], "discretization": discretization}})
    model = build_model(scene, comm)
    with ShellSolver(model, prefix=f"hact_{discretization}_", options=scene.petsc_options) as solver:
        problem = solver.problem
        rng = np.random.default_rng(11)  # the same global vectors on any number of ranks
        owned = slice(solver.x.getOwnershipRange()[0], solver.x.getOwnershipRange()[1])
        problem.state_to_vector(solver.x)
        solver.x.array[:] += 2e-3 * rng.standard_normal(solver.x.getSize())[owned]
        problem.update_state(solver.x)
        problem.hessian = "exact"
        problem.assemble_jacobian(solver.jacobian)
        direction, assembled, matrix_free = solver.x.duplicate(), solver.x.duplicate(), solver.x.duplicate()
        direction.array[:] = rng.standard_normal(solver.x.getSize())[owned]
        solver.jacobian.mult(direction, assembled)
        with ExactHessianAction(problem) as action:
            action.set_iterate()
            at_iterate = model.x.x.array.copy()
            model.x.x.array[:] += 1e-3  # a trial point evaluated after the iterate: the product stays at the iterate
            action.matrix.mult(direction, matrix_free)
            np.testing.assert_array_equal(model.x.x.array, at_iterate)
        assert len(problem.bc_local) > 0 and len(problem.contributions[1].targets) == 1
        difference = matrix_free.copy()
        difference.axpy(-1.0, assembled)
        assert difference.norm() <= 1e-10 * assembled.norm()
        assert assembled.norm() > 0
