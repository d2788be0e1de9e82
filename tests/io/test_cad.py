"""NURBS models in IGES and Rhino .3dm files: exact round trips, Rhino's own evaluation, models
made by OpenNURBS, and refused files."""

from __future__ import annotations

import numpy as np
import pytest
import rhino3dm

from bhem_hpc.geometry import nurbs
from bhem_hpc.geometry.surface import SurfaceError
from bhem_hpc.io.cad import read_parts, write_parts
from bhem_hpc.solids.quadrature import ray_cast_quadrature

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank


def model(rng) -> list[nurbs.NurbsSurface]:
    knots_u = np.array([0, 0, 0, 0, 0.2, 0.5, 0.5, 0.9, 1.3, 1.3, 1.3, 1.3])
    knots_v = np.array([-1, -1, -1, 0.1, 0.6, 2, 2, 2])
    free_form = nurbs.NurbsSurface(
        (3, 2), knots_u, knots_v, rng.normal(size=(8, 5, 3)), 0.3 + rng.random((8, 5)), "free form"
    )
    return [
        nurbs.sphere(1.0, center=(0.5, 0.0, 0.0)),
        nurbs.torus(2.0, 0.3),
        free_form,
        *nurbs.box_faces([0, 0, 0], [1, 2, 3])[:2],
    ]


def assert_same_surfaces(parts, back, rng):
    assert len(back) == len(parts)
    for a, b in zip(parts, back, strict=True):
        assert b.degrees == a.degrees
        (u0, u1), (v0, v1) = a.u.domain, a.v.domain
        u, v = u0 + (u1 - u0) * rng.random(100), v0 + (v1 - v0) * rng.random(100)
        for x, y in zip(a.evaluate(u, v), b.evaluate(u, v), strict=True):
            np.testing.assert_allclose(y, x, atol=1e-13)


@pytest.mark.parametrize("suffix", [".igs", ".3dm"])
def test_models_round_trip_exactly(suffix, tmp_path, rng):
    parts = model(rng)
    path = tmp_path / f"model{suffix}"
    write_parts(path, parts)
    assert_same_surfaces(parts, read_parts(path), rng)


def test_rhino_evaluates_written_parts_as_we_do(tmp_path, rng):
    parts = model(rng)
    write_parts(tmp_path / "model.3dm", parts)
    objects = rhino3dm.File3dm.Read(str(tmp_path / "model.3dm")).Objects
    assert [item.Attributes.Name for item in objects] == [part.name for part in parts]
    for item, part in zip(objects, parts, strict=True):
        (u0, u1), (v0, v1) = part.u.domain, part.v.domain
        for u, v in zip(u0 + (u1 - u0) * rng.random(10), v0 + (v1 - v0) * rng.random(10), strict=True):
            point = item.Geometry.PointAt(u, v)
            expected = part.evaluate(np.array([u]), np.array([v]))[0][0]
            np.testing.assert_allclose([point.X, point.Y, point.Z], expected, atol=1e-12)


def test_models_made_by_opennurbs_read_as_solids(tmp_path):
    """A Rhino sphere and a Rhino box (six faces, some reversed) enclose their exact volumes."""
    model3dm = rhino3dm.File3dm()
    model3dm.Objects.AddBrep(rhino3dm.Brep.CreateFromSphere(rhino3dm.Sphere(rhino3dm.Point3d(0, 0, 0), 2.0)))
    model3dm.Write(str(tmp_path / "sphere.3dm"), 7)
    (sphere,) = read_parts(tmp_path / "sphere.3dm")
    rule = ray_cast_quadrature([sphere], 64)
    assert rule.volume == pytest.approx(4.0 / 3.0 * np.pi * 8.0, rel=1e-3)
    box = rhino3dm.Brep.CreateFromBox(
        rhino3dm.Box(rhino3dm.BoundingBox(rhino3dm.Point3d(0, 0, 0), rhino3dm.Point3d(1, 2, 3)))
    )
    model3dm = rhino3dm.File3dm()
    model3dm.Objects.AddBrep(box)
    model3dm.Write(str(tmp_path / "box.3dm"), 7)
    faces = read_parts(tmp_path / "box.3dm")
    assert len(faces) == 6
    assert ray_cast_quadrature(faces, 16).volume == pytest.approx(6.0, rel=1e-12)


