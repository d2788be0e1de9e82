"""The definition of a shell problem besides its geometry and material: loads, point constraints and
time stepping, validated before anything is built (no dolfinx)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import ufl

from bhem_hpc.errors import UserError
from bhem_hpc.model.bcs import EDGES


class ModelError(UserError, ValueError):
    """Inconsistent problem definition (bad load, quadrature, Hessian choice, ...)."""


@dataclass(frozen=True)
class LineLoad:
    """Dead load per unit rest length on a boundary edge (``EDGES``)."""

    edge: str
    traction: tuple[float, float, float]


@dataclass(frozen=True)
class EdgeMoment:
    """Distributed moment per unit rest length on a boundary edge (``EDGES``), about the edge's
    current tangent; ``moment > 0`` curls the edge towards the surface normal ``a1 x a2``."""

    edge: str
    moment: float


@dataclass(frozen=True)
class AreaLoad:
    """Dead load per unit rest area, fixed in direction: ``force`` times ``profile(xi)``.

    Attributes:
        force: ``(3,)`` force per unit rest area [N/m^2] where the profile is 1.
        profile: the load's distribution, a function of the parameters ``xi`` (a UFL 2-vector,
            ``xi[0]``, ``xi[1]``) returning a UFL scalar, e.g. ``lambda xi: ufl.sin(ufl.pi * xi[0])``;
            None: uniform.
    """

    force: tuple[float, float, float]
    profile: Callable[[ufl.core.expr.Expr], ufl.core.expr.Expr] | None = None


@dataclass(frozen=True)
class PointLoad:
    """Dead point force at parameters ``(xi1, xi2)`` (paper eq. 21)."""

    xi1: float
    xi2: float
    force: tuple[float, float, float]


@dataclass(frozen=True)
class PointConstraint:
    """Hold the material point ``(xi1, xi2)`` at a target (paper §6.1, augmented Lagrangian).

    Attributes:
        xi1, xi2: parameters of the point (anywhere on the surface, not only at nodes).
        target: position ``(3,)`` or a callable of time (dynamics) / load factor (statics)
            returning it; only ``components`` are constrained.
        components: constrained Cartesian components.
    """

    xi1: float
    xi2: float
    target: Callable[[float], np.ndarray] | tuple[float, float, float]
    components: tuple[int, ...] = (0, 1, 2)

    def target_at(self, t: float) -> np.ndarray:
        value = self.target(t) if callable(self.target) else self.target
        return np.asarray(value, dtype=float)


@dataclass(frozen=True)
class Loads:
    """External loads; each is built only when given. All scale with the load factor."""

    gravity: tuple[float, float, float] | None = None
    pressure: float | None = None
    line_loads: tuple[LineLoad, ...] = field(default_factory=tuple)
    point_loads: tuple[PointLoad, ...] = field(default_factory=tuple)
    area_loads: tuple[AreaLoad, ...] = field(default_factory=tuple)
    edge_moments: tuple[EdgeMoment, ...] = field(default_factory=tuple)

    def validate(self) -> None:
        if self.gravity is not None:
            _check_vector("gravity", self.gravity)
        if self.pressure is not None and not np.isfinite(self.pressure):
            raise ModelError(f"loads.pressure must be finite, got {self.pressure!r}")
        for i, load in enumerate(self.point_loads):
            _check_vector(f"point_loads[{i}].force", load.force)
        for i, load in enumerate(self.area_loads):
            _check_vector(f"area_loads[{i}].force", load.force)
            if load.profile is not None and not callable(load.profile):
                raise ModelError(f"loads.area_loads[{i}].profile must be a function of xi, got {load.profile!r}")
        self._validate_edge_loads()

    def _validate_edge_loads(self) -> None:
        for name, loads in (("line_loads", self.line_loads), ("edge_moments", self.edge_moments)):
            for i, load in enumerate(loads):
                if load.edge not in EDGES:
                    raise ModelError(f"loads.{name}[{i}].edge = {load.edge!r}; expected one of {EDGES}")
        for i, load in enumerate(self.line_loads):
            _check_vector(f"line_loads[{i}].traction", load.traction)
        for i, load in enumerate(self.edge_moments):
            moment = load.moment
            if isinstance(moment, bool) or not isinstance(moment, int | float) or not np.isfinite(moment):
                raise ModelError(f"loads.edge_moments[{i}].moment must be a finite number, got {moment!r}")


def _check_vector(name: str, v: Sequence[float]) -> None:
    arr = np.asarray(v, dtype=float)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ModelError(f"loads.{name} must be 3 finite numbers, got {v!r}")


@dataclass(frozen=True)
class Dynamics:
    """Implicit Euler time stepping (paper eq. 30) with Rayleigh damping.

    Attributes:
        time_step: dt [s], > 0.
        mass_damping: alpha [1/s] of the damping matrix alpha M + beta K, >= 0.
        stiffness_damping: beta [s], >= 0 (K: the positive semi-definite elastic Hessian, lagged at
            the start of the step).
    """

    time_step: float
    mass_damping: float = 0.0
    stiffness_damping: float = 0.0

    def validate(self) -> None:
        for name, value, ok, expected in (
            ("time_step", self.time_step, lambda v: v > 0, "> 0"),
            ("mass_damping", self.mass_damping, lambda v: v >= 0, ">= 0"),
            ("stiffness_damping", self.stiffness_damping, lambda v: v >= 0, ">= 0"),
        ):
            if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or not ok(value):
                raise ModelError(f"dynamics.{name} = {value!r} is invalid: must be a number {expected}")
