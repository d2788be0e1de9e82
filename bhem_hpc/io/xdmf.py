"""XDMF/HDF5 files ParaView reads: a tessellated surface, or a time series of frames with per-point fields.

Each is accompanied by VTK XML files of the same data (:mod:`.vtu`: ``.vtu``, and ``.pvd`` for a
series), which declare the normals so that ParaView shades with them; XDMF cannot. Serial writers:
call them on one rank with a gathered surface. Every file is written under a temporary name and
renamed, so a reader never sees half a file.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
import sys
from pathlib import Path

import h5py
import numpy as np

from bhem_hpc.errors import InputError
from bhem_hpc.geometry.rational_bspline import RationalBSplineSurface
from bhem_hpc.geometry.surface import HermiteSurface
from bhem_hpc.geometry.trim import Trim
from bhem_hpc.io.fields import RestMetric, energy_densities, fundamental_forms, mean_curvature
from bhem_hpc.io.run_directory import write_replacing
from bhem_hpc.io.vtu import write_pvd, write_vtu

_ABANDONED: list = []  # HDF5 files whose writes failed: kept open, never freed, until the process ends
log = logging.getLogger("bhem_hpc.io")


def _is_h5py_deallocation(origin: object, tb) -> bool:
    """An error h5py reports while freeing an object of a file whose write failed."""
    if isinstance(origin, str) and origin.endswith("ObjectID.__dealloc__"):
        return True
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    code = tb.tb_frame.f_code if tb is not None else None
    return code is not None and code.co_name.endswith("__dealloc__") and "h5py" in code.co_filename


@contextlib.contextmanager
def _h5py_deallocation_errors_logged():
    """Once a write to a full disk fails, h5py prints a traceback for every object it frees (from
    Cython, through both sys.excepthook and sys.unraisablehook); the failed write raises once with
    the cause. These reports go to the debug log instead of stderr."""
    excepthook, unraisablehook = sys.excepthook, sys.unraisablehook

    def on_exception(kind, value, tb) -> None:
        if issubclass(kind, RuntimeError) and _is_h5py_deallocation(None, tb):
            log.debug("h5py while freeing an object: %s", value)
        else:
            excepthook(kind, value, tb)

    def on_unraisable(unraisable) -> None:
        if _is_h5py_deallocation(unraisable.object, unraisable.exc_traceback):
            log.debug("h5py while freeing an object: %s", unraisable.exc_value)
        else:
            unraisablehook(unraisable)

    sys.excepthook, sys.unraisablehook = on_exception, on_unraisable
    try:
        yield
    finally:
        sys.excepthook, sys.unraisablehook = excepthook, unraisablehook


def abandoned_files() -> int:
    """How many HDF5 files a failed write left open. HDF5 crashes when such a file is freed at
    interpreter exit: a process with any should end through ``os._exit`` (after MPI_Finalize)."""
    return len(_ABANDONED)


_FLOAT64 = 'NumberType="Float" Precision="8"'
_INT64 = 'NumberType="Int" Precision="8"'


def _attribute(name: str, npoints: int, vector: bool, location: str) -> str:
    """A node-centred Attribute: a Scalar per point ``(n,)`` or a 3-Vector ``(n, 3)``."""
    kind, dims = ("Vector", f"{npoints} 3") if vector else ("Scalar", f"{npoints}")
    return (
        f'<Attribute Name="{name}" AttributeType="{kind}" Center="Node"><DataItem Dimensions="{dims}" '
        f'{_FLOAT64} Format="HDF">{location}</DataItem></Attribute>'
    )


def _grid(name: str, h5: str, geometry: str, npoints: int, ncells: int, attributes: str, time: str = "") -> str:
    return (
        f'<Grid Name="{name}" GridType="Uniform">{time}'
        f'<Topology TopologyType="Quadrilateral" NumberOfElements="{ncells}">'
        f'<DataItem Dimensions="{ncells} 4" {_INT64} Format="HDF">{h5}:/topology</DataItem></Topology>'
        f'<Geometry GeometryType="XYZ"><DataItem Dimensions="{npoints} 3" {_FLOAT64} Format="HDF">'
        f"{h5}:{geometry}</DataItem></Geometry>{attributes}</Grid>"
    )


def _document(grids: str) -> str:
    return f'<?xml version="1.0"?>\n<Xdmf Version="3.0">\n  <Domain>\n{grids}\n  </Domain>\n</Xdmf>\n'


def _point_fields(point, rest: RestMetric | None = None, material=None) -> dict[str, np.ndarray]:
    """Per-point fields of a surface for ParaView: normal ``(n, 3)``, mean curvature ``(n,)`` and,
    given the rest surface's :class:`~bhem_hpc.io.fields.RestMetric` and the material, membrane and
    bending energy densities."""
    forms = fundamental_forms(point)
    fields = {"normal": point.normal, "mean_curvature": mean_curvature(point, forms)}
    if rest is not None and material is not None:
        membrane, bending = energy_densities(rest, point, material, forms)
        fields |= {"membrane_energy_density": membrane, "bending_energy_density": bending}
    return fields


def write_surface_xdmf(
    path: str | Path, surface: HermiteSurface, density: int = 4, name: str = "surface",
    rest: HermiteSurface | None = None, material=None,
) -> Path:  # fmt: skip
    """Write ``path`` (.xdmf) and its ``.h5`` with the surface tessellated at ``density``: normals,
    mean curvature and the parameters ``xi1``, ``xi2`` per point; with ``rest`` the displacement,
    and with ``material`` too the membrane and bending energy densities. The same data go to a
    ``.vtu`` beside it, with the normals declared.

    All files are written to temporary names and renamed, so a reader never sees half a file.
    """
    path = Path(path)
    h5_path = path.with_suffix(".h5")
    points, quads, params = surface.tessellate(density)
    point = surface.evaluate(params[:, 0], params[:, 1])
    rest_point = None if rest is None else rest.evaluate(params[:, 0], params[:, 1])
    metric = None if rest_point is None else RestMetric(rest_point)
    fields = {**_point_fields(point, metric, material), "xi1": params[:, 0], "xi2": params[:, 1]}
    if rest_point is not None:
        fields["displacement"] = point.x - rest_point.x
    tmp_h5 = h5_path.with_name(h5_path.name + ".tmp")
    with h5py.File(tmp_h5, "w") as f:
        f["geometry"] = points
        f["topology"] = quads.astype(np.int64)
        f["parameters"] = params  # (n, 2), for programs; ParaView gets the scalars xi1, xi2
        for key, array in fields.items():
            f[key] = array
    os.replace(tmp_h5, h5_path)
    attributes = "".join(
        _attribute(key, len(points), array.ndim == 2, f"{h5_path.name}:/{key}") for key, array in fields.items()
    )
    xml = _document("    " + _grid(name, h5_path.name, "/geometry", len(points), len(quads), attributes))
    write_replacing(path, xml)
    write_vtu(path.with_suffix(".vtu"), points, quads, fields)
    return path


#: The per-point fields of every frame of a series.
SERIES_FIELDS = ("normal", "mean_curvature", "membrane_energy_density", "bending_energy_density")


class SurfaceTimeSeries:
    """An XDMF time series of tessellated surfaces that ParaView plays as an animation.

    Heavy data go to ``<name>.h5`` (appended and flushed per frame); the ``.xdmf`` is rewritten
    atomically after every frame, so a run killed mid-way leaves a readable file listing every
    completed frame. The same frames go to ``<name>_frames/frame_<k>.vtu``, listed by ``<name>.pvd``
    (rewritten likewise), which declare the normals for shading. Serial: call on one rank with
    gathered surfaces.
    """

    def __init__(
        self, path: str | Path, rest: HermiteSurface, material, density: int = 4, continue_at: float | None = None,
        trim: Trim | None = None,
    ):
        """Start a series at ``path``, or with ``continue_at`` continue the one there: its frames up to
        that time are kept (later ones, written after the checkpoint being continued, are dropped).
        With a ``trim``, the quads whose centre it keeps (the file keeps its loops for the ray tracer)."""
        self.path = Path(path)
        self.h5_path = self.path.with_suffix(".h5")
        self.pvd_path = self.path.with_suffix(".pvd")
        self.vtu_folder = self.path.with_name(self.path.stem + "_frames")
        self.material = material
        self.density = density
        _, self.quads, self.params = rest.tessellate(density)
        if trim is not None:
            self.quads = trim.kept_elements(self.params, self.quads)
        self.rest_metric = RestMetric(rest.evaluate(self.params[:, 0], self.params[:, 1]))
        self.times: list[float] = []
        self._failed = False
        if continue_at is not None:
            self._continue(continue_at)
            return
        self.vtu_folder.mkdir(exist_ok=True)
        self.file = h5py.File(self.h5_path, "w")
        self.file["topology"] = self.quads.astype(np.int64)
        self.file["parameters"] = self.params
        grid = rest.grid
        self.file.attrs["patches"] = [grid.n1, grid.n2]
        self.file.attrs["xi1_range"] = grid.xi1_range
        self.file.attrs["xi2_range"] = grid.xi2_range
        self.file.attrs["periodic"] = [grid.periodic1, grid.periodic2]
        self.file.attrs["discretization"] = rest.discretization
        if isinstance(rest, RationalBSplineSurface):  # the weights (and own knots) complete the exact surface
            self.file["weights"] = rest.weights
            for axis, knots in enumerate(rest.knots or (None, None)):
                if knots is not None:
                    self.file[f"knots{axis + 1}"] = knots
        if trim is not None:
            self.file["trim_loops"] = np.concatenate(trim.loops)
            self.file["trim_loop_sizes"] = np.array([len(loop) for loop in trim.loops], dtype=np.int64)

    def _continue(self, until: float) -> None:
        if not self.h5_path.is_file():
            raise InputError(f"{self.h5_path} does not exist: there is no series to continue")
        self.file = h5py.File(self.h5_path, "a")
        if self.file.get("topology") is None or self.file["topology"].shape != self.quads.shape:
            self.file.close()
            raise InputError(f"{self.h5_path} holds another grid or output density: it cannot be continued")
        frames = self.file.get("frames")
        count = len(frames) if frames is not None else 0
        tolerance = 1e-9 * max(abs(until), 1e-300)
        for k in range(count):
            try:
                t = float(frames[str(k)].attrs["time"])
            except (KeyError, OSError):  # torn by a kill during its write: after the checkpoint
                t = math.inf
            if t > until + tolerance or len(self.times) < k:
                del frames[str(k)]  # written after the checkpoint (or after a gap): not part of this run
            else:
                self.times.append(t)
        self.file.flush()
        self.vtu_folder.mkdir(exist_ok=True)  # only once the series to continue is known to be there
        for stale in self.vtu_folder.glob("frame_*.vtu"):
            index = stale.stem.removeprefix("frame_")
            if index.isdigit() and int(index) >= len(self.times):
                stale.unlink()
        self._write_xml()

    def write(self, time: float, surface: HermiteSurface) -> None:
        """Append a frame; the XDMF lists it only once its data are flushed.

        Raises:
            OSError: the frame could not be written (disk full, I/O error); the frames before it
                stay readable and listed.
        """
        if self._failed:
            raise OSError(f"{self.h5_path}: an earlier frame failed to write")
        try:
            with _h5py_deallocation_errors_logged():
                self._write_frame(time, surface)
        except (OSError, RuntimeError) as exc:  # h5py reports a failed flush as RuntimeError
            self._failed = True
            _ABANDONED.append(self.file)  # closing (or freeing) a file HDF5 failed to flush can crash it
            error = " ".join(str(exc).split())
            cause = re.search(r"error message = '([^']*)'", error)  # HDF5's message holds the system's
            error = cause.group(1) if cause else error
            raise OSError(f"{self.h5_path}: frame at t = {time:.6g} s not written ({error})") from None
        self.times.append(float(time))
        self._write_xml()

    def _write_frame(self, time: float, surface: HermiteSurface) -> None:
        point = surface.evaluate(self.params[:, 0], self.params[:, 1])
        fields = _point_fields(point, self.rest_metric, self.material)
        fields = {name: fields[name] for name in SERIES_FIELDS}
        group = self.file.create_group(f"frames/{len(self.times)}")
        group["geometry"] = point.x
        for name, values in fields.items():
            group[name] = values
        group["nodal"] = surface.nodal  # the exact surface (Hermite nodal data or control points), for the ray tracer
        group.attrs["time"] = float(time)
        self.file.flush()
        write_vtu(self._vtu_path(len(self.times)), point.x, self.quads, fields)

    def _vtu_path(self, frame: int) -> Path:
        return self.vtu_folder / f"frame_{frame:06d}.vtu"

    def _write_xml(self) -> None:
        npoints, ncells = len(self.params), len(self.quads)
        h5 = self.h5_path.name
        grids = []
        for k, t in enumerate(self.times):
            attributes = "".join(
                _attribute(name, npoints, name == "normal", f"{h5}:/frames/{k}/{name}")
                for name in SERIES_FIELDS
            )
            grids.append(
                "      " + _grid(f"frame_{k}", h5, f"/frames/{k}/geometry", npoints, ncells, attributes,
                                 f'<Time Value="{t!r}"/>')
            )  # fmt: skip
        xml = _document(
            '    <Grid Name="surface" GridType="Collection" CollectionType="Temporal">\n'
            + "\n".join(grids)
            + "\n    </Grid>"
        )
        write_replacing(self.path, xml)
        write_pvd(self.pvd_path, self.frame_files())

    def frame_files(self) -> list[tuple[float, str]]:
        """``(time, VTK XML file relative to the series' folder)`` of every frame written."""
        folder = self.vtu_folder.name
        return [(t, f"{folder}/{self._vtu_path(k).name}") for k, t in enumerate(self.times)]

    def close(self) -> None:
        """Close the HDF5 file; after a failed write that may fail too, and is then left as it is."""
        if self.file and not self._failed:
            self.file.close()
        self.file = None


def read_frame(h5_path: str | Path, frame: int = -1) -> tuple[HermiteSurface, float]:
    """The surface (exact nodal data) and time of a frame of a :class:`SurfaceTimeSeries`.

    ``frame = -1`` is the last complete frame: one that a failed write (disk full) left behind
    half-written is skipped.
    """
    from bhem_hpc.geometry.bspline import surface_from_nodal
    from bhem_hpc.geometry.surface import ParameterGrid

    with h5py.File(h5_path, "r") as f:
        count = len(f["frames"]) if "frames" in f else 0
        if count == 0:
            raise InputError(f"{h5_path}: no frames written")
        index = frame if frame >= 0 else count + frame
        if not 0 <= index < count:
            raise InputError(f"{h5_path}: frame {frame} does not exist (0..{count - 1})")
        candidates = range(index, -1, -1) if frame == -1 else (index,)
        for k in candidates:
            try:
                nodal, time = f[f"frames/{k}/nodal"][()], float(f[f"frames/{k}"].attrs["time"])
                break
            except (KeyError, OSError, RuntimeError):
                continue
        else:
            raise InputError(f"{h5_path}: frame {frame} is incomplete (its write failed)")
        a = f.attrs
        grid = ParameterGrid(
            int(a["patches"][0]),
            int(a["patches"][1]),
            tuple(a["xi1_range"]),
            tuple(a["xi2_range"]),
            bool(a["periodic"][0]),
            bool(a["periodic"][1]),
        )
        discretization = str(a.get("discretization", "hermite"))
        weights = f["weights"][()] if "weights" in f else None
        knots = tuple(f[name][()] if name in f else None for name in ("knots1", "knots2"))
        return surface_from_nodal(discretization, grid, nodal, weights, knots), time


def read_trim_loops(h5_path: str | Path) -> list[np.ndarray] | None:
    """The trim loops ``(n_k, 2)`` a :class:`SurfaceTimeSeries` of a trimmed surface keeps, or None."""
    with h5py.File(h5_path, "r") as f:
        if "trim_loops" not in f:
            return None
        points, sizes = f["trim_loops"][()], f["trim_loop_sizes"][()]
    return np.split(points, np.cumsum(sizes)[:-1])
