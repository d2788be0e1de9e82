"""Output people look at: a ParaView-readable XDMF/HDF5 of a tessellated surface, and PNG renders.

Serial writers: call them on one rank with a gathered surface. The dynamics issue adds the
time-series writer; this module holds the single-frame form.
"""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np

from bhem_hpc.surface import HermiteSurface

_XDMF = """<?xml version="1.0"?>
<Xdmf Version="3.0">
  <Domain>
    <Grid Name="{name}" GridType="Uniform">
      <Topology TopologyType="Quadrilateral" NumberOfElements="{ncells}">
        <DataItem Dimensions="{ncells} 4" NumberType="Int" Format="HDF">{h5}:/topology</DataItem>
      </Topology>
      <Geometry GeometryType="XYZ">
        <DataItem Dimensions="{npoints} 3" Format="HDF">{h5}:/geometry</DataItem>
      </Geometry>
      <Attribute Name="normal" AttributeType="Vector" Center="Node">
        <DataItem Dimensions="{npoints} 3" Format="HDF">{h5}:/normal</DataItem>
      </Attribute>
      <Attribute Name="parameters" AttributeType="Vector" Center="Node">
        <DataItem Dimensions="{npoints} 2" Format="HDF">{h5}:/parameters</DataItem>
      </Attribute>
    </Grid>
  </Domain>
</Xdmf>
"""


def write_surface_xdmf(path: str | Path, surface: HermiteSurface, density: int = 4, name: str = "surface") -> Path:
    """Write ``path`` (.xdmf) and its ``.h5`` with the surface tessellated at ``density``.

    Both files are written to temporary names and renamed, so a reader never sees half a file.
    """
    path = Path(path)
    h5_path = path.with_suffix(".h5")
    points, quads, params = surface.tessellate(density)
    normals = surface.evaluate(params[:, 0], params[:, 1]).normal
    tmp_h5 = h5_path.with_name(h5_path.name + ".tmp")
    with h5py.File(tmp_h5, "w") as f:
        f["geometry"] = points
        f["topology"] = quads.astype(np.int64)
        f["normal"] = normals
        f["parameters"] = params
    os.replace(tmp_h5, h5_path)
    tmp_xdmf = path.with_name(path.name + ".tmp")
    tmp_xdmf.write_text(_XDMF.format(name=name, ncells=len(quads), npoints=len(points), h5=h5_path.name))
    os.replace(tmp_xdmf, path)
    return path


def render_surface_png(path: str | Path, surface: HermiteSurface, title: str = "", density: int = 4) -> Path:
    """A shaded matplotlib render of the tessellated surface (until the patch ray tracer exists)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    points, quads, params = surface.tessellate(density)
    normals = surface.evaluate(params[:, 0], params[:, 1]).normal
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    shade = 0.35 + 0.65 * np.abs(normals[quads].mean(axis=1) @ light)
    fig = plt.figure(figsize=(6, 5), dpi=120)
    ax = fig.add_subplot(projection="3d")
    faces = Poly3DCollection(points[quads], facecolors=plt.cm.Blues(0.3 + 0.6 * shade), edgecolor="none")
    ax.add_collection3d(faces)
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=False):
        setter(c - half, c + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    if title:
        ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return Path(path)
