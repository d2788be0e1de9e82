"""Path-following cases with closed-form references, for tests, jobs and the path-following page.

* The shallow arch: a strip pinned at both ends with the rest shape ``e sin(pi x / L)``, under a
  dead load ``p sin(pi x / L)``; with ``nu = 0`` it is a beam, whose symmetric snap-through path
  :func:`~bhem_hpc.studies.references.shallow_arch_load` gives in closed form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import ufl
from mpi4py import MPI

from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import AreaLoad, Loads, ShellModel


@dataclass(frozen=True)
class ShallowArch:
    """A pinned shallow sinusoidal arch (a strip, ``nu = 0``) of span ``length``, in units where its
    load factor is the closed form's ``P``.

    Attributes:
        initial_rise: ``e / r`` (``r = h / sqrt(12)``); 3.5 has two limit points and no bifurcation.
    """

    length: float = 1.0
    width: float = 0.05
    thickness: float = 0.01
    young: float = 1.0e7
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

            rest = bspline.from_callable(shape, grid, int(discretization[-1]))
        load = AreaLoad((0.0, 0.0, -self.unit_load), lambda xi: ufl.sin(ufl.pi * xi[0] / length))
        supports = [bcs.support_edge(rest, "xi1_min"), bcs.support_edge(rest, "xi1_max")]
        material = Material(self.young, 0.0, self.thickness, 1.0)
        return ShellModel(rest, material, Loads(area_loads=(load,)), supports, comm=comm)

    def midspan(self) -> tuple[float, float]:
        """Parameters of the midspan probe."""
        return (self.length / 2, self.width / 2)
