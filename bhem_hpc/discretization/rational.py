"""The rational B-spline (NURBS) discretization: control points as the unknowns, the homogeneous
field assembled in a Lagrange space.

With fixed weights ``w`` the homogeneous field ``Y = sum_i N_i (w_i q_i)`` is a polynomial B-spline
and lies exactly in the Lagrange space ``Q_p`` of the knot spans, as in
:mod:`.bspline`: the open layout holds ``Y`` at the ``Q_p`` DOF points, the prolongation
``E_w[b, i] = N_i(xi_b) w_i`` takes control points to it, and the position the forms see is
``x = Y / W`` with the fixed weight field ``W = sum_i N_i w_i`` (:attr:`weight`, a Function of the
same space whose three components all hold ``W``). The shell model rewrites its forms in ``Y``
(:meth:`RationalBSplineDiscretization.position_map`): every energy of ``x`` is an energy of ``Y``,
its derivatives follow by the chain rule through the linear map ``Y -> Y / W``.

Point bases (loads, probes, joints, collision meshes) are rational, ``phi_b / W`` and its
quotient-rule derivatives, so they act on the open ``Y`` values as the polynomial bases act on
positions.

A part's own non-uniform knots need nothing else: on each of the grid's uniform spans the basis,
as a function of the span's local coordinate, is still a polynomial of degree ``p`` (the part's
Bezier extraction), so it lies in ``Q_p`` too; its Greville points need not be DOF points, so
open values go back to control points by least squares over the DOF points (exact for the
fields of the space).
"""

from __future__ import annotations

import dolfinx.fem
import numpy as np
import scipy.sparse
import scipy.sparse.linalg
from mpi4py import MPI

from bhem_hpc.discretization.bspline import BSplineDiscretization
from bhem_hpc.discretization.protocol import DiscretizationError
from bhem_hpc.geometry.bspline import Knots, check_degree, point_weights
from bhem_hpc.geometry.rational_bspline import RationalBSplinePatches, RationalBSplineSurface, control_shape
from bhem_hpc.geometry.surface import ParameterGrid


def _same_knots(first: Knots | None, second: Knots | None) -> bool:
    """Whether two surfaces' non-uniform knots (None: uniform) are the same."""
    first, second = first or (None, None), second or (None, None)
    return all((a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))
               for a, b in zip(first, second, strict=True))  # fmt: skip


