"""Shell samples (a lattice of midsurface points per patch) and the shell's motion over a step."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bhem_hpc.contact.broad_phase import swept_boxes
from bhem_hpc.contact.closest_points import control_points
from bhem_hpc.errors import InputError
from bhem_hpc.geometry.surface import ParameterGrid, PatchLayout


def lattice_axes(grid: ParameterGrid, per_side: int) -> list[np.ndarray]:
    """The parameters of a uniform lattice of ``n * per_side`` steps along each direction of
    ``grid`` (its end included unless the direction is periodic): ``[xi1 (L1,), xi2 (L2,)]``."""
    axes = []
    for n, (lo, hi), periodic in ((grid.n1, grid.xi1_range, grid.periodic1), (grid.n2, grid.xi2_range, grid.periodic2)):
        count = n * per_side + (0 if periodic else 1)
        axes.append(lo + (hi - lo) * np.arange(count) / (n * per_side))
    return axes


@dataclass(frozen=True)
class ShellSamples:
    """Uniform samples of the midsurface, about ``per_side^2`` per patch.

    Attributes:
        patch: ``(S,)`` flat patch index ``p1 * n2 + p2``; local: ``(S, 2)`` local coordinates.
        index, weights: ``(S, 16)`` nodal weights of each sample.
    """

    patch: np.ndarray
    local: np.ndarray
    index: np.ndarray
    weights: np.ndarray

    @staticmethod
    def build(layout: PatchLayout, per_side: int) -> ShellSamples:
        """A uniform lattice of ``n * per_side (+ 1)`` points per direction over the whole surface,
        boundary edges included (an unsampled free edge could swing through a plane)."""
        if not (isinstance(per_side, int) and 1 <= per_side <= 16):
            raise InputError(f"samples_per_side must be an integer in 1..16, got {per_side!r}")
        grid = layout.grid
        xi1, xi2 = (a.ravel() for a in np.meshgrid(*lattice_axes(grid, per_side), indexing="ij"))
        p1, p2, t1, t2 = grid.locate(xi1, xi2)
        index, weights = layout.point_entries(p1, p2, t1, t2)
        return ShellSamples(p1 * grid.n2 + p2, np.stack([t1, t2], axis=1), index, weights)

    def positions(self, flat_nodal: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Positions ``(len(rows), 3)`` of samples ``rows`` for flat nodal data ``(N, 3)``."""
        return np.einsum("sj,sjc->sc", self.weights[rows], flat_nodal[self.index[rows]])


@dataclass(frozen=True)
class ShellMotion:
    """The shell's straight-line motion over one step, as detection sees it.

    Attributes:
        layout: the patches as maps of the entries (:class:`~bhem_hpc.geometry.surface.HermitePatches`).
        start, end: entries ``(N, 3)`` at the start and the end of the step.
        nets_start, nets_end: the patches' Bezier nets ``(patches, 4, 4, 3)`` at both ends (a solid's
            :class:`~bhem_hpc.contact.solid_surface.SolidMotion`: homogeneous ``(patches, 4, 4, 4)``).
        dt: the step [s]; gap: the push-out distance (contacts are found within it).
    """

    layout: PatchLayout
    start: np.ndarray
    end: np.ndarray
    nets_start: np.ndarray
    nets_end: np.ndarray
    dt: float
    gap: float

    @staticmethod
    def of(layout: PatchLayout, start: np.ndarray, end: np.ndarray, dt: float, gap: float) -> ShellMotion:
        return ShellMotion(layout, start, end, layout.bezier_nets(start), layout.bezier_nets(end), dt, gap)

    @property
    def num_patches(self) -> int:
        return len(self.nets_end)

    def patch_boxes(self, pad: float) -> np.ndarray:
        """``(patches, 2, 3)`` boxes around each patch over the step, padded by ``pad``."""
        return swept_boxes(control_points(self.nets_start), control_points(self.nets_end), pad)

    def patch_point_entries(self, patch: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The entries and weights ``(n, K)`` of the points at local ``uv (n, 2)`` of flat patches ``patch (n,)``."""
        n2 = self.layout.grid.n2
        return self.layout.point_entries(patch // n2, patch % n2, uv[:, 0], uv[:, 1])
