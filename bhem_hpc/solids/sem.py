"""A solid of the Shape Matching Element Method: preprocessing (Alg. 1) and its energy, gradient,
Hessian and mass, numpy and scipy only.

The DOFs are the parts' control points stacked part after part, ``q (n_q, 3)``; flattened they
are interleaved (``3 * point + component``), the layout PETSc's block size 3 wants. The
coefficients of the blended polynomial map are ``C = Pi q`` (:mod:`.shape_matching`); at the
volume quadrature points ``F = sum_d G_d C`` is the deformation gradient and the elastic energy is
``sum_k v_k psi(F_k)``. The error energy ``gamma |Phi_b Pi q - J q|^2_S`` (§7.6) ties the boundary
of the polynomial map to the parts; ``gamma`` defaults to Young's modulus, as the paper advises
(each part's own, in a solid of several materials).
Every stage of the preprocessing is timed (:attr:`ShapeMatchingSolid.seconds`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse

from bhem_hpc.geometry.nurbs import NurbsSurface
from bhem_hpc.geometry.surface import SurfaceError
from bhem_hpc.solids.assembly import (
    UPPER_PAIRS,
    coefficient_pattern,
    coefficient_stiffness,
    congruence,
    fits_dense,
    point_groups,
    weighted_gram,
)
from bhem_hpc.solids.blending import RayDistances, cutoff_distances, ray_distances
from bhem_hpc.solids.elasticity import MODELS, Lame, project_psd
from bhem_hpc.solids.origins import deformation_origins
from bhem_hpc.solids.quadrature import model_bounds, ray_cast_quadrature
from bhem_hpc.solids.sampling import sample_parts, stacked_bases
from bhem_hpc.solids.shape_matching import shape_matching


@dataclass(frozen=True)
class SolidMaterial:
    """Density [kg/m^3], Young's modulus [Pa], Poisson's ratio and energy model
    (``"neo-hookean"`` or ``"stvk"``)."""

    density: float
    young: float
    poisson: float
    model: str = "neo-hookean"

    def checked(self, name: str) -> SolidMaterial:
        if not (np.isfinite(self.density) and self.density > 0.0):
            raise SurfaceError(f"{name}: density must be positive, got {self.density!r}")
        if self.model not in MODELS:
            raise SurfaceError(f"{name}: model must be one of {sorted(MODELS)}, got {self.model!r}")
        Lame.of(self.young, self.poisson, name)
        return self


@dataclass(frozen=True)
class SolidOptions:
    """Preprocessing settings: shape-matching ``degree`` (1, 2), ray-cast ``lines_per_side`` and
    Gauss ``quadrature_order`` along lines, boundary ``sample_order`` (None: the NURBS order),
    blending ``sparsity`` target T (None: the cutoff ``alpha`` given, or all parts everywhere),
    deformation ``origins``: ``"flow"`` (the min-cost network flow of §6.2), ``"single"`` (one for
    all parts) or one origin index per part; ``weight_gradients``: keep the blending weights'
    gradients in ``F`` (eq. 15 whole; False: the paper's constant weights, under which parts may
    turn against each other at no strain); ``error_stiffness`` gamma (None: each part's Young's modulus)."""

    degree: int = 2
    lines_per_side: int = 24
    quadrature_order: int = 2
    sample_order: int | None = None
    sparsity: float | None = None
    alpha: float | None = None
    origins: str | tuple[int, ...] = "flow"
    weight_gradients: bool = True
    error_stiffness: float | None = None


class QuadratureShare:
    """The elastic energy of the solid's quadrature points ``start <= k < stop`` (a rank's share
    under MPI, or all of them), with its gradient and Hessian on the interleaved DOFs ``(3 n_q,)``.

    Args:
        solid: the solid; ``start, stop``: the points of the share.
    """

    def __init__(self, solid: ShapeMatchingSolid, start: int, stop: int):
        self.solid, self.start, self.stop = solid, start, stop
        self.weights = solid.quadrature.weights[start:stop]
        # F = G (Pi q): the product G Pi is nearly dense where parts blend everywhere (the castle:
        # 9 Q x 3 n_q), the factors are sparse and cheaper to build and to apply
        self._coefficient_gradients = solid._coefficient_gradients[9 * start : 9 * stop]
        self._groups = point_groups([g[start:stop] for g in solid._scalar_gradients])
        self._mu, self._lam = solid._mu[start:stop], solid._lam[start:stop]
        #: whether the stiffness is assembled densely: then the dense scalar projection and the entries
        #: ``(rows, columns)`` of the stiffness, made with the operators (they depend on the structure alone)
        self._dense = fits_dense(3 * solid.matching.coefficient_count) and fits_dense(solid._projection.shape[1])
        if self._dense:
            # the scalar projection: the interleaved one is it times I_3, two thirds zeros in the
            # products, and a pair of control points the stiffness reaches couples all their components
            projection = solid.matching.projection.toarray()
            reach = coefficient_pattern(self._groups, solid.matching.coefficient_count).astype(float)
            nonzero = (np.abs(projection) > 0.0).astype(float)
            reached = (nonzero.T @ reach @ nonzero) > 0.0
            self._dense_projection = projection
            self._pattern = np.nonzero(np.kron(reached, np.ones((3, 3), dtype=bool)))

    def deformation_gradients(self, q: np.ndarray) -> np.ndarray:
        """``(stop - start, 3, 3)`` at the share's points for control points ``q (n_q, 3)``."""
        coefficients = self.solid._projection @ np.asarray(q, dtype=float).reshape(-1)
        return (self._coefficient_gradients @ coefficients).reshape(-1, 3, 3)

    def energy(self, q: np.ndarray) -> float:
        """Elastic energy of the share [J] (inf where some ``det F <= 0``)."""
        psi, _, _ = self.solid._model(self.deformation_gradients(q), self._mu, self._lam, tangent=False)
        return float(self.weights @ psi)

    def gradient(self, q: np.ndarray) -> np.ndarray:
        """``(3 n_q,)`` interleaved."""
        _, stress, _ = self.solid._model(self.deformation_gradients(q), self._mu, self._lam, tangent=False)
        weighted = (self.weights[:, None, None] * stress).reshape(-1)
        return self.solid._projection.T @ (self._coefficient_gradients.T @ weighted)

    def hessian(self, q: np.ndarray, projected: bool = True) -> scipy.sparse.csr_matrix:
        """``(3 n_q, 3 n_q)``; ``projected``: each point's tangent clamped positive semi-definite."""
        _, _, tangent = self.solid._model(self.deformation_gradients(q), self._mu, self._lam)
        if projected:
            tangent = project_psd(tangent)
        solid = self.solid
        weighted, count = self.weights[:, None, None] * tangent, solid.matching.coefficient_count
        if self._dense:
            return self._dense_product(coefficient_stiffness(self._groups, weighted, count, pairs=True))
        coefficients = coefficient_stiffness(self._groups, weighted, count)
        if isinstance(coefficients, np.ndarray):
            coefficients = scipy.sparse.csr_matrix(coefficients)
        return (solid._projection.T @ coefficients @ solid._projection).tocsr()

    def _dense_product(self, blocks: np.ndarray) -> scipy.sparse.csr_matrix:
        """``Pi^T C Pi`` from the coefficient stiffness's component-pair blocks ``(6, n_c, n_c)`` by
        dense products with the scalar projection, one per pair (BLAS; scipy's sparse product of a
        projection that is nearly dense took 0.5 s for a rocket of 810 DoFs, the interleaved dense
        one 0.03 s for 648), on the entries the share's groups can reach, zeros included: the same
        pattern at every state."""
        rows, columns = self._pattern
        projection = self._dense_projection  # (n_c, n_q)
        points = projection.shape[1]
        product = np.empty((points, 3, points, 3))  # [i, c, j, c']
        for (c, d), block in zip(UPPER_PAIRS, blocks, strict=True):
            product[:, c, :, d] = projection.T @ (block @ projection)
            if c != d:
                product[:, d, :, c] = product[:, c, :, d].T
        product = product.reshape(3 * points, 3 * points)
        return scipy.sparse.csr_matrix((product[rows, columns], (rows, columns)), shape=(3 * points, 3 * points))


