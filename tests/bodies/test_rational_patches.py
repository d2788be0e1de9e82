"""Shells of several exact rational patches (the CAD parts' own NURBS): the Scordelis-Lo roof and
the pinched hemisphere in 2, 3 and 4 rational patches sharing their edges' control points give
the one patch's values; a scene of a tube revolved in CAD (only C0 at its quarter points) is cut
into pieces that share their seams, runs, and writes frames that read back exactly."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import REPO, wavy_cut_loops

from bhem_hpc.geometry.nurbs import NurbsSurface, box_faces, graph_parts, revolve
from bhem_hpc.geometry.rational_bspline import RationalBSplineSurface
from bhem_hpc.io import read_frame
from bhem_hpc.io.cad import ShellPart, read_parts, write_parts
from bhem_hpc.run import RunOptions, run_scene
from bhem_hpc.scene import SceneError
from bhem_hpc.scene.loader import load_any_scene
from bhem_hpc.studies.interfaces_page import roof
from bhem_hpc.studies.rational_cases import hemisphere
from bhem_hpc.studies.references import ROOF_DEFLECTION


@pytest.mark.parametrize("splits", [(2, 2), (1, 3), (3, 1)])
def test_the_roof_in_rational_patches_gives_the_one_patch_value(comm, splits):
    """The exact cylinder in cubic rational patches of 12 x 12 spans in all: 2 x 2, 1 x 3 and 3 x 1
    patches sharing their edges' control points give the one patch's midside deflection within 3e-4
    (measured 1.0e-4 at most), and the reference within 1e-3 (measured 3.8e-4)."""
    one, _, _ = roof("nurbs3", None, 1e3, comm=comm)
    joined, gap, solve = roof("nurbs3", "shared", 1e3, splits, comm=comm)
    assert not solve.failure and gap < 1e-12
    assert abs(joined / one - 1) < 3e-4, (joined, one)
    assert abs(-one / ROOF_DEFLECTION - 1) < 1e-3, one


@pytest.mark.parametrize("splits", [(1, 2), (3, 1), (2, 2)])
def test_the_pinched_hemisphere_in_rational_patches_gives_the_one_patch_value(comm, splits):
    """The exact sphere zone in 16 x 16 cubic spans (3 x 1: 15 x 16): 2, 3 and 4 rational patches give
    one patch's displacement within 1e-3 (measured 2e-4 at most), which lies in [0.092, 0.095]
    (measured 0.09343; the Hermite patches' 0.0934 to 0.0935, the literature's 0.0924)."""
    (one, _), (joined, solve) = hemisphere((1, 1), comm=comm), hemisphere(splits, comm=comm)
    assert not solve.failure
    assert abs(joined / one - 1) < 1e-3, (joined, one)
    assert 0.092 < one < 0.095, one


def _cad_scene(comm, folder, name: str, parts: list, patches: str, head: str, body: str):
    """``folder/scene.toml``: ``head`` (time, output, colliders), then a cad_shell body ``name`` of
    exact patches read from ``parts`` (written to ``<name>.igs``) on ``patches``, with ``body``'s
    keys and tables."""
    if comm.rank == 0:
        folder.mkdir(exist_ok=True)
        write_parts(folder / f"{name}.igs", parts)
        table = f'name = "{name}"\ntype = "cad_shell"\nfile = "{name}.igs"\npatches = {patches}\n'
        (folder / "scene.toml").write_text(f'{head}\n[[bodies]]\n{table}discretization = "nurbs"\n{body}')
    comm.Barrier()
    return folder / "scene.toml"


def _tube_scene(comm, folder, body: str = "", effects: str = ""):
    """A steel tube (r 0.1 m, 1 m, 1 mm) revolved in CAD (a rational circle, C0 at its quarter
    points), clamped at z = 0 and loaded sideways by 1 kPa, as a cad_shell of exact patches."""
    tube = revolve(np.array([[0.1, 0.0], [0.1, 1.0]]), np.ones(2), np.array([0.0, 0.0, 1.0, 1.0]), 1, "tube")
    return _cad_scene(comm, folder, "tube", [tube], "[8, 4]", "[time]\ndt = 0.001\nsteps = 4\n[output]\nevery = 2",
                      f"""material = {{ young = 2.0e11, poisson = 0.3, thickness = 1.0e-3, density = 7850.0 }}
