"""Contact by ``ipc`` in a scene: ipc-toolkit's barrier inside the Newton solve, every step bounded
by its collision-free step. A rubber sheet dropped onto a floor (a plane, or a two-triangle mesh)
never reaches it in any frame, comes to rest within dhat of it, and needs no recovery; two ranks
step it as one rank does; settings the barrier does not take are refused by key."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from helpers import RUBBER, STEEL

from bhem_hpc.errors import RunError
from bhem_hpc.io import read_checkpoint
from bhem_hpc.run import RunOptions, build_model, ipc_barrier, run_scene
from bhem_hpc.scene import SceneError, load_scene
from bhem_hpc.solver.contributions import ContributionState
from bhem_hpc.solver.dynamics import TimeStepper

#: A waved rubber sheet 3.5 to 7 mm above the plane z = 0, falling onto it ({discretization},
#: {contact}, {colliders}).
DROP = """
[surface]
kind = "rectangle"
size = [0.2, 0.2]
patches = [4, 4]
discretization = "{discretization}"
origin = [0.0, 0.0, 0.005]
height = "0.002 * sin(20.0 * xi1)"
[material]
young = {young}
poisson = {poisson}
thickness = {thickness}
density = {density}
[effects]
gravity = [0.0, 0.0, -9.81]
contact = {contact}
{colliders}
[time]
dt = 0.005
steps = 16
"""
PLANE = """
[[colliders]]
type = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
"""
IPC = '{ method = "ipc", dhat = 1e-3 }'
#: Four needles (one collider table, four capsules) under the sheet.
NEEDLES = """
[[colliders]]
type = "needles"
origin = [0.05, 0.05, -0.1]
spacing = [0.1, 0.1]
count = [2, 2]
length = 0.05
radius = 0.004
"""


def _scene(comm, directory, name: str, discretization: str = "hermite", contact: str = IPC,
           colliders: str = PLANE, extra: str = ""):  # fmt: skip
    path = directory / f"{name}.toml"
    if comm.rank == 0:
        path.write_text(DROP.format(discretization=discretization, contact=contact, colliders=colliders, **RUBBER)
                        + extra)  # fmt: skip
    comm.Barrier()
    return path


def _lowest_heights(out) -> np.ndarray:
    """The lowest point of every frame's output mesh [m]."""
    with h5py.File(out / "surface.h5", "r") as f:
        return np.array([f[f"frames/{k}/geometry"][:, 2].min() for k in range(len(f["frames"]))])


@pytest.mark.parametrize("discretization", ["hermite", "bspline2"])
def test_a_sheet_dropped_on_a_floor_never_reaches_it_and_rests_within_dhat(comm, shared_tmp_path, discretization):
    out = shared_tmp_path / discretization
    summary = run_scene(RunOptions(_scene(comm, shared_tmp_path, discretization, discretization), out,
                                   progress=False), comm)  # fmt: skip
    steps = summary["steps"]
    assert len(steps) == 16 and sum(s["recoveries"] for s in steps) == 0
    assert sum(s["newton_iterations"] for s in steps) / 16 <= 8.0  # measured 6.4 (Hermite), 6.2 (bspline2)
    if comm.rank == 0:
        lowest = _lowest_heights(out)
        # it falls 3.5 mm in the first 5 steps (t = 0.027 s), then lies on the floor, never below it
        assert lowest[0] == pytest.approx(0.005 - 0.002 * np.sin(20.0 * 0.2 * 0.75 * np.pi / 2.0 / 0.3), abs=2e-3)
        assert np.all(lowest > 0.0) and lowest[-1] < 1e-3 and np.all(lowest[10:] < 1e-3)


def test_the_trust_region_drops_the_sheet_on_the_floor_without_ever_reaching_it(comm, shared_tmp_path):
    """``hessian = "trust_region"``: a trial whose straight path the barrier's collision-free step
    cuts short counts as an infinite potential, so TAO rejects it and shrinks the region; the sheet
    lands and rests as by line search, never at or below the floor, with no step failing."""
    extra = '[solver]\nhessian = "trust_region"\n'
    out = shared_tmp_path / "trust-region"
    path = _scene(comm, shared_tmp_path, "trust-region", extra=extra)
    summary = run_scene(RunOptions(path, out, progress=False), comm)
    steps = summary["steps"]
    assert len(steps) == 16 and sum(s["recoveries"] + s["trust_region_failures"] for s in steps) == 0
    if comm.rank == 0:
        lowest = _lowest_heights(out)
        assert np.all(lowest > 0.0) and lowest[-1] < 1e-3 and np.all(lowest[10:] < 1e-3)


