"""Shells read from CAD surface models (``type = "cad_shell"``): every NURBS part a patch, joined
where whole edges meet (smooth seams and folds, either orientation), the joints and the free edges
reported, the patches the parts themselves where the discretization holds them; bad models and
tables refused naming the file, the body, the part and the key."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import frame_times, wavy_cut_loops

from bhem_hpc.geometry import nurbs
from bhem_hpc.geometry.interfaces import find_joints
from bhem_hpc.io import read_frame
from bhem_hpc.io.cad import read_shell_parts, write_parts
from bhem_hpc.io.run_directory import foreign_entries
from bhem_hpc.run import RunOptions, run_scene
from bhem_hpc.scene import SceneError
from bhem_hpc.scene.loader import load_any_scene

HOOD_FREE_EDGES = ["hood_0 xi1_min", "hood_0 xi2_min", "hood_1 xi1_min", "hood_1 xi2_max", "hood_2 xi1_max",
                   "hood_2 xi2_min", "hood_3 xi1_max", "hood_3 xi2_max"]  # fmt: skip


def _hood_parts() -> list[nurbs.NurbsSurface]:
    return nurbs.graph_parts(lambda x, y: 0.06 * (1 - (x / 0.6) ** 2) * (1 - (y / 0.5) ** 2), (-0.6, 0.6), (-0.5, 0.5),
                             (2, 2))  # fmt: skip


def _scene(comm, folder: Path, model: str, parts, body: str = "", discretization: str = "bspline3",
           name: str = "hood", patches: str = "[4, 4]", clock: tuple[float, int] = (0.002, 5),
           plate: tuple[float, float, float] = (1.0e-3, -3.0e3, 50.0)) -> Path:  # fmt: skip
    """A cad_shell scene of ``parts`` (written to ``model``): a steel sheet of thickness ``plate[0]``
    pressed by ``plate[1]`` Pa, mass damping ``plate[2]`` 1/s, ``clock``: dt [s] and steps."""
    thickness, pressure, damping = plate
    dt, steps = clock
    if comm.rank == 0:
        folder.mkdir(exist_ok=True)
        write_parts(folder / model, parts)
        (folder / "scene.toml").write_text(f"""
