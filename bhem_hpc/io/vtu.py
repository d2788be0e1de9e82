"""VTK XML files ParaView reads natively: a quadrilateral surface as ``.vtu`` and a time series as
``.pvd``, at float64, with the normals declared as the active normals.

XDMF has no attribute type for normals, and VTK's XDMF readers mark only scalars, vectors, tensors
and global ids active, so ParaView shades an XDMF surface flat. These files say ``Normals="normal"``
in their ``PointData``, which makes ParaView (and any VTK pipeline) shade with the surface's exact
normals. Serial writers: call them on one rank with gathered data. Every file is written under a
temporary name and renamed.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from bhem_hpc.io.run_directory import write_replacing

#: VTK cell types: a vertex, a quadrilateral.
VTK_VERTEX, VTK_QUAD = 1, 9
_TYPE_NAMES = {np.dtype(np.float64): "Float64", np.dtype(np.int64): "Int64", np.dtype(np.uint8): "UInt8"}


def _data_array(name: str, array: np.ndarray, offset: int) -> str:
    components = 1 if array.ndim == 1 else array.shape[1]
    return (
        f'<DataArray type="{_TYPE_NAMES[array.dtype]}" Name="{name}" NumberOfComponents="{components}" '
        f'format="appended" offset="{offset}"/>'
    )


def vtu_bytes(
    points: np.ndarray,
    quads: np.ndarray,
    fields: dict[str, np.ndarray],
    normals: str | None = "normal",
    cell_type: int = VTK_QUAD,
) -> bytes:
    """A VTK XML unstructured grid of one cell type with raw appended float64 data.

    Args:
        points: ``(n, 3)`` point coordinates.
        quads: ``(m, k)`` point indices of each cell: quadrilaterals counter-clockwise (``k = 4``),
            or vertices (``k = 1``) with ``cell_type = VTK_VERTEX``.
        fields: per-point arrays, ``(n,)`` scalars or ``(n, k)`` vectors and tensors, by name.
        normals: the field declared as the active normals (must be in ``fields``, ``(n, 3)``), or
            None (a point cloud).
        cell_type: :data:`VTK_QUAD` or :data:`VTK_VERTEX`.
    """
    if normals is not None and (normals not in fields or fields[normals].shape != points.shape):
        raise ValueError(f"normals field {normals!r} must be one of the fields, shaped like the points")
    blocks: list[np.ndarray] = []
    offset = 0

    def add(name: str, array: np.ndarray, dtype) -> str:
        nonlocal offset
        data = np.ascontiguousarray(array, dtype=dtype)
        xml = _data_array(name, data, offset)
        blocks.append(data)
        offset += 8 + data.nbytes  # a UInt64 byte count precedes each block
        return xml

    point_data = "".join(add(name, array, np.float64) for name, array in fields.items())
    geometry = add("Points", points, np.float64)
    connectivity = add("connectivity", quads.reshape(-1), np.int64)
    offsets = add("offsets", quads.shape[1] * np.arange(1, len(quads) + 1), np.int64)
    types = add("types", np.full(len(quads), cell_type), np.uint8)
    active = "" if normals is None else f' Normals="{normals}"'
    header = (
        '<?xml version="1.0"?>\n'
        '<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">\n'
        f'<UnstructuredGrid><Piece NumberOfPoints="{len(points)}" NumberOfCells="{len(quads)}">\n'
        f"<PointData{active}>{point_data}</PointData>\n"
        f"<Points>{geometry}</Points>\n"
        f"<Cells>{connectivity}{offsets}{types}</Cells>\n"
        "</Piece></UnstructuredGrid>\n"
        '<AppendedData encoding="raw">\n_'
    )
    body = b"".join(np.uint64(b.nbytes).astype("<u8").tobytes() + b.astype(b.dtype.newbyteorder("<")).tobytes()
                    for b in blocks)  # fmt: skip
    return header.encode() + body + b"\n</AppendedData>\n</VTKFile>\n"


def read_vtu(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The points ``(n, 3)`` and cells ``(m, k)`` of a file :func:`vtu_bytes` wrote (raw appended data).

    Raises:
        ValueError: the file is not such a file.
    """
    data = Path(path).read_bytes()
    marker = b'<AppendedData encoding="raw">\n_'
    start = data.find(marker)
    if start < 0:
        raise ValueError(f"{path}: not a VTK XML file with raw appended data")
    header, start = data[:start].decode(errors="replace"), start + len(marker)

    def block(name: str, dtype: str) -> np.ndarray:
        found = re.search(rf'Name="{name}" NumberOfComponents="\d+" format="appended" offset="(\d+)"', header)
        if found is None:
            raise ValueError(f"{path}: no appended array {name!r}")
        at = start + int(found.group(1))
        size = int(np.frombuffer(data, "<u8", 1, at)[0])
        return np.frombuffer(data, dtype, size // np.dtype(dtype).itemsize, at + 8)

    points = block("Points", "<f8").reshape(-1, 3)
    offsets = block("offsets", "<i8")
    width = int(offsets[0]) if len(offsets) else 1
    return points.copy(), block("connectivity", "<i8").reshape(-1, width).copy()


def write_vtu(
    path: str | Path, points, quads, fields: dict[str, np.ndarray], normals: str | None = "normal", cell_type=VTK_QUAD
) -> Path:
    """Write :func:`vtu_bytes` to ``path`` by rename."""
    path = Path(path)
    write_replacing(path, vtu_bytes(points, quads, fields, normals, cell_type))
    return path


def write_pvd(path: str | Path, frames: list[tuple[float, str]], parts: list[int] | None = None) -> Path:
    """Write a ParaView collection ``path`` (.pvd) listing ``(time, file relative to path)`` frames;
    ``parts``: each frame's part (several bodies at one time), default 0."""
    path = Path(path)
    parts = [0] * len(frames) if parts is None else parts
    entries = "".join(f'    <DataSet timestep="{time!r}" part="{part}" file="{file}"/>\n'
                      for (time, file), part in zip(frames, parts, strict=True))  # fmt: skip
    xml = (
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="1.0" byte_order="LittleEndian">\n'
        f"  <Collection>\n{entries}  </Collection>\n</VTKFile>\n"
    )
    write_replacing(path, xml)
    return path
