"""Output: XDMF time series for ParaView, checkpoints, PNG previews, per-point fields."""

from bhem_hpc.io.output import (
    SurfaceTimeSeries,
    read_checkpoint,
    read_frame,
    render_surface_png,
    write_checkpoint,
    write_surface_xdmf,
)

__all__ = [
    "SurfaceTimeSeries",
    "read_checkpoint",
    "read_frame",
    "render_surface_png",
    "write_checkpoint",
    "write_surface_xdmf",
]