[time]
dt = {dt}
steps = {steps}
[output]
every = {steps}
[[bodies]]
name = "{name}"
type = "cad_shell"
file = "{model}"
patches = {patches}
discretization = "{discretization}"
material = {{ young = 2.0e11, poisson = 0.3, thickness = {thickness}, density = 7850.0 }}
effects = {{ area_loads = [{{ force = [0.0, 0.0, {pressure}] }}], damping = {{ mass = {damping} }} }}
{body}
""")
    comm.Barrier()
    return folder / "scene.toml"


CLAMPED = "".join(f'[[bodies.constraints]]\npart = {k}\ntype = "clamp"\nedge = "{edge}"\n'
                  for k, edge in ((0, "xi1_min"), (1, "xi1_min"), (2, "xi1_max"), (3, "xi1_max")))  # fmt: skip


def test_a_models_file_is_read_once_while_it_is_unchanged(comm, shared_tmp_path, monkeypatch):
    """A cad_shell of four parts reads its file once (not once more per part), and again once the
    file changes."""
    import bhem_hpc.io.cad as cad

    reads = []
    read_parts = cad.read_shell_parts
    monkeypatch.setattr(cad, "read_shell_parts", lambda path: reads.append(path) or read_parts(path))
    path = _scene(comm, shared_tmp_path, "hood.igs", _hood_parts())
    load_any_scene(path)
    assert len(reads) == 1
    load_any_scene(path)
    assert len(reads) == 1
    comm.Barrier()
    if comm.rank == 0:  # the same parts written again: another modification time
        write_parts(shared_tmp_path / "hood.igs", _hood_parts()[::-1])
    comm.Barrier()
    load_any_scene(path)
    assert len(reads) == 2


@pytest.mark.parametrize("model", ["hood.3dm", "hood.igs"])
def test_a_hood_of_four_parts_is_one_shell_joined_where_its_parts_meet(comm, shared_tmp_path, model):
    """Four bicubic parts on uniform knots: the patches are the parts (to round-off); the four
    seams are joined, the eight outer edges reported free; clamped front and back and pressed, the
    hood stays joined along its seams (partners within 1e-5 of the sag)."""
    path = _scene(comm, shared_tmp_path, model, _hood_parts(), CLAMPED)
    scene = load_any_scene(path)
    assert scene.names == ("hood_0", "hood_1", "hood_2", "hood_3")
    report = scene.cad_models[0]
    assert report["parts"] == 4 and report["fit_error_m"] < 1e-12 and report["free_edges"] == HOOD_FREE_EDGES
    assert [joint[:4] for joint in report["joints"]] == [["hood_0", "xi2_max", "hood_1", "xi2_min"],
                                                         ["hood_0", "xi1_max", "hood_2", "xi1_min"],
                                                         ["hood_1", "xi1_max", "hood_3", "xi1_min"],
                                                         ["hood_2", "xi2_max", "hood_3", "xi2_min"]]  # fmt: skip
    summary = run_scene(RunOptions(path, shared_tmp_path / "out", progress=False), comm)
    assert summary["cad_models"] == [report] and len(summary["interfaces"]) == 4
    frames = {name: read_frame(shared_tmp_path / "out" / name / "surface.h5")[0] for name in scene.names}
    rest = read_frame(shared_tmp_path / "out" / "hood_0" / "surface.h5", 0)[0]
    sag = np.abs(frames["hood_0"].nodal[..., 0, :] - rest.nodal[..., 0, :]).max()
    assert sag > 1e-5
    along = np.linspace(0.0, 1.0, 7)
    for name_a, edge_a, name_b, _, _, _ in report["joints"]:
        a, b = frames[name_a], frames[name_b]
        on_a = (np.ones(7), along) if edge_a == "xi1_max" else (along, np.ones(7))
        on_b = (np.zeros(7), along) if edge_a == "xi1_max" else (along, np.zeros(7))
        assert np.abs(a.evaluate(*on_a).x - b.evaluate(*on_b).x).max() < 1e-5 * sag  # measured 3e-6: the penalty's
    # the deformed model, written back at every frame (the run's own files): the same four parts, each its patch
    assert foreign_entries(shared_tmp_path / "out") == []
    last = len(frame_times(shared_tmp_path / "out" / "hood_0")) - 1
    written = read_shell_parts(shared_tmp_path / "out" / "hood" / f"frame_{last:06d}.igs")
    assert len(written) == 4 and all(p.loops is None for p in written)
    u, v = (a.ravel() for a in np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 5), indexing="ij"))
    for part, name in zip(written, scene.names, strict=True):
        assert np.abs(part.surface.evaluate(u, v)[0] - frames[name].evaluate(u, v).x).max() < 1e-12


def test_a_hood_with_a_trimmed_corner_keeps_its_joints_and_drops_the_edges_its_trim_cuts(comm, shared_tmp_path):
    """The hood written to IGES with its fourth part trimmed (entity 144): a quarter disk of radius
    0.5 cut from its outer corner. The four seams stay joined; the two outer edges the trim cuts
    are reported as trimmed (not free), and the part as joined to nothing along its trim (the arc
    runs inside it); pressed for 5
    steps with the other three parts clamped, it runs without a dt halving and the trimmed part's
    output holds 1 - pi / 16 of the whole part's quads."""
    from bhem_hpc.io.cad import ShellPart

    arc = np.linspace(0.0, np.pi / 2, 33)
    corner = np.column_stack([1.0 - 0.5 * np.sin(arc), 1.0 - 0.5 * np.cos(arc)])  # from (1, 0.5) to (0.5, 1)
    loop = np.concatenate([[(0.0, 0.0), (1.0, 0.0)], corner, [(0.0, 1.0), (0.0, 0.0)]])
    parts = [*map(ShellPart, _hood_parts()[:3]), ShellPart(_hood_parts()[3], (loop,))]
    clamped = CLAMPED.split("[[bodies.constraints]]")[1:4]
    path = _scene(comm, shared_tmp_path, "hood.igs", parts, "".join("[[bodies.constraints]]" + c for c in clamped))
    scene = load_any_scene(path)
    report = scene.cad_models[0]
    assert len(report["joints"]) == 4
    assert report["trimmed_edges"] == ["hood_3 xi1_max", "hood_3 xi2_max"]
    assert report["free_edges"] == HOOD_FREE_EDGES[:6]
    assert report["trimmed_parts_joined_to_nothing_along_their_trims"] == ["hood_3"]
    summary = run_scene(RunOptions(path, shared_tmp_path / "out", progress=False), comm)
    assert sum(s["dt_halvings"] for s in summary["steps"]) == 0 and len(summary["steps"]) == 5
    if comm.rank == 0:
        import h5py

        counts = []
        for name in ("hood_0", "hood_3"):
            with h5py.File(shared_tmp_path / "out" / name / "surface.h5", "r") as f:
                counts.append(f["topology"].shape[0])
        assert counts[1] / counts[0] == pytest.approx(1 - np.pi / 16, rel=0.03)
        written = read_shell_parts(shared_tmp_path / "out" / "hood" / "frame_000001.igs")  # its trim written back
        assert [p.loops is not None for p in written] == [False, False, False, True]

        def area(polygon: np.ndarray) -> float:  # the shoelace formula
            return 0.5 * abs(float(np.dot(polygon[:-1, 0], polygon[1:, 1]) - np.dot(polygon[1:, 0], polygon[:-1, 1])))

        assert area(written[3].loops[0]) == pytest.approx(area(loop), rel=1e-9)  # the loop, densified (6e-12)


