"""A body of a scene: what the solver, contact and output need of it (:class:`Body`), and the shell
body (:class:`ShellBody`) every scene's ``[[bodies]]`` table builds.

The solver stacks the bodies' DOFs (each body owns a range of every rank's part of one global
vector, :class:`~bhem_hpc.bodies.layout.StackedLayout`); contact and output see a body through its
flat entries ``(N, 3)`` (Hermite nodal data or B-spline control points) and the sparse map from
them to the points they use (as ipc-toolkit's displacement map from DOFs to collision-mesh
vertices): ``points = point_map(parameters) @ entries``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np
import scipy.sparse
from dolfinx import fem

from bhem_hpc import forms
from bhem_hpc.bodies.layout import StackedLayout
from bhem_hpc.io import SurfaceTimeSeries
from bhem_hpc.model.jit import default_jit_params
from bhem_hpc.model.shell import ShellModel
from bhem_hpc.scene.records import Scene

if TYPE_CHECKING:
    from bhem_hpc.contact.ipc_setup import BodyMesh


@dataclass(frozen=True)
class ImpulseContact:
    """A body's part of contact by impulses: ``surface`` (a
    :class:`~bhem_hpc.contact.bodies.ContactSurface`), ``detector`` (its contacts with its colliders
    and itself) and ``projector`` (its share of the response's projection; owns PETSc objects)."""

    surface: object
    detector: object
    projector: object


class Body(Protocol):
    """What the solver, contact and output need of a body.

    Attributes:
        name: the body's name (its output folder, its messages).
        index: its place among the scene's bodies (the stacked order).
    """

    name: str
    index: int

    @property
    def kind(self) -> str:
        """What the body is (a shell's discretization, ``"solid"``), for the run's summary."""
        ...

    @property
    def dofs(self) -> int:
        """Its DOFs in all."""
        ...

    def dof_range(self, layout: StackedLayout) -> slice:
        """This rank's owned DOFs of the body within this rank's part of the stacked vector."""
        ...

    def mass(self) -> float:
        """The body's mass [kg]."""
        ...

    def entries(self, open_array: np.ndarray) -> np.ndarray:
        """Collective: the body's flat entries ``(N, 3)`` of its open-layout array, on every rank."""
        ...

    def point_map(self, parameters: np.ndarray) -> scipy.sparse.csr_matrix:
        """The sparse map ``(P, N)`` from the flat entries to the points at ``parameters (P, 2)``."""
        ...

    def collision_mesh(self) -> BodyMesh:
        """Collective: the body's collision mesh for contact by ``"ipc"`` (its scene's settings)."""
        ...

    def contact_surface(self) -> object:
        """The body as impulse contact sees it (a :class:`~bhem_hpc.contact.bodies.ContactSurface`)."""
        ...

    def impulse_contact(self, problem: object, prefix: str) -> ImpulseContact:
        """The body's part of contact by impulses (its scene's settings): its contact surface, its
        detector (its colliders, itself) and its projector, whose PETSc options take ``prefix``
        (``problem``: the body's problem in the solver)."""
        ...

    def writer(self, path: Path, continue_at: float | None = None) -> SurfaceTimeSeries:
        """The ParaView time series of the body's surface at ``path`` (``.xdmf``); with
        ``continue_at``, the series there continued after its frame at that time."""
        ...


class ShellBody:
    """A shell of a scene as a :class:`Body`: its scene of one body and its model.

    Args:
        name: the body's name; index: its place among the scene's bodies.
        scene: its scene of one body (surface, material, effects, contact, output density).
        model: its :class:`ShellModel` (its DOFs, forms, constraints and state); the model's
            :class:`~bhem_hpc.solver.problem.ShellProblem` holds its energy contributions (the UFL
            terms, point loads and point constraints).
    """

    def __init__(self, name: str, index: int, scene: Scene, model: ShellModel):
        self.name = name
        self.index = index
        self.scene = scene
        self.model = model

    @property
    def kind(self) -> str:
        """The body's discretization (``hermite``, ``bspline2``, ``bspline3``)."""
        return self.scene.surface.discretization

    @property
    def dofs(self) -> int:
        """Its closed DOFs in all."""
        return self.model.closed_dofs[1]

    def dof_range(self, layout: StackedLayout) -> slice:
        return layout.local_slice(self.index)

    def mass(self) -> float:
        m = self.model
        form = fem.form(m.in_unknowns(forms.total_mass(m.x_rest, m.density, m.thickness, m.dx)),
                        jit_params=default_jit_params())  # fmt: skip
        return float(m.comm.allreduce(fem.assemble_scalar(form)))

    def entries(self, open_array: np.ndarray) -> np.ndarray:
        return self.model.discretization.open_to_entries(open_array)

    def point_map(self, parameters: np.ndarray) -> scipy.sparse.csr_matrix:
        parameters = np.asarray(parameters, dtype=float).reshape(-1, 2)
        grid = self.model.rest_surface.grid
        p1, p2, t1, t2 = grid.locate(parameters[:, 0], parameters[:, 1])
        layout = self.model.discretization.patches
        index, weights = layout.point_entries(p1, p2, t1, t2)
        rows = np.repeat(np.arange(len(parameters)), index.shape[1])
        matrix = scipy.sparse.csr_matrix((weights.ravel(), (rows, index.ravel())),
                                         shape=(len(parameters), layout.num_entries))  # fmt: skip
        matrix.sum_duplicates()
        return matrix

    def collision_mesh(self) -> BodyMesh:
        from bhem_hpc.contact.ipc_friction import surface_friction
        from bhem_hpc.contact.ipc_setup import shell_mesh  # loaded with IPC contact only

        contact, material = self.scene.contact, self.scene.material
        return shell_mesh(self.model, contact.collision_cells, material.density, material.thickness,
                          contact.self_collision, surface_friction(contact))  # fmt: skip

    def contact_surface(self) -> object:
        from bhem_hpc.contact.bodies import ShellContactSurface

        return ShellContactSurface(self.model.discretization, self.model.x.x.array.size)

    def impulse_contact(self, problem: object, prefix: str) -> ImpulseContact:
        from bhem_hpc.contact.petsc import ContactProjector
        from bhem_hpc.contact.response import ContactHandler  # loaded with impulse contact only
        from bhem_hpc.run import contact_detector

        ContactHandler.check_model(self.model)
        return ImpulseContact(self.contact_surface(), contact_detector(self.scene, self.model),
                              ContactProjector(problem, prefix=prefix))

    def writer(self, path: Path, continue_at: float | None = None) -> SurfaceTimeSeries:
        scene = self.scene
        return SurfaceTimeSeries(path, scene.surface, scene.material, scene.written_density, continue_at=continue_at,
                                 trim=scene.trim)  # fmt: skip
