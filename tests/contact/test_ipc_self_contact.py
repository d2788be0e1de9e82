"""Self-contact by incremental potential contact: the barrier between a shell's collision mesh and
itself, and the diagonal compensation of Hessian blocks beyond a fixed pattern (which keeps it
positive semi-definite)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import hairpin_model

from bhem_hpc.contact.ipc_setup import shell_barrier
from bhem_hpc.solver.contributions import ContributionState, diagonal_compensation


def _barrier(model, self_contact: bool = True, cells: int = 2, dhat: float | None = None,
             stiffness: float | None = None):  # fmt: skip
    return shell_barrier(model, [], dhat, stiffness, cells, 200.0, 1e-3, self_contact=self_contact)


def test_diagonal_compensation_keeps_a_band_restricted_matrix_positive_semi_definite(rng):
    """A random PSD matrix on 6 blocks cut to a band (blocks i, j with |i - j| <= 1, as vertices of
    neighbouring triangles): with the blocks outside the band simply dropped it is indefinite (for
    this seed); with them replaced by their diagonal compensation it is PSD."""
    blocks = 6
    band = [(i, j) for i in range(blocks) for j in range(blocks) if abs(i - j) <= 1]
    outside = np.array([(i, j) for i in range(blocks) for j in range(blocks) if abs(i - j) > 1]).T
    factor = rng.standard_normal((3 * blocks, 4))
    full = factor @ factor.T  # PSD of rank 4: strong couplings between every pair of blocks

    def block(i: int, j: int) -> np.ndarray:
        return full[3 * i:3 * i + 3, 3 * j:3 * j + 3]

    dropped = np.zeros_like(full)
    for i, j in band:
        dropped[3 * i:3 * i + 3, 3 * j:3 * j + 3] = block(i, j)
    assert np.linalg.eigvalsh(dropped).min() < -1e-2 * np.abs(full).max()
    rows, columns, values = diagonal_compensation(outside[0], outside[1], [block(i, j) for i, j in outside.T])
    np.testing.assert_array_equal(rows, columns)
    compensated = dropped.copy()
    for i, value in zip(rows, values, strict=True):
        compensated[3 * i:3 * i + 3, 3 * i:3 * i + 3] += value
    assert np.linalg.eigvalsh(compensated).min() >= -1e-12 * np.abs(full).max()


def test_without_self_contact_the_shell_does_not_meet_itself(comm):
    """The hairpin squeezed until its arms are 0.1 mm apart: with self-contact the barrier is
    active, without it the shell's own pairs are filtered out (no obstacle: nothing to meet)."""
    model, _ = hairpin_model(comm, "hermite", 24)
    positions = model.x.x.array.reshape(-1, 3).copy()
    positions[:, 2] *= 0.1e-3 / 0.03  # the arms from 3 cm to 0.1 mm apart
    state = ContributionState(positions, 1.0, np.zeros((0, 3)))
    assert comm.allreduce(_barrier(model).energy(state)) > 0
    assert comm.allreduce(_barrier(model, self_contact=False).energy(state)) == 0.0