def test_trimmed_and_bad_files_are_refused(tmp_path, rng):
    with pytest.raises(SurfaceError, match="no such file"):
        read_parts(tmp_path / "missing.igs")
    (tmp_path / "model.step").write_text("ISO-10303-21;")
    with pytest.raises(SurfaceError, match=r"model.step: a NURBS model must be an IGES"):
        read_parts(tmp_path / "model.step")
    (tmp_path / "text.igs").write_text("hello\n")
    with pytest.raises(SurfaceError, match=r"text.igs: line 1 is not an IGES record"):
        read_parts(tmp_path / "text.igs")
    (tmp_path / "noise.3dm").write_bytes(rng.bytes(256))
    with pytest.raises(SurfaceError, match=r"noise.3dm: not a readable Rhino .3dm file"):
        read_parts(tmp_path / "noise.3dm")
    # a trimmed surface (entity 144) in an IGES file: made by retyping the first entry of a written file
    write_parts(tmp_path / "model.igs", model(rng)[:1])
    lines = (tmp_path / "model.igs").read_text().splitlines()
    for k, line in enumerate(lines):
        if line[72] == "D":
            lines[k] = f"{144:>8}" + line[8:]
    (tmp_path / "trimmed.igs").write_text("\n".join(lines) + "\n")
    with pytest.raises(SurfaceError, match=r"trimmed.igs: D1 is a trimmed surface \(entity 144\)"):
        read_parts(tmp_path / "trimmed.igs")
    trimmed = rhino3dm.Brep.CreateTrimmedPlane(rhino3dm.Plane.WorldXY(), rhino3dm.Circle(2.0).ToNurbsCurve())
    model3dm = rhino3dm.File3dm()
    model3dm.Objects.AddBrep(trimmed)
    model3dm.Write(str(tmp_path / "disc.3dm"), 7)
    with pytest.raises(SurfaceError, match=r"disc.3dm object 0 face 0 is trimmed"):
        read_parts(tmp_path / "disc.3dm")
    model3dm = rhino3dm.File3dm()
    model3dm.Objects.AddPoint(rhino3dm.Point3d(0, 0, 0))
    model3dm.Write(str(tmp_path / "point.3dm"), 7)
    with pytest.raises(SurfaceError, match=r"point.3dm: the file holds no NURBS surface"):
        read_parts(tmp_path / "point.3dm")


def square_with_disk_and_hole():
    """A flat bicubic part over [0, 2] x [0, 1] (nurbs.box_faces' first face's parameters) with an
    outer loop (a disk) and a hole (a small square) in its parameters."""
    part = nurbs.box_faces([0, 0, 0], [2, 1, 1], degree=3, spans=(2, 2))[0]
    (a, b), (c, d) = part.u.domain, part.v.domain
    centre, radius = np.array([(a + b) / 2, (c + d) / 2]), 0.45 * min(b - a, d - c)
    angles = np.linspace(0.0, 2 * np.pi, 65)
    outer = centre + radius * np.column_stack([np.cos(angles), np.sin(angles)])
    h = 0.1 * radius
    hole = centre + np.array([(-h, -h), (-h, h), (h, h), (h, -h), (-h, -h)])
    return part, (outer, hole)