def test_the_floors_barrier_reaches_dhat_without_a_step_in_its_energy(comm, shared_tmp_path):
    """A flat sheet (quadratic B-splines: a translation of its control points moves it whole)
    lowered onto the floor: its barrier energy is zero from dhat up and grows continuously below,
    across dhat / 2, where ipc-toolkit 1.6.1 alone starts its plane-vertex pairs (an energy step
    there stalled the line search of a cloth corner hanging onto the ground; without the scene's
    own pairs the energy at 0.51 dhat was 0)."""
    path = shared_tmp_path / "flat.toml"
    if comm.rank == 0:
        path.write_text(DROP.format(discretization="bspline2", contact=IPC, colliders=PLANE, **RUBBER).replace(
            'height = "0.002 * sin(20.0 * xi1)"\n', ""))  # fmt: skip
    comm.Barrier()
    scene = load_scene(path)
    model = build_model(scene, comm)
    barrier = ipc_barrier(scene, model, path)
    start = model.x.x.array.reshape(-1, 3).copy()

    def energy(height: float) -> float:
        positions = start + [0.0, 0.0, height - 0.005]  # the sheet is made 5 mm above the floor
        return comm.allreduce(barrier.energy(ContributionState(positions, 1.0, model.point_positions)))

    dhat = barrier.dhat
    energies = np.array([energy(f * dhat) for f in (0.3, 0.45, 0.49, 0.51, 0.55, 0.9, 0.99, 1.01, 1.5)])
    assert np.all(energies[:7] > 0.0) and np.all(energies[7:] == 0.0)
    assert np.all(np.diff(energies[:7]) < 0.0)
    assert energies[3] > 0.8 * energies[2]  # 0.51 against 0.49 dhat: the barrier's own ratio is 0.89


def test_ipcs_step_test_ends_the_solves_sooner_and_the_sheet_still_rests_above_the_floor(comm, shared_tmp_path):
    """``velocity_tolerance``: a solve also stops where the full Newton step is collision-free and
    moves no collision-mesh vertex by more than the tolerance times dt. With 0.01 m/s (50 um a
    step) the drop takes fewer Newton iterations and lands where the acceleration test lands it,
    never at or below the floor; with 1e-9 m/s the test never passes before the acceleration test;
    "auto" is IPC's 1e-2 of the rest bounding-box diagonal per second (the wavy 0.2 m sheet's)."""
    runs, tolerances = {}, {}
    for name, contact in (("default", IPC), ("loose", '{ method = "ipc", dhat = 1e-3, velocity_tolerance = 0.01 }'),
                          ("tight", '{ method = "ipc", dhat = 1e-3, velocity_tolerance = 1e-9 }'),
                          ("auto", '{ method = "ipc", dhat = 1e-3, velocity_tolerance = "auto" }')):  # fmt: skip
        out = shared_tmp_path / name
        summary = run_scene(RunOptions(_scene(comm, shared_tmp_path, name, contact=contact), out, progress=False), comm)
        assert sum(s["recoveries"] for s in summary["steps"]) == 0
        runs[name] = ([s["newton_iterations"] for s in summary["steps"]], out)
        tolerances[name] = summary["contact"]["velocity_tolerance_m_s"]
    default, loose, tight, auto = (runs[k][0] for k in ("default", "loose", "tight", "auto"))
    assert tight == default
    assert sum(loose) <= 0.85 * sum(default)  # measured 53 against 72
    assert tolerances["default"] is None and tolerances["loose"] == 0.01
    assert tolerances["auto"] == pytest.approx(1e-2 * np.hypot(0.2, 0.2), rel=0.02)  # the sheet's waves: 4 mm
    assert sum(loose) <= sum(auto) <= 0.85 * sum(default)  # measured 53 (2.8 mm/s) against 72
    if comm.rank == 0:
        lowest, reference = _lowest_heights(runs["loose"][1]), _lowest_heights(runs["default"][1])
        assert np.all(lowest > 0.0) and lowest[-1] < 1e-3
        assert np.abs(lowest - reference).max() <= 1e-5  # measured 9.1e-7 m


