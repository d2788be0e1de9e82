"""The Shape Matching Element Method on NURBS solids: energy densities, blending weights, the
patch test (affine and rigid motions reproduced exactly, a static uniaxial stretch solved to the
homogeneous state), derivatives against central differences, mass and gravity, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
import scipy.sparse

from bhem_hpc.geometry import nurbs
from bhem_hpc.geometry.surface import SurfaceError
from bhem_hpc.solids.blending import cutoff_distances, ray_distances
from bhem_hpc.solids.elasticity import (
    Lame,
    inverse_3x3,
    neo_hookean,
    positive_semidefinite,
    project_psd,
    st_venant_kirchhoff,
)
from bhem_hpc.solids.equilibrium import linearly_implicit_step, solve_static
from bhem_hpc.solids.origins import assign_candidates, candidate_groups, deformation_origins
from bhem_hpc.solids.quadrature import ray_cast_quadrature
from bhem_hpc.solids.sem import ShapeMatchingSolid, SolidMaterial, SolidOptions

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank

RUBBER = SolidMaterial(density=1000.0, young=1e6, poisson=0.45)
BOX = ([0.0, 0.0, 0.0], [2.0, 1.0, 0.5])


@pytest.fixture(scope="module", params=[1, 2], ids=["linear", "quadratic"])
def box_solid(request) -> ShapeMatchingSolid:
    """A 2 x 1 x 0.5 m box of six unconnected bilinear faces, blending sparsity target 0.5."""
    options = SolidOptions(degree=request.param, lines_per_side=16, sparsity=0.5)
    return ShapeMatchingSolid(nurbs.box_faces(*BOX), RUBBER, options, name="box")


@pytest.mark.parametrize("energy", [neo_hookean, st_venant_kirchhoff])
def test_stress_and_tangent_match_central_differences(energy, rng):
    f = np.eye(3) + 0.3 * rng.normal(size=(6, 3, 3))
    _, stress, tangent = energy(f, 2.0, 3.0)
    h = 1e-6
    for a in range(9):
        step = np.zeros(9)
        step[a] = h
        step = step.reshape(3, 3)
        plus, minus = energy(f + step, 2.0, 3.0), energy(f - step, 2.0, 3.0)
        np.testing.assert_allclose((plus[0] - minus[0]) / (2 * h), stress.reshape(6, 9)[:, a], rtol=1e-7, atol=1e-7)
        np.testing.assert_allclose(((plus[1] - minus[1]) / (2 * h)).reshape(6, 9), tangent[:, :, a], atol=1e-6)
    projected = project_psd(tangent)
    assert np.linalg.eigvalsh(projected).min() > -1e-10
    spd = np.einsum("qab,qcb->qac", tangent, tangent)
    np.testing.assert_allclose(project_psd(spd), spd)


def test_only_tangents_that_are_not_positive_semidefinite_are_projected(rng):
    """Seeded Neo-Hookean tangents, some stretched past their stability, some at rest rotated
    (singular in their rotations): the elimination test agrees with the smallest eigenvalue's sign
    (zero within round-off of the largest), the semi-definite ones are kept as they are, the others
    are the eigen-clamped ones (zero negative eigenvalues, the positive ones and their vectors kept)."""
    from scipy.spatial.transform import Rotation

    f = np.eye(3) + 0.15 * rng.normal(size=(400, 3, 3))
    f[:100] = Rotation.random(100, random_state=7).as_matrix()
    _, _, tangent = neo_hookean(f, np.full(400, 1e6), np.full(400, 4e6))
    values, vectors = np.linalg.eigh(tangent)
    passed = positive_semidefinite(tangent)
    assert passed[:100].all() and 0.1 < passed[100:].mean() < 0.9  # both kinds present
    np.testing.assert_array_equal(passed, values[:, 0] > -1e-12 * values[:, -1])
    projected = project_psd(tangent)
    np.testing.assert_array_equal(projected[passed], tangent[passed])
    clamped = np.einsum("qab,qb,qcb->qac", vectors, np.maximum(values, 0.0), vectors)
    np.testing.assert_allclose(projected[~passed], clamped[~passed], atol=1e-9 * np.abs(tangent).max())


def test_cofactor_inverse_is_numpys_inverse(rng):
    """Seeded deformation gradients (stretched, sheared, near-singular): the cofactor inverse and
    determinant agree with LAPACK's to 1e-12 relative to the inverse's size."""
    f = np.eye(3) + rng.normal(scale=0.4, size=(500, 3, 3))
    inverse, det = inverse_3x3(f)
    np.testing.assert_allclose(det, np.linalg.det(f), rtol=1e-12, atol=1e-14)
    expected = np.linalg.inv(f)
    scale = np.abs(expected).max(axis=(1, 2))[:, None, None]
    assert np.all(np.abs(inverse - expected) <= 1e-12 * scale * np.linalg.cond(f)[:, None, None])


def test_neo_hookean_refuses_inverted_elements():
    f = np.diag([1.0, 1.0, -0.5])[None]
    assert neo_hookean(f, 1.0, 1.0, tangent=False)[0][0] == np.inf


def test_blending_weights_partition_unity_and_meet_the_sparsity_target():
    parts = nurbs.box_faces(*BOX)
    rule = ray_cast_quadrature(parts, 24)
    distances = ray_distances(parts, rule.points, reach=1.2)
    for target in (0.3, 0.5, 0.8):
        alpha = distances.cutoff_for(target)
        weights = distances.weights(alpha).toarray()
        np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-14)
        assert weights.min() >= 0.0
        share = np.count_nonzero(weights) / weights.size
        assert target - 0.05 < share <= target
    # a point next to one face and far from the rest belongs to that face alone
    near = ray_distances(parts, np.array([[1.0, 0.5, 0.01]]), reach=1.2)
    np.testing.assert_allclose(near.weights(0.2).toarray(), [[0, 0, 0, 0, 1, 0]], atol=1e-12)
    with pytest.raises(SurfaceError, match="sparsity target must lie in"):
        distances.cutoff_for(1.5, "box")


@pytest.mark.parametrize("target", [0.3, 0.5, 0.8])
def test_cutoff_distances_cast_flat_parts_rays_only_below_the_cutoff_with_the_same_weights(target):
    """A box's flat faces and a sphere through its corner: the cutoff from the sphere's rays alone,
    then the faces' rays where their primary distance is below it, give the cutoff, weights and
    weight gradients of every ray at full reach, bit for bit, from fewer rays."""
    parts = [*nurbs.box_faces(*BOX), nurbs.sphere(0.4)]
    points = ray_cast_quadrature(parts, 16).points
    full = ray_distances(parts, points, reach=1.2)
    alpha = full.cutoff_for(target)
    distances, cutoff = cutoff_distances(parts, points, 1.2, target)
    assert cutoff == alpha
    np.testing.assert_array_equal(distances.weights(cutoff).toarray(), full.weights(alpha).toarray())
    np.testing.assert_array_equal(distances.weight_gradients(cutoff), full.weight_gradients(alpha))
    flat_rays = np.isfinite(distances.total[:, :6]).sum()
    assert flat_rays < np.isfinite(full.total[:, :6]).sum()


def test_distances_within_a_bound_skip_far_parts_and_keep_the_weights_below_it():
    """Four spheres on a line, 1.5 m apart: with ``within`` 0.6 m a point's far spheres are not
    projected (inf), the weights for cutoffs up to 0.6 m are those of all pairs bit for bit, and a
    point no sphere's box comes within 0.6 m of still belongs to its nearest sphere."""
    parts = [nurbs.sphere(0.4, center=(1.5 * k, 0.0, 0.0)) for k in range(4)]
    points = np.concatenate([ray_cast_quadrature(parts, 24).points, [[2.25, 1.5, 0.0]]])
    full = ray_distances(parts, points, reach=6.0)
    near = ray_distances(parts, points, reach=6.0, within=0.6)
    assert np.isfinite(full.primary).all()
    skipped = np.isinf(near.primary)
    assert 0.5 < skipped.mean() < 0.9
    np.testing.assert_array_equal(near.primary[~skipped], full.primary[~skipped])
    assert np.all(full.primary[skipped] >= 0.6)
    for alpha in (0.2, 0.45, 0.6):
        np.testing.assert_array_equal(near.weights(alpha).toarray(), full.weights(alpha).toarray())
        np.testing.assert_array_equal(near.weight_gradients(alpha), full.weight_gradients(alpha))
    # the last point lies 1.15 m from every sphere's box: projected onto all, it belongs to its nearest alone
    assert np.isfinite(near.primary[-1]).all()
    np.testing.assert_array_equal(near.weights(0.3).toarray()[-1], full.weights(0.3).toarray()[-1])


