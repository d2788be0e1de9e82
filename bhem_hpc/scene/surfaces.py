"""The ``[surface]`` table: each surface kind parses its own keys and registers itself in
:data:`SURFACES` (``kind = "rectangle"``, ...; ``"file"`` reads nodal data or a B-spline file)."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np

from bhem_hpc.geometry import bspline as B
from bhem_hpc.geometry import surface as S
from bhem_hpc.model.expression import ExpressionError, finite_on_patches, numpy_expression
from bhem_hpc.scene.table import Registry, SceneError, Table, regular_file

#: Parsers of the surface kinds: ``(table, scene path, discretization) -> surface``.
SURFACES = Registry("surface kind")
MAX_PATCHES = 1_000_000  # patches (knot spans) of one surface: about 12 million Hermite DoFs
ANGLE_RANGE = "2 numbers (min, max), at most 2 pi apart [rad]"
Shape = S.HermiteSurface | B.BSplineSurface
#: The shells' discretizations by name: ``"nurbs"`` is a CAD part's own rational B-splines (its degree).
SHELL_DISCRETIZATIONS = (*B.DISCRETIZATIONS, "nurbs")


def parse_surface(t: Table, path: Path) -> Shape:
    """The surface of the ``[surface]`` table ``t`` of the scene file ``path``."""
    kinds = SURFACES.names
    kind = t.get("kind", "a string", check=lambda v: v in kinds, expected=f"one of {kinds}")
    discretization = t.get(
        "discretization", "a string", "hermite", lambda v: v in SHELL_DISCRETIZATIONS, f"one of {SHELL_DISCRETIZATIONS}"
    )
    if discretization == "nurbs" and kind != "cad_part":
        t.fail("discretization", f'one of {B.DISCRETIZATIONS} for kind "{kind}" ("nurbs" keeps a CAD part\'s '
               'exact rational patches: kind "cad_part" or a cad_shell body)', discretization)  # fmt: skip
    try:
        surface = SURFACES[kind](t, path, discretization)
    except S.SurfaceError as exc:
        raise SceneError(f"{path}: table 'surface': {exc}") from exc
    rotation, translation = _placement(t)
    t.done()
    return surface if rotation is None and translation is None else surface.transformed(
        np.eye(3) if rotation is None else rotation, np.zeros(3) if translation is None else translation
    )


def _placement(t: Table) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``rotation = { axis = [x, y, z], degrees = a }`` and ``translation = [x, y, z]``: the surface
    the kind built, moved by ``x -> R x + t`` (about the world origin, rotation first)."""
    rotation = None
    table = t.table("rotation", None)
    if table is not None:
        axis = table.get("axis", "3 numbers", check=lambda v: all(math.isfinite(c) for c in v) and any(v),
                         expected="3 finite numbers, not all 0")  # fmt: skip
        axis = np.array(axis, float)
        degrees = table.get("degrees", "a number", check=math.isfinite, expected="a finite number (degrees)")
        table.done()
        k = axis / np.linalg.norm(axis)
        cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        angle = math.radians(degrees)  # Rodrigues' formula
        rotation = np.eye(3) + math.sin(angle) * cross + (1.0 - math.cos(angle)) * cross @ cross
    translation = t.get("translation", "3 numbers", None, lambda v: all(math.isfinite(c) for c in v),
                        "3 finite numbers [m]")  # fmt: skip
    return rotation, None if translation is None else np.array(translation, float)


def _patches(t: Table, discretization: str) -> tuple[list[int], dict[str, int], object]:
    """``patches`` of a constructed surface, the constructors' ``degree`` keyword (none: Hermite)
    and their module (Hermite nodal data, or B-spline control points by interpolation)."""
    patches = t.get(
        "patches", "2 integers", check=lambda v: min(v) >= 1 and v[0] * v[1] <= MAX_PATCHES,
        expected=f"2 integers >= 1, at most {MAX_PATCHES} patches in all",
    )  # fmt: skip
    spline = {} if discretization in ("hermite", "nurbs") else {"degree": int(discretization[-1])}
    return patches, spline, S if discretization == "hermite" else B


#: Lengths a surface may have, in the scene's length unit (beyond them its derivatives and metric
#: under- or overflow in floating point).
LENGTH_RANGE = (1e-9, 1e9)
_LENGTHS = f"in [{LENGTH_RANGE[0]:g}, {LENGTH_RANGE[1]:g}]"


def _is_length(value: float) -> bool:
    return LENGTH_RANGE[0] <= value <= LENGTH_RANGE[1]