def test_trimmed_parts_round_trip_through_iges(tmp_path, rng):
    """Written as a trimmed surface (144) with its loops as curves on the surface (142, 126 in the
    parameters) and read back: the same surface, loops that bound the same region (the same area
    and inside test), and a whole part beside it stays whole. SEM's reader refuses the file."""
    from bhem_hpc.geometry.trim import check_loops, inside, legendre_moments
    from bhem_hpc.io.cad import ShellPart, read_shell_parts

    part, loops = square_with_disk_and_hole()
    whole = nurbs.sphere(1.0)
    path = tmp_path / "trimmed.igs"
    write_parts(path, [ShellPart(part, loops), whole])
    back = read_shell_parts(path)
    assert [p.loops is None for p in back] == [False, True]
    assert_same_surfaces([part, whole], [p.surface for p in back], rng)
    domain = (part.u.domain, part.v.domain)
    written, read = check_loops(loops, domain, 1e-9), check_loops(back[0].loops, domain, 1e-9)
    assert legendre_moments(read, 0)[0, 0] == pytest.approx(legendre_moments(written, 0)[0, 0], rel=1e-12)
    points = np.column_stack([2 * rng.random(500), rng.random(500)])
    assert np.array_equal(inside(read, points), inside(written, points))
    with pytest.raises(SurfaceError, match=r"trimmed.igs: D\d+ is a trimmed surface \(entity 144\)"):
        read_parts(path)


def test_trim_curves_without_parameter_curves_are_refused(tmp_path):
    from bhem_hpc.io.cad import ShellPart, read_shell_parts

    part, loops = square_with_disk_and_hole()
    path = tmp_path / "model-space.igs"
    write_parts(path, [ShellPart(part, loops[:1])])
    # the curve on the surface (142) loses its parameter-space curve: BPTR = 0
    text = path.read_text().replace("142,1,1,3,0,1;", "142,1,1,0,0,1;")
    assert "142,1,1,0,0,1;" in text
    path.write_text(text)
    with pytest.raises(SurfaceError, match=r"model-space.igs: trimmed surface D7: the curve on the surface D5 has "
                                           r"no curve in the surface's parameters"):  # fmt: skip
        read_shell_parts(path)
    with pytest.raises(SurfaceError, match="written as IGES"):
        write_parts(tmp_path / "trimmed.3dm", [ShellPart(part, loops)])


def test_trimmed_rhino_faces_become_trimmed_parts(tmp_path):
    """A plane trimmed by a circle of radius 2 (OpenNURBS, rhino3dm): the shell reader gives the
    plane's surface and one loop in its parameters whose points lie on the circle and whose area is
    an inscribed 64-gon's (rhino3dm gives trims' 3D edges only: they are put on the surface by
    closest points); SEM's reader still refuses the face (the test above)."""
    from bhem_hpc.geometry.trim import check_loops, legendre_moments
    from bhem_hpc.io.cad import RHINO_TRIM_SAMPLES, read_shell_parts

    model3dm = rhino3dm.File3dm()
    model3dm.Objects.AddBrep(rhino3dm.Brep.CreateTrimmedPlane(rhino3dm.Plane.WorldXY(),
                                                              rhino3dm.Circle(2.0).ToNurbsCurve()))  # fmt: skip
    model3dm.Write(str(tmp_path / "disc.3dm"), 7)
    parts = read_shell_parts(tmp_path / "disc.3dm")
    assert len(parts) == 1 and len(parts[0].loops) == 1
    part = parts[0]
    loop = part.loops[0]
    on_surface = part.surface.evaluate(loop[:, 0], loop[:, 1])[0]
    np.testing.assert_allclose(np.linalg.norm(on_surface[:, :2], axis=1), 2.0, rtol=1e-9)
    checked = check_loops(part.loops, (part.surface.u.domain, part.surface.v.domain), 1e-9)
    polygon = 0.5 * RHINO_TRIM_SAMPLES * 4.0 * np.sin(2 * np.pi / RHINO_TRIM_SAMPLES)
    # the circle's rational parametrization spaces the samples a little unevenly: not quite regular
    assert legendre_moments(checked, 0)[0, 0] == pytest.approx(polygon, rel=1e-4)