def test_affine_and_rigid_motions_are_reproduced_exactly(box_solid, rng):
    q0 = box_solid.reference
    affine, shift = np.eye(3) + 0.2 * rng.normal(size=(3, 3)), rng.normal(size=3)
    q = q0 @ affine.T + shift
    np.testing.assert_allclose(
        box_solid.deformation_gradients(q),
        np.broadcast_to(affine, (len(box_solid.quadrature.weights), 3, 3)),
        atol=1e-12,
    )
    np.testing.assert_allclose(box_solid.position_map @ q, box_solid.quadrature.points @ affine.T + shift, atol=1e-12)
    # the error energy vanishes to round-off (gamma = Young's modulus)
    assert abs(q.reshape(-1) @ (box_solid._error @ q.reshape(-1))) < 1e-14 * RUBBER.young * (q**2).sum()
    rotation = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    rotation *= np.sign(np.linalg.det(rotation))
    rigid = q0 @ rotation.T + shift
    assert abs(box_solid.energy(rigid)) < 1e-9
    assert np.abs(box_solid.gradient(rigid)).max() < 1e-6  # against forces of order Y * area = 1e6 N


def test_gradient_and_hessian_match_central_differences(box_solid, rng):
    q = box_solid.reference + 0.02 * rng.normal(size=box_solid.reference.shape)
    gradient, hessian = box_solid.gradient(q), box_solid.hessian(q, projected=False)
    h = 1e-6
    for _ in range(3):
        direction = rng.normal(size=q.size)
        plus, minus = q.reshape(-1) + h * direction, q.reshape(-1) - h * direction
        assert (box_solid.energy(plus) - box_solid.energy(minus)) / (2 * h) == pytest.approx(
            gradient @ direction, rel=1e-7
        )
        change = (box_solid.gradient(plus) - box_solid.gradient(minus)) / (2 * h)
        np.testing.assert_allclose(change, hessian @ direction, atol=1e-7 * np.abs(hessian @ direction).max())
    eigenvalues = np.linalg.eigvalsh(box_solid.hessian(q).toarray())
    assert eigenvalues.min() > -1e-9 * eigenvalues.max()