@pytest.mark.parallel
def test_two_ranks_drop_the_sheet_as_one_rank_does(comm, shared_tmp_path):
    """Every rank evaluates the barrier on the whole collision mesh (its vertices summed over the
    ranks), so the states agree to round-off."""
    from mpi4py import MPI

    path = _scene(comm, shared_tmp_path, "parallel")
    summary = run_scene(RunOptions(path, shared_tmp_path / "two", steps=9, progress=False), comm)
    serial = None
    if comm.rank == 0:
        serial = run_scene(RunOptions(path, shared_tmp_path / "one", steps=9, progress=False), MPI.COMM_SELF)
        ours, _ = read_checkpoint(shared_tmp_path / "two" / "checkpoint.h5")
        theirs, _ = read_checkpoint(shared_tmp_path / "one" / "checkpoint.h5")
        assert np.abs(ours["position_dofs"] - theirs["position_dofs"]).max() <= 1e-9
        assert [s["newton_iterations"] for s in summary["steps"]] == [s["newton_iterations"] for s in serial["steps"]]
    comm.Barrier()


@pytest.mark.parametrize("radius, exact", [(0.05, False), (40.0, True)])
def test_a_sheet_dropped_across_a_cylinder_drapes_over_it_and_never_enters_it(comm, shared_tmp_path, radius, exact):
    """A cylinder along y under the sheet's middle, its top at z = 0, and the sheet ends resting
    on it. One of radius 40 m, almost a floor, is met through its exact distance: every output
    point of every frame stays outside it. A thin one the sheet folds over would need an offset
    beyond dhat for the sheet's triangles (1.2 mm): it is met as triangles within dhat / 4 inside
    it, and the sheet stays outside it but for that."""
    colliders = (f'[[colliders]]\ntype = "cylinder"\npoint = [0.1, 0.0, {-radius}]\naxis = [0.0, 1.0, 0.0]\n'
                 f'radius = {radius}\n')  # fmt: skip
    out = shared_tmp_path / f"cylinder-{radius}"
    summary = run_scene(RunOptions(_scene(comm, shared_tmp_path, f"cylinder-{radius}", colliders=colliders), out,
                                   progress=False), comm)  # fmt: skip
    assert sum(s["recoveries"] for s in summary["steps"]) == 0 and summary["contact"]["round_colliders"] == exact
    if comm.rank == 0:
        with h5py.File(out / "surface.h5", "r") as f:
            frames = [f[f"frames/{k}/geometry"][:] for k in range(len(f["frames"]))]
        axis_point = np.array([0.1, 0.0, -radius])
        gaps = [np.linalg.norm((x - axis_point)[:, [0, 2]], axis=1).min() - radius for x in frames]
        assert min(gaps) > (0.0 if exact else -0.25e-3) and gaps[-1] < 1e-3


def test_a_cylinder_too_wide_for_its_triangles_is_refused_by_key_before_any_output(comm, shared_tmp_path):
    """With friction the cylinder is met as triangles (friction acts on ipc-toolkit's pairs), too
    many of them around."""
    colliders = ('[[colliders]]\ntype = "cylinder"\npoint = [0.1, 0.0, -1e5]\naxis = [0.0, 1.0, 0.0]\nradius = 1e5\n'
                 'friction = 0.3\n')  # fmt: skip
    path = _scene(comm, shared_tmp_path, "wide", colliders=colliders)
    with pytest.raises(RunError, match=r"wide.toml: key 'colliders\[0\]': a cylinder of radius 100000 "
                                       r"needs more than 1024 vertices around .* a larger 'effects.contact.dhat'"):
        run_scene(RunOptions(path, shared_tmp_path / "wide", progress=False), comm)
    assert not (shared_tmp_path / "wide").exists()


def _write_floor(path, kind: str) -> None:
    """A floor at z = 0 under the sheet: two triangles whose diagonal runs under no lattice point
    (``mesh``), or two flat bicubic Bezier patches (``patches``, met as their tessellation)."""
    from bhem_hpc.collision import PatchModel

    if kind == "mesh":
        path.write_text("v -1 -0.7 0\nv 1.3 -1 0\nv 0.9 1.1 0\nv -1.2 0.8 0\nf 1 2 3\nf 1 3 4\n")
        return
    i, j = np.meshgrid(np.arange(4) / 3.0, np.arange(4) / 3.0, indexing="ij")
    halves = [np.stack([-0.1 + 0.2 * i + 0.2 * k, -0.1 + 0.4 * j, 0.0 * i], axis=-1) for k in (0, 1)]
    PatchModel(np.stack(halves)).save(path)