effects = {{ area_loads = [{{ force = [0.0, 1.0e3, 0.0] }}]{effects} }}
[[bodies.constraints]]
part = 0
type = "clamp"
edge = "xi2_min"
{body}""")  # fmt: skip


def test_a_revolved_tube_is_cut_at_its_kinks_into_exact_pieces_that_share_their_seams(comm, shared_tmp_path):
    path = _tube_scene(comm, shared_tmp_path)
    scene = load_any_scene(path)
    assert scene.names == ("tube_0_0_0", "tube_0_1_0", "tube_0_2_0", "tube_0_3_0")
    report = scene.cad_models[0]
    assert report["parts"] == 1 and report["patches"] == 4 and report["fit_error_m"] < 1e-14
    assert len(report["joints"]) == 4 and all(j[-1] == "whole" for j in report["joints"])
    assert report["free_edges"] == [f"tube_0_{k}_0 {edge}" for k in range(4) for edge in ("xi2_min", "xi2_max")]
    assert all(isinstance(body.surface, RationalBSplineSurface) for body in scene.bodies)
    # every seam shares its 6 control points (quadratic, 4 spans along the tube)
    assert [record.shared is not None and len(record.shared) for record in scene.interfaces] == [6] * 4
    out = shared_tmp_path / "out"
    summary = run_scene(RunOptions(path, out, progress=False), comm)
    assert summary["status"] == "completed" and summary["dofs"] == 4 * 3 * (4 * 6) - 4 * 3 * 6
    surface, time = read_frame(out / "tube_0_1_0" / "surface.h5")
    assert isinstance(surface, RationalBSplineSurface) and time == pytest.approx(0.004)
    # the sideways load moves the free end towards +y; the clamped end stays where it was
    rest, u = scene.bodies[1].surface, np.linspace(0.25, 0.5, 5)
    free, clamped = (surface.evaluate(u, np.full(5, v)).x - rest.evaluate(u, np.full(5, v)).x for v in (1.0, 0.0))
    assert np.all(free[:, 1] > 1e-7) and np.abs(clamped).max() < 1e-12
    # the deformed model written back: the four pieces joined into the one rational part of the file
    # (C0 at its quarter points again), each piece exactly
    (written,) = read_parts(out / "tube" / "frame_000002.igs")
    assert np.any(written.weights != 1.0) and np.count_nonzero(written.u.knots == 0.5) == 2
    v = np.linspace(0.0, 1.0, 5)
    for k in range(4):
        piece, _ = read_frame(out / f"tube_0_{k}_0" / "surface.h5")
        at = np.linspace(*piece.grid.xi1_range, 5)
        np.testing.assert_allclose(written.evaluate(at, v)[0], piece.evaluate(at, v).x, atol=1e-12)


@pytest.mark.parametrize(
    ("body", "effects", "message"),
    [
        ("", ", contact = { }, self_collision = true",
         r"key 'effects.contact.method' = 'impulse'.*rational.*use method = 'ipc'"),
        ("", ", pressure = 1.0e3", r"body 'tube_0_0_0': key 'effects.pressure' = 1000.0: a follower pressure has no "
         r"potential, and a scene of 4 bodies \(or patches\) is solved on its total potential"),
        ('[[bodies.constraints]]\npart = 0\ntype = "pin"\nnodes = [[0, 0]]\n', "",
         r"key 'constraints\[1\].nodes' must be 'edge' or 'corners': part 0 is cut at its C0 knots into 4 x 1 pieces"),
    ],
)  # fmt: skip
def test_what_rational_pieces_cannot_do_is_refused_naming_the_key(comm, shared_tmp_path, body, effects, message):
    path = _tube_scene(comm, shared_tmp_path, body, effects)
    with pytest.raises(SceneError, match=message):
        load_any_scene(path)


def test_the_pipe_elbow_job_is_its_cad_model_exactly():
    """jobs/pipe-elbow.toml: the revolved bend's one part in four exact pieces sharing their seams."""
    scene = load_any_scene(REPO / "jobs" / "pipe-elbow.toml")
    report = scene.cad_models[0]
    assert report["parts"] == 1 and report["patches"] == 4 and report["fit_error_m"] < 1e-15
    assert [len(record.shared) for record in scene.interfaces] == [10] * 4  # 8 spans along the bend, degree 2
    assert all(isinstance(body.surface, RationalBSplineSurface) and body.surface.grid.n1 == 4 for body in scene.bodies)


