"""Material and section constants of a thin shell, validated before anything is built."""

from __future__ import annotations

import math
from dataclasses import dataclass


class MaterialError(ValueError):
    """A material constant is out of its physical range."""


@dataclass(frozen=True)
class Material:
    """St. Venant-Kirchhoff shell material.

    Attributes:
        young: Young's modulus Y [Pa], > 0.
        poisson: Poisson's ratio nu in (-1, 0.5].
        thickness: shell thickness h [m], in (0, 1e3].
        density: mass density rho [kg/m^3], in [0, 1e6].
    """

    young: float
    poisson: float
    thickness: float
    density: float = 0.0

    def __post_init__(self) -> None:
        checks = (
            # bounds far beyond any shell's, so that Y h^3 and rho h dt^-2 stay finite doubles
            ("young", self.young, lambda v: 0 < v <= 1e15, "in (0, 1e15] Pa"),
            ("poisson", self.poisson, lambda v: -1 < v <= 0.5, "in (-1, 0.5]"),
            ("thickness", self.thickness, lambda v: 0 < v <= 1e3, "in (0, 1e3] m"),
            ("density", self.density, lambda v: 0 <= v <= 1e6, "in [0, 1e6] kg/m^3"),
        )
        for name, value, ok, expected in checks:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise MaterialError(f"material.{name} must be a number, got {value!r}")
            if not math.isfinite(value) or not ok(value):
                raise MaterialError(f"material.{name} = {value!r} is invalid: must be {expected}")

    @property
    def bending_stiffness(self) -> float:
        """Plate bending stiffness ``D = Y h^3 / (12 (1 - nu^2))``."""
        return self.young * self.thickness**3 / (12 * (1 - self.poisson**2))
