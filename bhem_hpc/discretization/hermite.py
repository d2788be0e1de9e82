"""The bicubic Hermite discretization: :class:`~bhem_hpc.discretization.protocol.Discretization`
on the element of :mod:`.element`, one cell per patch of the open parameter grid.

Two DOF layouts appear:

* *open*: the dolfinx function space on the open parameter grid, blocked with block size 3
  (``array[3 * block + component]``), local = owned + ghost blocks. Forms are assembled here.
* *closed*: the unknowns the solver iterates on. On a surface without periodic directions it is
  the open layout itself; on a closed surface each seam node is kept once (paper §4.2) and the
  open vector is ``P @ closed`` with the 0/1 prolongation ``P`` whose nonzeros are
  ``(open block, closed block)`` = (:attr:`open_blocks`, :attr:`closed_of_open`).

This module is the *only* place that converts between parametric derivatives and the element's
reference-cell DOFs (see :meth:`HermiteDiscretization.reference_scale`).
"""

from __future__ import annotations

import dolfinx
import dolfinx.fem
import dolfinx.mesh
import numpy as np
from mpi4py import MPI

from bhem_hpc.discretization.element import DOFS_PER_VERTEX, create_hermite_element, hermite_ufl_element
from bhem_hpc.discretization.grid_mesh import GridMesh
from bhem_hpc.discretization.protocol import ConstrainedDofs, DiscretizationError
from bhem_hpc.geometry.surface import KIND_NAMES, HermitePatches, HermiteSurface, ParameterGrid

GDIM = 3


