"""Material and section constants of a thin shell, validated before anything is built."""

from __future__ import annotations

import math
from dataclasses import dataclass

from bhem_hpc.errors import UserError


class MaterialError(UserError, ValueError):
    """A material constant is out of its physical range."""


#: Membrane energies: Kirchhoff-Love St. Venant-Kirchhoff, or the FEM Baraff-Witkin cloth membrane.
MEMBRANE_MODELS = ("svk", "fbw")
#: Bending energies: Kirchhoff-Love St. Venant-Kirchhoff, the quadratic (Bergou) bending energy, or
#: none (a membrane without bending stiffness, e.g. the membrane-locking test).
BENDING_MODELS = ("svk", "quadratic", "none")


@dataclass(frozen=True)
class Material:
    """Shell material: its constants and which membrane and bending energies it has.

    Attributes:
        young: Young's modulus Y [Pa], > 0.
        poisson: Poisson's ratio nu in (-1, 0.5].
        thickness: shell thickness h [m], in (0, 1e3].
        density: mass density rho [kg/m^3], in [0, 1e6].
        membrane: ``"svk"`` (Kirchhoff-Love St. Venant-Kirchhoff, isotropic) or ``"fbw"`` (the FEM
            Baraff-Witkin cloth membrane, anisotropic along the rest surface's parametric directions:
            stretch stiffness ``Y h`` along warp and weft, shear stiffness ``shear_ratio Y h``).
        bending: ``"svk"`` (Kirchhoff-Love St. Venant-Kirchhoff) or ``"quadratic"`` (Bergou et al.'s
            quadratic energy ``D/2 int |Delta x|^2`` for flat rest surfaces, ``D = Y h^3 / (12 (1 - nu^2))``)
            or ``"none"`` (no bending stiffness).
        shear_ratio: shear-to-stretch stiffness ratio of the ``"fbw"`` membrane, in (0, 1e3]; only
            with it, and required there.
    """

    young: float
    poisson: float
    thickness: float
    density: float = 0.0
    membrane: str = "svk"
    bending: str = "svk"
    shear_ratio: float | None = None

    def __post_init__(self) -> None:
        checks = (
            # bounds far beyond any shell's, so that Y h^3 and rho h dt^-2 stay finite doubles
            ("young", self.young, lambda v: 0 < v <= 1e15, "in (0, 1e15] Pa"),
            ("poisson", self.poisson, lambda v: -1 < v <= 0.5, "in (-1, 0.5]"),
            ("thickness", self.thickness, lambda v: 0 < v <= 1e3, "in (0, 1e3] m"),
            ("density", self.density, lambda v: 0 <= v <= 1e6, "in [0, 1e6] kg/m^3"),
        )
        for name, value, ok, expected in checks:
            _check_number(name, value, ok, expected)
        self._check_models()

    def _check_models(self) -> None:
        for name, value, models in (("membrane", self.membrane, MEMBRANE_MODELS), ("bending", self.bending,
                                                                                     BENDING_MODELS)):  # fmt: skip
            if value not in models:
                raise MaterialError(f"material.{name} = {value!r} is invalid: must be one of {models}")
        if self.membrane == "fbw":
            if self.shear_ratio is None:
                raise MaterialError("material.shear_ratio is required with material.membrane = 'fbw' "
                                    "(shear-to-stretch stiffness ratio, e.g. 1.0)")  # fmt: skip
            _check_number("shear_ratio", self.shear_ratio, lambda v: 0 < v <= 1e3, "in (0, 1e3]")
        elif self.shear_ratio is not None:
            raise MaterialError(f"material.shear_ratio = {self.shear_ratio!r} applies only to "
                                f"material.membrane = 'fbw', not {self.membrane!r}")  # fmt: skip

    @property
    def stretch_stiffness(self) -> float:
        """Membrane stiffness ``Y h`` [N/m] (the Baraff-Witkin membrane's yarn stretch stiffness)."""
        return self.young * self.thickness

    @property
    def bending_stiffness(self) -> float:
        """Plate bending stiffness ``D = Y h^3 / (12 (1 - nu^2))``."""
        return self.young * self.thickness**3 / (12 * (1 - self.poisson**2))


def _check_number(name: str, value: object, ok, expected: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise MaterialError(f"material.{name} must be a number, got {value!r}")
    if not math.isfinite(value) or not ok(value):
        raise MaterialError(f"material.{name} = {value!r} is invalid: must be {expected}")
