"""Incremental potential contact on collision meshes embedded in the bodies (ipc-toolkit): the
lattice, the barrier's gradient and Hessian in the bodies' entries against finite differences, its
positive semi-definite projection, distances, and the collision-free step bound."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import RUBBER, SHEET

from bhem_hpc.bodies.body import ShellBody
from bhem_hpc.contact.ipc import CollisionSurface, IpcContact, IpcError, collision_lattice
from bhem_hpc.run import build_model
from bhem_hpc.scene.loader import load_scene

#: The floor: two triangles of the plane z = 0 under the sheets, ``(vertices, triangles)``; their
#: shared edge passes under no lattice point (where the closest feature changes from face to edge).
FLOOR = (np.array([[-1.0, -0.7, 0.0], [1.3, -1.0, 0.0], [0.9, 1.1, 0.0], [-1.2, 0.8, 0.0]]),
         np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32))  # fmt: skip


def _body(comm, tmp_path, discretization: str, height: float, index: int = 0) -> ShellBody:
    """A rubber sheet of side 0.2 whose rest surface is the plane z = ``height``, slightly waved."""
    path = tmp_path / f"{discretization}-{index}.toml"
    if comm.rank == 0:
        text = SHEET.format(size=0.2, discretization=discretization, origin=[0.0, 0.0, 0.0],
                            time="dt = 0.01\nsteps = 1", rest="", **RUBBER)  # fmt: skip
        wave = f'height = "{height} + 2e-4 * sin(20.0 * xi1) * cos(15.0 * xi2)"'
        path.write_text(text.replace('discretization = "', wave + '\ndiscretization = "', 1))
    comm.Barrier()
    scene = load_scene(path)
    return ShellBody(discretization, index, scene, build_model(scene, comm))


def _positions(body: ShellBody, entries: np.ndarray) -> np.ndarray:
    """Which entries are positions (a translation moves them alone): Hermite's value entries
    (entry ``4 node + kind``, kind 0), every B-spline control point."""
    if body.scene.surface.discretization == "hermite":
        return np.arange(len(entries)) % 4 == 0
    return np.ones(len(entries), dtype=bool)


def _surface(body: ShellBody, cells: int) -> CollisionSurface:
    grid = body.model.rest_surface.grid
    parameters, triangles = collision_lattice(grid.xi1_range, grid.xi2_range, (cells, cells))
    return CollisionSurface(body.point_map(parameters), triangles)


def _contact(body: ShellBody, cells: int = 8, dhat: float = 2e-3, stiffness: float = 1e3):
    entries = body.entries(body.model.x.x.array)
    return IpcContact([_surface(body, cells)], [entries], [FLOOR], dhat, stiffness), entries


def test_the_lattice_covers_the_rectangle_and_closes_periodic_directions():
    parameters, triangles = collision_lattice((0.0, 2.0), (0.0, 1.0), (4, 3))
    assert parameters.shape == (5 * 4, 2) and triangles.shape == (2 * 4 * 3, 3)
    corners = parameters[triangles]
    edges1, edges2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    signed = 0.5 * (edges1[:, 0] * edges2[:, 1] - edges1[:, 1] * edges2[:, 0])
    assert np.all(signed > 0) and signed.sum() == pytest.approx(2.0, rel=1e-14)  # counter-clockwise, all of it
    # periodic in xi1: 4 lines of points, and every edge is shared by two triangles along xi1
    parameters, triangles = collision_lattice((0.0, 2.0), (0.0, 1.0), (4, 3), periodic=(True, False))
    assert parameters.shape == (4 * 4, 2) and triangles.shape == (24, 3) and triangles.max() == 15
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    on_open_edges = 2 * 4  # the lines xi2 = 0 and xi2 = 1 are the only boundary
    assert (counts == 1).sum() == on_open_edges and set(counts) == {1, 2}
    with pytest.raises(IpcError, match=r"cells per side must be in \[2, 2000\], got \(1, 3\)"):
        collision_lattice((0.0, 1.0), (0.0, 1.0), (1, 3))


@pytest.mark.parametrize("discretization", ["hermite", "bspline2"])
def test_the_barrier_gradient_and_hessian_in_the_entries_match_finite_differences(comm, shared_tmp_path, rng,
                                                                                  discretization):  # fmt: skip
    """A waved rubber sheet 1 mm above the floor, within dhat = 2 mm: the barrier is active at
    every lattice point; its gradient and Hessian with respect to the sheet's entries (through the
    point map) match central differences of energy and gradient."""
    body = _body(comm, shared_tmp_path, discretization, 1e-3)
    contact, entries = _contact(body)
    assert contact.energy(entries) > 0 and contact.min_distance(entries) <= 1.3e-3
    gradient = contact.gradient(entries)
    hessian = contact.hessian(entries, project=False)
    assert gradient.shape == entries.shape and hessian.shape == (entries.size, entries.size)
    for _ in range(3):
        direction = rng.normal(size=entries.shape) * 1e-4
        h = 1e-3
        numeric = (contact.energy(entries + h * direction) - contact.energy(entries - h * direction)) / (2 * h)
        assert numeric == pytest.approx(np.sum(gradient * direction), rel=1e-6)
        numeric = (contact.gradient(entries + h * direction) - contact.gradient(entries - h * direction)) / (2 * h)
        exact = (hessian @ direction.ravel()).reshape(-1, 3)
        assert np.abs(numeric - exact).max() <= 1e-5 * np.abs(exact).max()
    projected = contact.hessian(entries).toarray()
    assert np.allclose(projected, projected.T, atol=1e-9 * np.abs(projected).max())
    assert np.linalg.eigvalsh(projected).min() >= -1e-9 * np.abs(projected).max()


def test_the_barrier_sees_the_distance_and_is_blind_to_sliding(comm, shared_tmp_path):
    body = _body(comm, shared_tmp_path, "hermite", 1.5e-3)
    flat = IpcContact([_surface(body, 8)], [body.entries(body.model.x.x.array)], [FLOOR], 2e-3, 1e3)
    entries = body.entries(body.model.x.x.array)
    lowest = (flat.displacement_map @ entries)[: flat.num_body_vertices, 2].min()
    assert flat.min_distance(entries) == pytest.approx(lowest, rel=1e-9)
    slid = entries.copy()
    slid[_positions(body, entries)] += [0.05, -0.03, 0.0]
    assert flat.energy(slid) == pytest.approx(flat.energy(entries), rel=1e-9)  # the floor is a plane
    raised = entries.copy()
    raised[_positions(body, entries)] += [0.0, 0.0, 0.01]
    assert flat.energy(raised) == 0.0 and flat.min_distance(raised) == float("inf")


def test_the_step_bound_keeps_every_step_free_of_intersections(comm, shared_tmp_path):
    """Moving the waved sheet 1.5 mm above the floor down by 3 mm would cross it halfway: the bound
    stops the step before, with no intersection at the bound and one at the crossing."""
    body = _body(comm, shared_tmp_path, "bspline2", 1.5e-3)
    contact, entries = _contact(body)
    down = np.zeros_like(entries)
    down[_positions(body, entries)] = [0.0, 0.0, -3e-3]
    lowest = (contact.displacement_map @ entries)[: contact.num_body_vertices, 2].min()
    bound = contact.max_step(entries, down)
    assert 0.5 * lowest / 3e-3 < bound < lowest / 3e-3  # conservative, within a factor 2 of the crossing
    assert not contact.intersects(entries + bound * down)
    assert contact.intersects(entries + 0.5 * down)  # the waved sheet straddles the floor
    assert contact.max_step(entries, -down) == 1.0


def test_bad_barrier_settings_are_refused(comm, shared_tmp_path):
    body = _body(comm, shared_tmp_path, "hermite", 1e-2)
    with pytest.raises(IpcError, match=r"dhat must be a positive length, got -0.001"):
        _contact(body, dhat=-1e-3)
    with pytest.raises(IpcError, match=r"the barrier stiffness must be positive, got 0.0"):
        _contact(body, stiffness=0.0)


def test_the_chord_gap_of_a_cylinders_lattice_is_its_sagitta_and_falls_with_the_square_of_the_cells():
    """A cylinder of radius 0.1 (closed in its periodic direction) on n cells around: the surface
    bows at most R (1 - cos(pi / n)) from the lattice's flat triangles, and the gap measured at
    their centroids falls by four when n doubles (a parabola's chord height)."""
    from bhem_hpc.contact.ipc import chord_gap

    radius = 0.1

    def cylinder(theta: np.ndarray, z: np.ndarray) -> np.ndarray:
        return np.stack([radius * np.cos(theta), radius * np.sin(theta), z], axis=-1)

    gaps = []
    for around in (12, 24):
        parameters, triangles = collision_lattice((0.0, 2 * np.pi), (0.0, 0.3), (around, 3), periodic=(True, False))
        vertices = cylinder(parameters[:, 0], parameters[:, 1])
        gaps.append(chord_gap(cylinder, parameters, vertices, triangles, (2 * np.pi, None)))
        assert 0.5 * radius * (1 - np.cos(np.pi / around)) < gaps[-1] <= radius * (1 - np.cos(np.pi / around))
    assert gaps[1] / gaps[0] == pytest.approx(0.25, rel=0.05)


def test_a_solids_collision_grid_holds_every_knot():
    """Quadratic rational arcs meeting at double knots (a circle's quarter arcs): 6 cells over 4
    spans become 2 per span, the knots among the grid lines."""
    from types import SimpleNamespace

    from bhem_hpc.geometry.nurbs import knot_aligned_grid

    axis = SimpleNamespace(domain=(0.0, 2.0), knots=[0, 0, 0, 0.5, 0.5, 1, 1, 1.5, 1.5, 2, 2, 2])
    np.testing.assert_allclose(knot_aligned_grid(axis, 6), np.arange(9) / 8)
    np.testing.assert_allclose(knot_aligned_grid(axis, 2), [0.0, 0.25, 0.5, 0.75, 1.0])
