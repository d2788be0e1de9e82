"""Output: XDMF files and time series for ParaView (:mod:`.xdmf`), checkpoints (:mod:`.checkpoint`),
PNG previews (:mod:`.preview`) and the per-point fields written with each frame (:mod:`.fields`)."""

from bhem_hpc.io.checkpoint import read_checkpoint, write_checkpoint
from bhem_hpc.io.preview import render_surface_png
from bhem_hpc.io.xdmf import SurfaceTimeSeries, read_frame, write_surface_xdmf

__all__ = [
    "SurfaceTimeSeries",
    "read_checkpoint",
    "read_frame",
    "render_surface_png",
    "write_checkpoint",
    "write_surface_xdmf",
]