def test_secondary_rays_of_boundary_samples_start_beyond_their_point():
    """A boundary sample lies on its own part: the secondary ray from another part's closest point
    through it goes on to the next surface, never stopping at the sample's own crossing (which
    round-off would count on some rays and not on others). Of the castle's 1280 rays, 325 meet a
    surface within reach: rays in the plane of a block's face do not meet it, nor do the 71 rays
    that leave a tower's foot along the tangent to its wall (a search to a tolerance counts those
    as meeting the wall a few micrometres on)."""
    from bhem_hpc.solids.sampling import sample_parts
    from bhem_hpc.studies.sem_models import castle

    parts = castle()
    samples = sample_parts(parts)
    points = np.concatenate([s.points for s in samples])
    on_part = np.repeat(np.arange(len(samples)), [len(s.points) for s in samples])
    distances = ray_distances(parts, points, 0.3, on_part)
    cast = np.isfinite(distances.total) & (distances.primary > 0.0)
    assert cast.sum() >= 320
    assert np.all(distances.total[cast] - distances.primary[cast] > 1e-6)


def test_dense_and_sparse_stiffness_assembly_agree(box_solid, rng, monkeypatch):
    """Small models assemble the coefficient stiffness densely (runs of slices, then BLAS for
    Pi^T C Pi on a fixed pattern), large ones as sparse triplets: the two give the same Hessian,
    and the dense one keeps its pattern at every state."""
    from bhem_hpc.solids import assembly
    from bhem_hpc.solids.sem import QuadratureShare

    q = box_solid.reference + 0.02 * rng.normal(size=box_solid.reference.shape)
    dense_share = QuadratureShare(box_solid, 0, len(box_solid.quadrature.points))
    dense = dense_share.hessian(q, projected=False)
    monkeypatch.setattr(assembly, "DENSE_LIMIT", 0)
    sparse = QuadratureShare(box_solid, 0, len(box_solid.quadrature.points)).hessian(q, projected=False)
    np.testing.assert_allclose(dense.toarray(), sparse.toarray(), atol=1e-10 * abs(sparse).max())
    rest = dense_share.hessian(box_solid.reference, projected=False)
    assert rest.nnz == dense.nnz and np.array_equal(rest.indices, dense.indices)


