"""The discretization protocol: what the model, solver, contact and output need of a discretization."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import dolfinx.fem
import dolfinx.mesh
import numpy as np
import ufl
from mpi4py import MPI

from bhem_hpc.errors import UserError
from bhem_hpc.geometry.surface import HermiteSurface, ParameterGrid, PatchLayout


class DiscretizationError(UserError, ValueError):
    """The mesh or DOF layout cannot represent the surface (non-uniform grid, bad node, ...)."""


@dataclass(frozen=True)
class ConstrainedDofs:
    """Owned closed-layout DOFs selected by node, kind and component.

    ``rows`` are global closed indices (``3 * closed_block + component``) owned by this rank,
    ``local`` the matching local offsets into an owned closed array, and ``values`` their
    reference-DOF values for a given surface; all of shape ``(k,)``.
    """

    rows: np.ndarray
    local: np.ndarray
    node: np.ndarray  # (k, 2) distinct-node indices
    kind: np.ndarray  # (k,) parametric kind
    component: np.ndarray  # (k,)


class Discretization(Protocol):
    """What the model, solver, contact and output ask of a discretization; it owns every DOF layout.

    Four forms of the same state, each converted only here:

    * *surface*: the geometric object (:class:`HermiteSurface`) that scenes, output and studies use;
    * *entries*: the surface's data as a flat ``(N, 3)`` array - for bicubic Hermite the nodal data
      ``(i1 * m2 + i2) * 4 + kind`` (value, d/dxi1, d/dxi2, d2/dxi1dxi2 of each distinct node), for a
      B-spline discretization the control points. Contact rows, Bezier nets and point weights act on
      entries;
    * *open*: the dolfinx Function array of :attr:`function_space` (owned + ghost blocks of 3,
      ``array[3 * block + component]``), where forms are assembled. Hermite blocks are
      reference-cell derivatives (scaled entries); control points are their own DOFs;
    * *closed*: the owned part of the solver's unknowns, one block of 3 per entry. Hermite without
      periodic directions: the open layout itself; on a closed Hermite surface each seam entry is
      kept once and open = ``P`` closed with a 0/1 prolongation; B-splines: the control points, and
      ``P`` holds the basis values at the open DOF points (:meth:`prolongation`).
    """

    comm: MPI.Comm
    #: The parameter grid of the patches (Hermite: one patch per cell; B-splines: knot spans).
    grid: ParameterGrid
    mesh: dolfinx.mesh.Mesh
    function_space: dolfinx.fem.FunctionSpace
    #: Closed blocks (of 3 DOFs) owned by this rank, in all ranks, and the first owned one.
    num_owned_closed: int
    num_closed: int
    closed_offset: int

    @property
    def is_periodic(self) -> bool:
        """Whether the closed layout differs from the open one (a seam)."""
        ...

    @property
    def num_entries(self) -> int:
        """``N``, rows of the entry array (Hermite: 4 per distinct node; B-splines: control points)."""
        ...

    @property
    def patches(self) -> PatchLayout:
        """The patches as linear maps of the entries (point weights, Bezier nets) for contact."""
        ...

    # surface <-> layouts
    def surface_to_open(self, surface: HermiteSurface) -> np.ndarray: ...

    def surface_to_closed(self, surface: HermiteSurface) -> np.ndarray: ...

    def closed_to_surface(self, closed: np.ndarray) -> HermiteSurface:
        """Collective: the surface of every rank's owned closed arrays."""
        ...

    def open_to_surface(self, open_array: np.ndarray) -> HermiteSurface:
        """Collective: the surface of an open array (its owned blocks are read)."""
        ...

    # entries <-> layouts
    def entries_of_surface(self, surface: HermiteSurface) -> np.ndarray: ...

    def surface_of_entries(self, entries: np.ndarray) -> HermiteSurface: ...

    def open_to_entries(self, open_array: np.ndarray) -> np.ndarray:
        """Collective: entries ``(N, 3)`` on every rank."""
        ...

    def entries_to_open(self, entries: np.ndarray) -> np.ndarray: ...

    def entries_to_closed(self, entries: np.ndarray) -> np.ndarray: ...

    def closed_to_entries(self, closed: np.ndarray) -> np.ndarray:
        """Collective: entries ``(N, 3)`` on every rank."""
        ...

    def entry_closed_blocks(self) -> tuple[np.ndarray, np.ndarray]:
        """``(block, scale)``, ``(N,)`` each: entry ``e`` lives in closed DOFs ``3 * block[e] + c``
        as ``scale[e]`` times its value (Hermite: the reference-cell factor; control points: 1)."""
        ...

    # open <-> closed
    def open_to_closed(self, open_array: np.ndarray) -> np.ndarray:
        """Collective: the owned closed array of an open array that the prolongation produced."""
        ...

    @property
    def closed_is_open(self) -> bool:
        """Whether the closed layout is the open one (no prolongation)."""
        ...

    def position_map(self) -> Callable[[ufl.core.expr.Expr], ufl.core.expr.Expr] | None:
        """What the forms take for a Function of :attr:`function_space` (and its variations) as the
        position: None where the open values are positions (Hermite, B-splines); ``Y -> Y / W`` for
        the homogeneous values of rational B-splines."""
        ...

    def open_block_weights(self) -> np.ndarray | None:
        """``(open blocks,)`` what divides each open block (owned and ghost) to give a position:
        ``W`` at the DOF point for rational B-splines; None elsewhere."""
        ...

    def prolongation(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """``P`` over the owned open blocks as block CSR ``(indptr, closed blocks, weights)`` (one
        weight per block pair; it acts alike on x, y, z); None where the closed layout is the open one."""
        ...

    def component_ties(self) -> tuple[np.ndarray, np.ndarray]:
        """Scalar closed DOFs ``3 block + component`` tied to others: ``(slaves, masters)`` (empty
        without ties); the prolongation's slave columns act on their masters instead."""
        ...

    def prolongation_offset(self) -> np.ndarray | None:
        """The open array (owned + ghost blocks) that the prolongation adds to ``P x``: the tied
        slaves' rest offsets from their masters; None without ties."""
        ...

    def tied_roots(self, dofs: ConstrainedDofs) -> ConstrainedDofs:
        """Collective: the owned roots of tied components among every rank's ``dofs`` (a held
        component that follows a root holds its root); empty without ties."""
        ...

    # constraints, point loads, checkpoints
    def select_dofs(self, nodes: np.ndarray, kinds: tuple[int, ...], components: tuple[int, ...]) -> ConstrainedDofs:
        """Owned closed DOFs of nodes ``(k, 2)``, kinds and components (Hermite: distinct nodes,
        kinds 0..3; B-splines: control points ``(i1, i2)``, kind 0 only - other kinds are refused)."""
        ...

    def dof_values(self, surface: HermiteSurface, dofs: ConstrainedDofs) -> np.ndarray: ...

    def point_basis(self, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        """``(open blocks, basis values)`` of the cell holding a parameter point, on its owning rank."""
        ...

    def points_basis(self, xi1: np.ndarray, xi2: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """:meth:`point_basis` at parameter points ``xi1, xi2 (N,)`` (one tabulation for all)."""
        ...

    def point_frame_basis(self, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]:
        """``(open blocks (n,), values (3, n))``: the basis and its xi1 and xi2 derivatives there."""
        ...

    def gather_raw_dofs(self, open_array: np.ndarray) -> np.ndarray:
        """Collective: the DOF values themselves, without conversion (bit-exact checkpoints)."""
        ...

    def scatter_raw_dofs(self, raw: np.ndarray) -> np.ndarray: ...