@pytest.mark.parametrize("kind, name", [("mesh", "floor.obj"), ("patches", "floor.npz")])
def test_a_sheet_dropped_on_a_mesh_or_patch_floor_stays_above_it(comm, shared_tmp_path, kind, name):
    floor = shared_tmp_path / name
    if comm.rank == 0:
        _write_floor(floor, kind)
    comm.Barrier()
    colliders = f'[[colliders]]\ntype = "{kind}"\nfile = "{floor}"\n'
    out = shared_tmp_path / f"on-{kind}"
    summary = run_scene(RunOptions(_scene(comm, shared_tmp_path, kind, colliders=colliders), out, steps=10,
                                   progress=False), comm)  # fmt: skip
    assert sum(s["recoveries"] for s in summary["steps"]) == 0
    if comm.rank == 0:
        lowest = _lowest_heights(out)
        assert np.all(lowest > 0.0) and lowest[-1] < 1e-3


def test_a_sheet_dropped_on_a_sphere_stays_outside_it(comm, shared_tmp_path):
    """The sphere meets the barrier through its exact distance: the sheet draping its top stays
    outside it, and within dhat of it once landed."""
    colliders = '[[colliders]]\ntype = "sphere"\ncenter = [0.1, 0.1, -0.1]\nradius = 0.1\n'
    out = shared_tmp_path / "on-sphere"
    summary = run_scene(RunOptions(_scene(comm, shared_tmp_path, "sphere", colliders=colliders), out, steps=12,
                                   progress=False), comm)  # fmt: skip
    assert summary["status"] == "completed" and len(summary["steps"]) == 12
    assert summary["contact"]["round_colliders"] == 1
    if comm.rank == 0:
        with h5py.File(out / "surface.h5", "r") as f:
            gaps = [np.linalg.norm(f[f"frames/{k}/geometry"][...] - [0.1, 0.1, -0.1], axis=1).min() - 0.1
                    for k in range(len(f["frames"]))]  # fmt: skip
        assert min(gaps) > 0.0 and min(gaps[8:]) <= 1e-3  # within dhat of it once landed


def test_a_floor_under_the_sphere_does_not_change_the_sheets_landing_on_it(comm, shared_tmp_path):
    """The sphere resting on a floor (its icosphere's lowest vertex on the plane): colliders never
    meet each other, so the sheet lands on the sphere as without the floor (measured: the same
    frames to round-off). Were the sphere's vertex on the plane a contact, its constant barrier
    energy would swamp the line search's energy scale, which then takes no step where the sheet
    lands (measured so: the frames 13 mm apart after 12 steps)."""
    sphere = '[[colliders]]\ntype = "sphere"\ncenter = [0.1, 0.1, -0.1]\nradius = 0.1\n'
    floor = PLANE.replace("[0.0, 0.0, 0.0]", "[0.0, 0.0, -0.2]")
    frames = {}
    for name, colliders in (("sphere-alone", sphere), ("sphere-on-floor", sphere + floor)):
        out = shared_tmp_path / name
        summary = run_scene(RunOptions(_scene(comm, shared_tmp_path, name, colliders=colliders), out, steps=12,
                                       progress=False), comm)  # fmt: skip
        assert summary["status"] == "completed" and summary["contact"]["stiffness_doublings"] == 0
        if comm.rank == 0:
            with h5py.File(out / "surface.h5", "r") as f:
                frames[name] = np.array([f[f"frames/{k}/geometry"][...] for k in range(len(f["frames"]))])
    if comm.rank == 0:
        assert np.abs(frames["sphere-on-floor"] - frames["sphere-alone"]).max() < 1e-9


