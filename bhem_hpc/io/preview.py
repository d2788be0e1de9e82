"""PNG previews of a surface (matplotlib, off-screen)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from bhem_hpc.geometry.surface import HermiteSurface


def render_surface_png(
    path: str | Path, surface: HermiteSurface | Sequence[HermiteSurface], title: str = "",
    size: tuple[int, int] = (480, 360),
) -> Path:
    """Ray-trace the surface's patches, or several surfaces' (:func:`bhem_hpc.io.render.render`), to a
    PNG with a title line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bhem_hpc.io.render import render

    width, height = size
    image, _ = render(surface, width, height)
    fig = plt.figure(figsize=(width / 100, height / 100 + 0.3), dpi=100)
    ax = fig.add_axes((0.0, 0.0, 1.0, height / (height + 30)))
    ax.imshow(image, interpolation="none")
    ax.set_axis_off()
    if title:
        fig.suptitle(title, fontsize=10, y=0.99)
    fig.savefig(path)
    plt.close(fig)
    return Path(path)