def test_merged_point_groups_give_the_stiffness_of_the_distinct_ones(box_solid, rng, monkeypatch):
    """Groups of points that see the same coefficients are merged where the cost model says one
    product beats two; with a cost model under which nothing merges, the stiffness is the same."""
    from bhem_hpc.solids import assembly
    from bhem_hpc.solids.sem import QuadratureShare

    q = box_solid.reference + 0.02 * rng.normal(size=box_solid.reference.shape)
    merged = QuadratureShare(box_solid, 0, len(box_solid.quadrature.points))
    monkeypatch.setattr(assembly, "ENTRY_SECONDS", 0.0)
    monkeypatch.setattr(assembly, "GROUP_SECONDS", 0.0)
    distinct = QuadratureShare(box_solid, 0, len(box_solid.quadrature.points))
    assert len(merged._groups) < len(distinct._groups)
    expected = distinct.hessian(q).toarray()
    np.testing.assert_allclose(merged.hessian(q).toarray(), expected, atol=1e-12 * abs(expected).max())


def test_symmetric_solves_are_dense_cholesky_or_sparse_lu(rng, monkeypatch):
    """A full positive definite system goes to the dense Cholesky factorization, an indefinite one
    (no Cholesky factor) and a sparse one to the sparse LU: all three solve to round-off."""
    import scipy.sparse.linalg

    from bhem_hpc.solids import equilibrium

    sparse_solves = []
    lu = scipy.sparse.linalg.spsolve
    monkeypatch.setattr(scipy.sparse.linalg, "spsolve", lambda *args: sparse_solves.append(1) or lu(*args))
    factor = rng.normal(size=(40, 40))
    definite, indefinite = factor @ factor.T + 40 * np.eye(40), factor + factor.T
    sparse = scipy.sparse.diags([np.full(39, -1.0), np.full(40, 3.0), np.full(39, -1.0)], [-1, 0, 1])
    rhs = rng.normal(size=40)
    for matrix in (definite, indefinite, sparse.toarray()):
        solution = equilibrium.solve_symmetric(scipy.sparse.csr_matrix(matrix), rhs)
        np.testing.assert_allclose(matrix @ solution, rhs, atol=1e-10 * np.abs(rhs).max())
    assert len(sparse_solves) == 2  # the indefinite and the sparse system