def test_a_sheet_dropped_across_a_capsule_stays_outside_it(comm, shared_tmp_path):
    """A capsule (a needle lying along y under the sheet's middle) too thin for an offset within
    dhat (4.9 mm for the sheet's triangles) meets the barrier as rings of triangles within dhat / 4
    inside it: the sheet folding over it stays outside the exact capsule but for that, and rests on
    it within dhat."""
    from bhem_hpc.collision.colliders import Capsule

    colliders = '[[colliders]]\ntype = "capsule"\na = [0.1, -0.05, -0.01]\nb = [0.1, 0.25, -0.01]\nradius = 0.01\n'
    out = shared_tmp_path / "on-capsule"
    summary = run_scene(RunOptions(_scene(comm, shared_tmp_path, "capsule", colliders=colliders), out, steps=12,
                                   progress=False), comm)  # fmt: skip
    assert summary["status"] == "completed" and sum(s["recoveries"] for s in summary["steps"]) == 0
    assert summary["contact"]["round_colliders"] == 0
    if comm.rank == 0:
        capsule = Capsule(np.array([0.1, -0.05, -0.01]), np.array([0.1, 0.25, -0.01]), 0.01)
        with h5py.File(out / "surface.h5", "r") as f:
            gaps = [capsule.signed_distance(f[f"frames/{k}/geometry"][...])[0].min() for k in range(len(f["frames"]))]
        assert min(gaps) >= -0.25e-3 and min(gaps[8:]) <= 1e-3


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda s: s.replace("dhat = 1e-3", "dhat = -1e-3"), r"'effects.contact.dhat' must be a length in \[1e-9, 1\]"),
        (lambda s: s.replace("dhat = 1e-3", "dhat = 1e-3, push_out = 1e-4"), r"unknown key 'effects.contact.push_out'"),
        (lambda s: s.replace("contact = {", "self_collision = { friction = 0.2 }\ncontact = {"),
         r"key 'effects.self_collision' = \{'friction': 0.2\}: contact by 'ipc' takes a boolean"),
        (lambda s: s.replace("contact = {", "friction = -0.3\ncontact = {"),
         r"key 'effects.friction' must be a number >= 0 \(Coulomb coefficient\), got -0.3"),
        (lambda s: s.replace("contact = {", "static_friction = 'high'\ncontact = {"),
         r"key 'effects.static_friction' must be a number"),
        (lambda s: s.replace('normal = [0.0, 0.0, 1.0]', 'normal = [0.0, 0.0, 1.0]\nstatic_friction = -1'),
         r"key 'colliders\[0\].static_friction' must be a number >= 0"),
        (lambda s: s.replace("dhat = 1e-3", "dhat = 1e-3, eps_v = 0.0"),
         r"'effects.contact.eps_v' must be a sticking speed"),
        (lambda s: s.replace("dhat = 1e-3", "dhat = 1e-3, velocity_tolerance = 0.0"),
         r"key 'effects.contact.velocity_tolerance' must be a speed in \[1e-09, 1000\] \[m/s\] or \"auto\", got 0.0"),
        (lambda s: s.replace("dhat = 1e-3", 'dhat = 1e-3, velocity_tolerance = "fast"'),
         r"key 'effects.contact.velocity_tolerance' must be a speed in .* or \"auto\", got 'fast'"),
        (lambda s: s.replace('method = "ipc", dhat = 1e-3', 'method = "impulse"').replace(
            "contact = {", "static_friction = 0.5\ncontact = {"),
         r"key 'effects.static_friction' = 0.5: impulses have one Coulomb coefficient"),
        (lambda s: s.replace('method = "ipc", dhat = 1e-3', 'method = "impulse"').replace(
            'type = "plane"\npoint = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 1.0]',
            'type = "sphere"\ncenter = [0.1, 0.1, -1.0]\nradius = 0.5\nspin = [0.0, 0.0, 1.0]'),
         r"key 'colliders\[0\].spin' = \[0.0, 0.0, 1.0\]: spinning colliders are for contact method 'ipc' only"),
        (lambda s: s.replace('normal = [0.0, 0.0, 1.0]', 'normal = [0.0, 0.0, 1.0]\nvelocity = [0.0, 0.0, 0.1]\n'
                             'friction = 0.3'),
         r"key 'colliders\[0\].friction' = 0.3 \(static .*'effects.friction'\): a translating plane meets the "
         r"shell without friction by 'ipc'"),
        (lambda s: s.replace('[[colliders]]\ntype = "plane"', NEEDLES + '[[colliders]]\ntype = "plane"').replace(
            'normal = [0.0, 0.0, 1.0]', 'normal = [0.0, 0.0, 1.0]\nvelocity = [0.0, 0.0, 0.1]\nfriction = 0.3'),
         r"key 'colliders\[1\].friction' = 0.3"),  # the scene's index, not that among the needles' capsules
        (lambda s: s.replace('method = "ipc"', 'method = "barrier"'), r"key 'effects.contact.method' must be one of"),
    ],
)  # fmt: skip
def test_settings_the_barrier_does_not_take_are_refused(comm, shared_tmp_path, edit, message):
    path = shared_tmp_path / "bad.toml"
    if comm.rank == 0:
        path.write_text(edit(DROP.format(discretization="hermite", contact=IPC, colliders=PLANE, **RUBBER)))
    comm.Barrier()
    with pytest.raises(SceneError, match=message):
        load_scene(path)


