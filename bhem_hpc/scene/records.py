"""What a scene file describes, parsed and checked (no PETSc): the records :func:`load_scene`
returns, which map one to one onto the library's objects."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bhem_hpc.geometry import surface as S
from bhem_hpc.geometry.trim import Trim
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.path import PathPlan, Probe


@dataclass(frozen=True)
class Motion:
    """A prescribed motion of a constraint's values, as a function of time."""

    kind: str
    values: Callable[[float, np.ndarray], np.ndarray]  # (t, initial values) -> values


@dataclass(frozen=True)
class SceneConstraint:
    constraint: bcs.NodalConstraint
    motion: Motion | None = None
    key: str = ""


@dataclass(frozen=True)
class ScenePoint:
    """A material point held at a target: fixed (``target``) or moving (``motion``)."""

    xi1: float
    xi2: float
    components: tuple[int, ...]
    target: tuple[float, float, float]
    motion: Motion | None = None

    def target_at(self, t: float) -> np.ndarray:
        """Full 3-vector target at time ``t`` (unconstrained components keep ``target``)."""
        out = np.array(self.target, dtype=float)
        if self.motion is not None:
            comps = list(self.components)
            out[comps] = np.asarray(self.motion.values(t, out[comps][None, None, :]), dtype=float).reshape(-1)
        return out


@dataclass(frozen=True)
class Effects:
    gravity: tuple[float, float, float] | None = None
    pressure: float | None = None
    mass_damping: float = 0.0
    stiffness_damping: float = 0.0
    point_loads: tuple[tuple[float, float, tuple[float, float, float]], ...] = ()
    line_loads: tuple[tuple[str, tuple[float, float, float]], ...] = ()
    area_loads: tuple[tuple[tuple[float, float, float], str | None], ...] = ()  # (force, profile expression)
    edge_moments: tuple[tuple[str, float], ...] = ()


@dataclass(frozen=True)
class SceneContact:
    """Contact effects of a scene: colliders (built), settings and friction coefficients."""

    colliders: tuple[Any, ...]  # bhem_hpc.contact.detection.ColliderEntry
    push_out: float
    samples_per_side: int
    self_collision: bool
    self_friction: float
    metric: str = "mass"  # the impulse metric: "mass" (M + S) or "jacobian" (dt^2 J + S)
    friction: float = 0.0  # the body's Coulomb coefficient (``effects.friction``)
    method: str = "impulse"  # "impulse" (between steps) or "ipc" (a barrier inside the solve)
    dhat: float | None = None  # ipc: the barrier's activation distance [m] (None: 1e-3 of the bounding box)
    barrier_stiffness: float | None = None  # ipc: kappa [N/m] (None: ipc-toolkit's rule)
    collision_cells: int = 4  # ipc: collision-lattice cells per patch side
    static_friction: float | None = None  # ipc: the body's static Coulomb coefficient (None: ``friction``)
    eps_v: float = 1e-3  # ipc: the sticking speed of lagged friction [m/s]
    # ipc: Newton also stops at IPC's step test [m/s] ("auto": IPC's choice; None: not)
    velocity_tolerance: float | str | None = None


@dataclass(frozen=True)
class Scene:
    path: Path
    surface: S.HermiteSurface
    material: Material
    constraints: tuple[SceneConstraint, ...]
    effects: Effects
    static: bool
    dt: float
    steps: int
    load_steps: int
    hessian: str
    quadrature: int | str | None  # Gauss points per direction, 'reduced', None: the default
    linear: str = "auto"  # linear solver: auto | direct | iterative
    factorization: str = "reuse"  # reuse | fresh
    acceleration_tolerance: float | None = None  # time steps: Newton stops at this RMS acceleration [m/s^2]
    #: time steps: Newton also stops once its step leaves a velocity below this [m/s], or "auto"
    #: (:mod:`bhem_hpc.solver.step_test`)
    velocity_tolerance: float | str | None = None
    petsc_options: dict[str, Any] = field(default_factory=dict)
    point_constraints: tuple[ScenePoint, ...] = ()
    output_every: int = 1
    output_density: int = 4
    raw: dict[str, Any] = field(default_factory=dict)
    contact: SceneContact | None = None
    path_plan: PathPlan | None = None  # static scenes: how the equilibrium path is followed
    probes: tuple[Probe, ...] = ()
    initial_velocity: tuple[float, float, float] | None = None  # the shell's uniform velocity at t = 0 [m/s]
    trim: Trim | None = None  # the part of the surface simulated (``[trim]``); None: all of it

    @property
    def nodal_shape(self) -> tuple[int, ...]:
        """The shape of the surface's nodal data (what a checkpoint keeps of a frame)."""
        return self.surface.nodal.shape

    @property
    def written_density(self) -> int:
        """Tessellation quads per patch side of the shell's output: ``output.density``, or in contact
        by IPC its collision lattice's cells (the same points and triangles: the meshes ParaView
        shows are the meshes IPC keeps apart)."""
        contact = self.contact
        return contact.collision_cells if contact is not None and contact.method == "ipc" else self.output_density