def test_an_open_box_is_joined_along_its_folds_in_either_orientation(comm, shared_tmp_path):
    """Five faces of a box (the lid left off): every fold between two faces is found, whichever way
    their edges run, and the rim's four edges are free; Hermite patches fit the flat faces exactly."""
    faces = nurbs.box_faces([0.0, 0.0, 0.0], [0.3, 0.2, 0.1], degree=2)[:5]
    joints, free = find_joints([nurbs.shell_surface(face, (2, 2), "hermite") for face in faces], 1e-9)
    assert len(joints) == 8 and len(free) == 4
    assert {face for face, _ in free} == {0, 1, 2, 3}  # the side faces' top edges: the rim
    path = _scene(comm, shared_tmp_path, "tray.igs", faces, discretization="hermite")
    report = load_any_scene(path).cad_models[0]
    assert len(report["joints"]) == 8 and len(report["free_edges"]) == 4 and report["fit_error_m"] < 1e-12


def test_the_hoods_conforming_seams_share_their_control_points(comm, shared_tmp_path):
    """The hood's bicubic parts meet with matching knots: by default ("auto") each seam's 7 control
    points are shared (21 DOFs a joint, 81 unknowns fewer: the cross point is one of four), the
    seams have no gap (the penalty's leaves 1e-4 of the crown's sag), and the crown's sag is the
    penalty-coupled hood's ("coupled") within 3e-4 of it (what the displacement penalty gives); a
    Hermite hood's seams conform too (its nodes' positions and slopes along each seam)."""
    sags, dofs = {}, {}
    for choice in ("auto", "coupled"):
        folder = shared_tmp_path / choice
        path = _scene(comm, folder, "hood.3dm", _hood_parts(), f'dofs = "{choice}"\n' + CLAMPED)
        summary = run_scene(RunOptions(path, folder / "out", progress=False), comm)
        assert [i["shared_dofs"] for i in summary["interfaces"]] == [21 if choice == "auto" else 0] * 4
        dofs[choice] = summary["dofs"]
        frames = [read_frame(folder / "out" / f"hood_{k}" / "surface.h5")[0] for k in range(4)]
        along = np.linspace(0.0, 1.0, 7)
        gap = max(np.abs(frames[a].evaluate(*first).x - frames[b].evaluate(*second).x).max()
                  for a, b, first, second in ((0, 1, (along, np.ones(7)), (along, np.zeros(7))),
                                              (0, 2, (np.ones(7), along), (np.zeros(7), along))))  # fmt: skip
        sags[choice] = frames[0].evaluate(np.array(1.0), np.array(1.0)).x[2] - 0.06
        assert gap < 1e-15 if choice == "auto" else gap > 1e-5 * abs(sags[choice])  # the penalty's compliance
    assert dofs["coupled"] - dofs["auto"] == 81
    assert abs(sags["auto"] / sags["coupled"] - 1) < 3e-4, sags  # measured 1.4e-4
    path = _scene(comm, shared_tmp_path / "hermite", "hood.3dm", _hood_parts(), 'dofs = "shared"\n',
                  discretization="hermite")  # fmt: skip
    hermite = load_any_scene(path).interfaces
    assert [3 * len(i.shared) for i in hermite] == [30] * 4  # 5 nodes' positions and slopes along each seam


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ('[[bodies.constraints]]\ntype = "clamp"\nedge = "xi1_min"\n',
         r"body 'hood' \(bodies\[0\]\): key 'constraints\[0\].part' must be the part \(0..3\) the constraint holds, "
         r"got None"),
        ('[[bodies.constraints]]\npart = 7\ntype = "clamp"\nedge = "xi1_min"\n',
         r"constraints\[0\].part' must be the part"),
        ('[[bodies.constraints]]\npart = 1\ntype = "clamp"\nedge = "xi5_min"\n',
         r"body 'hood' \(bodies\[0\]\): part 1 \(.*\): key 'constraints\[0\].edge'"),
        ("sem = {}\n", r"body 'hood' \(bodies\[0\]\): key 'sem' must be absent \(a cad_shell body lists file, patches"),
        ("tolerance = -1.0\n", r"key 'tolerance' must be a length > 0 \[m\], got -1.0"),
        ('dofs = "merged"\n', r"key 'dofs' must be \"auto\", \"shared\", \"coupled\", got 'merged'"),
        ('[[bodies]]\nname = "hood_2"\nsurface = { kind = "rectangle", size = [0.1, 0.1], patches = [2, 2] }\n'
         'material = { young = 1e6, poisson = 0.3, thickness = 1e-3, density = 100.0 }\n',
         r"body 'hood' \(bodies\[0\]\): its parts are bodies named hood_0, ... and another body has one of these"),
    ],
)  # fmt: skip
def test_bad_cad_shells_are_refused_naming_the_body_part_and_key(comm, shared_tmp_path, body, message):
    path = _scene(comm, shared_tmp_path, "hood.3dm", _hood_parts(), body)
    with pytest.raises(SceneError, match=message):
        load_any_scene(path)