class HermiteDiscretization:
    """Bicubic Hermite elements on the open parameter grid of a surface.

    Args:
        grid: the parameter grid (from the surface).
        comm: MPI communicator.

    Raises:
        DiscretizationError: if the cells do not share one axis-aligned Jacobian, which C1
            continuity with reference-cell derivative DOFs requires.
    """

    def __init__(self, grid: ParameterGrid, comm: MPI.Comm = MPI.COMM_WORLD):
        self.comm = comm
        self.grid = grid
        self.grid_mesh = GridMesh(grid, comm)
        self.mesh = self.grid_mesh.mesh
        self.element = create_hermite_element()
        self.function_space = dolfinx.fem.FunctionSpace(self.mesh, hermite_ufl_element(GDIM))
        self.jacobian = self.grid_mesh.jacobian
        self._cell_vertices = self.grid_mesh.cell_vertices
        self._scale = self.reference_scale(self.jacobian)
        self._build_block_maps()

    @staticmethod
    def reference_scale(jacobian: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """How reference DOFs relate to parametric derivatives for an axis-aligned Jacobian.

        Reference DOF ``k`` (value, d/dX, d/dY, d2/dXdY) equals ``scale[k]`` times the
        parametric nodal datum of kind ``kind[k]`` (x, d1, d2, d12).

        Returns:
            ``(kind, scale)``, each of shape ``(4,)``.
        """
        j = jacobian
        if abs(j[0, 0]) > abs(j[1, 0]):  # reference X runs along xi1
            kind = np.array([0, 1, 2, 3])
            scale = np.array([1.0, j[0, 0], j[1, 1], j[0, 0] * j[1, 1]])
        else:  # reference X runs along xi2
            kind = np.array([0, 2, 1, 3])
            scale = np.array([1.0, j[1, 0], j[0, 1], j[1, 0] * j[0, 1]])
        return kind, scale

    # -- block maps ------------------------------------------------------------------------------
    def _build_block_maps(self) -> None:
        grid = self.grid
        index_map = self.function_space.dofmap.index_map
        self.num_owned_blocks = index_map.size_local
        num_blocks = index_map.size_local + index_map.num_ghosts
        kind_of_ref, _ = self._scale
        node_of_block = np.full((num_blocks, 2), -1, dtype=np.int64)
        ref_of_block = np.full(num_blocks, -1, dtype=np.int64)
        h = np.array([grid.h1, grid.h2])
        origin = np.array([grid.xi1_range[0], grid.xi2_range[0]])
        vertex_nodes = np.rint((self._cell_vertices - origin) / h).astype(np.int64)  # (cells, 4, 2)
        dofmap = self.function_space.dofmap
        cells = np.arange(len(vertex_nodes))
        cell_dofs = np.array([dofmap.cell_dofs(c) for c in cells], dtype=np.int64).reshape(
            len(cells), 4, DOFS_PER_VERTEX
        )
        node_of_block[cell_dofs.ravel()] = np.repeat(vertex_nodes.reshape(-1, 2), DOFS_PER_VERTEX, axis=0)
        ref_of_block[cell_dofs.ravel()] = np.tile(np.arange(DOFS_PER_VERTEX), len(cells) * 4)
        if np.any(ref_of_block < 0):
            raise DiscretizationError("some DOF blocks belong to no local cell")
        self.open_node = node_of_block  # (blocks, 2) open-grid node of each local block
        self.block_reference_kind = ref_of_block
        self.block_kind = kind_of_ref[ref_of_block]  # parametric kind of each local block
        self.block_scale = self._scale[1][ref_of_block]
        self.distinct_node = np.stack(grid.wrap_node(node_of_block[:, 0], node_of_block[:, 1]), axis=1)
        self._cell_dofs = cell_dofs.reshape(len(cells), 16)

        # Closed numbering: one block per entry (distinct node, kind); owned where the open block
        # with the unwrapped node (the seam's first copy) is owned.
        m1, m2 = grid.node_shape
        self.entry_of_block = (self.distinct_node[:, 0] * m2 + self.distinct_node[:, 1]) * 4 + self.block_kind
        key = self.entry_of_block
        if not self.is_periodic:
            self.closed_of_open = np.asarray(
                index_map.local_to_global(np.arange(num_blocks, dtype=np.int32)), dtype=np.int64
            )
            self.closed_offset = index_map.local_range[0]
            self.num_owned_closed = self.num_owned_blocks
            owned_master = np.arange(self.num_owned_blocks)
        else:
            is_master = np.all(self.open_node == self.distinct_node, axis=1)
            owned_master = np.flatnonzero(is_master[: self.num_owned_blocks])
            self.num_owned_closed = len(owned_master)
            self.closed_offset = self.comm.exscan(self.num_owned_closed) or 0
            lookup = np.full(m1 * m2 * 4, -1, dtype=np.int64)
            for keys, first in self.comm.allgather((key[owned_master], self.closed_offset)):
                lookup[keys] = first + np.arange(len(keys))
            self.closed_of_open = lookup[key]
            if np.any(self.closed_of_open < 0):
                raise DiscretizationError("seam identification failed: a closed DOF has no owner")
        self.num_closed = self.comm.allreduce(self.num_owned_closed)
        # Owned closed blocks in closed order: (local open block that represents it).
        order = np.argsort(self.closed_of_open[owned_master])
        self.owned_closed_open_block = owned_master[order]
        # Every entry's global closed block and scale, on every rank (contact rows name entries).
        owned = self.owned_closed_open_block
        self._entry_closed_block = np.full(m1 * m2 * 4, -1, dtype=np.int64)
        self._entry_scale = np.zeros(m1 * m2 * 4)
        owned_entries = (self.entry_of_block[owned], self.closed_offset, self.block_scale[owned])
        for entries, first, scales in self.comm.allgather(owned_entries):
            self._entry_closed_block[entries] = first + np.arange(len(entries))
            self._entry_scale[entries] = scales

    # -- interface -----------------------------------------------------------------------------
    @property
    def is_periodic(self) -> bool:
        return self.grid.periodic1 or self.grid.periodic2

    @property
    def open_blocks(self) -> np.ndarray:
        """Owned open blocks (rows of P)."""
        return np.arange(self.num_owned_blocks)

    def _values(self, surface: HermiteSurface, blocks: np.ndarray) -> np.ndarray:
        if surface.grid != self.grid:
            raise DiscretizationError(f"surface grid {surface.grid} differs from the discretization's {self.grid}")
        node = self.distinct_node[blocks]
        values = surface.nodal[node[:, 0], node[:, 1], self.block_kind[blocks], :]
        return values * self.block_scale[blocks, None]

    def surface_to_open(self, surface: HermiteSurface) -> np.ndarray:
        """Open-layout DOF array (owned + ghost blocks), shape ``(3 * blocks,)``."""
        return self._values(surface, np.arange(len(self.block_kind))).ravel()

    def surface_to_closed(self, surface: HermiteSurface) -> np.ndarray:
        """Owned part of the closed-layout DOF vector, shape ``(3 * num_owned_closed,)``."""
        return self._values(surface, self.owned_closed_open_block).ravel()

    def closed_to_surface(self, closed: np.ndarray) -> HermiteSurface:
        """Collective: assemble the full surface from every rank's owned closed DOFs."""
        blocks = self.owned_closed_open_block
        values = np.asarray(closed, dtype=float).reshape(-1, 3) / self.block_scale[blocks, None]
        node = self.distinct_node[blocks]
        nodal = np.full((*self.grid.node_shape, 4, 3), np.nan)
        for n, k, v in self.comm.allgather((node, self.block_kind[blocks], values)):
            nodal[n[:, 0], n[:, 1], k] = v
        return HermiteSurface(self.grid, nodal)

    def open_to_surface(self, open_array: np.ndarray) -> HermiteSurface:
        """Collective: the surface of an open-layout array (owned blocks are read)."""
        owned = np.asarray(open_array).reshape(-1, 3)[self.owned_closed_open_block].ravel()
        return self.closed_to_surface(owned)

    def gather_raw_dofs(self, open_array: np.ndarray) -> np.ndarray:
        """Collective: the DOF values themselves (no unit conversion), for bit-exact checkpoints.

        Returns:
            ``(m1, m2, 4, 3)`` indexed ``[i1, i2, reference DOF, component]``, on every rank.
        """
        blocks = self.owned_closed_open_block
        local = (self.distinct_node[blocks], self.block_reference_kind[blocks], open_array.reshape(-1, 3)[blocks])
        out = np.zeros((*self.grid.node_shape, 4, 3))
        for node, kind, values in self.comm.allgather(local):
            out[node[:, 0], node[:, 1], kind] = values
        return out

    def scatter_raw_dofs(self, raw: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`gather_raw_dofs`: the open-layout array (owned + ghost blocks)."""
        node, kind = self.distinct_node, self.block_reference_kind
        return np.asarray(raw)[node[:, 0], node[:, 1], kind].ravel()

    def open_to_closed(self, open_array: np.ndarray) -> np.ndarray:
        """The owned closed array ``(3 * num_owned_closed,)`` of an open-layout array."""
        return np.asarray(open_array).reshape(-1, 3)[self.owned_closed_open_block].ravel()

    def position_map(self) -> None:
        """The open values are positions."""
        return None

    def open_block_weights(self) -> None:
        """The open blocks need no division."""
        return None

    @property
    def closed_is_open(self) -> bool:
        """Without seams the closed layout is the open one (no prolongation)."""
        return not self.is_periodic

    def set_ties(self, ties, rest) -> None:
        """Hermite nodal vectors are not tied (a tie joins B-spline control points)."""
        raise DiscretizationError("ties join control points of B-spline surfaces; Hermite surfaces have none")

    def component_ties(self) -> tuple[np.ndarray, np.ndarray]:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty

    def prolongation_offset(self) -> np.ndarray | None:
        return None

    def tied_roots(self, dofs: ConstrainedDofs) -> ConstrainedDofs:
        empty = np.zeros(0, dtype=np.int64)
        return ConstrainedDofs(empty, empty, np.zeros((0, 2), dtype=np.int64), empty, empty)

    def prolongation(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The seam prolongation over the owned open blocks as CSR ``(indptr, closed blocks,
        weights)``: one unit entry per block (None without seams)."""
        if self.closed_is_open:
            return None
        blocks = self.open_blocks
        return np.arange(len(blocks) + 1), self.closed_of_open[blocks], np.ones(len(blocks))

    # -- flat entries: the surface's nodal data as rows of an (N, 3) array --------------------
    @property
    def num_entries(self) -> int:
        """``N = 4 m1 m2``: entry ``(i1 * m2 + i2) * 4 + kind`` is the nodal datum of that kind."""
        return 4 * self.grid.num_nodes

    @property
    def patches(self) -> HermitePatches:
        """The patches as linear maps of the entries (point weights, Bezier nets)."""
        return HermitePatches(self.grid)

    def entries_of_surface(self, surface: HermiteSurface) -> np.ndarray:
        """The surface's entries ``(N, 3)``."""
        if surface.grid != self.grid:
            raise DiscretizationError(f"surface grid {surface.grid} differs from the discretization's {self.grid}")
        return surface.nodal.reshape(-1, 3)

    def surface_of_entries(self, entries: np.ndarray) -> HermiteSurface:
        """The surface whose entries are ``entries (N, 3)``."""
        return HermiteSurface(self.grid, np.asarray(entries).reshape(*self.grid.node_shape, 4, 3))

    def open_to_entries(self, open_array: np.ndarray) -> np.ndarray:
        """Collective: the entries ``(N, 3)`` of an open-layout array, on every rank."""
        return self.open_to_surface(open_array).nodal.reshape(-1, 3)

    def entries_to_open(self, entries: np.ndarray) -> np.ndarray:
        """Open-layout array (owned + ghost blocks) of entries ``(N, 3)``."""
        return (np.asarray(entries)[self.entry_of_block] * self.block_scale[:, None]).ravel()

    def entries_to_closed(self, entries: np.ndarray) -> np.ndarray:
        """Owned closed-layout array ``(3 * num_owned_closed,)`` of entries ``(N, 3)``."""
        blocks = self.owned_closed_open_block
        return (np.asarray(entries)[self.entry_of_block[blocks]] * self.block_scale[blocks, None]).ravel()

    def closed_to_entries(self, closed: np.ndarray) -> np.ndarray:
        """Collective: the entries ``(N, 3)`` of every rank's owned closed array, on every rank."""
        blocks = self.owned_closed_open_block
        out = np.zeros((self.num_entries, 3))
        local = (self.entry_of_block[blocks], np.asarray(closed).reshape(-1, 3))
        for entries, values in self.comm.allgather(local):
            out[entries] = values / self._entry_scale[entries, None]
        return out

    def entry_closed_blocks(self) -> tuple[np.ndarray, np.ndarray]:
        """Every entry's global closed block and scale, ``(N,)`` each, on every rank: the closed
        DOFs ``3 * block + component`` of entry ``e`` hold ``scale[e]`` times its value."""
        return self._entry_closed_block, self._entry_scale

    def select_dofs(self, nodes: np.ndarray, kinds: tuple[int, ...], components: tuple[int, ...]) -> ConstrainedDofs:
        """Owned closed DOFs of the given distinct nodes ``(k, 2)``, parametric kinds and components."""
        nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, 2)
        m1, m2 = self.grid.node_shape
        outside = (nodes[:, 0] < 0) | (nodes[:, 0] >= m1) | (nodes[:, 1] < 0) | (nodes[:, 1] >= m2)
        if np.any(outside):
            raise DiscretizationError(f"node {tuple(nodes[outside][0])} does not exist: the grid has {m1} x {m2} nodes")
        for k in kinds:
            if k not in range(4):
                raise DiscretizationError(f"DOF kind {k!r} does not exist (0..3 = {KIND_NAMES})")
        for c in components:
            if c not in range(3):
                raise DiscretizationError(f"component {c!r} does not exist (0, 1, 2 = x, y, z)")
        wanted = np.zeros((m1, m2, 4), dtype=bool)
        for k in kinds:
            wanted[nodes[:, 0], nodes[:, 1], k] = True
        blocks = self.owned_closed_open_block
        node = self.distinct_node[blocks]
        hit = np.flatnonzero(wanted[node[:, 0], node[:, 1], self.block_kind[blocks]])
        comps = np.asarray(components, dtype=np.int64)
        local = (3 * hit[:, None] + comps[None, :]).ravel()
        return ConstrainedDofs(
            rows=self.closed_offset * 3 + local,
            local=local,
            node=np.repeat(node[hit], len(comps), axis=0),
            kind=np.repeat(self.block_kind[blocks][hit], len(comps)),
            component=np.tile(comps, len(hit)),
        )

    def dof_values(self, surface: HermiteSurface, dofs: ConstrainedDofs) -> np.ndarray:
        """Reference-DOF values of ``surface`` at the selected DOFs, shape ``(k,)``."""
        return self.surface_to_closed(surface)[dofs.local]

    def point_basis(self, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        """The 16 basis values at a parameter point, in the cell that owns it on this rank.

        Returns:
            ``(blocks, values)`` of shape ``(16,)`` each (local open blocks); empty arrays on
            ranks that do not own the containing cell.
        """
        return self.grid_mesh.tabulate_point(self.element, self._cell_dofs, xi1, xi2)

    def points_basis(self, xi1: np.ndarray, xi2: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """:meth:`point_basis` at parameter points ``xi1, xi2 (N,)``, tabulated at once."""
        return self.grid_mesh.tabulate_points(self.element, self._cell_dofs, xi1, xi2)

    def point_frame_basis(self, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        """``(open blocks (n,), values (3, n))``: the basis and its derivatives along xi1 and xi2 at a
        parameter point (position and tangents), on the rank owning its cell (empty elsewhere)."""
        return self.grid_mesh.tabulate_point(self.element, self._cell_dofs, xi1, xi2, derivatives=True)
