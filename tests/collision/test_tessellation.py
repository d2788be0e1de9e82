"""Triangle meshes on colliders that have none (what barrier contact meets): a cylinder over the part
of its axis the bodies can reach, closed, outward and within the sagitta inside it; Bezier patch
models within the sagitta of their patches at the same parameters, adjacent patches welded."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.spatial

from bhem_hpc.collision import Cylinder, PatchModel
from bhem_hpc.collision.bezier import evaluate
from bhem_hpc.collision.tessellation import TessellationError

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def _closed_genus_zero(vertices: np.ndarray, triangles: np.ndarray) -> bool:
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(np.all(counts == 2) and len(vertices) - len(unique) + len(triangles) == 2)


@pytest.mark.parametrize("sagitta", [1e-3, 1e-4, 2.5e-5])
def test_a_cylinders_triangles_close_it_outward_within_the_sagitta_over_the_bodies_reach(rng, sagitta):
    """A tilted cylinder meshed for a box of bodies: closed, every face outward, every band vertex on
    the cylinder, sampled face points at most ``sagitta`` inside it (and deeper than a sixteenth of
    it), the caps beyond the box's projection on the axis by its diagonal."""
    cylinder = Cylinder([0.1, -0.2, 0.3], [0.3, 0.1, 1.0], 0.05)
    cover = np.array([[-0.2, -0.3, 0.0], [0.4, 0.1, 0.5]])
    vertices, triangles = cylinder.tessellation(sagitta, cover)
    assert _closed_genus_zero(vertices, triangles)
    distance, _ = cylinder.signed_distance(vertices[:-2])  # the last two are the caps' centres
    assert np.abs(distance).max() < 1e-15
    along = (vertices - cylinder.point) @ cylinder.axis
    corners = np.array([[cover[i, 0], cover[j, 1], cover[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    reach = (corners - cylinder.point) @ cylinder.axis
    diagonal = np.linalg.norm(cover[1] - cover[0])
    assert along.min() == pytest.approx(reach.min() - diagonal) and along.max() == pytest.approx(reach.max() + diagonal)
    corners_of = vertices[triangles]
    normals = np.cross(corners_of[:, 1] - corners_of[:, 0], corners_of[:, 2] - corners_of[:, 0])
    centroids = corners_of.mean(axis=1)
    centre_along = (centroids - cylinder.point) @ cylinder.axis
    on_band = (centre_along > along.min() + 1e-12) & (centre_along < along.max() - 1e-12)
    _, radial_out = cylinder.signed_distance(centroids[on_band])
    assert np.all(np.einsum("ij,ij->i", normals[on_band], radial_out) > 0)
    assert np.all(np.sign(centre_along[~on_band] - along.mean()) * (normals[~on_band] @ cylinder.axis) > 0)
    weights = rng.dirichlet([1.0, 1.0, 1.0], size=(int(on_band.sum()), 16))
    depth = -cylinder.signed_distance(np.einsum("fsk,fkc->fsc", weights, corners_of[on_band]).reshape(-1, 3))[0]
    assert sagitta / 16 <= depth.max() <= sagitta
    with pytest.raises(TessellationError, match="needs more than 1024 vertices around"):
        cylinder.tessellation(1e-12, cover)


def _saddle_and_dome() -> np.ndarray:
    """Two bicubic patches sharing the edge u = 1 of the first (u = 0 of the second): a dome and a
    saddle over [0, 2] x [0, 1]."""
    i, j = np.meshgrid(np.arange(4), np.arange(4), indexing="ij")
    first = np.stack([i / 3.0, j / 3.0, 0.3 * np.sin(np.pi * i / 3.0) * np.sin(np.pi * j / 3.0)], axis=-1)
    second = np.stack([1.0 + i / 3.0, j / 3.0, 0.2 * (i / 3.0 - 0.5) * (j / 3.0 - 0.5)], axis=-1)
    second[0] = first[3]  # the shared edge (control points of the first's last row)
    return np.stack([first, second])


@pytest.mark.parametrize("sagitta", [1e-2, 1e-3, 1e-4])
def test_a_patch_models_triangles_lie_within_the_sagitta_of_its_patches(rng, sagitta):
    """Points of every triangle against the patch at the same parameters (the triangle's corners'
    parameters, interpolated): within ``sagitta``; the shared edge welded (a manifold mesh with
    fewer vertices than the two grids)."""
    nets = _saddle_and_dome()
    vertices, triangles = PatchModel(nets).tessellation(sagitta, np.zeros((2, 3)))
    cells = round(np.sqrt(len(triangles) / 4))  # two patches of cells x cells, two triangles each
    assert len(triangles) == 4 * cells**2 and len(vertices) == 2 * (cells + 1) ** 2 - (cells + 1)
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    assert np.unique(edges, axis=0, return_counts=True)[1].max() == 2
    # each patch's grid parameters, in the order the tessellation evaluates them
    g = np.linspace(0.0, 1.0, cells + 1)
    u, v = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    worst = 0.0
    for patch, net in enumerate(nets):
        per_patch = triangles[2 * cells**2 * patch: 2 * cells**2 * (patch + 1)]
        points = evaluate(net, u, v)
        # the vertices of this patch's triangles, matched to its grid points by position
        distance, index = scipy.spatial.cKDTree(points).query(vertices[per_patch])
        assert distance.max() < 1e-12
        weights = rng.dirichlet([1.0, 1.0, 1.0], size=(len(per_patch), 8))
        on_triangles = np.einsum("fsk,fkc->fsc", weights, vertices[per_patch])
        on_patch = evaluate(net, np.einsum("fsk,fk->fs", weights, u[index]), np.einsum("fsk,fk->fs", weights, v[index]))
        worst = max(worst, float(np.linalg.norm(on_triangles - on_patch, axis=-1).max()))
    assert worst <= sagitta
    with pytest.raises(TessellationError, match="more than 256 x 256 cells per patch"):
        PatchModel(nets).tessellation(1e-9, np.zeros((2, 3)))
