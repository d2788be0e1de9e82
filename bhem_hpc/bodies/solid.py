"""The solid body of a scene (``type = "solid"``): an SEM solid of a NURBS model as a
:class:`~bhem_hpc.bodies.body.Body`, and its model built from its scene table."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse
from mpi4py import MPI

from bhem_hpc.bodies.layout import StackedLayout
from bhem_hpc.geometry.nurbs import knot_aligned_grid
from bhem_hpc.geometry.surface import SurfaceError
from bhem_hpc.io.solid_output import SolidTimeSeries
from bhem_hpc.scene.solids import SolidScene
from bhem_hpc.scene.table import SceneError
from bhem_hpc.solids.model import FixedPoints, SolidDynamics, SolidModel
from bhem_hpc.solids.sem import ShapeMatchingSolid

if TYPE_CHECKING:
    from bhem_hpc.contact.ipc_setup import BodyMesh
    from bhem_hpc.solids.petsc import SolidProblem


def build_solid_model(scene: SolidScene, comm: MPI.Comm, name: str = "solid") -> SolidModel:
    """Collective: the solid's preprocessing (on every rank, its quadrature then split among them)
    and its model with the scene's loads, held control points and initial velocity.

    Raises:
        SceneError: the model cannot be preprocessed (no inside found, a part too coarse for
            shape matching, ...), naming the scene, the body's file and the cause.
    """
    try:
        solid = ShapeMatchingSolid(list(scene.parts), list(scene.materials), scene.options, name=f"{scene.file.name}")
    except SurfaceError as exc:
        raise SceneError(f"{scene.path}: body '{name}': key 'file' = {scene.file.name!r}: {exc}") from None
    held = [FixedPoints(region.points(solid.reference), region.components) for region in scene.held]
    wind = scene.wind.at if scene.wind is not None else None
    return SolidModel(solid, comm, SolidDynamics(scene.dt), gravity=scene.gravity or (0.0, 0.0, 0.0), fixed=held,
                      hessian=scene.hessian, body_force=wind, initial_velocity=scene.initial_velocity)  # fmt: skip


class SolidBody:
    """A solid of a scene as a :class:`~bhem_hpc.bodies.body.Body`: its flat entries are its control
    points ``(n_q, 3)``, replicated on every rank.

    Args:
        name: the body's name; index: its place among the scene's bodies.
        scene: its table; model: its :class:`SolidModel`.
    """

    kind = "solid"

    def __init__(self, name: str, index: int, scene: SolidScene, model: SolidModel):
        self.name, self.index, self.scene, self.model = name, index, scene, model
        #: the solid's samples against its colliders, in contact by impulses (else None)
        self._impulse_detector = None
        if scene.contact is not None and scene.contact.method == "impulse":
            self._impulse_detector = self._checked_impulse_detector()

    def _checked_impulse_detector(self):
        """The solid's :class:`~bhem_hpc.contact.solid_surface.SolidContactDetector`; a solid whose
        boundary samples start inside a collider (the impulse response would push them through it)
        is refused, before anything is written."""
        from bhem_hpc.contact.solid_surface import SolidContactDetector

        surface = self.contact_surface(self.scene.contact.samples_per_side)
        detector = SolidContactDetector(surface, self.scene.contact.colliders)
        problem = detector.starting_problem(surface.open_to_entries(self.model.position))
        if problem is not None:
            raise SceneError(f"{self.scene.path}: body '{self.name}': key 'effects.contact.method' = 'impulse': "
                             f"{problem}")  # fmt: skip
        return detector

    def dof_range(self, layout: StackedLayout) -> slice:
        return layout.local_slice(self.index)

    def mass(self) -> float:
        return self.model.solid.mass

    @property
    def dofs(self) -> int:
        return self.model.closed_dofs[1]

    def entries(self, open_array: np.ndarray) -> np.ndarray:
        return np.asarray(open_array, dtype=float).reshape(-1, 3)

    def point_map(self, parameters: np.ndarray) -> scipy.sparse.csr_matrix:
        raise SceneError(f"{self.scene.path}: body '{self.name}': a solid has no surface parameters "
                         f"{np.shape(parameters)}: it meets other bodies by contact method 'ipc'")  # fmt: skip

    def collision_mesh(self) -> BodyMesh:
        from bhem_hpc.contact.ipc_friction import surface_friction
        from bhem_hpc.contact.ipc_setup import solid_mesh  # loaded with IPC contact only

        contact = self.scene.contact
        return solid_mesh(self.model.solid.parts, self.model.comm.rank, self.mass(), contact.collision_cells + 1,
                          surface_friction(contact))  # fmt: skip

    def contact_surface(self, samples_per_side: int = 1):
        """The solid's parts as impulse contact sees them (``samples_per_side`` per knot span)."""
        from bhem_hpc.contact.solid_surface import SolidContactSurface

        return SolidContactSurface(self.model.solid.parts, samples_per_side)

    def impulse_contact(self, problem: SolidProblem, prefix: str):
        """The solid's samples against its colliders, and its projection in its mass or the step's
        Jacobian (numpy and scipy: ``prefix`` names no PETSc solver)."""
        from bhem_hpc.bodies.body import ImpulseContact
        from bhem_hpc.contact.solid_projection import SolidContactProjector

        model, detector = self.model, self._impulse_detector
        return ImpulseContact(detector.surface, detector,
                              SolidContactProjector(model.mass_matrix, model.solid.error_matrix, model.constrained,
                                                    problem.jacobian_csr))  # fmt: skip

    def writer(self, path: Path, continue_at: float | None = None) -> SolidTimeSeries:
        """The solid's series; in contact by IPC its boundary is written on its collision mesh's grid
        (every part's knots and ``collision_cells`` per side), so that the output meshes ParaView
        shows are the meshes IPC keeps apart."""
        contact, parts = self.scene.contact, self.model.solid.parts
        if contact is not None and contact.method == "ipc":
            cells = contact.collision_cells
            grids = [(knot_aligned_grid(part.u, cells), knot_aligned_grid(part.v, cells)) for part in parts]
            return SolidTimeSeries(path, parts, grids, continue_at)
        return SolidTimeSeries(path, parts, 2 * self.scene.output_density + 1, continue_at)
