"""Stability suite: hard cases must stay finite, converge and not gain energy.

Every case asserts: no NaN/Inf, every step converged (after at most the recoveries it records),
total energy (kinetic + elastic + gravity) never grows by more than a stated tolerance when no
external work is done, no penetration when contact is on. The suite runs serially and under
``mpirun -n 2`` (the test command runs both); the fast cases are in the default suite, the long
ones behind the ``stress`` marker (``make stress``).
"""

from __future__ import annotations

import numpy as np
import pytest
from stability_cases import (
    CASES,
    STRESS_AGREEMENT,
    STRESS_CASES,
    final_positions,
    incompressible_case,
    plane_drop_case,
    random_velocities_case,
    serial_reference,
    stiff_metal_case,
    thin_case,
)


def test_stiff_thin_metal_with_a_large_time_step(comm):
    stepper, _, _ = stiff_metal_case(comm)
    assert sum(r.dt_halvings for r in stepper.history) <= 25


def test_incompressible_poisson_ratio(comm):
    incompressible_case(comm)


def test_near_zero_bending_stiffness(comm):
    thin_case(comm)


def test_random_large_initial_velocities(comm):
    _, energies, _ = random_velocities_case(comm)
    assert energies[-1] < energies[0]


def test_contact_drop_on_a_plane_stays_stable(comm):
    _, _, model = plane_drop_case(comm)
    assert model.state_surface().nodal[..., 0, 2].min() >= 0.0


@pytest.mark.parallel
@pytest.mark.parametrize("name", sorted(CASES))
def test_two_ranks_give_the_serial_numbers(comm, shared_tmp_path, name):
    """Each case in this process (2 ranks under mpirun) against a serial run in a fresh process."""
    serial = serial_reference(name, "SERIAL_POSITIONS", comm, None, shared_tmp_path)
    here_result = final_positions(name, comm)
    np.testing.assert_allclose(here_result, serial, atol=1e-8)


@pytest.mark.stress
@pytest.mark.parametrize("name", list(STRESS_CASES))
def test_stress_case(comm, serial_results, shared_tmp_path, name):
    """Each stress case passes its own checks; serially it saves its final positions (with
    ``--serial-results DIR``), on 2 ranks they must equal the serial run's."""
    positions = STRESS_CASES[name](comm)
    assert np.all(np.isfinite(positions))
    if comm.size == 1:
        if serial_results is not None and comm.rank == 0:
            serial_results.mkdir(parents=True, exist_ok=True)
            np.save(serial_results / f"{name}.npy", positions)
        return
    serial = serial_reference(name, "STRESS_CASES", comm, serial_results, shared_tmp_path)
    distance = float(np.linalg.norm(positions - serial, axis=-1).max())
    print(f"{name}: {comm.size} ranks vs serial: largest nodal distance {distance:.3e} m")
    assert distance <= STRESS_AGREEMENT[name], distance
