"""The discretization protocol: what the model, solver, contact and output need of a discretization."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import dolfinx.fem
import dolfinx.mesh
import numpy as np
from mpi4py import MPI

from bhem_hpc.geometry.surface import HermiteSurface, ParameterGrid


class DiscretizationError(ValueError):
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
    """What the model and the solver need from a discretization (Hermite today, B-splines later).

    Layouts: *open* arrays are dolfinx Function arrays (owned + ghost blocks of 3); *closed* arrays
    are the owned part of the solver's unknowns; the prolongation from closed to open has one unit
    entry per owned open block, in column ``closed_of_open[block]``.
    """

    comm: MPI.Comm
    grid: ParameterGrid
    mesh: dolfinx.mesh.Mesh
    function_space: dolfinx.fem.FunctionSpace
    num_owned_closed: int
    num_closed: int
    closed_of_open: np.ndarray
    owned_closed_open_block: np.ndarray

    @property
    def is_periodic(self) -> bool: ...

    @property
    def open_blocks(self) -> np.ndarray: ...

    def surface_to_open(self, surface: HermiteSurface) -> np.ndarray: ...

    def surface_to_closed(self, surface: HermiteSurface) -> np.ndarray: ...

    def closed_to_surface(self, closed: np.ndarray) -> HermiteSurface: ...

    def open_to_surface(self, open_array: np.ndarray) -> HermiteSurface: ...

    def select_dofs(
        self, nodes: np.ndarray, kinds: tuple[int, ...], components: tuple[int, ...]
    ) -> ConstrainedDofs: ...

    def dof_values(self, surface: HermiteSurface, dofs: ConstrainedDofs) -> np.ndarray: ...

    def point_basis(self, xi1: float, xi2: float) -> tuple[np.ndarray, np.ndarray]: ...

    def gather_raw_dofs(self, open_array: np.ndarray) -> np.ndarray: ...

    def scatter_raw_dofs(self, raw: np.ndarray) -> np.ndarray: ...
