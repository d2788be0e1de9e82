"""The B-spline discretization: control points as the unknowns, assembled in a Lagrange space.

A B-spline of degree ``p`` on uniform knots is a piecewise polynomial of degree ``p`` in each
parameter on every knot span, so it lies exactly in the continuous Lagrange space ``Q_p`` on the
knot-span mesh. Forms are assembled there (the *open* layout: equispaced ``Q_p`` DOFs, blocks of 3),
and the solver iterates on the control points (the *closed* layout). The prolongation ``E`` takes
control points to ``Q_p`` DOFs: row ``b`` holds the ``(p + 1)^2`` B-spline basis values at the DOF
point of block ``b``, so ``F_c = E^T F(E x_c)`` and ``J_c = E^T J E``. Periodic directions are
just another ``E``.

The inverse map (open values of a B-spline field to its control points) interpolates at the
Greville points: they are ``Q_p`` DOF points of the equispaced variant, so the open values there
determine the control points through the two 1-D collocation matrices (exact up to round-off).
"""

from __future__ import annotations

import basix
import basix.ufl_wrapper
import dolfinx.fem
import numpy as np
from mpi4py import MPI

from bhem_hpc.discretization.grid_mesh import GridMesh
from bhem_hpc.discretization.protocol import ConstrainedDofs, DiscretizationError
from bhem_hpc.geometry.bspline import (
    BSplinePatches,
    BSplineSurface,
    collocation,
    greville,
    interpolate_at_greville,
)
from bhem_hpc.geometry.surface import ParameterGrid

GDIM = 3


