"""Solids built like the SEM paper's Table 1 models from NURBS parts that overlap as a modeller
leaves them (numpy only): a rocket (a body of revolution and four fins through it), a mug (a cup
of revolution and a torus handle through its wall), a castle (blocks and round towers) and the
paper's tyre of two materials (a torus tread on a hub of revolution)."""

from __future__ import annotations

import numpy as np

from bhem_hpc.geometry import nurbs


def _solid_of_revolution(profile: list[tuple[float, float]], name: str, offset=(0.0, 0.0, 0.0)) -> nurbs.NurbsSurface:
    """The closed surface of revolution about the z axis of a polyline ``(radius, z)`` running from
    the axis back to the axis, moved by ``offset``."""
    points = np.asarray(profile, dtype=float)
    knots = np.r_[0.0, np.linspace(0.0, 1.0, len(points)), 1.0]
    surface = nurbs.revolve(points, np.ones(len(points)), knots, 1, name)
    return surface.with_control(surface.control + np.asarray(offset, dtype=float))


def _turned_about_z(part: nurbs.NurbsSurface, angle: float) -> nurbs.NurbsSurface:
    c, s = np.cos(angle), np.sin(angle)
    return part.with_control(part.control @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]))


def rocket() -> list[nurbs.NurbsSurface]:
    """A 0.85 m rocket: a body of revolution (radius 0.1 m, flared at the tail, an ogive nose) and
    four fins reaching into it, each a box of 6 bilinear faces with two spans along one side: 25
    parts, 216 control points (the paper's 648 DoFs)."""
    body = _solid_of_revolution(
        [(0.0, 0.0), (0.09, 0.0), (0.1, 0.05), (0.1, 0.3), (0.1, 0.6), (0.085, 0.72), (0.05, 0.8), (0.0, 0.85)], "body"
    )
    fin = nurbs.box_faces([0.05, -0.008, 0.0], [0.22, 0.008, 0.18], degree=1, spans=(1, 2))
    fins = [_turned_about_z(face, k * np.pi / 2).with_name(f"fin {k} {face.name}") for k in range(4) for face in fin]
    return [body, *fins]


def mug() -> list[nurbs.NurbsSurface]:
    """A mug: a cup of revolution (outer radius 45 mm, 100 mm tall, 5 mm walls) and a torus handle
    standing in the x-z plane whose tube runs through the cup's wall: 2 overlapping parts."""
    cup = _solid_of_revolution(
        [(0.0, 0.01), (0.04, 0.01), (0.04, 0.055), (0.04, 0.1), (0.045, 0.1), (0.045, 0.05), (0.045, 0.0), (0.0, 0.0)],
        "cup",
    )
    handle = nurbs.torus(0.022, 0.006)
    standing = handle.control[..., [0, 2, 1]] * np.array([1.0, -1.0, 1.0])  # the ring in the x-z plane
    handle = handle.with_control(standing + np.array([0.069, 0.0, 0.05])).with_name("handle")
    return [cup, handle]


def castle() -> list[nurbs.NurbsSurface]:
    """A castle: a base block, a keep and four round towers at the base's corners, overlapping:
    16 parts."""
    base = [f.with_name(f"base {f.name}") for f in nurbs.box_faces([0.0, 0.0, 0.0], [1.0, 1.0, 0.3])]
    keep = [f.with_name(f"keep {f.name}") for f in nurbs.box_faces([0.3, 0.3, 0.2], [0.7, 0.7, 0.7], degree=2)]
    towers = [
        _solid_of_revolution([(0.0, 0.0), (0.12, 0.0), (0.12, 0.3), (0.12, 0.6), (0.0, 0.6)], f"tower {k}", (x, y, 0.0))
        for k, (x, y) in enumerate([(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)])
    ]
    return base + keep + towers


def refined(parts: list[nurbs.NurbsSurface], extra: list[tuple[int, int]]) -> list[nurbs.NurbsSurface]:
    """``parts`` with ``extra[k] = (rows, columns)`` more control points each, the shapes unchanged
    (knots inserted by :func:`~bhem_hpc.geometry.nurbs.refine`)."""
    return [nurbs.refine(part, more) for part, more in zip(parts, extra, strict=True)]


def _bezier_pieces(surface: nurbs.NurbsSurface, name: str) -> list[nurbs.NurbsSurface]:
    """The rational Bezier patches of ``surface`` as parts of their own (one per knot-span pair)."""
    (p, q), nets = surface.degrees, surface.bezier_patches.nets
    knots_u, knots_v = np.r_[np.zeros(p + 1), np.ones(p + 1)], np.r_[np.zeros(q + 1), np.ones(q + 1)]
    return [nurbs.NurbsSurface((p, q), knots_u, knots_v, net[..., :3] / net[..., 3:], net[..., 3], f"{name} {k}")
            for k, net in enumerate(nets)]  # fmt: skip


def tyre() -> list[nurbs.NurbsSurface]:
    """A tyre lying in the x-y plane: a torus tread (major radius 0.3 m, minor 0.1 m) cut into its
    16 rational Bezier patches, on a hub of revolution (radius 0.22 m, 0.12 m wide) that reaches
    2 cm into it: 17 parts, ``tread 0`` to ``tread 15`` and ``hub``."""
    tread = _bezier_pieces(nurbs.torus(0.3, 0.1), "tread")
    hub = _solid_of_revolution([(0.0, -0.06), (0.22, -0.06), (0.22, 0.0), (0.22, 0.06), (0.0, 0.06)], "hub")
    return [*tread, hub]