def test_mass_and_gravity(box_solid):
    volume = 2.0 * 1.0 * 0.5
    assert box_solid.mass == pytest.approx(RUBBER.density * volume, rel=1e-12)
    mass_matrix = box_solid.mass_matrix()
    ones = np.tile([1.0, 0.0, 0.0], len(box_solid.reference))
    assert ones @ (mass_matrix @ ones) == pytest.approx(box_solid.mass, rel=1e-12)  # a translation's kinetic energy
    force = box_solid.gravity_force(np.array([0.0, 0.0, -9.81])).reshape(-1, 3).sum(axis=0)
    np.testing.assert_allclose(force, [0.0, 0.0, -9.81 * box_solid.mass], atol=1e-9)


def test_static_uniaxial_stretch_is_the_homogeneous_state(box_solid):
    """Ends pulled to 1.2 times the length, symmetry planes at x = 0, y = 0 and z = 0: the
    Neo-Hookean equilibrium is homogeneous, F = diag(1.2, m, m) with zero lateral stress."""
    q0, stretch = box_solid.reference, 1.2
    fixed = np.zeros(q0.shape, dtype=bool)
    fixed[np.isclose(q0[:, 0], 0.0) | np.isclose(q0[:, 0], 2.0), 0] = True
    fixed[np.isclose(q0[:, 1], 0.0), 1] = True
    fixed[np.isclose(q0[:, 2], 0.0), 2] = True
    q = q0.copy()
    q[:, 0] *= np.where(fixed[:, 0], stretch, 1.0)
    equilibrium = solve_static(box_solid, q, fixed, tolerance=1e-12)
    solution, iterations = equilibrium.q, equilibrium.iterations
    lame = Lame.of(RUBBER.young, RUBBER.poisson)
    lateral = scipy.optimize.brentq(
        lambda m: lame.mu * (m - 1 / m) + lame.lam * np.log(stretch * m * m) / m, 0.5, 1.5, xtol=1e-15
    )
    f = box_solid.deformation_gradients(solution)
    np.testing.assert_allclose(f, np.broadcast_to(np.diag([stretch, lateral, lateral]), f.shape), atol=1e-10)
    assert iterations <= 8


def test_bad_solid_input_is_refused():
    faces = nurbs.box_faces(*BOX)
    with pytest.raises(SurfaceError, match=r"young must be positive, got -1"):
        ShapeMatchingSolid(faces, SolidMaterial(1000.0, -1.0, 0.3), name="box")
    with pytest.raises(SurfaceError, match=r"poisson must lie in \(-1, 0.5\), got 0.5"):
        ShapeMatchingSolid(faces, SolidMaterial(1000.0, 1e6, 0.5), name="box")
    with pytest.raises(SurfaceError, match=r"model must be one of"):
        ShapeMatchingSolid(faces, SolidMaterial(1000.0, 1e6, 0.3, model="hooke"), name="box")
    with pytest.raises(SurfaceError, match=r"box: alpha must be positive, got 0.0"):
        ShapeMatchingSolid(faces, RUBBER, SolidOptions(alpha=0.0, lines_per_side=8), name="box")
    with pytest.raises(SurfaceError, match=r"box: 2 materials for 6 parts"):
        ShapeMatchingSolid(faces, [RUBBER, RUBBER], name="box")


def test_deformation_origins_solve_the_network_flow():
    """Every part draws one unit through a candidate whose set of parts holds it, at the least total
    cost (with unbounded candidates, each part's cheapest edge), and parts drawing through one
    candidate share one origin."""
    parts = nurbs.box_faces(*BOX)
    rule = ray_cast_quadrature(parts, 12)
    weights = ray_distances(parts, rule.points, reach=1.2).weights(0.4)
    patterns, group = candidate_groups(weights)
    dense = weights.toarray()
    cost = np.array([dense[group == g].sum(axis=0) for g in range(len(patterns))])
    candidate, edge_cost = assign_candidates(weights, "box")
    np.testing.assert_allclose(edge_cost, np.where(patterns, cost, np.inf))
    assert np.all(patterns[candidate, np.arange(6)])
    assert cost[candidate, np.arange(6)].sum() == pytest.approx(np.where(patterns, cost, np.inf).min(axis=0).sum())
    origins = deformation_origins(weights, "box")
    np.testing.assert_array_equal(candidate[:, None] == candidate[None, :], origins[:, None] == origins[None, :])
    assert origins[0] == 0 and len(np.unique(origins)) > 1