def test_the_hairpin_arms_meet_without_intersecting_and_keep_the_momentum(comm):
    """The arms (3 cm apart, 2 m/s closing speed; Hermite patches, a collision lattice of 2 x 2
    cells per patch) meet in the eighth step and bounce, every step converging without recovery.
    Every accepted state's collision mesh is free of intersections and within dhat of itself where
    they meet; the exact surface's arms dip past each other between lattice points by less than
    1 mm (measured 0.67 mm: the lattice's 11 mm chords cut the impact's bending waves; 4 x 4 cells
    halve that, at tens of Newton iterations more); the momentum is that of the start (the
    barrier's forces are internal); the arms' couplings lie beyond the fixed pattern (they grow the
    Jacobian's). The solve as contact by 'ipc' runs it: fresh factorizations, the acceleration
    test, and up to 100 Newton iterations per attempt."""
    import ipctk
    from helpers import momentum

    from bhem_hpc.solver import ShellSolver
    from bhem_hpc.solver.dynamics import TimeStepper

    model, (arm, length, width) = hairpin_model(comm, "hermite", 24)
    barrier = _barrier(model, cells=2)
    before = momentum(model)
    u, v = np.linspace(0.0, 0.95 * arm, 60), np.linspace(0.0, width, 9)
    separations, beyond, distances = [], [], []
    with ShellSolver(model, prefix="ipc_hairpin_", contributions=[barrier], factorization="fresh",
                     acceleration_tolerance=1e-2, options={"snes_max_it": 100}) as solver:  # fmt: skip
        stepper = TimeStepper(model, solver)
        for _ in range(14):  # they meet in the eighth step and part in the thirteenth
            stepper.advance()
            positions = model.x.x.array.reshape(-1, 3)
            assert not ipctk.has_intersections(barrier.mesh, barrier._vertices(positions))
            distances.append(barrier.min_distance(positions))
            beyond.append(len(barrier.hessian_beyond_pattern()[0]))
            surface = model.state_surface()
            upper = surface.evaluate(*np.meshgrid(u, v, indexing="ij")).x
            lower = surface.evaluate(*np.meshgrid(length - u, v, indexing="ij")).x
            separations.append((upper[..., 2] - lower[..., 2]).min())
        after = momentum(model)
    assert min(distances) < barrier.dhat  # they met
    assert min(separations) > -1e-3
    assert comm.allreduce(max(beyond)) > 0  # rank 0 assembles the Hessian
    assert sum(r.recoveries for r in stepper.history) == 0
    np.testing.assert_allclose(after, before, atol=1e-6 * np.abs(before).max())


@pytest.mark.parametrize("discretization", ["hermite", "bspline2"])
def test_a_translating_plane_carries_the_blocks_it_reaches_as_a_translation(comm, discretization):
    """A plane 0.4 mm off the hairpin's bend (x = its largest), moving into it at 1 m/s: a step of
    2 ms reaches every collision vertex within dhat plus its 2 mm travel; the carried blocks move
    each of those vertices by exactly the travel (Hermite values by it, their derivatives not at
    all: the weights solve ``B c = 1``), and the plane itself sits where it is at the step's end."""
    from bhem_hpc.collision.colliders import Plane

    model, _ = hairpin_model(comm, discretization, 12)
    positions = model.x.x.array.reshape(-1, 3).copy()
    state = ContributionState(positions, 1.0, np.zeros((0, 3)))
    probe = shell_barrier(model, [], 1e-3, 1.0, 2, 200.0, 1e-3)
    vertices = probe._vertices(positions)[: probe.num_points]
    front = vertices[:, 0].max() + 4e-4
    plane = Plane(np.array([front, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0]))
    barrier = shell_barrier(model, [plane], 1e-3, 1.0, 2, 200.0, 1e-3)
    barrier.begin_step(state, 0.0, 2e-3)
    reached, displacement = barrier.carried(state, 0.0)
    moved = barrier._vertices(positions + displacement)[: barrier.num_points] - vertices
    near = front - vertices[:, 0] < 1e-3 + 2e-3
    assert 0 < near.sum() < len(vertices) and comm.allreduce(int(reached.sum())) > 0
    np.testing.assert_allclose(moved[near], np.broadcast_to([-2e-3, 0.0, 0.0], moved[near].shape), atol=1e-12)
    assert np.all(np.abs(moved[~near]).max(axis=1) <= 2e-3 + 1e-12)
    np.testing.assert_allclose(-barrier.mesh.planes[0].offset(), -(front - 2e-3), rtol=1e-12)