#: Largest ``|F - I|`` at rest a solid is built with (the shape matching reproduces affine maps
#: exactly; round-off leaves 1e-13).
REST_TOLERANCE = 1e-8


#: Up to this many points times parts the parts blended together are found on a dense array
#: (a sparse product costs 0.7 ms of scipy's bookkeeping where the dense one takes 0.1 ms).
DENSE_BLEND_ENTRIES = 20_000_000


def _blended_neighbours(blend: scipy.sparse.spmatrix) -> list[np.ndarray]:
    """Per part, the parts with nonzero weights at one of its points, itself included: ``blend
    (Q, parts)``."""
    parts = blend.shape[1]
    if blend.shape[0] * parts <= DENSE_BLEND_ENTRIES:
        seen = (blend.toarray() != 0).astype(float)
        together = seen.T @ seen
        return [np.flatnonzero(together[i]) for i in range(parts)]
    touching = (blend != 0).astype(float)
    blended = (touching.T @ touching).tocsr()
    return [blended.indices[blended.indptr[i] : blended.indptr[i + 1]] for i in range(parts)]


def _interleave(scalar: scipy.sparse.spmatrix) -> scipy.sparse.csr_matrix:
    """``scalar ⊗ I_3``: the operator on interleaved 3-vectors acting on each component alike."""
    return scipy.sparse.kron(scalar, scipy.sparse.identity(3), format="csr")


