"""The dolfinx mesh of a parameter grid: one quadrilateral cell per patch, all sharing one Jacobian."""

from __future__ import annotations

import dolfinx
import dolfinx.mesh
import numpy as np
from mpi4py import MPI

from bhem_hpc.discretization.protocol import DiscretizationError
from bhem_hpc.geometry.surface import ParameterGrid


def shared_jacobian(cell_vertices: np.ndarray, patch_size: tuple[float, float], comm: MPI.Comm) -> np.ndarray:
    """The one Jacobian ``J[b, a] = dxi_b / dX_a`` shared by all cells (collective).

    Args:
        cell_vertices: ``(cells, 4, 2)`` parameter coordinates of each cell's reference vertices
            (0,0), (1,0), (0,1), (1,1).
        patch_size: ``(h1, h2)``, for tolerances.

    Raises:
        DiscretizationError: a cell is not a parallelogram, cells (on any rank) have different
            Jacobians, or the Jacobian is not axis aligned.
    """
    v = np.asarray(cell_vertices, dtype=float)
    jac = np.stack([v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]], axis=2)  # (cells, b, a)
    tol = 1e-10 * max(patch_size)
    skew = np.abs(v[:, 3] - v[:, 1] - v[:, 2] + v[:, 0]).max(axis=1) if len(v) else np.zeros(0)
    first_skew = comm.allreduce(int(np.argmax(skew)) if np.any(skew > tol) else -1, op=MPI.MAX)
    if first_skew >= 0:
        detail = (
            f"cell {int(np.argmax(skew))} has vertices {v[int(np.argmax(skew))].tolist()}"
            if np.any(skew > tol)
            else "on another rank"
        )
        raise DiscretizationError(f"a cell is not a parallelogram ({detail}): the grid is not uniform")
    reference = comm.bcast(jac[0] if len(jac) and comm.rank == 0 else None, root=0)
    if reference is None:
        raise DiscretizationError("rank 0 holds no cells: use fewer ranks or more patches")
    mismatch = np.abs(jac - reference).max(axis=(1, 2)) if len(jac) else np.zeros(0)
    bad = np.flatnonzero(mismatch > tol)
    if comm.allreduce(len(bad), op=MPI.SUM):
        detail = f"cell {bad[0]} has J = {jac[bad[0]].tolist()}" if len(bad) else "a cell on another rank differs"
        raise DiscretizationError(
            f"cells do not share one Jacobian ({detail}; cell 0 of rank 0 has {reference.tolist()}): the Hermite "
            "DOFs are reference-cell derivatives and need a uniform, consistently ordered grid"
        )
    axis_aligned = abs(reference[0, 0] * reference[0, 1]) <= tol**2 and abs(reference[1, 0] * reference[1, 1]) <= tol**2
    if not axis_aligned or abs(np.linalg.det(reference)) < tol**2:
        raise DiscretizationError(f"cell Jacobian {reference.tolist()} is not axis aligned")
    return reference


