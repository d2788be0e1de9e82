"""Path-following cases with closed-form references, for tests, jobs and the path-following page.

* The shallow arch: a strip pinned at both ends with the rest shape ``e sin(pi x / L)``, under a
  dead load ``p sin(pi x / L)``; with ``nu = 0`` it is a beam, whose symmetric snap-through path
  :func:`~bhem_hpc.studies.references.shallow_arch_load` gives in closed form.
* The compressed strip: pinned at both ends, one sliding, under an end load: Euler's bifurcation
  and the post-buckled elastica (:func:`~bhem_hpc.studies.references.pinned_elastica`).
* The cylindrical panel: a thin shallow panel under a central point load, which snaps through with
  a snap-back; its reference is the same path on a finer mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import ufl
from mpi4py import MPI

from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import AreaLoad, LineLoad, Loads, PointLoad, ShellModel


@dataclass(frozen=True)
class Strip:
    """A strip's dimensions and Young's modulus (``nu = 0``: it bends as a beam)."""

    length: float = 1.0
    width: float = 0.05
    thickness: float = 0.01
    young: float = 1.0e7


@dataclass(frozen=True)
class ShallowArch(Strip):
    """A pinned shallow sinusoidal arch (a strip, ``nu = 0``) of span ``length``, in units where its
    load factor is the closed form's ``P``.

    Attributes:
        initial_rise: ``e / r`` (``r = h / sqrt(12)``); 3.5 has two limit points and no bifurcation.
    """

    initial_rise: float = 3.5

    @property
    def gyration_radius(self) -> float:
        return self.thickness / np.sqrt(12.0)

    @property
    def rise(self) -> float:
        return self.initial_rise * self.gyration_radius

    @property
    def unit_load(self) -> float:
        """Pressure amplitude [N/m^2] of ``P = 1``: ``pi^4 E h^3 r / (12 L^4)`` (``EI = E w h^3 / 12``)."""
        return np.pi**4 * self.young * self.thickness**3 * self.gyration_radius / (12 * self.length**4)

    def model(self, patches: int = 16, comm: MPI.Comm = MPI.COMM_WORLD, discretization: str = "hermite") -> ShellModel:
        """The arch on ``patches`` x 1 patches (knot spans for B-splines), ends simply supported."""
        length, rise = self.length, self.rise
        grid = S.ParameterGrid(patches, 1, (0.0, length), (0.0, self.width))

        def shape(a, b):
            return np.stack([a, b, rise * np.sin(np.pi * a / length)], -1)

        if discretization == "hermite":
            rest = S.from_callable(shape, grid)
        else:
            from bhem_hpc.geometry import bspline

            rest = bspline.from_callable(shape, grid, degree=int(discretization[-1]))
        load = AreaLoad((0.0, 0.0, -self.unit_load), lambda xi: ufl.sin(ufl.pi * xi[0] / length))
        supports = [bcs.support_edge(rest, "xi1_min"), bcs.support_edge(rest, "xi1_max")]
        material = Material(self.young, 0.0, self.thickness, 1.0)
        return ShellModel(rest, material, Loads(area_loads=(load,)), supports, comm=comm)

    def midspan(self) -> tuple[float, float]:
        """Parameters of the midspan probe."""
        return (self.length / 2, self.width / 2)


@dataclass(frozen=True)
class CompressedStrip(Strip):
    """A strip (``nu = 0``: a beam) pinned at both ends, one end sliding along the strip, compressed
    by an end load of ``load factor x P_cr`` (``P_cr = pi^2 EI / L^2``, Euler's first load), so its
    path is the pinned elastica (:func:`~bhem_hpc.studies.references.pinned_elastica`).

    Attributes:
        imperfection: rest midspan bow ``w0 / L`` of the shape ``sin(pi x / L)`` (0: straight, a
            bifurcation at load factor 1; small: a smooth path onto the buckled branch).
    """

    imperfection: float = 0.0

    @property
    def critical_load(self) -> float:
        """Euler's load [N] of the strip, ``pi^2 E w h^3 / (12 L^2)``."""
        return np.pi**2 * self.young * self.width * self.thickness**3 / (12 * self.length**2)

    def model(self, patches: int = 16, comm: MPI.Comm = MPI.COMM_WORLD) -> ShellModel:
        """The strip on ``patches`` x 1 Hermite patches; pinned at ``xi1 = 0`` (position and the edge
        direction held), at ``xi1 = L`` the same but free to slide along x; loaded at ``xi1 = L``."""
        length, bow = self.length, self.imperfection * self.length
        grid = S.ParameterGrid(patches, 1, (0.0, length), (0.0, self.width))
        rest = S.from_callable(lambda a, b: np.stack([a, b, bow * np.sin(np.pi * a / length)], -1), grid)
        end = bcs.edge_nodes(grid, "xi1_max")
        supports = [
            bcs.simply_supported(rest, "xi1_min"),
            bcs.NodalConstraint(end, (0,), (1, 2)),  # the loaded end slides along x
            bcs.NodalConstraint(end, (2,), (0, 1, 2)),  # and keeps its direction: a hinge
        ]
        traction = (-self.critical_load / self.width, 0.0, 0.0)
        loads = Loads(line_loads=(LineLoad("xi1_max", traction),))
        return ShellModel(rest, Material(self.young, 0.0, self.thickness, 1.0), loads, supports, comm=comm)


@dataclass(frozen=True)
class CylindricalPanel:
    """A shallow cylindrical panel (radius 2540 mm, straight edges 508 mm long and hinged, curved
    edges free, arc 0.2 rad; E 3102.75 N/mm^2, nu 0.3) under a central point load of ``load factor``
    kN: thin enough (``thickness`` 6.35 mm) to snap through with a snap-back of the loaded point.
    Modelled as the quarter by its two symmetry planes (Hermite patches)."""

    radius: float = 2540.0
    length: float = 508.0
    angle: float = 0.2
    thickness: float = 6.35
    young: float = 3102.75
    poisson: float = 0.3

    def model(self, patches: int = 8, comm: MPI.Comm = MPI.COMM_WORLD) -> ShellModel:
        half = self.angle / 2
        rest = S.cylinder(self.radius, self.length / 2, patches, patches, closed=False, angle=half,
                          seam_angle=np.pi / 2 - half)  # fmt: skip
        loads = Loads(point_loads=(PointLoad(*self.centre(), (0.0, -250.0, 0.0)),))  # a quarter of 1 kN
        supports = [bcs.hinged_edge(rest, "xi2_min"), *bcs.symmetry_edge(rest, "xi1_max", "z"),
                    *bcs.symmetry_edge(rest, "xi2_max", "x")]  # fmt: skip
        material = Material(self.young, self.poisson, self.thickness, 1.0)
        return ShellModel(rest, material, loads, supports, comm=comm)

    def centre(self) -> tuple[float, float]:
        """Parameters of the loaded centre (a corner of the quarter)."""
        return (self.length / 2, np.pi / 2)

    def follow(self, patches: int, settings, comm: MPI.Comm = MPI.COMM_WORLD) -> list:
        """The path by arc length (:class:`~bhem_hpc.model.path.ArcLength` ``settings``) on ``patches``
        x ``patches``, probing the centre: a list of :class:`~bhem_hpc.solver.path.PathPoint`."""
        from bhem_hpc.solver import ShellSolver
        from bhem_hpc.solver.path import PathFollower, Probe

        with ShellSolver(self.model(patches, comm)) as solver:
            with PathFollower(solver, [Probe("centre", *self.centre())]) as follower:
                follower.arc_length(settings)
                return follower.path


def snap_landmarks(factors: list[float], deflections: list[float]) -> dict[str, float]:
    """Landmarks of a snap-through path with a snap-back (load factors and a deflection along it):
    the limit load, the lowest load, the deflection where it turns back and the smallest one after,
    each the vertex of the parabola through the three points around it."""

    def vertex(values: list[float], k: int) -> float:
        y0, y1, y2 = values[k - 1 : k + 2]
        return y1 - (y2 - y0) ** 2 / (8 * (y0 - 2 * y1 + y2))

    lowest = int(np.argmin(factors))
    turn = int(np.argmax(deflections[:lowest]))
    back = turn + int(np.argmin(deflections[turn : lowest + 5]))
    return {
        "limit load": vertex(factors, int(np.argmax(factors[:lowest]))),
        "lowest load": vertex(factors, lowest),
        "turning deflection": vertex(deflections, turn),
        "snap-back deflection": vertex(deflections, back),
    }