def test_a_sheet_starting_below_the_plane_is_refused_before_the_first_step(comm, shared_tmp_path):
    colliders = PLANE.replace("point = [0.0, 0.0, 0.0]", "point = [0.0, 0.0, 0.004]")  # under the waves' troughs
    path = _scene(comm, shared_tmp_path, "below", colliders=colliders)
    with pytest.raises(RunError, match=r"starts in contact with its colliders .*colliders\[0\] \(a plane\) has \d+ "
                                       r"collision vertices"):
        run_scene(RunOptions(path, shared_tmp_path / "below", progress=False), comm)


def test_a_sheet_starting_within_a_spheres_offset_is_refused_before_the_first_step(comm, shared_tmp_path):
    """A sphere of radius 0.1 m met through its exact distance, its top 0.3 mm under the sheet's
    wave crest above it: the sheet is outside it, but within the offset (0.6 mm) its triangles need."""
    colliders = '[[colliders]]\ntype = "sphere"\ncenter = [0.1, 0.1, -0.0935]\nradius = 0.1\n'
    path = _scene(comm, shared_tmp_path, "within-offset", colliders=colliders)
    with pytest.raises(RunError, match=r"starts in contact with its colliders .*colliders\[0\] has collision "
                                       r"vertices within 0.000\d+ m of it \(the offset that keeps the mesh's "
                                       r"triangles out of it\)"):
        run_scene(RunOptions(path, shared_tmp_path / "within-offset", progress=False), comm)
    assert not (shared_tmp_path / "within-offset").exists()


def test_self_contact_by_ipc_needs_no_collider_and_sets_the_barriers_solve(comm, shared_tmp_path):
    """A scene with self_collision and contact by 'ipc' but no collider loads; contact by 'ipc' sets
    its solve's defaults (fresh factorizations, the acceleration test, 100 Newton iterations) where
    the scene does not, and a scene's own choice stands."""
    text = DROP.format(discretization="hermite", contact=IPC, colliders="", **RUBBER)
    path = shared_tmp_path / "self.toml"
    own = shared_tmp_path / "self-own.toml"
    if comm.rank == 0:
        path.write_text(text.replace("contact = {", "self_collision = true\ncontact = {"))
        own.write_text(text.replace("contact = {", "self_collision = true\ncontact = {") + '[solver]\n'
                       'factorization = "reuse"\nacceleration_tolerance = 0.5\noptions = { snes_max_it = 40 }\n')
    comm.Barrier()
    scene = load_scene(path)
    assert scene.contact.method == "ipc" and scene.contact.self_collision and not scene.contact.colliders
    assert (scene.factorization, scene.acceleration_tolerance, scene.petsc_options) == ("fresh", 1e-2,
                                                                                     {"snes_max_it": 100})
    scene = load_scene(own)
    assert (scene.factorization, scene.acceleration_tolerance, scene.petsc_options) == ("reuse", 0.5,
                                                                                     {"snes_max_it": 40})


def test_a_collision_mesh_farther_from_the_surface_than_dhat_is_refused_with_its_gap(comm, shared_tmp_path):
    """The waved sheet (curvature up to 0.8 /m) on 2 collision cells per patch (25 mm cells) lies
    about kappa L^2 / 9 = 5.6e-5 m from its flat triangles at their centroids (a parabola against
    the plane through three of its points): with dhat = 1e-5 m the run is refused before its first
    step, naming the key and the measured gap (5.42e-5), and leaves no output; 8 cells per patch (a
    sixteenth of the gap) are accepted."""
    import re

    coarse = _scene(comm, shared_tmp_path, "coarse", contact='{ method = "ipc", dhat = 1e-5, collision_cells = 2 }')
    refusal = (r"key 'effects.contact.collision_cells' = 2: the collision mesh lies up to \S+ m from the exact "
               r"surface at rest .* more than dhat = 1e-05 m")
    with pytest.raises(RunError, match=refusal) as caught:
        run_scene(RunOptions(coarse, shared_tmp_path / "coarse", progress=False), comm)
    gap = float(re.search(r"lies up to (\S+) m", str(caught.value)).group(1))
    assert 4e-5 < gap < 7e-5
    assert not (shared_tmp_path / "coarse" / "surface.h5").exists()
    fine = _scene(comm, shared_tmp_path, "fine", contact='{ method = "ipc", dhat = 1e-5, collision_cells = 8 }')
    summary = run_scene(RunOptions(fine, shared_tmp_path / "fine", steps=1, progress=False), comm)
    assert summary["status"] == "completed"


