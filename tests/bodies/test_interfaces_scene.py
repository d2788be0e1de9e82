"""Scenes whose shell bodies are joined (``[[interfaces]]``): the shipped folded bracket keeps its
fold, two panels sewn along a seam hang as the one sheet they make, and interfaces that do not fit
their bodies are refused naming the file, the interface, the bodies and the edges."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import REPO, write_scene

from bhem_hpc.io import read_frame
from bhem_hpc.run import RunOptions, run_scene
from bhem_hpc.scene import SceneError
from bhem_hpc.scene.loader import load_any_scene

DEG = np.pi / 180


def test_the_folded_bracket_keeps_its_fold_while_its_wall_is_pushed_over(comm, shared_tmp_path):
    """jobs/folded-plate.toml for 30 steps: the wall's top moves by centimetres, the two patches stay
    together along the fold and at right angles to each other there."""
    summary = run_scene(RunOptions(REPO / "jobs" / "folded-plate.toml", shared_tmp_path / "fold", steps=30,
                                   progress=False), comm)  # fmt: skip
    assert summary["status"] == "completed"
    (interface,) = summary["interfaces"]
    assert interface.pop("length_m") == pytest.approx(0.1, rel=1e-12)  # the fold: the plate's width
    assert interface.pop("rest_gap_m") <= 1e-15  # the edges meet: round-off of the 0.1 m edges' points
    assert interface == {"type": "joint", "bodies": ["plate", "wall"], "edges": ["xi1_max", "xi1_min"],
                         "penalty": 1000.0, "points": 8, "sewing_time_s": None,
                         "keeps_angle": True, "shared_dofs": 18}  # fmt: skip
    plate, _ = read_frame(shared_tmp_path / "fold" / "plate" / "surface.h5")
    wall, time = read_frame(shared_tmp_path / "fold" / "wall" / "surface.h5")
    rest, _ = read_frame(shared_tmp_path / "fold" / "wall" / "surface.h5", 0)
    assert time == pytest.approx(0.03)
    top = (np.array(0.3), np.array(0.05))
    assert np.linalg.norm(wall.evaluate(*top).x - rest.evaluate(*top).x) > 0.05
    for y in (0.0, 0.05, 0.1):
        flat_side = plate.evaluate(np.array(0.5), np.array(y))
        upright_side = wall.evaluate(np.array(0.0), np.array(y))
        assert np.linalg.norm(flat_side.x - upright_side.x) < 1e-6
        assert abs(np.arccos(np.dot(flat_side.normal, upright_side.normal)) - 90 * DEG) < 0.05 * DEG


def _cubic_bracket(dofs: str) -> str:
    """jobs/folded-plate.toml in cubic B-splines, its joint's ``dofs`` as given."""
    text = (REPO / "jobs" / "folded-plate.toml").read_text()
    text = text.replace("patches = [8, 2] }", 'patches = [8, 2], discretization = "bspline3" }')
    text = text.replace("patches = [6, 2]\n", 'patches = [6, 2]\ndiscretization = "bspline3"\n')
    return text + f'dofs = "{dofs}"\n'


def test_a_bracket_whose_patches_share_the_folds_control_points_bends_as_the_penalty_joint_lets_it(
        comm, shared_tmp_path):  # fmt: skip
    """The folded bracket in cubic B-splines, 20 steps, its joint by shared control points (the fold's
    5, so 15 unknowns fewer) and by the displacement penalty: the wall's top within 1e-6 m of each
    other's, no gap along the shared fold (round-off), the angle there kept."""
    tops, frames = [], {}
    for dofs in ("shared", "coupled"):
        path = write_scene(comm, shared_tmp_path / f"{dofs}.toml", _cubic_bracket(dofs))
        summary = run_scene(RunOptions(path, shared_tmp_path / dofs, steps=20, progress=False), comm)
        assert summary["status"] == "completed"
        assert summary["interfaces"][0]["shared_dofs"] == (15 if dofs == "shared" else 0)
        frames[dofs] = summary["dofs"]
        plate, _ = read_frame(shared_tmp_path / dofs / "plate" / "surface.h5")
        wall, _ = read_frame(shared_tmp_path / dofs / "wall" / "surface.h5")
        tops.append(wall.evaluate(np.array(0.3), np.array(0.05)).x)
        for y in (0.0, 0.05, 0.1):
            flat_side = plate.evaluate(np.array(0.5), np.array(y))
            upright_side = wall.evaluate(np.array(0.0), np.array(y))
            assert np.linalg.norm(flat_side.x - upright_side.x) < (1e-14 if dofs == "shared" else 1e-6)
            assert abs(np.arccos(np.dot(flat_side.normal, upright_side.normal)) - 90 * DEG) < 0.05 * DEG
    assert frames["coupled"] - frames["shared"] == 15
    assert np.linalg.norm(tops[0] - tops[1]) < 1e-6, tops