def test_a_rational_ring_dropped_by_ipc_rests_on_the_floor_without_crossing_it(comm, shared_tmp_path):
    """A rubber ring (a CAD tube on its side, 2 cm above the floor) falls onto a plane collider by
    incremental potential contact on its rational pieces: no output frame crosses the floor, and the
    ring comes to lie on it."""
    tube = revolve(np.array([[0.05, -0.05], [0.05, 0.05]]), np.ones(2), np.array([0.0, 0.0, 1.0, 1.0]), 1, "ring")
    lying = tube.control[..., [2, 1, 0]] + [0.0, 0.0, 0.07]  # the axis along x, the lowest line at z = 0.02
    floor = '[[colliders]]\ntype = "plane"\npoint = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 1.0]\nfriction = 0.3'
    path = _cad_scene(comm, shared_tmp_path, "ring", [tube.with_control(lying)], "[8, 2]",
                      f"[time]\ndt = 0.005\nsteps = 30\n[output]\nevery = 5\n{floor}",
                      "material = { young = 1.0e6, poisson = 0.45, thickness = 2.0e-3, density = 1100.0 }\n"
                      'effects = { gravity = [0.0, 0.0, -9.81], contact = { method = "ipc", collision_cells = 8 } }\n')
    summary = run_scene(RunOptions(path, shared_tmp_path / "out", progress=False), comm)
    assert summary["status"] == "completed"
    lowest = []
    for frame in range(7):
        surfaces = [read_frame(shared_tmp_path / "out" / f"ring_0_{k}_0" / "surface.h5", frame)[0] for k in range(4)]
        lowest.append(min(float(s.tessellate(6)[0][:, 2].min()) for s in surfaces))
    assert lowest[0] == pytest.approx(0.02, abs=1e-12)
    assert min(lowest) >= 0.0 and lowest[-1] < 1e-3, lowest


def test_a_part_on_its_own_knots_with_a_kink_is_two_exact_pieces_sharing_the_kink(comm, shared_tmp_path):
    """A quadratic part folded along u = 0.5 (a double knot: only C0 there) whose v knots (0.13,
    0.41, 1/pi + 0.5) lie on no uniform lattice: two pieces on the part's own v knots, within
    round-off of the part, sharing the fold's control points."""
    knots_u = [0, 0, 0, 0.25, 0.5, 0.5, 0.75, 1, 1, 1]
    knots_v = [0, 0, 0, 0.13, 0.41, 1 / np.pi + 0.5, 1, 1, 1]
    i, j = np.meshgrid(np.linspace(0, 1, 7), np.linspace(0, 1, 6), indexing="ij")
    control = np.stack([i, j, 0.3 * np.abs(i - 0.5) + 0.02 * np.sin(7 * j)], -1)  # a roof fold at u = 0.5
    part = NurbsSurface((2, 2), knots_u, knots_v, control, 1.0 + 0.2 * np.cos(3 * i + j), "folded loft")
    path = _cad_scene(comm, shared_tmp_path, "fold", [part], "[4, 6]", "[time]\ndt = 0.001\nsteps = 1",
                      "material = { young = 2.0e11, poisson = 0.3, thickness = 1.0e-3, density = 7850.0 }\n")
    scene = load_any_scene(path)
    assert scene.names == ("fold_0_0_0", "fold_0_1_0") and scene.cad_models[0]["fit_error_m"] < 1e-13
    for body in scene.bodies:
        assert body.surface.knots[0] is None and body.surface.knots[1] is not None  # u: lattice; v: its own
        assert (body.surface.grid.n1, body.surface.grid.n2) == (2, 8)  # 4 spans asked per part: 2 a piece
    (record,) = scene.interfaces
    assert record.shared is not None and len(record.shared) == 8 + 2  # the fold's control points


def test_a_tray_of_bilinear_faces_becomes_quadratic_patches_sharing_its_folds(comm, shared_tmp_path):
    """Five planar faces of a box as a modeller writes them (degree 1 x 1, one span): raised exactly
    to quadratic patches; all eight folds conform and share their control points."""
    faces = box_faces([0.0, 0.0, 0.0], [0.3, 0.2, 0.1], degree=1)[:5]
    path = _cad_scene(comm, shared_tmp_path, "tray", faces, "[2, 2]", "[time]\ndt = 0.001\nsteps = 1",
                      "material = { young = 2.0e11, poisson = 0.3, thickness = 1.0e-3, density = 7850.0 }\n")
    scene = load_any_scene(path)
    report = scene.cad_models[0]
    assert len(report["joints"]) == 8 and len(report["free_edges"]) == 4 and report["fit_error_m"] < 1e-15
    assert all(body.surface.degree == 2 and body.surface.knots is None for body in scene.bodies)
    assert [len(record.shared) for record in scene.interfaces] == [4] * 8  # 2 spans a side, quadratic