def _positive(t: Table, key: str) -> float:
    """A length of the surface (radius, length)."""
    return t.get(key, "a number", check=_is_length, expected=f"a number {_LENGTHS}")


def _lengths(t: Table, key: str) -> list[float]:
    """Two lengths of the surface (size, radii)."""
    return t.get(key, "2 numbers", check=lambda v: all(_is_length(x) for x in v), expected=f"2 numbers {_LENGTHS}")


def _angle_range(angles: list[float]) -> bool:
    return 0 < angles[1] - angles[0] <= 2 * math.pi + 1e-12


@SURFACES.register("rectangle")
def _rectangle(t: Table, path: Path, discretization: str) -> Shape:
    """A flat rectangle, or one raised by ``z = height(xi1, xi2)`` (parameters from 0 to the size),
    e.g. a shallow arch or panel: ``height = "0.01 * sin(pi * xi1)"``."""
    patches, spline, _ = _patches(t, discretization)
    size = _lengths(t, "size")
    origin = tuple(t.get("origin", "3 numbers", [0.0, 0.0, 0.0]))
    height = t.get("height", "a string", None)
    if height is None and spline:
        return B.flat_rectangle(size[0], size[1], patches[0], patches[1], origin=origin, **spline)
    if height is None:
        return S.flat_rectangle(size[0], size[1], patches[0], patches[1], origin=origin)
    try:
        z = numpy_expression(height)
    except ExpressionError as exc:
        t.fail("height", f"an expression of xi1 and xi2 ({exc})", height)
    grid, flat = S.rectangle_shape(size[0], size[1], patches[0], patches[1], origin)

    def shape(a, b):
        return flat(a, b) + np.stack([0 * a, 0 * a, z(a, b)], axis=-1)

    if not finite_on_patches(height, (grid.xi1_range, grid.xi2_range), (grid.n1, grid.n2)):
        t.fail("height", "an expression finite on the whole rectangle", height)
    return B.from_callable(shape, grid, **spline) if spline else S.from_callable(shape, grid)


@SURFACES.register("cylinder")
def _cylinder(t: Table, path: Path, discretization: str) -> Shape:
    patches, spline, shapes = _patches(t, discretization)
    closed = t.get("closed", "a boolean", True)
    angle = t.get("angle", "a number", 2 * math.pi, lambda v: 0 < v <= 2 * math.pi, "in (0, 2 pi]")
    low, high = t.get("angles", "2 numbers", [0.0, angle], _angle_range, ANGLE_RANGE)
    if closed and not math.isclose(high - low, 2 * math.pi):
        t.fail("closed", "false for an open sector (angles less than 2 pi apart)", closed)
    radius, length = _positive(t, "radius"), _positive(t, "length")
    return shapes.cylinder(radius, length, patches[0], patches[1], **spline, closed=closed,
                           angle=high - low if not closed else 2 * math.pi, seam_angle=low)  # fmt: skip


@SURFACES.register("sphere_zone")
def _sphere_zone(t: Table, path: Path, discretization: str) -> Shape:
    patches, spline, shapes = _patches(t, discretization)
    turn = {"closed": t.get("closed", "a boolean", None)}  # default: closed for a full turn
    polar = t.get("polar", "2 numbers")
    azimuth = t.get("azimuth", "2 numbers", [0.0, 2 * math.pi], _angle_range, ANGLE_RANGE)
    return shapes.sphere_zone(_positive(t, "radius"), polar[0], polar[1], *patches, **spline,
                              azimuth=tuple(azimuth), **turn)  # fmt: skip


@SURFACES.register("annulus_sector")
def _annulus_sector(t: Table, path: Path, discretization: str) -> Shape:
    patches, spline, shapes = _patches(t, discretization)
    turn = {"closed": t.get("closed", "a boolean", None)}
    radii = _lengths(t, "radii")
    angles = t.get("angles", "2 numbers", check=_angle_range, expected=ANGLE_RANGE)
    return shapes.annulus_sector(radii[0], radii[1], angles[0], angles[1], *patches, **spline, **turn)


@SURFACES.register("torus")
def _torus(t: Table, path: Path, discretization: str) -> Shape:
    patches, spline, shapes = _patches(t, discretization)
    t.get("closed", "a boolean", None)  # accepted as for the other surfaces of revolution (always closed)
    radii = _lengths(t, "radii")
    return shapes.torus(radii[0], radii[1], *patches, **spline)