class ShapeMatchingSolid:
    """One SEM solid of NURBS ``parts`` with a ``material`` (one per part, or one for all).

    Attributes:
        reference: ``(n_q, 3)`` the parts' control points stacked.
        offsets: ``(parts + 1,)`` where each part's control points start.
        quadrature: the ray-cast volume rule; ``blend`` its points' weights ``(Q, parts)``.
        matching: the shape-matching projection and kinematic map.
        seconds: wall time of each stage (``sample``, ``quadrature``, ``weights``, ``origins``,
            ``projection``, ``operators``).
    """

    def __init__(
        self,
        parts: Sequence[NurbsSurface],
        material: SolidMaterial | Sequence[SolidMaterial],
        options: SolidOptions | None = None,
        name: str = "solid",
    ):
        options = options or SolidOptions()
        self.name, self.parts, self.options = name, list(parts), options
        materials = [material] * len(parts) if isinstance(material, SolidMaterial) else list(material)
        if len(materials) != len(parts):
            raise SurfaceError(f"{name}: {len(materials)} materials for {len(parts)} parts")
        self.materials = [m.checked(f"{name} material of {p.name}") for m, p in zip(materials, parts, strict=True)]
        models = sorted({m.model for m in self.materials})
        if len(models) > 1:
            raise SurfaceError(f"{name}: the parts' materials must share one energy model, got {models}")
        self.seconds: dict[str, float] = {}
        clock = time.perf_counter()
        self.offsets = np.r_[0, np.cumsum([p.control[..., 0].size for p in parts])]
        self.reference = np.concatenate([p.control.reshape(-1, 3) for p in parts])
        samples = sample_parts(parts, options.sample_order)
        self.seconds["sample"] = time.perf_counter() - clock
        clock = time.perf_counter()
        self.quadrature = ray_cast_quadrature(parts, options.lines_per_side, options.quadrature_order, name=name)
        self.seconds["quadrature"] = time.perf_counter() - clock
        clock = time.perf_counter()
        self.blend, self.blend_gradients, self.alpha = self._blending_weights()
        self.seconds["weights"] = time.perf_counter() - clock
        clock = time.perf_counter()
        self.origin_of_part = self._origins()
        self.seconds["origins"] = time.perf_counter() - clock
        clock = time.perf_counter()
        neighbours = _blended_neighbours(self.blend)
        names = [p.name for p in parts]
        self.matching = shape_matching(samples, options.degree, self.origin_of_part, names, neighbours)
        self.seconds["projection"] = time.perf_counter() - clock
        clock = time.perf_counter()
        self._build_operators(samples)
        self.seconds["operators"] = time.perf_counter() - clock
        self._check_rest_shape()

    def _check_rest_shape(self) -> None:
        """The rest shape must map to itself (``F = I`` at every quadrature point): where a part's
        polynomial is fitted from too few samples its blend may not reproduce it.

        Raises:
            SurfaceError: naming the parts blended where it fails and what to raise.
        """
        deviation = np.abs(self.deformation_gradients(self.reference) - np.eye(3)).max(axis=(1, 2))
        wrong = np.flatnonzero(deviation > REST_TOLERANCE)
        if not len(wrong):
            return
        worst = wrong[np.argmax(deviation[wrong])]
        blended = sorted({self.parts[i].name for i in self.blend[wrong].nonzero()[1]})
        raise SurfaceError(
            f"{self.name}: the rest shape is not reproduced at {len(wrong)} of {len(deviation)} quadrature points "
            f"(|F - I| up to {deviation[worst]:.3g}, near {np.round(self.quadrature.points[worst], 4).tolist()}), "
            f"where parts {', '.join(blended)} blend: the shape matching is not well posed there; raise "
            f"lines_per_side ({self.options.lines_per_side}) or the blending cutoff (alpha {self.alpha:.3g})"
        )

    def _blending_weights(self) -> tuple[scipy.sparse.csr_matrix, np.ndarray | None, float]:
        points, options = self.quadrature.points, self.options
        if len(self.parts) == 1:
            return scipy.sparse.csr_matrix(np.ones((len(points), 1))), None, np.inf
        lo, hi = model_bounds(self.parts)
        diagonal = float(np.linalg.norm(hi - lo))
        if options.alpha is not None:
            if not (np.isfinite(options.alpha) and options.alpha > 0.0):
                raise SurfaceError(f"{self.name}: alpha must be positive, got {options.alpha!r}")
            distances = ray_distances(self.parts, points, options.alpha)
            return distances.weights(options.alpha), self._gradients(distances, options.alpha), options.alpha
        if options.sparsity is None:
            distances, alpha = ray_distances(self.parts, points, 0.5 * diagonal), 0.5 * diagonal
        else:
            distances, alpha = cutoff_distances(self.parts, points, 0.5 * diagonal, options.sparsity, self.name)
        return distances.weights(alpha), self._gradients(distances, alpha), alpha

    def _sample_blends(self, samples) -> list[scipy.sparse.csr_matrix]:
        """The blending weights ``(samples, parts)`` at each part's boundary samples (cutoff alpha)."""
        counts = [len(s.points) for s in samples]
        if len(self.parts) == 1:
            return [scipy.sparse.csr_matrix(np.ones((count, 1))) for count in counts]
        points = np.concatenate([s.points for s in samples])
        on_part = np.repeat(np.arange(len(samples)), counts)
        reach = min(self.alpha, float(np.linalg.norm(np.subtract(*model_bounds(self.parts)))))
        weights = ray_distances(self.parts, points, reach, on_part).weights(self.alpha)
        starts = np.r_[0, np.cumsum(counts)]
        return [weights[a:b] for a, b in zip(starts[:-1], starts[1:], strict=True)]

    def _gradients(self, distances: RayDistances, alpha: float) -> np.ndarray | None:
        return distances.weight_gradients(alpha) if self.options.weight_gradients else None

    def _origins(self) -> np.ndarray:
        origins = self.options.origins
        if isinstance(origins, str):
            if origins not in ("flow", "single"):
                raise SurfaceError(
                    f"{self.name}: origins must be 'flow', 'single' or one index per part, got {origins!r}"
                )
            if origins == "single" or len(self.parts) == 1:
                return np.zeros(len(self.parts), dtype=int)
            return deformation_origins(self.blend, self.name)
        indices = np.asarray(origins)
        if indices.shape != (len(self.parts),) or not np.issubdtype(indices.dtype, np.integer) or indices.min() < 0:
            raise SurfaceError(
                f"{self.name}: origins must give one index >= 0 per part ({len(self.parts)}), got {origins!r}"
            )
        return indices

    def _build_operators(self, samples) -> None:
        matching, rule = self.matching, self.quadrature
        phi, grad = matching.kinematic_maps(rule.points, self.blend, self.blend_gradients)
        projection = matching.projection
        # deformation gradient rows: F[k, c, d] = sum_m G_d[k, m] C[m, c]; in interleaved columns
        # (3 m + c) of the coefficients, row 9 k + 3 c + d
        blocks = []
        for c in range(3):
            for d in range(3):
                select = scipy.sparse.csr_matrix(([1.0], ([0], [c])), shape=(1, 3))
                blocks.append((c, d, scipy.sparse.kron(grad[d], select, format="csr")))
        count = len(rule.points)
        stacked = scipy.sparse.vstack([b for _, _, b in blocks]).tocsr()  # rows (3c + d) * Q + k
        order = np.arange(9 * count).reshape(9, count).T.ravel()  # to rows 9 k + 3 c + d
        self._projection = _interleave(projection)
        self._coefficient_gradients = stacked[order]  # (9 Q, 3 coefficients): F = this @ (Pi q)
        self._scalar_gradients = grad  # the stiffness is assembled on the coefficients, by groups of points
        # material per quadrature point: the part of largest blending weight
        part_of_point = np.asarray(self.blend.argmax(axis=1)).ravel()
        lame = [Lame.of(m.young, m.poisson) for m in self.materials]
        self._mu = np.array([lame[i].mu for i in part_of_point])
        self._lam = np.array([lame[i].lam for i in part_of_point])
        self._density = np.array([self.materials[i].density for i in part_of_point])
        self._model = MODELS[self.materials[0].model]
        # consistent mass: Pi^T Phi^T diag(rho v) Phi Pi per component
        position_map = phi @ projection  # (Q, n_q): x = position_map @ q
        self.position_map = position_map
        self.mass_scalar = congruence(projection, weighted_gram(phi, self._density * rule.weights))
        # error energy (eq. 16): each part's boundary samples under the blended map Gamma(X) q
        # against the part itself, J(X) q; the blend ties every part to the volume's polynomials
        gamma = self.options.error_stiffness
        gammas = [m.young if gamma is None else gamma for m in self.materials]
        blends = self._sample_blends(samples)
        rows = []
        for s, part_basis, blend, part_gamma in zip(samples, stacked_bases(samples), blends, gammas, strict=True):
            boundary_phi, _ = matching.kinematic_maps(s.points, blend)
            difference = boundary_phi @ projection - part_basis
            rows.append(weighted_gram(difference, part_gamma * s.weights))
        self.error_scalar = sum(rows).tocsr()
        self._error = _interleave(self.error_scalar)
        self.whole = QuadratureShare(self, 0, len(rule.points))

    def share(self, part: int, parts: int) -> QuadratureShare:
        """The ``part``-th of ``parts`` contiguous shares of the quadrature points (a rank's)."""
        if parts == 1:
            return self.whole  # its point groups are made already
        count = len(self.quadrature.points)
        return QuadratureShare(self, count * part // parts, count * (part + 1) // parts)

    # ---- the solid as an energy -----------------------------------------------------------

    @property
    def dof_count(self) -> int:
        return 3 * len(self.reference)

    def deformation_gradients(self, q: np.ndarray) -> np.ndarray:
        """``(Q, 3, 3)`` at the quadrature points for control points ``q (n_q, 3)``."""
        return self.whole.deformation_gradients(q)

    def positions(self, q: np.ndarray) -> np.ndarray:
        """``(Q, 3)`` deformed quadrature points for control points ``q (n_q, 3)``."""
        return self.position_map @ np.asarray(q, dtype=float).reshape(-1, 3)

    def deformed_parts(self, q: np.ndarray) -> list[NurbsSurface]:
        """The parts with control points ``q (n_q, 3)`` (stacked in part order)."""
        q = np.asarray(q, dtype=float).reshape(-1, 3)
        return [
            part.with_control(q[start:stop].reshape(part.control.shape))
            for part, start, stop in zip(self.parts, self.offsets[:-1], self.offsets[1:], strict=True)
        ]

    def cauchy_stresses(self, q: np.ndarray) -> np.ndarray:
        """``(Q, 3, 3)`` Cauchy stresses [Pa] ``P F^T / det F`` at the quadrature points."""
        f = self.deformation_gradients(q)
        _, first_piola, _ = self._model(f, self._mu, self._lam, tangent=False)
        return np.einsum("kij,klj->kil", first_piola.reshape(-1, 3, 3), f) / np.linalg.det(f)[:, None, None]

    @property
    def error_matrix(self) -> scipy.sparse.csr_matrix:
        """``(3 n_q, 3 n_q)``: the error energy is ``q^T E q / 2`` (interleaved ``q``)."""
        return self._error

    def energy(self, q: np.ndarray) -> float:
        """Elastic plus error energy [J] (inf where some ``det F <= 0``)."""
        flat = np.asarray(q, dtype=float).reshape(-1)
        return self.whole.energy(q) + 0.5 * float(flat @ (self._error @ flat))

    def gradient(self, q: np.ndarray) -> np.ndarray:
        """``(3 n_q,)`` interleaved."""
        return self.whole.gradient(q) + self._error @ np.asarray(q, dtype=float).reshape(-1)

    def hessian(self, q: np.ndarray, projected: bool = True) -> scipy.sparse.csr_matrix:
        """``(3 n_q, 3 n_q)``; ``projected``: each point's tangent clamped positive semi-definite."""
        return (self.whole.hessian(q, projected) + self._error).tocsr()

    def mass_matrix(self) -> scipy.sparse.csr_matrix:
        """``(3 n_q, 3 n_q)`` consistent mass [kg]."""
        return _interleave(self.mass_scalar)

    def gravity_force(self, gravity: np.ndarray) -> np.ndarray:
        """``(3 n_q,)`` generalized force of ``rho g`` [N]: ``(Pi^T Phi^T rho v) ⊗ g``."""
        weights = self.position_map.T @ (self._density * self.quadrature.weights)
        return np.outer(weights, np.asarray(gravity, dtype=float)).reshape(-1)

    @property
    def mass(self) -> float:
        return float(self._density @ self.quadrature.weights)