def test_polynomial_parts_as_exact_patches_step_as_the_b_spline_shell(comm, shared_tmp_path):
    """Four bicubic parts (unit weights) as "nurbs" and as "bspline3": the rational rewrite of every
    form (inertia, mass damping, the area load, the shared seams' angle term) leaves the same
    steps, within round-off (measured 1.7e-13 m after 10 steps of jobs/hood.toml)."""
    parts = graph_parts(lambda x, y: 0.06 * (1 - (x / 0.6) ** 2) * (1 - (y / 0.5) ** 2), (-0.6, 0.6), (-0.5, 0.5),
                        (2, 2))  # fmt: skip
    body = ("material = { young = 2.0e11, poisson = 0.3, thickness = 1.0e-3, density = 7850.0 }\n"
            "effects = { area_loads = [{ force = [0.0, 0.0, -3.0e3] }], damping = { mass = 50.0 } }\n"
            + "".join(f'[[bodies.constraints]]\npart = {k}\ntype = "clamp"\nedge = "{edge}"\n'
                      for k, edge in ((0, "xi1_min"), (1, "xi1_min"), (2, "xi1_max"), (3, "xi1_max"))))  # fmt: skip
    finals = []
    for discretization in ("nurbs", "bspline3"):
        folder = shared_tmp_path / discretization
        path = _cad_scene(comm, folder, "hood", parts, "[2, 2]", "[time]\ndt = 0.002\nsteps = 3\n[output]\nevery = 3",
                          body)  # fmt: skip
        if comm.rank == 0:
            text = path.read_text().replace('discretization = "nurbs"', f'discretization = "{discretization}"')
            path.write_text(text)
        comm.Barrier()
        run_scene(RunOptions(path, folder / "out", progress=False), comm)
        finals.append([read_frame(folder / "out" / f"hood_{k}" / "surface.h5")[0] for k in range(4)])
    rest = read_frame(shared_tmp_path / "nurbs" / "out" / "hood_0" / "surface.h5", 0)[0]
    assert np.abs(finals[1][0].control - rest.control).max() > 1e-4  # it moved
    for exact, polynomial in zip(*finals, strict=True):
        assert isinstance(exact, RationalBSplineSurface) and not isinstance(polynomial, RationalBSplineSurface)
        np.testing.assert_allclose(exact.control, polynomial.control, atol=1e-12)


def _flat_cubic(x0: float, x1: float, width: float, knot: float) -> NurbsSurface:
    """A flat part over ``[x0, x1] x [0, width]`` of degree 3 with an interior u knot at ``knot`` (x
    linear in u: the control points at the Greville abscissae)."""
    knots_u = np.array([0, 0, 0, 0, knot, 1, 1, 1, 1], dtype=float)
    greville = np.array([knots_u[i + 1 : i + 4].mean() for i in range(5)])
    x, y = np.meshgrid(x0 + (x1 - x0) * greville, np.linspace(0.0, width, 4), indexing="ij")
    return NurbsSurface((3, 3), knots_u, [0, 0, 0, 0, 1, 1, 1, 1], np.stack([x, y, 0 * x], -1), np.ones(x.shape),
                        "flat")  # fmt: skip


def test_parts_on_their_own_knots_trimmed_along_a_wavy_cut_are_joined_along_it(comm, shared_tmp_path):
    """Two overlapping flat cubic parts with a u knot at 1/pi (no uniform lattice: the patches keep
    it), each trimmed by the same wavy cut x = 0.8 + 0.06 sin(2 pi y / 0.5), as exact patches: their
    trim loops go to the patches' parameters and the trim-curve joint's partners to the second
    patch's, so its points pair up in space (within 1e-9 m) along the whole cut (its length within
    1e-3). (The polynomial patches' run of this plate bends as the one plate: test_cad_shell.)"""
    loops = wavy_cut_loops()
    parts = [ShellPart(_flat_cubic(0.0, 1.2, 0.5, 1 / np.pi), loops[:1]),
             ShellPart(_flat_cubic(0.4, 1.6, 0.5, 1 / np.pi), loops[1:])]  # fmt: skip
    path = _cad_scene(comm, shared_tmp_path, "plate", parts, "[6, 3]", "[time]\ndt = 0.01\nsteps = 1",
                      "material = { young = 2.0e11, poisson = 0.3, thickness = 5.0e-3, density = 7850.0 }\n")
    scene = load_any_scene(path)
    assert all(b.surface.knots is not None and b.surface.knots[0] is not None for b in scene.bodies)
    (record,) = scene.interfaces
    assert record.edges == ("trim curve", "trim curve") and record.quadrature.gap < 1e-12
    first, second = (body.surface for body in scene.bodies)
    q = record.quadrature
    apart = first.evaluate(q.first[:, 0], q.first[:, 1]).x - second.evaluate(q.second[:, 0], q.second[:, 1]).x
    assert np.abs(apart).max() < 1e-9
    y = np.linspace(0.0, 0.5, 20001)
    length = np.sum(np.hypot(np.diff(0.06 * np.sin(2 * np.pi * y / 0.5)), np.diff(y)))
    assert q.weights.sum() == pytest.approx(length, rel=1e-3)