@pytest.mark.parametrize(("edit", "message"), [
    (lambda s: s.replace("patches = [8, 2] }", 'patches = [8, 2], discretization = "bspline3" }') + 'dofs = "shared"\n',
     r"key 'interfaces\[0\].dofs' = \"shared\": bodies 'plate' and 'wall' do not conform along xi1_max and xi1_min: "
     r"a BSplineSurface and a HermiteSurface share no data"),
    (lambda s: _cubic_bracket("shared").replace("patches = [6, 2]", "patches = [6, 3]"),
     r"key 'interfaces\[0\].dofs' = \"shared\": .* have 5 and 6 control points \(their knots do not match\)"),
    (lambda s: s + 'dofs = "merged"\n',
     r"key 'interfaces\[0\].dofs' must be \"auto\", \"shared\", \"coupled\", got 'merged'"),
    (lambda s: s + 'dofs = "shared"\npartial = true\n',
     r"key 'interfaces\[0\].dofs' must be \"auto\" or \"coupled\" for a partial joint"),
])  # fmt: skip
def test_a_joint_that_cannot_share_its_control_points_is_refused_saying_why(comm, shared_tmp_path, edit, message):
    path = write_scene(comm, shared_tmp_path / "bad.toml", edit((REPO / "jobs" / "folded-plate.toml").read_text()))
    with pytest.raises(SceneError, match=message):
        load_any_scene(path)


RUBBER = "material = { young = 5.0e6, poisson = 0.49, thickness = 2.0e-3, density = 1100.0 }"
EFFECTS = "effects = { gravity = [0.0, 0.0, -9.81], damping = { mass = 10.0 } }"
CLOCK = "[time]\ndt = 0.01\nduration = 0.6\n[output]\nevery = 30\n"
SEWN = f"""{CLOCK}
[[bodies]]
name = "near"
surface = {{ kind = "rectangle", size = [0.1, 0.1], patches = [4, 4] }}
{RUBBER}
{EFFECTS}
constraints = [{{ type = "clamp", edge = "xi1_min" }}]

[[bodies]]
name = "far"
surface = {{ kind = "rectangle", size = [0.1, 0.1], patches = [4, 4], origin = [0.12, 0.0, 0.0] }}
{RUBBER}
{EFFECTS}

[[interfaces]]
type = "seam"
bodies = ["near", "far"]
edges = ["xi1_max", "xi1_min"]
sewing_time = 0.1
keep_angle = true
"""
ONE_SHEET = f"""surface = {{ kind = "rectangle", size = [0.2, 0.1], patches = [8, 4] }}
{RUBBER}
{EFFECTS}
constraints = [{{ type = "clamp", edge = "xi1_min" }}]
{CLOCK}"""


def test_two_panels_sewn_along_a_seam_hang_as_the_one_sheet_they_make(comm, shared_tmp_path):
    """A rubber panel clamped along one edge and a free one 2 cm beyond it, sewn in 0.1 s while
    they fall: after 0.6 s (damped) the far panel's free edge is where the one sheet of both
    panels has its free edge, within 0.5 % of its drop (measured 0.2 %)."""
    sewn = run_scene(RunOptions(write_scene(comm, shared_tmp_path / "sewn.toml", SEWN), shared_tmp_path / "sewn",
                                progress=False), comm)  # fmt: skip
    assert sewn["status"] == "completed" and sewn["interfaces"][0]["rest_gap_m"] == pytest.approx(0.02)
    assert max(step["newton_iterations"] for step in sewn["steps"]) <= 15
    run_scene(RunOptions(write_scene(comm, shared_tmp_path / "one.toml", ONE_SHEET), shared_tmp_path / "one",
                         progress=False), comm)  # fmt: skip
    far, _ = read_frame(shared_tmp_path / "sewn" / "far" / "surface.h5")
    near, _ = read_frame(shared_tmp_path / "sewn" / "near" / "surface.h5")
    one, _ = read_frame(shared_tmp_path / "one" / "surface.h5")
    edge = np.linspace(0.0, 0.1, 5)
    free = far.evaluate(np.full(5, 0.1), edge).x
    expected = one.evaluate(np.full(5, 0.2), edge).x
    drop = -expected[:, 2].min()
    assert drop > 0.1 and np.abs(free - expected).max() < 5e-3 * drop
    seam = np.abs(near.evaluate(np.full(5, 0.1), edge).x - far.evaluate(np.zeros(5), edge).x).max()
    assert seam < 1e-5


