"""The parameter grid of a surface and its files (numpy only).

A :class:`ParameterGrid` is a uniform grid of ``n1 x n2`` patches over a rectangle of parameter
space, periodic (closed) or not in each direction. A surface file (Hermite nodal data, B-spline
control points) is a NumPy ``.npz`` archive with ``format``, ``version``, the grid's keys and the
surface's arrays; reading one checks every key and names the file and key of anything wrong.
"""

from __future__ import annotations

import math
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bhem_hpc.errors import UserError


class SurfaceError(UserError, ValueError):
    """Invalid surface data (bad grid, non-finite or degenerate geometry, bad file)."""


@dataclass(frozen=True)
class ParameterGrid:
    """A uniform grid of ``n1 x n2`` patches over ``[xi1_min, xi1_max] x [xi2_min, xi2_max]``."""

    n1: int
    n2: int
    xi1_range: tuple[float, float]
    xi2_range: tuple[float, float]
    periodic1: bool = False
    periodic2: bool = False

    def __post_init__(self) -> None:
        for name, n in (("n1", self.n1), ("n2", self.n2)):
            if not isinstance(n, int | np.integer) or n < 1:
                raise SurfaceError(f"ParameterGrid.{name} must be a positive integer, got {n!r}")
        for name, (lo, hi) in (("xi1_range", self.xi1_range), ("xi2_range", self.xi2_range)):
            if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
                raise SurfaceError(f"ParameterGrid.{name} must be finite with max > min, got {(lo, hi)!r}")
        for name, periodic, n in (
            ("periodic1", self.periodic1, self.n1),
            ("periodic2", self.periodic2, self.n2),
        ):
            if periodic and n < 3:
                raise SurfaceError(f"ParameterGrid.{name}=True needs at least 3 patches in that direction, got {n}")

    @property
    def h1(self) -> float:
        return (self.xi1_range[1] - self.xi1_range[0]) / self.n1

    @property
    def h2(self) -> float:
        return (self.xi2_range[1] - self.xi2_range[0]) / self.n2

    @property
    def node_shape(self) -> tuple[int, int]:
        """Number of distinct nodes ``(m1, m2)``; a closed direction stores seam nodes once."""
        return (self.n1 + (0 if self.periodic1 else 1), self.n2 + (0 if self.periodic2 else 1))

    @property
    def num_nodes(self) -> int:
        m1, m2 = self.node_shape
        return m1 * m2

    def node_parameters(self) -> tuple[np.ndarray, np.ndarray]:
        """Parameters of the distinct nodes, two arrays of shape ``(m1, m2)``."""
        m1, m2 = self.node_shape
        xi1 = self.xi1_range[0] + self.h1 * np.arange(m1)
        xi2 = self.xi2_range[0] + self.h2 * np.arange(m2)
        return np.meshgrid(xi1, xi2, indexing="ij")

    def wrap_node(self, i1: np.ndarray, i2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map open-grid node indices (``0..n_a``) to distinct node indices (seam nodes wrap)."""
        i1 = np.asarray(i1)
        i2 = np.asarray(i2)
        if self.periodic1:
            i1 = np.mod(i1, self.n1)
        if self.periodic2:
            i2 = np.mod(i2, self.n2)
        return i1, i2

    def locate(self, xi1: np.ndarray, xi2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Patch indices and local coordinates of parameters.

        Points on a shared edge go to the patch with the larger index except on the domain's
        upper boundary. Periodic directions wrap; others must lie inside the domain (within
        1e-12 of the patch width).

        Returns:
            ``(p1, p2, theta1, theta2)``, each of the broadcast shape of ``xi1`` and ``xi2``.
        """
        xi1, xi2 = np.broadcast_arrays(np.asarray(xi1, dtype=float), np.asarray(xi2, dtype=float))
        out = []
        for xi, (lo, hi), n, h, periodic, name in (
            (xi1, self.xi1_range, self.n1, self.h1, self.periodic1, "xi1"),
            (xi2, self.xi2_range, self.n2, self.h2, self.periodic2, "xi2"),
        ):
            if not np.all(np.isfinite(xi)):
                raise SurfaceError(f"parameter {name} contains NaN/Inf")
            s = (xi - lo) / h
            if periodic:
                s = np.mod(s, n)
            elif np.any(s < -1e-12) or np.any(s > n + 1e-12):
                bad = xi[(s < -1e-12) | (s > n + 1e-12)].ravel()[0]
                raise SurfaceError(f"parameter {name}={bad!r} lies outside [{lo}, {hi}]")
            p = np.clip(np.floor(s).astype(np.int64), 0, n - 1)
            out.append((p, np.clip(s - p, 0.0, 1.0)))
        return out[0][0], out[1][0], out[0][1], out[1][1]


def save_surface_file(
    path: str | Path, file_format: str, version: int, grid: ParameterGrid, **arrays: np.ndarray
) -> None:
    """Write a surface file: ``format``, ``version``, the grid's keys and ``arrays``; atomically."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(
        tmp,
        format=np.array(file_format),
        version=np.array(version),
        patches=np.array([grid.n1, grid.n2]),
        xi1_range=np.array(grid.xi1_range, float),
        xi2_range=np.array(grid.xi2_range, float),
        periodic=np.array([grid.periodic1, grid.periodic2]),
        **arrays,
    )
    tmp.replace(path)


def load_surface_file(
    path: str | Path, file_format: str, version: int, keys: tuple[str, ...], what: str
) -> tuple[ParameterGrid, dict[str, np.ndarray]]:
    """Read a file of :func:`save_surface_file`: its grid and the arrays ``keys``; errors name the
    file and key (also for a truncated or corrupt archive)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            return _read_surface_file(path, data, file_format, version, keys)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        if isinstance(exc, SurfaceError):
            raise
        raise SurfaceError(f"{path}: cannot read {what} ({type(exc).__name__}: {exc})") from None


def _scalar(path: Path, data, key: str, kind: type):
    """``data[key]`` as one ``kind`` (str or int); raises :class:`SurfaceError` naming the key."""
    value = data[key]
    usable = value.shape == () and (value.dtype.kind in "US" if kind is str else value.dtype.kind in "iu")
    if not usable:
        expected = "a string" if kind is str else "an integer"
        raise SurfaceError(f"{path}: key {key!r} must be {expected}, got {value.tolist()!r}")
    return kind(value[()])


def _read_surface_file(path: Path, data, file_format: str, version: int, keys: tuple[str, ...]):
    for key in ("format", "version", "patches", "xi1_range", "xi2_range", "periodic", *keys):
        if key not in data.files:
            raise SurfaceError(f"{path}: missing key {key!r} (has {sorted(data.files)})")
    if (found := _scalar(path, data, "format", str)) != file_format:
        raise SurfaceError(f"{path}: key 'format' is {found!r}, expected {file_format!r}")
    if (found := _scalar(path, data, "version", int)) != version:
        raise SurfaceError(f"{path}: key 'version' is {found}, expected {version}")
    shapes = {"patches": (2,), "xi1_range": (2,), "xi2_range": (2,), "periodic": (2,)}
    for key, shape in shapes.items():
        if data[key].shape != shape or data[key].dtype.kind not in "iufb":
            raise SurfaceError(f"{path}: key {key!r} must be 2 numbers, got {data[key].tolist()!r}")
    try:
        n1, n2 = (int(v) for v in data["patches"])
        grid = ParameterGrid(
            n1,
            n2,
            tuple(float(v) for v in data["xi1_range"]),
            tuple(float(v) for v in data["xi2_range"]),
            *(bool(v) for v in data["periodic"]),
        )
    except (SurfaceError, ValueError, TypeError) as exc:
        raise SurfaceError(f"{path}: {exc}") from exc
    return grid, {key: data[key][()] for key in keys}