def test_the_cheapest_edges_are_the_optimum_of_the_integer_flow(rng):
    """Random sparse blending weights (seeded): the flow of :func:`assign_candidates` costs what
    HiGHS's integer program (eq. 10: every part receives one unit over 0/1 candidate edges) costs."""
    for _ in range(20):
        weights = rng.random((60, 7)) * (rng.random((60, 7)) < 0.4)
        weights[np.arange(7), np.arange(7)] += 0.1  # every part has a point
        candidate, edge_cost = assign_candidates(scipy.sparse.csr_matrix(weights))
        edges = np.argwhere(np.isfinite(edge_cost))
        flows = np.arange(len(edges))
        receive = scipy.sparse.csr_matrix((np.ones(len(edges)), (edges[:, 1], flows)), shape=(7, len(edges)))
        result = scipy.optimize.milp(
            c=edge_cost[edges[:, 0], edges[:, 1]],
            constraints=scipy.optimize.LinearConstraint(receive, np.ones(7), np.ones(7)),
            integrality=np.ones(len(edges)),
            bounds=scipy.optimize.Bounds(np.zeros(len(edges)), np.ones(len(edges))),
        )
        assert result.success
        assert edge_cost[candidate, np.arange(7)].sum() == pytest.approx(result.fun, rel=1e-9)


@pytest.mark.parametrize("degree", [1, 2])
def test_monomials_about_one_centre_are_a_linear_map_of_those_about_another(degree, rng):
    """The fits sum per-part moments moved to the origin: ``Q(Y + d) = T(d) Q(Y)`` exactly."""
    from bhem_hpc.solids.shape_matching import monomials, shifts

    points, deltas = rng.normal(size=(50, 3)), rng.normal(size=(4, 3))

    def about(offsets):
        return np.hstack([np.ones((len(offsets), 1)), monomials(offsets, degree)])

    for delta, shift in zip(deltas, shifts(deltas, degree), strict=True):
        np.testing.assert_allclose(about(points + delta), about(points) @ shift.T, atol=1e-12)


def test_tied_parts_share_a_candidate():
    """Four parts, each with two candidates of equal cost, pairwise shared: the flow routes them
    through two candidates (the optimum through fewest), not four."""
    weights = np.zeros((8, 4))
    for point, pair in enumerate([(0, 1), (1, 2), (2, 3), (3, 0), (0, 1), (1, 2), (2, 3), (3, 0)]):
        weights[point, list(pair)] = 0.5
    candidate, edge_cost = assign_candidates(scipy.sparse.csr_matrix(weights))
    assert len(np.unique(candidate)) == 2
    assert edge_cost[candidate, np.arange(4)].sum() == pytest.approx(np.min(edge_cost, axis=0).sum())


@pytest.mark.parametrize("degree", [1, 2])
def test_dense_and_per_part_projections_agree(degree, monkeypatch):
    """Small models keep the projection's rows dense, large ones per part: on the castle's 16
    parts, three origins, both give the same projection."""
    from bhem_hpc.solids import shape_matching as sm
    from bhem_hpc.solids.sampling import sample_parts
    from bhem_hpc.studies import sem_models

    samples = sample_parts(sem_models.castle())
    origins = np.arange(len(samples)) % 3
    dense = sm.shape_matching(samples, degree, origins).projection.toarray()
    monkeypatch.setattr(sm, "DENSE_PROJECTION_ENTRIES", 0)
    per_part = sm.shape_matching(samples, degree, origins).projection.toarray()
    np.testing.assert_allclose(per_part, dense, atol=1e-12 * np.abs(dense).max())