def test_a_partial_joint_joins_the_part_its_edges_share(comm, shared_tmp_path):
    """A panel beside half of a panel twice as long (a T-junction): the joint, declared partial, is
    the shared 0.1 m; its summary says so."""
    text = SEWN.replace("[0.1, 0.1], patches = [4, 4] }", "[0.2, 0.1], patches = [8, 4] }")
    text = text.replace("origin = [0.12, 0.0, 0.0]", "origin = [0.1, 0.1, 0.0]")
    text = text.replace('type = "seam"', 'type = "joint"\npartial = true').replace('["xi1_max", "xi1_min"]',
                                                                                    '["xi2_max", "xi2_min"]')
    text = text.replace("sewing_time = 0.1\nkeep_angle = true\n", "")
    scene = load_any_scene(write_scene(comm, shared_tmp_path / "t.toml", text))
    (joint,) = scene.interfaces
    summary = joint.summary()
    assert summary["type"] == "joint" and summary["length_m"] == pytest.approx(0.1, rel=1e-12)
    assert summary["rest_gap_m"] < 1e-12


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda s: s.replace('bodies = ["near", "far"]', 'bodies = ["near", "back"]'),
         r"key 'interfaces\[0\].bodies' must be the names of two bodies of the scene \(near, far\)"),
        (lambda s: s.replace('edges = ["xi1_max", "xi1_min"]', 'edges = ["xi1_max", "xi3_min"]'),
         r"key 'interfaces\[0\].edges' must be two edges, one of each body"),
        (lambda s: s.replace('type = "seam"', 'type = "joint"').replace("sewing_time = 0.1\nkeep_angle = true\n", ""),
         r"key 'interfaces\[0\].edges': edge xi1_max of body 'near' and edge xi1_min of body 'far' do not meet: "
         r"their ends lie 0.02 m from the other edge"),
        (lambda s: s.replace("[0.1, 0.1], patches = [4, 4], origin", "[0.1, 0.15], patches = [4, 4], origin"),
         r"key 'interfaces\[0\].edges': the seam's sides differ in length: edge xi1_max of body 'near' is 0.1 m, "
         r"edge xi1_min of body 'far' 0.15 m"),
        (lambda s: s.replace('type = "seam"', 'type = "joint"\npartial = true').replace("sewing_time = 0.1\n"
                                                                                     "keep_angle = true\n", ""),
         r"key 'interfaces\[0\].edges': edge xi1_max of body 'near' and edge xi1_min of body 'far' share no part "
         r"of an edge"),
        (lambda s: s.replace('type = "seam"', 'type = "joint"\npartial = "yes"').replace("sewing_time = 0.1\n"
                                                                                        "keep_angle = true\n", ""),
         r"key 'interfaces\[0\].partial' must be a boolean, got 'yes'"),
        (lambda s: s.replace("keep_angle = true", "keep_angle = true\npenalty = 1e9"),
         r"key 'interfaces\[0\].penalty' must be a number in \[1, 1e\+06\], got 1000000000.0"),
        (lambda s: s.replace("keep_angle = true", "keep_angle = true\nstrength = 2"),
         r"unknown key 'interfaces\[0\].strength'"),
        (lambda s: s.replace("sewing_time = 0.1", "sewing_time = -1.0"),
         r"key 'interfaces\[0\].sewing_time' must be a time > 0 \[s\], got -1.0"),
        (lambda s: s.replace('type = "seam"', 'type = "weld"'),
         r"key 'interfaces\[0\].type' must be one of joint, seam, got 'weld'"),
        (lambda s: "interfaces = 3\n" + s[:s.index("[[interfaces]]")],
         r"key 'interfaces' must be a list of interface tables"),
    ],
)  # fmt: skip
def test_interfaces_that_do_not_fit_their_bodies_are_refused_naming_them(comm, shared_tmp_path, edit, message):
    path = write_scene(comm, shared_tmp_path / "bad.toml", edit(SEWN))
    with pytest.raises(SceneError, match=message):
        load_any_scene(path)
    with pytest.raises(SceneError, match=message):
        run_scene(RunOptions(path, shared_tmp_path / "out", progress=False), comm)
    assert not (shared_tmp_path / "out").exists()


@pytest.mark.parametrize("method", ["impulse", "ipc"])
def test_joined_patches_in_contact_meet_colliders_but_not_each_other(comm, shared_tmp_path, method):
    """The folded bracket with contact effects on both patches and a floor below: its joined
    patches touch along the fold from the start, yet the run starts (no overlap or intersection
    refused), finds no contact between them, and self-collision of a joined patch is refused."""
    contact = ('{ method = "ipc", collision_cells = 4 }' if method == "ipc" else "{ push_out = 1.0e-4 }")
    text = (REPO / "jobs" / "folded-plate.toml").read_text()
    text = text.replace("effects = { damping", f"effects = {{ contact = {contact}, damping")
    text += '\n[[colliders]]\ntype = "plane"\npoint = [0.0, 0.0, -0.2]\nnormal = [0.0, 0.0, 1.0]\n'
    path = write_scene(comm, shared_tmp_path / "bracket.toml", text)
    summary = run_scene(RunOptions(path, shared_tmp_path / method, steps=3, progress=False), comm)
    assert summary["status"] == "completed"
    assert all(step["contacts"] == 0 for step in summary["steps"])
    selfish = write_scene(comm, shared_tmp_path / "selfish.toml", text.replace(
        "effects = { contact", "effects = { self_collision = true, contact", 1))  # fmt: skip
    with pytest.raises(SceneError, match=r"body 'plate' \(bodies\[0\]\): key 'effects.self_collision': a "
                                         r"body joined to another by interfaces\[0\] does not collide with itself"):
        load_any_scene(selfish)