class RationalBSplineDiscretization(BSplineDiscretization):
    """Degree-``p`` rational B-splines (p = 2 or 3) with fixed ``weights (c1, c2)`` on ``grid``."""

    def __init__(self, grid: ParameterGrid, degree: int, weights: np.ndarray, comm: MPI.Comm = MPI.COMM_WORLD,
                 knots: Knots | None = None):  # fmt: skip
        self.weights, self.knots = np.asarray(weights, dtype=float), knots  # the patches are made of them
        expected = control_shape(grid, check_degree(degree), knots)
        if self.weights.shape != expected:
            raise DiscretizationError(f"weights must have shape {expected}, got {self.weights.shape}")
        super().__init__(grid, degree, comm)
        # E_w: the (polynomial) B-spline basis at the DOF points times the weights: the homogeneous map
        p1, p2, t1, t2 = grid.locate(self.block_points[:, 0], self.block_points[:, 1])
        self._rows, basis = point_weights(grid, self.degree, p1, p2, t1, t2, knots=knots)
        self._weights = basis * self.weights.ravel()[self._rows]
        self._normal_solve = None
        self._open_weight = self._weights.sum(axis=1)  # W at every open block (owned + ghost)
        self.weight = dolfinx.fem.Function(self.function_space, name="weight")
        self.weight.x.array[:] = np.repeat(self._open_weight, 3)

    def _make_patches(self, grid: ParameterGrid, degree: int) -> RationalBSplinePatches:
        return RationalBSplinePatches(grid, degree, self.weights, self.knots)

    def _greville_setup(self) -> None:
        """On uniform knots the Greville interpolation; a part's own knots go back by least squares."""
        if self.knots is None:
            super()._greville_setup()

    # -- surface <-> layouts ---------------------------------------------------------------------
    def _check(self, surface: RationalBSplineSurface) -> None:
        if (not isinstance(surface, RationalBSplineSurface) or surface.grid != self.grid
                or surface.degree != self.degree or not np.array_equal(surface.weights, self.weights)
                or not _same_knots(surface.knots, self.knots)):  # fmt: skip
            raise DiscretizationError(f"the surface is not a degree-{self.degree} rational B-spline on {self.grid} "
                                      f"with these weights and knots (got {type(surface).__name__})")  # fmt: skip

    def surface_of_entries(self, entries: np.ndarray) -> RationalBSplineSurface:
        return RationalBSplineSurface(self.grid, self.degree, np.asarray(entries).reshape(*self.control_shape, 3),
                                      self.weights, self.knots)  # fmt: skip

    def open_to_entries(self, open_array: np.ndarray) -> np.ndarray:
        """Collective: the control points of the field whose homogeneous open values are given:
        interpolated at the Greville points on uniform knots; on a part's own knots (whose Greville
        points need not be DOF points) the least-squares fit over every owned DOF point, exact for
        the fields of the space."""
        if self.knots is None:
            return super().open_to_entries(open_array) / self.weights.reshape(-1, 1)
        owned = self.num_owned_blocks
        parts = self.comm.allgather((self._rows[:owned], self._weights[:owned],
                                     np.asarray(open_array).reshape(-1, 3)[:owned]))  # fmt: skip
        rows, values, data = (np.concatenate(column) for column in zip(*parts, strict=True))
        if self._normal_solve is None:  # E_w^T E_w, factorized once (the same on every rank)
            width = rows.shape[1]
            matrix = scipy.sparse.csr_matrix((values.ravel(), rows.ravel(), np.arange(len(rows) + 1) * width),
                                             shape=(len(rows), self.num_entries))  # fmt: skip
            self._normal_solve = (matrix, scipy.sparse.linalg.factorized((matrix.T @ matrix).tocsc()))
        matrix, solve = self._normal_solve  # E_w holds the weights: its solution is the control points
        right = matrix.T @ data
        return np.stack([solve(right[:, c]) for c in range(3)], axis=1)

    # -- the position the forms see ----------------------------------------------------------------
    def position_map(self):
        """``x = Y / W``: what the shell model's forms take for a homogeneous Function ``Y`` (and for
        its variations, the map being linear)."""
        weight = self.weight[0]
        return lambda homogeneous: homogeneous / weight

    def open_block_weights(self) -> np.ndarray:
        """``(open blocks,)`` ``W`` at each DOF point: an open block over it is the position there."""
        return self._open_weight

    # -- point data ----------------------------------------------------------------------------------
    def point_basis(self, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        """``(open blocks, phi / W)``: the rational basis at a parameter point, on the rank owning it."""
        return self.points_basis(np.array([xi1]), np.array([xi2]))[0]

    def points_basis(self, xi1: np.ndarray, xi2: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """:meth:`point_basis` at parameter points ``xi1, xi2 (N,)``, tabulated at once."""
        bases = self.grid_mesh.tabulate_points(self.element, self._cell_dofs, xi1, xi2)
        return [(blocks, values / (values @ self._open_weight[blocks]) if len(blocks) else values)
                for blocks, values in bases]  # fmt: skip

    def point_frame_basis(self, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        """``(open blocks (n,), values (3, n))``: the rational basis and its xi1 and xi2 derivatives
        (the quotient rule ``(phi_a - (phi / W) W_a) / W``) on the rank owning the point."""
        blocks, values = self.grid_mesh.tabulate_point(self.element, self._cell_dofs, xi1, xi2, derivatives=True)
        if not len(blocks):
            return blocks, values
        weight = values @ self._open_weight[blocks]  # (3,): W, W_1, W_2
        rational = values[0] / weight[0]
        return blocks, np.stack([rational, *((values[a] - rational * weight[a]) / weight[0] for a in (1, 2))])