def test_origins_option_is_checked():
    with pytest.raises(SurfaceError, match=r"box: origins must be 'flow', 'single' or one index per part, got 'many'"):
        ShapeMatchingSolid(nurbs.box_faces(*BOX), RUBBER, SolidOptions(origins="many", lines_per_side=8), name="box")
    with pytest.raises(SurfaceError, match=r"box: origins must give one index >= 0 per part \(6\)"):
        ShapeMatchingSolid(nurbs.box_faces(*BOX), RUBBER, SolidOptions(origins=(0, 1), lines_per_side=8), name="box")


def test_a_linearly_implicit_step_of_free_fall_is_exact(box_solid):
    """Gravity on a free solid: the generalized force is the mass matrix times a uniform
    acceleration and a translation costs no elastic energy, so one step gains exactly g dt."""
    gravity, dt = np.array([0.0, 0.0, -9.81]), 0.01
    q, velocity = box_solid.reference, np.tile([0.3, 0.0, 0.0], (len(box_solid.reference), 1))
    fixed = np.zeros(q.shape, dtype=bool)
    q1, v1 = linearly_implicit_step(box_solid, q, velocity, dt, fixed, box_solid.gravity_force(gravity))
    np.testing.assert_allclose(v1, velocity + dt * gravity, atol=1e-9)
    np.testing.assert_allclose(q1, q + dt * v1, atol=1e-12)


def _mapped_control(parts, mapping) -> np.ndarray:
    """Stacked control points of ``parts`` whose surfaces are ``mapping (P, 3) -> (P, 3)`` of the
    reference surfaces (least squares on a parameter grid: exact where the parts can represent it)."""
    grid = np.linspace(0.0, 1.0, 9)
    u, v = (a.ravel() for a in np.meshgrid(grid, grid, indexing="ij"))
    stacked = []
    for part in parts:
        index, values = part.basis_matrix(u, v)
        basis = np.zeros((len(u), part.control[..., 0].size))
        np.put_along_axis(basis, index, values, axis=1)
        stacked.append(np.linalg.lstsq(basis, mapping(basis @ part.control.reshape(-1, 3)), rcond=None)[0])
    return np.concatenate(stacked)


@pytest.mark.parametrize("weight_gradients", [False, True])
def test_quadratic_motions_are_reproduced_exactly(weight_gradients, rng):
    """Biquadratic flat faces moved by a quadratic field: every point and deformation gradient of the
    blended map is the field's, with the planar parts' terms along their normals completed from
    their neighbours (the paper's per-part fit leaves them zero)."""
    parts = nurbs.beam_faces([0.0, 0.0, 0.0], [1.0, 0.3, 0.2], 2, degree=2)
    options = SolidOptions(degree=2, lines_per_side=12, sparsity=0.4, weight_gradients=weight_gradients)
    solid = ShapeMatchingSolid(parts, RUBBER, options, name="beam")
    linear, quadratic = 0.1 * rng.normal(size=(3, 3)), 0.1 * rng.normal(size=(3, 3, 3))

    def field(x):
        return x + x @ linear.T + np.einsum("iab,pa,pb->pi", quadratic, x, x)

    def gradient(x):
        return np.eye(3) + linear + np.einsum("iab,pb->pia", quadratic + quadratic.transpose(0, 2, 1), x)

    q = _mapped_control(solid.parts, field)
    points = solid.quadrature.points
    np.testing.assert_allclose(solid.position_map @ q, field(points), atol=1e-10)
    np.testing.assert_allclose(solid.deformation_gradients(q), gradient(points), atol=1e-9)


