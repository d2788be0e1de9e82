"""The intersection audit of a run's output (``bhem-hpc intersections``): two rubber plates that
pass through each other intersect in every frame where they cross; with the impulse contact between
them they meet at the push-out distance and intersect in a frame at most. Two solid blocks (whose
parts meet along their edges) are tested against each other, never against themselves: they
intersect in the frames where they pass through each other."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import REPO, write_scene

from bhem_hpc import cli
from bhem_hpc.contact.audit import audit_run, read_frames
from bhem_hpc.errors import InputError, UserError
from bhem_hpc.geometry import nurbs
from bhem_hpc.io.cad import write_parts
from bhem_hpc.run import RunOptions, run_scene

CONTACT = "effects = { contact = { push_out = 1.0e-4 }, friction = 0.2 }\n"


def _plates(comm, directory, contact: bool):
    """The two-plates job, a frame every step, with or without its contact."""
    text = (REPO / "jobs" / "two-plates.toml").read_text().replace("every = 5", "every = 1")
    assert text.count(CONTACT) == 2
    path = directory / f"plates-{contact}.toml"
    if comm.rank == 0:
        path.write_text(text if contact else text.replace(CONTACT, ""))
    comm.Barrier()
    out = directory / f"plates-{contact}"
    run_scene(RunOptions(path, out, steps=11, progress=False), comm)
    return out


def test_plates_passing_through_each_other_intersect_and_with_impulses_touch(comm, shared_tmp_path, capsys):
    crossing = _plates(comm, shared_tmp_path, contact=False)
    touching = _plates(comm, shared_tmp_path, contact=True)
    if comm.rank != 0:
        return
    audits = audit_run(crossing, within=1e-3)
    assert len(audits) == 12 and [a.index for a in audits] == list(range(12))
    # 10 mm apart, closing at 1 m/s: the vertical plate's edge reaches the horizontal one at t = 0.01 s
    hits = [a.time for a in audits if a.intersecting]
    # at t = 0.01 s the vertical plate's edge lies exactly on the horizontal plate (whether that
    # frame counts as intersecting is round-off); before it they are apart, after it they cross
    assert min(hits) == pytest.approx(0.01) or min(hits) == pytest.approx(0.012)
    assert [t for t in hits if t > 0.011] == pytest.approx([a.time for a in audits[6:]])
    # With impulses the plates stay apart but for a frame or so: the response keeps samples at the
    # push-out distance (1e-4 m), not the tessellated output meshes, and the vertical plate's edge
    # lies between samples (measured: frame 7, t = 0.014 s).
    touched = audit_run(touching, within=1e-3)
    assert sum(a.intersecting for a in touched) <= 2 and not touched[5].intersecting
    assert 5e-5 <= touched[5].min_distance <= 2e-4  # at the push-out distance where they meet
    assert cli.main(["intersections", str(crossing)]) == 1
    out = capsys.readouterr().out
    assert "frame 6 (t = 0.012): intersecting" in out and f"12 frames, {len(hits)} intersecting" in out


def test_the_audit_refuses_what_is_not_a_run(comm, shared_tmp_path):
    if comm.rank != 0:
        return
    with pytest.raises(UserError, match="does not exist: .* is not the output directory of `bhem-hpc run`"):
        audit_run(shared_tmp_path, within=1e-3)
    with pytest.raises(InputError, match=r"--within must be a positive distance, got -1.0"):
        audit_run(shared_tmp_path, within=-1.0)


BLOCK = """
[[bodies]]
name = "{name}"
type = "solid"
file = "block.igs"
offset = [{x}, 0.0, 0.0]
material = {{ density = 1100.0, young = 2.0e6, poisson = 0.45 }}
sem = {{ degree = 2, lines_per_side = 8, sparsity = 0.3 }}
initial = {{ velocity = [{v}, 0.0, 0.0] }}
"""


def test_solids_passing_through_each_other_intersect_in_the_frames_where_they_cross(comm, shared_tmp_path):
    if comm.rank == 0:
        write_parts(shared_tmp_path / "block.igs", nurbs.box_faces([-0.1, -0.1, -0.1], [0.1, 0.1, 0.1], degree=2))
    text = ("[time]\ndt = 0.01\nsteps = 6\n[output]\nevery = 1\n" + BLOCK.format(name="left", x=-0.12, v=1.0)
            + BLOCK.format(name="right", x=0.12, v=-1.0))  # fmt: skip
    path = write_scene(comm, shared_tmp_path / "blocks.toml", text)
    out = shared_tmp_path / "blocks"
    run_scene(RunOptions(path, out, progress=False), comm)
    if comm.rank != 0:
        return
    meshes = read_frames(out)
    assert len(meshes.frames) == 7 and len(set(meshes.groups.tolist())) == 2  # one group per solid
    audits = audit_run(out, within=1e-3)
    # 0.04 m apart, closing at 2 m/s: they touch at t = 0.02 s and cross after it; every block's own
    # parts meet along its edges and are never counted
    assert [a.intersecting for a in audits] == [False, False, audits[2].intersecting, True, True, True, True]
    assert audits[1].min_distance == float("inf")  # 0.02 m apart: beyond the 1e-3 m measured


def test_bodies_in_contact_by_ipc_are_written_on_their_collision_meshes(comm, shared_tmp_path):
    """What the audit (and ParaView) sees of a cloth and a block in contact by IPC is their collision
    meshes: the cloth's lattice of ``collision_cells`` per patch side, the block's knot-aligned grid."""
    from bhem_hpc.contact.ipc_setup import solid_mesh

    parts = nurbs.box_faces([-0.1, -0.1, 0.05], [0.1, 0.1, 0.25], degree=2)
    if comm.rank == 0:
        write_parts(shared_tmp_path / "block.igs", parts)
    block_table = BLOCK.format(name="block", x=0.0, v=0.0).replace(
        "initial = { velocity = [0.0, 0.0, 0.0] }", 'effects = { contact = { method = "ipc", collision_cells = 6 } }')
    text = ("[time]\ndt = 0.01\nsteps = 1\n[output]\nevery = 1\ndensity = 5\n[[bodies]]\nname = \"cloth\"\n"
            'surface = { kind = "rectangle", size = [0.4, 0.4], patches = [4, 4], origin = [-0.2, -0.2, 0.0] }\n'
            "material = { young = 1.0e5, poisson = 0.3, thickness = 1.0e-3, density = 200.0 }\n"
            'effects = { gravity = [0.0, 0.0, -9.81], contact = { method = "ipc", collision_cells = 3 } }\n'
            + block_table)  # fmt: skip
    out = shared_tmp_path / "ipc"
    run_scene(RunOptions(write_scene(comm, shared_tmp_path / "ipc.toml", text), out, progress=False), comm)
    if comm.rank != 0:
        return
    meshes = read_frames(out)
    cloth = (4 * 3 + 1) ** 2
    assert len(meshes.frames[0][0]) == cloth + 6 * 7**2  # not density 5's 21^2 and 6 x 11^2
    block = solid_mesh(parts, 0, 1.0, 7)
    np.testing.assert_allclose(meshes.frames[0][0][cloth:], block.rest, atol=1e-14)
    written = meshes.faces[len(meshes.faces) - len(block.triangles):] - cloth
    np.testing.assert_array_equal(np.unique(np.sort(written, axis=1), axis=0),
                                  np.unique(np.sort(block.triangles, axis=1), axis=0))  # fmt: skip