class GridMesh:
    """The quadrilateral mesh of ``grid`` (the open grid: seams are not identified here).

    Attributes:
        mesh: the dolfinx mesh over the parameter domain.
        cell_vertices: ``(cells, 4, 2)`` parameters of each local cell's reference vertices.
        jacobian: the one ``J[b, a] = dxi_b / dX_a`` of every cell.
        patch_cells: ``(n1, n2)`` the owned local cell of each patch, -1 where another rank owns it.
    """

    def __init__(self, grid: ParameterGrid, comm: MPI.Comm):
        self.grid = grid
        self.mesh = dolfinx.mesh.create_rectangle(
            comm,
            [
                np.array([grid.xi1_range[0], grid.xi2_range[0]]),
                np.array([grid.xi1_range[1], grid.xi2_range[1]]),
            ],
            [grid.n1, grid.n2],
            dolfinx.mesh.CellType.quadrilateral,
        )
        geometry = self.mesh.geometry
        cells = self.mesh.topology.index_map(2)
        nodes = np.array(
            [geometry.dofmap.links(c) for c in range(cells.size_local + cells.num_ghosts)], dtype=np.int64
        )
        self.cell_vertices = geometry.x[nodes][:, :, :2]
        self.jacobian = shared_jacobian(self.cell_vertices, (grid.h1, grid.h2), comm)
        h = np.array([grid.h1, grid.h2])
        origin = np.array([grid.xi1_range[0], grid.xi2_range[0]])
        corner = np.rint((self.cell_vertices.min(axis=1) - origin) / h).astype(np.int64)
        self.patch_cells = np.full((grid.n1, grid.n2), -1, dtype=np.int64)
        owned = corner[: cells.size_local]
        self.patch_cells[owned[:, 0], owned[:, 1]] = np.arange(len(owned))

    def reference_points(self, xi1: np.ndarray, xi2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The owned local cells ``(N,)`` holding parameter points ``xi1, xi2 (N,)`` (-1 where another
        rank owns the cell) and the points' reference coordinates ``(N, 2)`` in them, clipped to the
        cell (zeros where not owned)."""
        grid = self.grid
        xi1, xi2 = np.broadcast_arrays(np.asarray(xi1, dtype=float).ravel(), np.asarray(xi2, dtype=float).ravel())
        p1, p2, _, _ = grid.locate(xi1, xi2)
        cells = self.patch_cells[p1, p2]
        owned = cells >= 0
        xi = np.stack([xi1[owned], xi2[owned]], axis=1)
        origin = self.cell_vertices[cells[owned], 0]
        periods = ((grid.periodic1, grid.xi1_range), (grid.periodic2, grid.xi2_range))
        for k, (periodic, (low, high)) in enumerate(periods):
            if periodic:  # bring a wrapped parameter into its cell
                xi[:, k] = origin[:, k] + np.mod(xi[:, k] - origin[:, k], high - low)
        reference = np.zeros((len(cells), 2))
        reference[owned] = np.clip(np.linalg.solve(self.jacobian, (xi - origin).T).T, 0.0, 1.0)
        return cells, reference

    def tabulate_points(self, element, cell_dofs: np.ndarray, xi1: np.ndarray, xi2: np.ndarray,
                        derivatives: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:  # fmt: skip
        """The basis of ``element`` at parameter points ``xi1, xi2 (N,)``, each in the owned cell
        holding it: one basix tabulation for all points.

        Args:
            element: the basix element of every cell; cell_dofs: ``(cells, n)`` each cell's open blocks.
            derivatives: with the first parametric derivatives.

        Returns:
            Per point ``(blocks (n,), values)``: values ``(n,)``, or with ``derivatives`` ``(3, n)``
            (value, d/dxi1, d/dxi2); empty arrays where another rank owns the cell.
        """
        cells, reference = self.reference_points(xi1, xi2)
        owned = np.flatnonzero(cells >= 0)
        empty = (np.zeros(0, dtype=np.int64), np.zeros((3, 0) if derivatives else 0))
        bases = [empty] * len(cells)
        if not len(owned):
            return bases
        table = element.tabulate(1 if derivatives else 0, reference[owned])[..., 0]  # (derivatives, points, n)
        if derivatives:
            # d/dX_a = sum_b d/dxi_b J[b, a]: the parametric gradient is J^-T times the reference one
            slopes = np.linalg.solve(self.jacobian.T, table[1:].reshape(2, -1)).reshape(table[1:].shape)
            table = np.concatenate([table[:1], slopes])
        for k, point in enumerate(owned):
            bases[point] = (cell_dofs[cells[point]], table[:, k] if derivatives else table[0, k])
        return bases

    def tabulate_point(self, element, cell_dofs: np.ndarray, xi1: float, xi2: float,
                       derivatives: bool = False) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """:meth:`tabulate_points` at one parameter point."""
        return self.tabulate_points(element, cell_dofs, np.array([xi1]), np.array([xi2]), derivatives)[0]