@pytest.mark.parametrize(("weight_gradients", "soft_directions"), [(False, 2), (True, 0)])
def test_weight_gradients_stiffen_the_turns_between_sections(weight_gradients, soft_directions):
    """A beam of two sections clamped at one end: with constant weights (the paper's F) two motions
    of the sections against each other cost the elastic energy less than 1e-7 of the stiffest one
    (9e-9 and 5e-8 measured, where the beam's own bending costs 3e-6); the weights' gradients see
    them. (The error energy, eq. 16, stiffens them too: 1.2e-4 with it.)"""
    parts = nurbs.beam_faces([0.0, 0.0, 0.0], [1.0, 0.2, 0.2], 2)
    options = SolidOptions(degree=2, lines_per_side=20, origins="single", weight_gradients=weight_gradients)
    solid = ShapeMatchingSolid(parts, SolidMaterial(1000.0, 1e7, 0.45), options, name="beam")
    free = ~np.isclose(solid.reference[:, 0], 0.0).repeat(3)
    elastic = solid.whole.hessian(solid.reference).toarray()[free][:, free]
    eigenvalues = np.linalg.eigvalsh(elastic)
    assert np.count_nonzero(eigenvalues < 1e-7 * eigenvalues.max()) == soft_directions


def test_materials_of_one_solid_share_an_energy_model():
    faces = nurbs.box_faces(*BOX)
    stvk = SolidMaterial(1000.0, 1e6, 0.3, model="stvk")
    with pytest.raises(SurfaceError, match=r"box: the parts' materials must share one energy model"):
        ShapeMatchingSolid(faces, [RUBBER] * 5 + [stvk], SolidOptions(lines_per_side=8), name="box")


def test_two_legs_move_independently_with_a_local_cutoff():
    """The paper's Fig. 14: a body on two legs (18 flat parts; the legs' tops overlap the body's
    bottom), the body held, one foot moved 0.1 m along x. With a cutoff of 0.3 m (the gap between
    the legs is 0.6 m) the other leg moves less than 10 % of that (7 % measured: the legs share
    the body's parts); blending every part everywhere (T = 0.9) drags it along (49 % measured)."""
    body = nurbs.box_faces([0.0, 0.0, 1.0], [2.0, 1.0, 1.6])
    leg_a, leg_b = nurbs.box_faces([0.0, 0.0, 0.0], [0.7, 1.0, 1.0]), nurbs.box_faces([1.3, 0.0, 0.0], [2.0, 1.0, 1.0])
    moved = {}
    for label, cutoff in (("local", {"alpha": 0.3}), ("wide", {"sparsity": 0.9})):
        options = SolidOptions(degree=2, lines_per_side=16, **cutoff)
        solid = ShapeMatchingSolid(body + leg_a + leg_b, RUBBER, options, name="two legs")
        reference = solid.reference
        part_of = np.repeat(np.arange(len(solid.parts)), np.diff(solid.offsets))
        foot = (part_of >= 6) & (part_of < 12) & np.isclose(reference[:, 2], 0.0)
        fixed = np.zeros(reference.shape, dtype=bool)
        fixed[(part_of < 6) | foot] = True
        start = reference.copy()
        start[foot, 0] += 0.1
        state = solve_static(solid, start, fixed)
        moved[label] = np.linalg.norm(state.q - reference, axis=1)[part_of >= 12].max()
    assert moved["local"] < 0.01
    assert moved["wide"] > 0.04


def test_the_table_models_have_the_papers_dofs():
    """Table 1's models (the rocket, the twisted beam, the refined mug and castle) have the paper's
    DoF counts, three per control point as its q."""
    from bhem_hpc.studies import sem_models, sem_table
    from bhem_hpc.studies.solid_twist import twist_parts

    parts = {
        "rocket (soft)": sem_models.rocket(),
        "beam (twist)": twist_parts(),
        "coffee mug (soft)": sem_models.refined(sem_models.mug(), sem_table.MUG_REFINEMENT),
        "castle": sem_models.refined(sem_models.castle(), sem_table.CASTLE_REFINEMENT),
    }
    for name, model in parts.items():
        assert 3 * sum(part.control.shape[0] * part.control.shape[1] for part in model) == sem_table.PAPER[name][0]