def test_a_missing_model_file_is_refused_naming_the_key(comm, shared_tmp_path):
    path = _scene(comm, shared_tmp_path, "hood.3dm", _hood_parts())
    if comm.rank == 0:
        path.write_text(path.read_text().replace('file = "hood.3dm"', 'file = "nothing.3dm"'))
    comm.Barrier()
    with pytest.raises(SceneError, match=r"body 'hood' \(bodies\[0\]\): key 'file' must be an existing regular file"):
        load_any_scene(path)


def test_a_trim_that_cuts_a_seam_joins_what_is_left_of_it_along_the_trim(comm, shared_tmp_path):
    """The hood's fourth part with a quarter disk cut at its inner corner, which both its seams
    reach: the two edge joints go (the edges are trimmed), and the parts of the seams the trim keeps
    are joined along its loop instead (trim-curve joints to hood_1 and hood_2, each along the kept
    half of its seam: their arc lengths); no edge of the hood is free but its outer ones."""
    from bhem_hpc.io.cad import ShellPart

    arc = np.linspace(0.0, np.pi / 2, 33)
    corner = np.column_stack([0.5 * np.sin(arc), 0.5 * np.cos(arc)])  # from (0, 0.5) to (0.5, 0)
    loop = np.concatenate([corner, [(1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.0, 0.5)]])
    parts = [*map(ShellPart, _hood_parts()[:3]), ShellPart(_hood_parts()[3], (loop,))]
    scene = load_any_scene(_scene(comm, shared_tmp_path, "hood.igs", parts))
    report = scene.cad_models[0]
    assert [joint[:4] for joint in report["joints"]] == [["hood_0", "xi2_max", "hood_1", "xi2_min"],
                                                         ["hood_0", "xi1_max", "hood_2", "xi1_min"],
                                                         ["hood_3", "trim curve", "hood_1", "surface"],
                                                         ["hood_3", "trim curve", "hood_2", "surface"]]  # fmt: skip
    assert report["trimmed_edges"] == ["hood_3 xi1_min", "hood_3 xi2_min"]
    assert report["free_edges"] == HOOD_FREE_EDGES and not report["trimmed_parts_joined_to_nothing_along_their_trims"]
    curves = [r.quadrature for r in scene.interfaces if "trim" in str(r.edges)]
    # the seams' kept halves on the patches themselves: hood_3's edges xi1_min and xi2_min from 0.5 to 1
    t, w = np.polynomial.legendre.leggauss(40)
    t, w, zeros = 0.75 + 0.25 * t, 0.25 * w, np.zeros(40)
    hood_3 = scene.bodies[3].surface
    lengths = [float(np.sum(w * np.linalg.norm(getattr(hood_3.evaluate(*at), tangent), axis=1)))
               for at, tangent in (((zeros, t), "a2"), ((t, zeros), "a1"))]  # fmt: skip
    assert [q.weights.sum() for q in curves] == [pytest.approx(v, rel=1e-9) for v in lengths]
    assert max(q.gap for q in curves) < 1e-9


