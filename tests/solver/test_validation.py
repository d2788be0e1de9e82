"""Validation against analytic references: Kirchhoff plates and the heavy cantilever master curve."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import Loads, ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.studies.cantilever import CANTILEVER_SIZE, cantilever_model
from bhem_hpc.studies.references import CLAMPED_SQUARE_PLATE, heavy_cantilever_tip, simply_supported_square_plate

PLATE = Material(young=1e6, poisson=0.3, thickness=0.01, density=1.0)
EDGES = ("xi1_min", "xi1_max", "xi2_min", "xi2_max")


def plate_centre_deflection(comm, patches: int, support: str, pressure: bool = False) -> float:
    """Centre deflection in units of q a^4 / D of a unit square plate, q small (w ~ 1e-6 h)."""
    rest = S.flat_rectangle(1.0, 1.0, patches, patches)
    make = bcs.clamp if support == "clamped" else None
    constraints = [make(bcs.edge_nodes(rest.grid, e)) if make else bcs.simply_supported(rest, e) for e in EDGES]
    q = 1e-6 * PLATE.bending_stiffness
    loads = Loads(pressure=-q) if pressure else Loads(gravity=(0.0, 0.0, -q / (PLATE.density * PLATE.thickness)))
    model = ShellModel(rest, PLATE, loads, constraints, comm=comm)
    with ShellSolver(model) as solver:
        solver.solve()
    w = -model.state_surface().evaluate(np.array(0.5), np.array(0.5)).x[2]
    return float(w * PLATE.bending_stiffness / q)


def test_simply_supported_plate_converges_at_fourth_order(comm):
    reference = simply_supported_square_plate()
    assert abs(reference - 0.00406235) < 5e-9  # the tabulated value
    errors = [abs(plate_centre_deflection(comm, n, "ss") / reference - 1) for n in (4, 8, 16)]
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(rates >= 3.5), (errors, rates)
    assert errors[-1] < 5e-6


def test_clamped_plate_matches_reference(comm):
    errors = [abs(plate_centre_deflection(comm, n, "clamped") / CLAMPED_SQUARE_PLATE - 1) for n in (4, 8, 16)]
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    # The reference has 6 digits (4e-6 relative), which bounds what the finest mesh can show.
    assert np.all(rates >= 2.0), (errors, rates)
    assert errors[-1] < 1e-5


def test_follower_pressure_equals_dead_load_in_small_deflection(comm):
    dead = plate_centre_deflection(comm, 6, "ss")
    follower = plate_centre_deflection(comm, 6, "ss", pressure=True)
    assert abs(follower / dead - 1) < 1e-6


@pytest.mark.parametrize(("gamma", "load_steps"), [(0.5, 1), (5.0, 3), (50.0, 8), (300.0, 15)])
def test_cantilever_master_curve(comm, gamma, load_steps):
    """Strip under self-weight vs the heavy elastica (Romero et al. 2021; paper Fig. 19), nu = 0."""
    length, width = CANTILEVER_SIZE
    model = cantilever_model(gamma, 32, comm=comm)
    with ShellSolver(model) as solver:
        solver.solve(load_steps)
    tip = model.state_surface().evaluate(np.array(length), np.array(width / 2)).x
    ref_width, ref_height = heavy_cantilever_tip(gamma)
    assert abs(tip[0] / length / ref_width - 1) < 0.01
    assert abs(-tip[2] / length / ref_height - 1) < 0.01
    assert abs((-tip[2] / tip[0]) / (ref_height / ref_width) - 1) < 0.01  # the master curve's H/W
