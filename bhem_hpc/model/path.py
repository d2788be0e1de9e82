"""What a path-following analysis asks for, apart from how it is solved (no PETSc here): probes,
arc-length settings and a static scene's path plan. The solver is :mod:`bhem_hpc.solver.path`."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from bhem_hpc.errors import UserError

if TYPE_CHECKING:
    from bhem_hpc.model.shell import ShellModel

PATH_METHODS = ("load", "displacement", "arc_length")
MAX_PATH_POINTS = 100_000


class PathSettingError(UserError, ValueError):
    """Path-following settings out of range (raised before any solve)."""


@dataclass(frozen=True)
class Probe:
    """A named material point ``(xi1, xi2)`` whose position is recorded at every path point (static)
    or time step (dynamic)."""

    name: str
    xi1: float
    xi2: float


class ProbeSet:
    """Positions and displacements (from the model's initial surface) of probes; collective.

    Raises:
        PathSettingError: duplicate names or a probe outside the parameter domain.
    """

    def __init__(self, model: ShellModel, probes: Sequence[Probe]):
        names = [p.name for p in probes]
        if len(set(names)) != len(names):
            raise PathSettingError(f"probe names must be unique, got {names}")
        grid = model.rest_surface.grid
        for probe in probes:
            inside1 = grid.xi1_range[0] <= probe.xi1 <= grid.xi1_range[1]
            inside2 = grid.xi2_range[0] <= probe.xi2 <= grid.xi2_range[1]
            if not (inside1 and inside2):
                raise PathSettingError(
                    f"probe {probe.name!r} at (xi1, xi2) = ({probe.xi1!r}, {probe.xi2!r}) lies outside the "
                    f"parameter domain {grid.xi1_range} x {grid.xi2_range}"
                )
        self.model = model
        self.probes = tuple(probes)
        self.names = names
        self._basis = [model.discretization.point_basis(p.xi1, p.xi2) for p in self.probes]
        initial = model.initial_surface
        self.start = np.array([initial.evaluate(np.array(p.xi1), np.array(p.xi2)).x for p in self.probes]).reshape(
            -1, 3
        )

    def positions(self) -> np.ndarray:
        """Positions ``(probes, 3)`` at the model's current state (collective)."""
        return self.model.point_positions(self._basis)

    def record(self) -> dict[str, dict[str, np.ndarray]]:
        """Per probe name its ``position`` and ``displacement`` ``(3,)`` (collective)."""
        positions = self.positions()
        return {
            name: {"position": positions[k], "displacement": positions[k] - self.start[k]}
            for k, name in enumerate(self.names)
        }


def _number(name: str, value, ok: Callable[[float], bool], expected: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or np.isnan(value) or not ok(value):
        raise PathSettingError(f"{name} = {value!r} is invalid: must be {expected}")


@dataclass(frozen=True)
class ArcLength:
    """Arc-length continuation settings.

    Attributes:
        initial_step: first arc length ``ds`` [m], a root-mean-square change of the DOFs
            (``|du| / sqrt(n)``), so the same settings serve any mesh.
        min_step, max_step: bounds of the adapted ``ds``.
        max_steps: path points to compute at most.
        load_factor_range: stop once lambda leaves ``(low, high)``.
        target_iterations: Newton iterations per step the step size adapts to
            (``ds *= sqrt(target / iterations)``, within a factor of 2 per step).
        max_cuts: halvings of ``ds`` in a row before the step is given up.
        direction: +1 to start with increasing lambda, -1 decreasing.
    """

    initial_step: float
    min_step: float = 0.0
    max_step: float = float("inf")
    max_steps: int = 100
    load_factor_range: tuple[float, float] = (-np.inf, 1.0)
    target_iterations: int = 5
    max_cuts: int = 8
    direction: int = 1

    def validate(self, prefix: str = "arc_length.") -> None:
        _number(f"{prefix}initial_step", self.initial_step, lambda v: 0 < v < np.inf, "a number > 0")
        _number(f"{prefix}min_step", self.min_step, lambda v: 0 <= v <= self.initial_step, "in [0, initial_step]")
        _number(f"{prefix}max_step", self.max_step, lambda v: v >= self.initial_step, ">= initial_step")
        for name, value, low, high in (
            ("max_steps", self.max_steps, 1, MAX_PATH_POINTS),
            ("target_iterations", self.target_iterations, 1, 50),
            ("max_cuts", self.max_cuts, 0, 50),
        ):
            _number(f"{prefix}{name}", value, lambda v, lo=low, hi=high: int(v) == v and lo <= v <= hi,
                    f"an integer in {low}..{high}")  # fmt: skip
        low, high = self.load_factor_range
        _number(f"{prefix}load_factor_range[0]", low, lambda v: v < high, "below load_factor_range[1]")
        _number(f"{prefix}load_factor_range[1]", high, lambda v: v > low, "above load_factor_range[0]")
        if not low < 0.0 < high:  # the path starts at load factor 0 and ends once it leaves the range
            raise PathSettingError(f"{prefix}load_factor_range = [{low:g}, {high:g}] is invalid: it must contain the "
                                   "start, load factor 0 (the path ends once it leaves the range)")  # fmt: skip
        if self.direction not in (1, -1):
            raise PathSettingError(f"{prefix}direction = {self.direction!r} is invalid: must be 1 or -1")


def check_levels(name: str, levels: Sequence[float]) -> np.ndarray:
    """``levels`` as a float array; raises :class:`PathSettingError` unless non-empty and finite."""
    try:
        values = np.asarray(levels, dtype=float)
    except (TypeError, ValueError):
        values = np.array([np.nan])
    if values.ndim != 1 or len(values) == 0 or not np.all(np.isfinite(values)):
        raise PathSettingError(f"{name} must be a non-empty list of finite numbers, got {levels!r}")
    if len(values) > MAX_PATH_POINTS:
        raise PathSettingError(f"{name} has {len(values)} entries; at most {MAX_PATH_POINTS}")
    return values


@dataclass(frozen=True)
class PathPlan:
    """A static scene's path: ``method`` (:data:`PATH_METHODS`) with its levels, controlled probe
    and values, or arc-length settings; ``options`` for the constrained SNES."""

    method: str = "load"
    levels: tuple[float, ...] = (1.0,)
    probe: str | None = None
    component: int | None = None
    values: tuple[float, ...] = ()
    arc_length: ArcLength | None = None
    max_cuts: int = 8
    options: dict = field(default_factory=dict)

    @property
    def point_count(self) -> int:
        """Path points after the start."""
        if self.method == "arc_length":
            return self.arc_length.max_steps
        return len(self.levels if self.method == "load" else self.values)

    def is_complete(self, done: int, load_factor: float) -> bool:
        """Whether a path with ``done`` points after the start, the last at ``load_factor``, has
        nothing left to run (all its points, or arc length outside its load-factor range)."""
        if done >= self.point_count:
            return True
        if self.arc_length is None:
            return False
        low, high = self.arc_length.load_factor_range
        return not low < load_factor < high

    @property
    def time_is_load_factor(self) -> bool:
        """Whether frames are timed by the load factor (load control with rising levels from 0);
        otherwise by the path's arc length."""
        return self.method == "load" and bool(np.all(np.diff([0.0, *self.levels]) > 0))