@SURFACES.register("file")
def _surface_file(t: Table, path: Path, discretization: str) -> Shape:
    """``kind = "file"``: a Hermite nodal data file, or a B-spline file of the named degree."""
    file = t.get("path", "a string")
    target = regular_file(t, "path", file, path)
    if discretization == "hermite":
        return S.HermiteSurface.load(target)
    surface = B.BSplineSurface.load(target)
    if surface.discretization != discretization:
        raise SceneError(
            f"{path}: key 'surface.discretization' is {discretization!r} but {target} holds a {surface.discretization}"
        )
    return surface


@SURFACES.register("mapped")
def _mapped(t: Table, path: Path, discretization: str) -> Shape:
    """``kind = "mapped"``: a panel of any outline, the square of parameters ``[0, 1]^2`` mapped onto
    its rest shape by expressions of ``xi1`` and ``xi2`` (the B-spline cloth paper's irregular
    sheets): ``position = ["x", "y", "z"]``, e.g. a trapezoid
    ``["(0.5 + 0.3 * xi2) * (xi1 - 0.5)", "0.6 * xi2", "0"]``."""
    patches, spline, _ = _patches(t, discretization)
    texts = t.get("position", "a list", check=lambda v: len(v) == 3 and all(isinstance(c, str) for c in v),
                  expected="3 expressions of xi1 and xi2 (x, y, z) [m]")  # fmt: skip
    try:
        parts = [numpy_expression(text) for text in texts]
    except ExpressionError as exc:
        t.fail("position", f"3 expressions of xi1 and xi2 ({exc})", texts)
    unit = ((0.0, 1.0), (0.0, 1.0))
    if not all(finite_on_patches(text, unit, (patches[0], patches[1])) for text in texts):
        t.fail("position", "3 expressions finite on the whole square [0, 1]^2", texts)
    grid = S.ParameterGrid(patches[0], patches[1], (0.0, 1.0), (0.0, 1.0), False, False)

    def shape(a, b):
        return np.stack([np.broadcast_to(f(a, b), np.shape(a)) for f in parts], axis=-1)

    surface = B.from_callable(shape, grid, **spline) if spline else S.from_callable(shape, grid)
    S.check_regular(surface, name="the mapped panel")
    return surface


@functools.lru_cache(maxsize=8)
def _read_model(resolved: str, modified_ns: int, size: int) -> tuple:
    from bhem_hpc.io.cad import read_shell_parts  # the CAD code loads for CAD models only

    return tuple(read_shell_parts(resolved))


def model_parts(file: Path) -> list:
    """The parts of a CAD model file as shells take them (:func:`~bhem_hpc.io.cad.read_shell_parts`:
    each a NURBS surface and its trim loops or None), read once while the file is unchanged (a
    ``cad_shell`` body's parts each name the file)."""
    stat = file.stat()
    return list(_read_model(str(file.resolve()), stat.st_mtime_ns, stat.st_size))


@SURFACES.register("cad_part")
def _cad_part(t: Table, path: Path, discretization: str) -> Shape:
    """``kind = "cad_part"``: part ``part`` (its index in the file) of a NURBS model (IGES or .3dm,
    ``file`` relative to the scene) on ``patches`` uniform knot spans
    (:func:`~bhem_hpc.geometry.nurbs.shell_surface`); a ``cad_shell`` body names every part of a
    model so (:mod:`bhem_hpc.scene.cad_shell`). With ``discretization = "nurbs"`` the part itself,
    exactly (:func:`~bhem_hpc.geometry.rational_bspline.on_uniform_knots`: at least ``patches`` spans),
    or with ``piece = [i, j]`` its piece between the knots where it is only C0
    (:func:`~bhem_hpc.geometry.rational_bspline.split_at_kinks`)."""
    from bhem_hpc.geometry.nurbs import shell_surface  # the CAD code loads for CAD models only
    from bhem_hpc.geometry.rational_bspline import on_uniform_knots, split_at_kinks

    target = regular_file(t, "file", t.get("file", "a string"), path)
    parts = model_parts(target)
    index = t.get("part", "an integer", check=lambda v: 0 <= v < len(parts),
                  expected=f"a part of the file, 0..{len(parts) - 1}")  # fmt: skip
    patches, _, _ = _patches(t, discretization)
    if discretization == "nurbs":
        part = parts[index].surface
        if "piece" in t.data:  # a piece of a part cut at its C0 knots
            pieces = split_at_kinks(part)
            rows, columns = len(pieces), len(pieces[0])
            place = t.get("piece", "2 integers", check=lambda v: 0 <= v[0] < rows and 0 <= v[1] < columns,
                          expected=f"a piece [i, j] of part {index}, i < {rows}, j < {columns}")  # fmt: skip
            part = pieces[place[0]][place[1]]
        return on_uniform_knots(part, tuple(patches))
    return shell_surface(parts[index].surface, tuple(patches), discretization)