def test_kept_candidates_give_the_pairs_and_energy_of_a_fresh_search(comm, rng):
    """The hairpin's collision mesh with its arms 1.5 mm apart (dhat 1 mm: no pair of the two arms
    within it): mesh states whose vertices move by random amounts up to the candidate margin in
    each coordinate (seeded) keep the candidates found at the first state, and give the pairs and
    barrier energy of a barrier that searches anew at each state (the arms come within 0.6 mm);
    a state moved beyond the margin searches anew."""
    import ipctk

    from bhem_hpc.contact.ipc_contribution import CANDIDATE_MARGIN

    model, _ = hairpin_model(comm, "hermite", 12)
    positions = model.x.x.array.reshape(-1, 3).copy()
    positions[:, 2] *= 1.5e-3 / 0.03
    kept = _barrier(model, dhat=1e-3, stiffness=1.0)
    start = kept._vertices(positions)
    kept._collisions(start)
    first = kept._candidates[1]
    margin = CANDIDATE_MARGIN * kept.dhat
    fresh, counts = _barrier(model, dhat=1e-3, stiffness=1.0), []
    for _ in range(4):
        moved = np.asfortranarray(start + comm.bcast(rng.uniform(-margin, margin, start.shape), root=0))
        pairs = kept._collisions(moved)
        assert kept._candidates[1] is first
        reference = ipctk.NormalCollisions()
        reference.build(fresh.mesh, moved, fresh.dhat)
        counts.append(len(pairs))
        assert len(pairs) == len(reference)
        np.testing.assert_allclose(kept.barrier(pairs, kept.mesh, moved), fresh.barrier(reference, fresh.mesh, moved),
                                   rtol=1e-12)  # fmt: skip
    assert min(counts) > 0
    kept._collisions(np.asfortranarray(start + np.array([0.0, 0.0, 1.01 * margin])))
    assert kept._candidates[1] is not first


def test_kept_vertices_follow_positions_changed_in_place(comm):
    """The barrier keeps the vertices of the last two block positions it was asked for: positions
    changed in place (the same array) give the vertices of their new values, and the two kept states
    give theirs again. B-spline control points: a shift of them all moves every point by it."""
    model, _ = hairpin_model(comm, "bspline2", 12)
    barrier = _barrier(model)
    positions = model.x.x.array.reshape(-1, 3).copy()
    first = barrier._vertices(positions)
    moved = positions + np.array([1e-3, -2e-3, 0.5e-3])
    second = barrier._vertices(moved)
    positions[:, 2] += 1e-3  # in place
    third = barrier._vertices(positions)
    np.testing.assert_allclose(third[:, 2] - first[:, 2], 1e-3, atol=1e-12)
    np.testing.assert_allclose(second - first, np.broadcast_to([1e-3, -2e-3, 0.5e-3], first.shape), atol=1e-12)
    np.testing.assert_array_equal(barrier._vertices(moved), second)
    np.testing.assert_array_equal(barrier._vertices(positions), third)


def test_a_motion_far_beyond_the_mesh_is_bounded_through_its_first_stretch(comm):
    """The hairpin's upper arm (1.5 mm above the lower) moved 20 diagonals down and sideways: the
    CCD sees no vertex move farther than CCD_REACH diagonals, the bound is its result scaled to the
    whole motion, the motion up to it is free of intersections, and it cuts the arm short of the
    other."""
    import types

    import ipctk

    from bhem_hpc.contact.ipc_contribution import CCD_REACH

    model, _ = hairpin_model(comm, "hermite", 12)
    positions = model.x.x.array.reshape(-1, 3).copy()
    positions[:, 2] *= 1.5e-3 / 0.03
    barrier = _barrier(model, cells=2)
    start = barrier._vertices(positions)
    far = 20.0 * barrier.diagonal
    arm = start[:, 2:3] > 0.7e-3  # the upper arm's points (the bend's stay)
    shift = np.where(arm, 1.0, 0.0) * np.array([0.3, 0.0, -1.0]) * far / np.hypot(0.3, 1.0)
    seen = []

    def stepsize(mesh, first, last, *args):
        seen.append((np.linalg.norm(last - first, axis=1).max(), ipctk.compute_collision_free_stepsize(
            mesh, first, last, *args)))  # fmt: skip
        return seen[-1][1]

    barrier._ipctk = types.SimpleNamespace(compute_collision_free_stepsize=stepsize)
    bound = barrier._collision_free_fraction(start, np.asfortranarray(start + shift))
    (move, stretch_bound), = seen
    assert move <= CCD_REACH * barrier.diagonal * (1.0 + 1e-12) and CCD_REACH < 1.0
    np.testing.assert_allclose(bound, move / far * stretch_bound, rtol=1e-12)
    assert 0.0 < bound < 1.5e-3 * np.hypot(0.3, 1.0) / far  # before the arm would reach the other
    assert ipctk.is_step_collision_free(barrier.mesh, start, np.asfortranarray(start + bound * shift))