@pytest.mark.parametrize(("thrown", "pushes"), [(0.0, 0), (-2.0, 1)])
def test_a_rising_floor_lifts_the_sheet_without_ever_reaching_it(comm, shared_tmp_path, thrown, pushes):
    """The floor rises at 0.2 m/s into the sheet, which falls or is thrown down at 2 m/s: each
    step's first guess carries what the floor reaches along with it; where the thrown sheet would
    still cross the floor on the way to its guess, the first step is solved with the floor part of
    the way first (one push). Then every step lifts the sheet with the floor in one or two Newton
    iterations, within dhat above it and never on or below it in any frame."""
    colliders = PLANE.replace("normal = [0.0, 0.0, 1.0]", "normal = [0.0, 0.0, 1.0]\nvelocity = [0.0, 0.0, 0.2]")
    extra = f"[initial]\nvelocity = [0.0, 0.0, {thrown}]\n" if thrown else ""
    path = _scene(comm, shared_tmp_path, "lift", colliders=colliders, extra=extra)
    text = path.read_text().replace("steps = 16", "steps = 40")
    comm.Barrier()
    if comm.rank == 0:
        path.write_text(text)
    comm.Barrier()
    summary = run_scene(RunOptions(path, shared_tmp_path / "lift", progress=False), comm)
    steps = summary["steps"]
    assert len(steps) == 40 and sum(s["recoveries"] + s["dt_halvings"] for s in steps) == 0
    assert [s["collider_pushes"] for s in steps] == [pushes] + [0] * 39
    assert sum(s["newton_iterations"] for s in steps) / 40 <= 3.0  # measured 1.45 (falling), 1.35 (thrown)
    if comm.rank == 0:
        above = _lowest_heights(shared_tmp_path / "lift") - 0.2 * 0.005 * np.arange(41)
        assert np.all(above > 0.0) and np.all(above[10:] < 1e-3)


@pytest.mark.parametrize("forced_inertial", [False, True])
def test_a_step_starts_from_the_lower_potential_of_the_prediction_and_the_start(comm, shared_tmp_path, monkeypatch,
                                                                                forced_inertial):  # fmt: skip
    """A steel sheet clamped along one edge and thrown down at 1 m/s: the inertial prediction moves
    the free part 5 mm against a clamped edge, a state of far higher potential than the step's
    start, which the first step starts from instead (measured: 15 Newton iterations, no recovery;
    forced to start from the prediction, 20 iterations after 4 recoveries). A rubber sheet falling
    freely onto a floor starts every step from its prediction until it lands."""
    if forced_inertial:
        monkeypatch.setattr(TimeStepper, "_lowest_potential", lambda self, guesses: 0)
    clamped = PLANE + '[[constraints]]\ntype = "clamp"\nedge = "xi1_min"\n[initial]\nvelocity = [0.0, 0.0, -1.0]\n'
    path = shared_tmp_path / "thrown.toml"
    if comm.rank == 0:
        path.write_text(DROP.format(discretization="hermite", contact=IPC, colliders=clamped, **STEEL)
                        .replace('height = "0.002 * sin(20.0 * xi1)"', "").replace("steps = 16", "steps = 2"))
    comm.Barrier()
    steps = run_scene(RunOptions(path, shared_tmp_path / "thrown", progress=False), comm)["steps"]
    first = steps[0]
    if forced_inertial:
        assert first["start_guesses"] == 0 and first["recoveries"] > 0
    else:
        assert first["start_guesses"] == 1 and first["recoveries"] == 0 and first["newton_iterations"] <= 18
        falling = run_scene(RunOptions(_scene(comm, shared_tmp_path, "falling"), shared_tmp_path / "falling",
                                       steps=4, progress=False), comm)["steps"]  # fmt: skip
        assert [s["start_guesses"] for s in falling] == [0, 0, 0, 0]