class BSplineDiscretization:
    """Degree-``p`` B-splines (p = 2 or 3) on the knot spans of ``grid``.

    Args:
        grid: the knot spans and periodic directions (from the surface).
        degree: 2 or 3.
        comm: MPI communicator. Control points are split among ranks in contiguous chunks of the
            order ``i1 * c2 + i2``.
    """

    def __init__(self, grid: ParameterGrid, degree: int, comm: MPI.Comm = MPI.COMM_WORLD):
        self.comm = comm
        self.grid = grid
        self.patches = self._make_patches(grid, degree)
        self.degree = self.patches.degree
        self.control_shape = self.patches.control_shape
        self.grid_mesh = GridMesh(grid, comm)
        self.mesh = self.grid_mesh.mesh
        self.jacobian = self.grid_mesh.jacobian
        self.element = basix.create_element(
            basix.ElementFamily.P, basix.CellType.quadrilateral, self.degree, basix.LagrangeVariant.equispaced
        )
        scalar = basix.ufl_wrapper.BasixElement(self.element)
        self.function_space = dolfinx.fem.FunctionSpace(self.mesh, basix.ufl_wrapper.VectorElement(scalar, GDIM))
        index_map = self.function_space.dofmap.index_map
        self.num_owned_blocks = index_map.size_local
        num_blocks = index_map.size_local + index_map.num_ghosts
        # equispaced DOF points lie on a lattice of step h / p: snapped to it, every rank computes the
        # same coordinates (and so the same values) for a DOF it owns or holds as a ghost
        points = self.function_space.tabulate_dof_coordinates()[:num_blocks, :2]
        origin = np.array([grid.xi1_range[0], grid.xi2_range[0]])
        step = np.array([grid.h1, grid.h2]) / self.degree
        self.block_points = origin + np.rint((points - origin) / step) * step
        p1, p2, t1, t2 = grid.locate(self.block_points[:, 0], self.block_points[:, 1])
        self._rows, self._weights = self.patches.point_entries(p1, p2, t1, t2)  # (blocks, (p+1)^2)
        cells = self.mesh.topology.index_map(2)
        dofmap = self.function_space.dofmap
        self._cell_dofs = np.array(
            [dofmap.cell_dofs(c) for c in range(cells.size_local + cells.num_ghosts)], dtype=np.int64
        )
        counts = [len(chunk) for chunk in np.array_split(np.arange(self.num_entries), comm.size)]
        self.num_owned_closed = counts[comm.rank]
        self.closed_offset = int(sum(counts[: comm.rank]))
        self.num_closed = self.num_entries
        self._greville_setup()

    def _make_patches(self, grid: ParameterGrid, degree: int) -> BSplinePatches:
        """The patch layout of the control points (a subclass's own kind of spline)."""
        return BSplinePatches(grid, degree)

    def _greville_setup(self) -> None:
        """Owned blocks at the tensor Greville points and the 1-D collocation matrices."""
        grid, p = self.grid, self.degree
        axes = []
        for points, (lo, hi), n, periodic, h in (
            (self.block_points[: self.num_owned_blocks, 0], grid.xi1_range, grid.n1, grid.periodic1, grid.h1),
            (self.block_points[: self.num_owned_blocks, 1], grid.xi2_range, grid.n2, grid.periodic2, grid.h2),
        ):
            g = greville(n, p, periodic, lo, hi)
            distance = np.abs(points[:, None] - g[None, :])
            index = np.argmin(distance, axis=1)
            axes.append(np.where(distance[np.arange(len(points)), index] <= 1e-9 * h, index, -1))
        hit = (axes[0] >= 0) & (axes[1] >= 0)
        self._greville_blocks = np.flatnonzero(hit)
        self._greville_nodes = np.stack([axes[0][hit], axes[1][hit]], axis=1)
        found = self.comm.allreduce(len(self._greville_blocks))
        if found != self.num_entries:
            raise DiscretizationError(
                f"{found} of the {self.num_entries} Greville points are DOF points of the degree-{p} Lagrange space"
            )
        self._collocation = (
            collocation(grid.n1, p, grid.periodic1, *grid.xi1_range),
            collocation(grid.n2, p, grid.periodic2, *grid.xi2_range),
        )

    # -- sizes and layouts -----------------------------------------------------------------------
    @property
    def num_entries(self) -> int:
        """``N = c1 c2`` control points; entry ``i1 * c2 + i2``."""
        return self.control_shape[0] * self.control_shape[1]

    @property
    def is_periodic(self) -> bool:
        return self.grid.periodic1 or self.grid.periodic2

    def position_map(self) -> None:
        """The open values are positions."""
        return None

    def open_block_weights(self) -> None:
        """The open blocks need no division."""
        return None

    @property
    def closed_is_open(self) -> bool:
        """Never: the open layout holds Lagrange DOFs, the closed one control points."""
        return False

    @property
    def open_blocks(self) -> np.ndarray:
        return np.arange(self.num_owned_blocks)

    def prolongation(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``E`` over the owned open blocks as CSR ``(indptr, closed blocks, weights)``."""
        owned = self.num_owned_blocks
        width = self._rows.shape[1]
        indptr = np.arange(owned + 1) * width
        return indptr, self._rows[:owned].ravel(), self._weights[:owned].ravel()

    def set_ties(self, ties, rest: BSplineSurface) -> None:
        """Tie control-point components (:class:`~bhem_hpc.model.bcs.NodalTie`): components joined by
        ties (directly or through others, as where two symmetry planes meet) follow one root, each at
        its rest offset from it."""
        c2 = self.control_shape[1]
        parent: dict[int, int] = {}

        def find(k: int) -> int:
            while parent.setdefault(k, k) != k:
                k = parent[k]
            return k

        slaves: set[int] = set()
        for tie in ties:
            for (s1, s2), (m1, m2) in zip(np.asarray(tie.nodes), np.asarray(tie.masters), strict=True):
                for c in tie.components:
                    slave, master = int(3 * (s1 * c2 + s2) + c), int(3 * (m1 * c2 + m2) + c)
                    slaves.add(slave)
                    parent[find(slave)] = find(master)
        groups: dict[int, list[int]] = {}
        for k in list(parent):
            groups.setdefault(find(k), []).append(k)
        members, roots = [], []
        for group in groups.values():  # the root: a component that is nobody's slave (else the first)
            root = min((k for k in group if k not in slaves), default=min(group))
            members += [k for k in group if k != root]
            roots += [root] * (len(group) - 1)
        self._tie_slaves, self._tie_masters = np.array(members, dtype=np.int64), np.array(roots, dtype=np.int64)
        rest_entries = self.entries_of_surface(rest).ravel()
        self._tie_offsets = rest_entries[self._tie_slaves] - rest_entries[self._tie_masters]

    def tied_roots(self, dofs: ConstrainedDofs) -> ConstrainedDofs:
        """Collective: the owned roots of the tied components among every rank's ``dofs`` (a held
        component that follows a root holds its root)."""
        slaves, masters = self.component_ties()
        held = np.concatenate(self.comm.allgather(np.asarray(dofs.rows, dtype=np.int64)))
        roots = np.unique(masters[np.isin(slaves, held)])
        first, last = 3 * self.closed_offset, 3 * (self.closed_offset + self.num_owned_closed)
        roots = roots[(roots >= first) & (roots < last)]
        entries, components = roots // 3, roots % 3
        c2 = self.control_shape[1]
        return ConstrainedDofs(rows=roots, local=roots - first, node=np.stack([entries // c2, entries % c2], axis=1),
                               kind=np.zeros(len(roots), dtype=np.int64), component=components)  # fmt: skip

    def component_ties(self) -> tuple[np.ndarray, np.ndarray]:
        empty = np.zeros(0, dtype=np.int64)
        return getattr(self, "_tie_slaves", empty), getattr(self, "_tie_masters", empty)

    def prolongation_offset(self) -> np.ndarray | None:
        slaves, _ = self.component_ties()
        if not len(slaves):
            return None
        offsets = np.zeros(3 * self.num_entries)
        offsets[slaves] = self._tie_offsets
        return self.entries_to_open(offsets.reshape(-1, 3))

    def _apply_ties(self, entries: np.ndarray) -> np.ndarray:
        """Entries ``(N, 3)`` with every tied component set from its master."""
        slaves, masters = self.component_ties()
        if len(slaves):
            flat = entries.reshape(-1)
            flat[slaves] = flat[masters] + self._tie_offsets
        return entries

    def _owned_entries(self) -> np.ndarray:
        return self.closed_offset + np.arange(self.num_owned_closed)

    # -- surface <-> layouts ---------------------------------------------------------------------
    def _check(self, surface: BSplineSurface) -> None:
        if not isinstance(surface, BSplineSurface) or surface.grid != self.grid or surface.degree != self.degree:
            raise DiscretizationError(
                f"the surface is not a degree-{self.degree} B-spline on {self.grid} (got {type(surface).__name__})"
            )

    def entries_of_surface(self, surface: BSplineSurface) -> np.ndarray:
        self._check(surface)
        return surface.control.reshape(-1, 3)

    def surface_of_entries(self, entries: np.ndarray) -> BSplineSurface:
        return BSplineSurface(self.grid, self.degree, np.asarray(entries).reshape(*self.control_shape, 3))

    def entries_to_open(self, entries: np.ndarray) -> np.ndarray:
        """Open array (owned + ghost blocks): ``E`` applied to entries ``(N, 3)``."""
        return np.einsum("bj,bjc->bc", self._weights, np.asarray(entries)[self._rows]).ravel()

    def entries_to_closed(self, entries: np.ndarray) -> np.ndarray:
        return np.asarray(entries)[self._owned_entries()].ravel()

    def closed_to_entries(self, closed: np.ndarray) -> np.ndarray:
        """Collective: every rank's owned control points, on every rank."""
        out = np.zeros((self.num_entries, 3))
        for first, values in self.comm.allgather((self.closed_offset, np.asarray(closed).reshape(-1, 3))):
            out[first : first + len(values)] = values
        return self._apply_ties(out)

    def open_to_entries(self, open_array: np.ndarray) -> np.ndarray:
        """Collective: the control points of a B-spline field given by its open values."""
        values = np.asarray(open_array).reshape(-1, 3)[self._greville_blocks]
        at_points = np.zeros((*self.control_shape, 3))
        for nodes, part in self.comm.allgather((self._greville_nodes, values)):
            at_points[nodes[:, 0], nodes[:, 1]] = part
        return interpolate_at_greville(*self._collocation, at_points).reshape(-1, 3)

    def entry_closed_blocks(self) -> tuple[np.ndarray, np.ndarray]:
        """Every control point is its own closed block, unscaled."""
        return np.arange(self.num_entries), np.ones(self.num_entries)

    def surface_to_open(self, surface: BSplineSurface) -> np.ndarray:
        return self.entries_to_open(self.entries_of_surface(surface))

    def surface_to_closed(self, surface: BSplineSurface) -> np.ndarray:
        return self.entries_to_closed(self.entries_of_surface(surface))

    def closed_to_surface(self, closed: np.ndarray) -> BSplineSurface:
        return self.surface_of_entries(self.closed_to_entries(closed))

    def open_to_surface(self, open_array: np.ndarray) -> BSplineSurface:
        return self.surface_of_entries(self.open_to_entries(open_array))

    def open_to_closed(self, open_array: np.ndarray) -> np.ndarray:
        """Collective (control points are recovered by interpolation)."""
        return self.entries_to_closed(self.open_to_entries(open_array))

    # -- constraints, point data, checkpoints ------------------------------------------------------
    def select_dofs(self, nodes: np.ndarray, kinds: tuple[int, ...], components: tuple[int, ...]) -> ConstrainedDofs:
        """Owned closed DOFs of control points ``nodes (k, 2)``; the only kind is 0 (the position)."""
        nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, 2)
        c1, c2 = self.control_shape
        outside = (nodes[:, 0] < 0) | (nodes[:, 0] >= c1) | (nodes[:, 1] < 0) | (nodes[:, 1] >= c2)
        if np.any(outside):
            raise DiscretizationError(
                f"control point {tuple(int(v) for v in nodes[outside][0])} does not exist: there are {c1} x {c2}"
            )
        if tuple(kinds) != (0,):
            raise DiscretizationError(
                f"DOF kinds {tuple(kinds)!r} do not exist for B-splines: a control point has only its position (0)"
            )
        for c in components:
            if c not in range(3):
                raise DiscretizationError(f"component {c!r} does not exist (0, 1, 2 = x, y, z)")
        entries = np.unique(nodes[:, 0] * c2 + nodes[:, 1])
        owned = entries[(entries >= self.closed_offset) & (entries < self.closed_offset + self.num_owned_closed)]
        comps = np.asarray(components, dtype=np.int64)
        local = (3 * (owned - self.closed_offset)[:, None] + comps[None, :]).ravel()
        return ConstrainedDofs(
            rows=3 * self.closed_offset + local,
            local=local,
            node=np.repeat(np.stack([owned // c2, owned % c2], axis=1), len(comps), axis=0),
            kind=np.zeros(len(local), dtype=np.int64),
            component=np.tile(comps, len(owned)),
        )

    def dof_values(self, surface: BSplineSurface, dofs: ConstrainedDofs) -> np.ndarray:
        return self.surface_to_closed(surface)[dofs.local]

    def point_basis(self, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        """The Lagrange basis values at a parameter point in its cell, on the rank owning it."""
        return self.grid_mesh.tabulate_point(self.element, self._cell_dofs, xi1, xi2)

    def points_basis(self, xi1: np.ndarray, xi2: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """:meth:`point_basis` at parameter points ``xi1, xi2 (N,)``, tabulated at once."""
        return self.grid_mesh.tabulate_points(self.element, self._cell_dofs, xi1, xi2)

    def point_frame_basis(self, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        """``(open blocks (n,), values (3, n))``: the basis and its derivatives along xi1 and xi2 at a
        parameter point (position and tangents), on the rank owning its cell (empty elsewhere)."""
        return self.grid_mesh.tabulate_point(self.element, self._cell_dofs, xi1, xi2, derivatives=True)

    def _lattice_index(self) -> np.ndarray:
        """Each local block's place ``k1 * (n2 p + 1) + k2`` on the lattice of its DOF point: an
        order that does not depend on how the mesh was partitioned."""
        grid, p = self.grid, self.degree
        origin = np.array([grid.xi1_range[0], grid.xi2_range[0]])
        step = np.array([grid.h1, grid.h2]) / p
        k = np.rint((self.block_points - origin) / step).astype(np.int64)
        return k[:, 0] * (grid.n2 * p + 1) + k[:, 1]

    def gather_raw_dofs(self, open_array: np.ndarray) -> np.ndarray:
        """Collective: the open DOF values ``(blocks, 3)`` in lattice order (the same for every rank
        count, so a checkpoint restarts on any), on every rank (bit-exact)."""
        p, grid = self.degree, self.grid
        owned = np.asarray(open_array).reshape(-1, 3)[: self.num_owned_blocks]
        index = self._lattice_index()[: self.num_owned_blocks]
        out = np.zeros(((grid.n1 * p + 1) * (grid.n2 * p + 1), 3))
        for where, values in self.comm.allgather((index, owned)):
            out[where] = values
        return out

    def scatter_raw_dofs(self, raw: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`gather_raw_dofs`: the open array (owned + ghost blocks)."""
        return np.asarray(raw)[self._lattice_index()].ravel()