def _flat_part(x0: float, x1: float, width: float) -> nurbs.NurbsSurface:
    """A bilinear flat part over ``[x0, x1] x [0, width]`` (parameters [0, 1]^2)."""
    knots = np.array([0.0, 0.0, 1.0, 1.0])
    control = np.array([[[x0, 0, 0], [x0, width, 0]], [[x1, 0, 0], [x1, width, 0]]], dtype=float)
    return nurbs.NurbsSurface((1, 1), knots, knots, control, np.ones((2, 2)), name="flat")


def test_two_parts_trimmed_along_a_wavy_cut_bend_as_one_plate(comm, shared_tmp_path):
    """A steel plate 1.6 m x 0.5 m as two overlapping flat parts ([0, 1.2] and [0.4, 1.6] along x),
    each trimmed by the same wavy cut x = 0.8 + 0.06 sin(2 pi y / 0.5) (entity 144 in IGES), is one
    shell joined along the cut (a trim-curve joint): clamped at x = 0 and pressed, its free end
    deflects as the single untrimmed plate's within 1e-3 (measured 1.3e-6 after 30 steps)."""
    from bhem_hpc.io.cad import ShellPart

    loops = wavy_cut_loops()
    tips = []
    for model, parts, patches in (("two.igs", [ShellPart(_flat_part(0.0, 1.2, 0.5), loops[:1]),
                                               ShellPart(_flat_part(0.4, 1.6, 0.5), loops[1:])], "[6, 3]"),
                                  ("one.igs", [_flat_part(0.0, 1.6, 0.5)], "[8, 3]")):  # fmt: skip
        folder = shared_tmp_path / model.removesuffix(".igs")
        clamp = '[[bodies.constraints]]\npart = 0\ntype = "clamp"\nedge = "xi1_min"\n'
        _scene(comm, folder, model, parts, clamp, name="plate", patches=patches, clock=(0.01, 6),
               plate=(5.0e-3, -2.0e2, 100.0))  # fmt: skip
        summary = run_scene(RunOptions(folder / "scene.toml", folder / "out", progress=False), comm)
        free_end = read_frame(folder / "out" / f"plate_{len(parts) - 1}" / "surface.h5")[0]
        tips.append(free_end.evaluate(np.ones(3), np.array([0.0, 0.5, 1.0])).x[:, 2])
        if model == "two.igs":
            joints = summary["cad_models"][0]["joints"]
            assert [j[:4] for j in joints] == [["plate_0", "trim curve", "plate_1", "trim curve"]]
            assert joints[0][4] < 1e-12
    assert tips[1].min() < -1e-3  # it bends
    np.testing.assert_allclose(tips[0], tips[1], rtol=1e-3)
