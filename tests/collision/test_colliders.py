"""Colliders: distances, times of impact (never late), mesh and patch-file validation, shipped files."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import REPO

from bhem_hpc.collision import Capsule, ColliderError, Cylinder, PatchModel, Plane, Sphere, TriangleMesh
from bhem_hpc.collision.colliders import icosphere

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank

MESHES = REPO / "meshes"


def _dense_first_contact(collider, start, end, dt, gap=0.0, samples=20001):
    """Reference: the first of many samples along the step where the distance reaches ``gap``."""
    out = np.full(len(start), np.inf)
    for s in np.linspace(0.0, 1.0, samples):
        d, _ = collider.signed_distance(start + s * (end - start), s * dt)
        newly = (d <= gap) & ~np.isfinite(out)
        out[newly] = s
    return out


@pytest.mark.parametrize(
    "collider",
    [
        Plane([0, 0, 0.1], [0.2, 0.1, 1.0], velocity=[0, 0, 0.3]),
        Sphere([0.1, -0.2, 0.0], 0.4, velocity=[0.2, 0.0, -0.1]),
        Capsule([0, 0, -0.5], [0.1, 0.0, 0.5], 0.15, velocity=[0.3, 0.0, 0.0]),
        Cylinder([0.1, 0.0, 0.0], [0.2, 1.0, 0.1], 0.3, velocity=[0.0, 0.0, 0.4]),
    ],
    ids=["plane", "sphere", "capsule", "cylinder"],
)
def test_time_of_impact_is_never_later_than_dense_sampling(rng, collider):
    start = rng.normal(size=(300, 3)) * 0.8
    end = start + rng.normal(size=(300, 3)) * 0.6
    dt = 0.5
    toi = collider.time_of_impact(start, end, dt)
    reference = _dense_first_contact(collider, start, end, dt)
    hit = np.isfinite(reference)
    assert hit.sum() >= 5 and (~hit).sum() >= 20
    assert np.all(np.isfinite(toi[hit]))
    assert np.all(toi[hit] <= reference[hit] + 1e-12)
    assert np.all(toi[hit] >= reference[hit] - 1.0 / 20000 - 1e-9)  # same contact, to the sampling step
    # where the reference sees no contact the TOI may only report a contact it can prove
    for k in np.flatnonzero(~hit & np.isfinite(toi)):
        d, _ = collider.signed_distance(start[k] + toi[k] * (end[k] - start[k]), toi[k] * dt)
        assert d[0] <= 1e-9


def test_signed_distances_and_normals():
    sphere = Sphere([0, 0, 0], 1.0)
    d, n = sphere.signed_distance(np.array([[2.0, 0, 0], [0, 0.5, 0]]))
    np.testing.assert_allclose(d, [1.0, -0.5])
    np.testing.assert_allclose(n, [[1, 0, 0], [0, 1, 0]])
    plane = Plane([0, 0, 1], [0, 0, 2])
    d, n = plane.signed_distance(np.array([[5.0, 3.0, 0.0]]), t=0.0)
    assert d[0] == -1.0 and np.allclose(n, [0, 0, 1])
    cylinder = Cylinder([0, 0, 0], [0, 0, 3], 0.5)
    d, n = cylinder.signed_distance(np.array([[1.0, 0, 7.0]]))
    assert d[0] == 0.5 and np.allclose(n, [[1, 0, 0]])
    capsule = Capsule([0, 0, 0], [0, 0, 1], 0.1)
    d, _ = capsule.signed_distance(np.array([[0.5, 0, 0.5], [0, 0, 1.3]]))
    np.testing.assert_allclose(d, [0.4, 0.2])


def test_shipped_obstacles_are_valid():
    dome = TriangleMesh.read(MESHES / "bumpy_dome.obj")
    edges = np.sort(
        np.concatenate([dome.triangles[:, [0, 1]], dome.triangles[:, [1, 2]], dome.triangles[:, [2, 0]]]), 1
    )
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)  # closed and manifold
    assert len(dome.vertices) - len(counts) + len(dome.triangles) == 2  # a sphere's Euler characteristic
    torus = PatchModel.load(MESHES / "torus_patches.npz")
    radial = np.linalg.norm(torus.samples()[:, :2], axis=1)
    tube = np.hypot(radial - 0.4, torus.samples()[:, 2])
    np.testing.assert_allclose(tube, 0.12, rtol=2e-3)


def test_bad_colliders_are_rejected(tmp_path):
    with pytest.raises(ColliderError, match="sphere radius must be a finite number > 0, got -1"):
        Sphere([0, 0, 0], -1)
    with pytest.raises(ColliderError, match="cylinder axis is zero"):
        Cylinder([0, 0, 0], [0, 0, 0], 1.0)
    with pytest.raises(ColliderError, match="plane normal is zero"):
        Plane([0, 0, 0], [0, 0, 0])
    with pytest.raises(ColliderError, match="empty"):
        TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    with pytest.raises(ColliderError, match=r"vertex 1 has NaN/Inf"):
        TriangleMesh(np.array([[0, 0, 0], [np.nan, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    fan = np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]])
    with pytest.raises(ColliderError, match="non-manifold"):
        TriangleMesh(np.random.default_rng(1).random((5, 3)), fan)
    with pytest.raises(ColliderError, match="zero-area control net"):
        PatchModel(np.zeros((1, 4, 4, 3)))
    np.savez(tmp_path / "bad.npz", format=np.array("something"), nets=np.zeros((1, 4, 4, 3)))
    with pytest.raises(ColliderError, match="key 'format' is 'something'"):
        PatchModel.load(tmp_path / "bad.npz")
    (tmp_path / "broken.obj").write_text("this is not a mesh")
    with pytest.raises(ColliderError, match="broken.obj"):
        TriangleMesh.read(tmp_path / "broken.obj")


@pytest.mark.parametrize("subdivisions", [0, 1, 3])
def test_the_icosphere_is_a_closed_outward_mesh_on_the_unit_sphere(subdivisions):
    vertices, triangles = icosphere(subdivisions)
    assert len(triangles) == 20 * 4**subdivisions and np.allclose(np.linalg.norm(vertices, axis=1), 1.0, atol=1e-15)
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2) and len(vertices) - len(unique) + len(triangles) == 2  # closed, genus 0
    corners = vertices[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert np.all(np.einsum("ij,ij->i", normals, corners.mean(axis=1)) > 0)  # outward


@pytest.mark.parametrize("sagitta", [1e-2, 1e-3, 2.5e-4])
def test_a_spheres_triangles_lie_within_the_sagitta_inside_it(sagitta):
    sphere = Sphere([0.1, -0.2, 0.3], 0.25)
    vertices, triangles = sphere.triangles(sagitta)
    corners = vertices[triangles] - sphere.center
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    depth = sphere.radius - np.einsum("ij,ij->i", normals, corners[:, 0])  # the face's deepest point
    assert depth.max() <= sagitta and depth.max() >= sagitta / 16  # no finer than one more subdivision needs
    with pytest.raises(ColliderError, match="needs more than 7 subdivisions"):
        sphere.triangles(1e-9)


@pytest.mark.parametrize("sagitta", [1e-3, 1e-4, 2.5e-5])
def test_a_capsules_triangles_close_it_outward_within_the_sagitta(rng, sagitta):
    """A tilted capsule's mesh: closed and of genus 0, every face outward, every vertex on the
    capsule, and points sampled on the faces at most ``sagitta`` inside it (and deeper than a
    sixteenth of it: not finer than needed)."""
    capsule = Capsule([0.1, -0.2, 0.3], [0.3, 0.1, 0.2], 0.01)
    vertices, triangles = capsule.triangles(sagitta)
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2) and len(vertices) - len(unique) + len(triangles) == 2
    assert np.abs(capsule.signed_distance(vertices)[0]).max() < 1e-15
    corners = vertices[triangles]
    centroids = corners.mean(axis=1)
    _, outward = capsule.signed_distance(centroids)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert np.all(np.einsum("ij,ij->i", normals, outward) > 0)
    weights = rng.dirichlet([1.0, 1.0, 1.0], size=(len(triangles), 16))
    depth = -capsule.signed_distance(np.einsum("fsk,fkc->fsc", weights, corners).reshape(-1, 3))[0]
    assert sagitta / 16 <= depth.max() <= sagitta
    with pytest.raises(ColliderError, match="needs more than 512 vertices around"):
        capsule.triangles(1e-12)
