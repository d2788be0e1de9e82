"""The energy trust region (``hessian = "trust_region"``) on cotton: the shear job's first steps, whose
compressed cloth makes the exact Hessian indefinite at every iteration."""

from __future__ import annotations

import pytest
from helpers import REPO

from bhem_hpc.run import build_model, prescribed_motions
from bhem_hpc.scene.loader import load_scene
from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.dynamics import StepFailure, TimeStepper
from bhem_hpc.solver.energy_trust_region import MAX_ITERATIONS
from bhem_hpc.solver.petsc import SolverSetupError


def sheared_cotton(hessian: str, patches: int = 8):
    """The shear job (cotton, FBW membrane, quadratic bending) at ``patches`` x ``patches``."""
    return load_scene(REPO / "jobs" / "shear.toml", {"surface": {"patches": [patches, patches]},
                                                     "solver": {"hessian": hessian}})  # fmt: skip


def advance(comm, scene, steps: int, prefix: str):
    """The steps' records, the solver's counters, and the residual norm at the final state relative
    to its largest term's (membrane, bending, inertia, gravity), after ``steps`` time steps."""
    model = build_model(scene, comm)
    with ShellSolver(model, prefix=prefix, options=scene.petsc_options) as solver:
        stepper = TimeStepper(model, solver, prescribed_motions(scene), max_halvings=0)
        records = [stepper.advance() for _ in range(steps)]
        counters = solver.counters()
        problem = solver.problem
        problem.state_to_vector(solver.x)
        problem.update_state(solver.x)
        problem.assemble_residual(solver.x, solver.f)
        relative_residual = solver.f.norm() / max(problem.term_residual_norms().values())
    return records, counters, relative_residual


def test_the_energy_trust_region_steps_cotton_where_line_search_newton_fails(comm):
    """Three shear steps at 8 x 8 patches: each converges in the trust region (no failure, no
    fallback, no halving) within its iteration limit, on positive definite factorizations, to an
    equilibrium (residual 1e-7 of its largest term's). Line-search Newton with the exact, the
    adaptive or the projected Hessian fails the first of them (and its trust-region fallback too)."""
    records, counters, relative_residual = advance(comm, sheared_cotton("trust_region"), 3, "etr_")
    assert counters["trust_region_failures"] == 0 and counters["trust_region_solves"] == 0
    assert all(r.dt_halvings == 0 and r.regularized_retries == 0 for r in records)
    assert all(0 < r.newton_iterations < MAX_ITERATIONS for r in records)
    assert counters["negative_pivots"] == 0
    assert relative_residual < 1e-7
    for kind in ("exact", "adaptive", "projected"):
        with pytest.raises(StepFailure, match=r"time step 1 .* failed after 0 halvings"):
            advance(comm, sheared_cotton(kind), 1, f"etr_{kind}_")


@pytest.mark.parametrize("initial_radius", ["constant", "direction"])
def test_every_initial_radius_of_tao_starts_from_a_factored_preconditioner(comm, initial_radius):
    """TAO asks for the first Hessian of a solve at iteration 1 unless it initializes the radius by
    interpolation (at iteration 0): the preconditioner is factored at a solve's first Hessian whatever
    its iteration number, so the shear steps converge from either radius as from the default."""
    scene = sheared_cotton("trust_region", patches=4)
    scene.petsc_options["ntr_tao_ntr_init_type"] = initial_radius
    records, counters, relative_residual = advance(comm, scene, 2, f"etr_{initial_radius}_")
    assert counters["trust_region_failures"] == 0 and counters["trust_region_solves"] == 0
    assert all(r.dt_halvings == 0 and r.regularized_retries == 0 for r in records)
    assert all(0 < r.newton_iterations < MAX_ITERATIONS for r in records)
    assert relative_residual < 1e-7


@pytest.mark.parametrize("subproblem", ["gltr", "gmres"])
def test_a_subproblem_solver_other_than_steihaug_or_nash_is_refused_by_option_and_value(comm, subproblem):
    """PETSc 3.18's ntr with ``gltr`` aborts the process (free(): invalid pointer): the option is
    refused by name and value before the first solve."""
    scene = sheared_cotton("trust_region", patches=4)
    scene.petsc_options["ntr_tao_ntr_ksp_type"] = subproblem
    with pytest.raises(SolverSetupError, match=rf"option -etr_bad_ntr_tao_ntr_ksp_type = '{subproblem}': the trust "
                                               r"region's subproblem takes 'stcg' or 'nash'"):  # fmt: skip
        advance(comm, scene, 1, "etr_bad_")
