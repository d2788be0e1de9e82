"""Path following: load control at the requested levels, displacement control and arc length through
the limit points of a shallow arch, against its closed-form path; stability and events; bad settings."""

from __future__ import annotations

import numpy as np
import pytest
from mpi4py import MPI

from bhem_hpc.solver import ShellSolver
from bhem_hpc.solver.path import ArcLength, PathFollower, PathSettingError, Probe
from bhem_hpc.studies.paths import CompressedStrip, ShallowArch
from bhem_hpc.studies.references import pinned_elastica, shallow_arch_load

ARCH = ShallowArch()
#: Marguerre's shallow-arch theory against the exact shell: errors of order (pi e / L)^2 ~ 1e-3 of P_max.
TOLERANCE = 2e-3 * float(shallow_arch_load(np.sqrt((ARCH.initial_rise**2 - 4) / 3), ARCH.initial_rise))
LIMIT_RISE = np.sqrt((ARCH.initial_rise**2 - 4) / 3)


def arch_path(comm, method: str, discretization: str = "hermite") -> tuple[np.ndarray, np.ndarray, list]:
    """The arch's path by ``method``: load factors, midspan rises (units of r) and the points."""
    model = ARCH.model(16, comm, discretization)
    with ShellSolver(model) as solver, PathFollower(solver, [Probe("mid", *ARCH.midspan())]) as follower:
        if method == "arc_length":
            follower.arc_length(ArcLength(1e-4, max_step=2.5e-4, max_steps=200, load_factor_range=(-1.0, 7.0)))
        elif method == "displacement":
            follower.displacement_control("mid", "z", -np.linspace(0, 2 * ARCH.rise, 21)[1:])  # or 2
        else:
            follower.load_control(np.linspace(0.5, 5.5, 11))
        points = follower.path
    factors = np.array([p.load_factor for p in points])
    rises = np.array([(ARCH.rise + p.probes["mid"]["displacement"][2]) / ARCH.gyration_radius for p in points])
    return factors, rises, points


def check_path(factors, rises, points) -> None:
    """On the closed-form path; one negative pivot exactly between the limit points; an event at each."""
    assert np.abs(factors - shallow_arch_load(rises, ARCH.initial_rise)).max() < TOLERANCE
    for point, rise in zip(points, rises, strict=True):
        if abs(abs(rise) - LIMIT_RISE) > 0.05:  # away from the limit points the inertia is certain
            assert point.negative_pivots == (1 if abs(rise) < LIMIT_RISE else 0), (point.step, rise)
    events = [(k, p.event) for k, p in enumerate(points) if p.event]
    assert [e for _, e in events] == ["limit", "limit"], events
    for k, _ in events:  # each limit point lies between the flagged point and the one before
        lo, hi = sorted(rises[k - 1 : k + 1])
        assert lo <= LIMIT_RISE <= hi or lo <= -LIMIT_RISE <= hi, (k, rises[k - 1 : k + 1])


@pytest.mark.parametrize("discretization", ["hermite", "bspline3"])
def test_arc_length_passes_both_limit_points_of_a_shallow_arch(comm, discretization):
    factors, rises, points = arch_path(comm, "arc_length", discretization)
    check_path(factors, rises, points)
    assert rises[-1] < -ARCH.initial_rise  # through the inverted equilibrium
    assert factors[rises > 0].max() < shallow_arch_load(LIMIT_RISE, ARCH.initial_rise) + TOLERANCE  # no overshoot


def test_displacement_control_follows_the_unstable_branch(comm):
    factors, rises, points = arch_path(comm, "displacement")
    np.testing.assert_allclose(rises[1:], ARCH.initial_rise * (1 - np.linspace(0, 2, 21)[1:]), atol=1e-9)
    check_path(factors, rises, points)


def test_load_control_stops_at_exactly_the_requested_levels(comm):
    factors, rises, points = arch_path(comm, "load")
    assert factors.tolist() == [0.0, *np.linspace(0.5, 5.5, 11).tolist()]
    assert np.abs(factors - shallow_arch_load(rises, ARCH.initial_rise)).max() < TOLERANCE
    assert all(p.negative_pivots == 0 and p.newton_iterations > 0 for p in points[1:])


def strip_path(comm, imperfection: float, method: str, step: float = 5e-4) -> list:
    strip = CompressedStrip(imperfection=imperfection)
    probes = [Probe("mid", 0.5, 0.025), Probe("end", 1.0, 0.025)]
    with ShellSolver(strip.model(16, comm)) as solver, PathFollower(solver, probes) as follower:
        if method == "displacement":
            follower.displacement_control("mid", 2, np.linspace(0.02, 0.3, 8))
        else:
            follower.arc_length(ArcLength(step, max_step=max(step, 2.5e-3), max_steps=80, load_factor_range=(-1, 1.16)))
        return follower.path


@pytest.mark.parametrize("method", ["displacement", "arc_length"])
def test_a_compressed_strip_follows_the_elastica_past_buckling(comm, method):
    """A bow of 1e-4 L carries the path onto the buckled branch; it lowers the load at deflection w
    by about w0 / w (Southwell), which the tolerance allows for."""
    imperfection = 1e-4
    points = strip_path(comm, imperfection, method)[1:]
    deflections = [p.probes["mid"]["displacement"][2] + imperfection for p in points]
    assert max(deflections) > 0.29
    for point, w in zip(points, deflections, strict=True):
        load, shortening = pinned_elastica(w)
        assert abs(point.load_factor / load - 1) < 1.5 * imperfection / w + 5e-4, (w, point.load_factor, load)
        assert abs(-point.probes["end"]["displacement"][0] - shortening) < 2e-4, (w, shortening)
        assert point.negative_pivots == 0 and not point.event


def test_a_straight_strip_flags_the_bifurcation_at_eulers_load(comm):
    points = strip_path(comm, 0.0, "arc_length", step=1e-6)
    events = [k for k, p in enumerate(points) if p.event]
    assert [points[k].event for k in events] == ["bifurcation"]
    k = events[0]
    assert points[k - 1].load_factor < 1.0 < points[k].load_factor
    assert [p.negative_pivots for p in points[k:]] == [1] * (len(points) - k)
    assert max(abs(p.probes["mid"]["displacement"][2]) for p in points) < 1e-12  # it stays straight


@pytest.mark.parallel
def test_two_ranks_follow_the_serial_path(comm):
    here = arch_path(comm, "displacement")
    serial = arch_path(MPI.COMM_SELF, "displacement")
    np.testing.assert_allclose(here[0], serial[0], rtol=0, atol=1e-9)
    assert [p.negative_pivots for p in here[2]] == [p.negative_pivots for p in serial[2]]


def test_a_step_that_cannot_converge_keeps_the_path_so_far(comm):
    from bhem_hpc.solver.path import PathError

    model = ARCH.model(8, comm)
    with ShellSolver(model, options={"snes_max_it": 3}) as solver, PathFollower(solver) as follower:
        with pytest.raises(PathError, match=r"path step 2 at load factor .* failed: load factor 9 not reached"):
            follower.load_control([1.0, 9.0], max_cuts=2)
        assert [p.load_factor for p in follower.path] == [0.0, 1.0]


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda f: f.arc_length(ArcLength(0.0)), r"arc_length.initial_step = 0.0 is invalid"),
        (lambda f: f.arc_length(ArcLength(1e-3, max_step=1e-4)), r"arc_length.max_step = 0.0001 is invalid"),
        (lambda f: f.arc_length(ArcLength(1e-3, direction=0)), r"arc_length.direction = 0 is invalid"),
        (lambda f: f.load_control([]), r"load levels must be a non-empty list"),
        (lambda f: f.load_control([1.0, float("nan")]), r"load levels must be a non-empty list of finite"),
        (lambda f: f.displacement_control("tip", 2, [0.1]), r"probe 'tip'; the probes are \['mid'\]"),
        (lambda f: f.displacement_control("mid", 3, [0.1]), r"component = 3"),
        (lambda f: f.displacement_control("mid", "w", [0.1]), r"component = 'w'; expected 'x', 'y', 'z' or 0, 1, 2"),
    ],
)
def test_bad_settings_are_refused_before_any_solve(comm, call, message):
    model = ARCH.model(4, comm)
    with ShellSolver(model) as solver, PathFollower(solver, [Probe("mid", *ARCH.midspan())]) as follower:
        with pytest.raises(PathSettingError, match=message):
            call(follower)
        assert len(follower.path) == 1


def test_a_probe_outside_the_parameter_domain_is_refused(comm):
    with ShellSolver(ARCH.model(4, comm)) as solver, pytest.raises(PathSettingError, match=r"probe 'far' .* outside"):
        PathFollower(solver, [Probe("far", 2.0, 0.0)])


def test_a_prescribed_end_rotation_rolls_a_strip_into_the_exact_circle_at_every_level(comm):
    """The free end's nodal vectors are turned about the y axis by 2 pi lambda (as a rotation, not
    a straight-line interpolation): pure bending, so at every level the strip is an arc of radius
    L / (2 pi lambda), at lambda = 1 a full circle whose end meets the clamp."""
    from bhem_hpc.geometry import surface as S
    from bhem_hpc.model import bcs
    from bhem_hpc.model.material import Material
    from bhem_hpc.model.shell import Loads, ShellModel

    length, width = 1.0, 0.05
    rest = S.flat_rectangle(length, width, 16, 1)
    end = bcs.edge_nodes(rest.grid, "xi1_max")
    model = ShellModel(rest, Material(1e7, 0.0, 0.01, 1.0), Loads(),
                       [bcs.clamp_edge(rest, "xi1_min"), bcs.NodalConstraint(end, (1, 3))], comm=comm)  # fmt: skip
    directors = rest.nodal[end[:, 0], end[:, 1]][:, [1, 3]]

    def turned(factor: float) -> np.ndarray:
        c, s = np.cos(2 * np.pi * factor), np.sin(2 * np.pi * factor)
        rotation = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
        return model.prescribed_values([bcs.NodalConstraint(end, (1, 3), (0, 1, 2), directors @ rotation.T)])

    stations = np.linspace(0.0, length, 9)
    probes = [Probe(f"s{k}", s, width / 2) for k, s in enumerate(stations)]
    with ShellSolver(model) as solver:
        solver.prescribed = turned
        with PathFollower(solver, probes) as follower:
            follower.load_control(np.arange(1, 9) / 8)
            points = follower.path[1:]
    for point in points:
        radius = length / (2 * np.pi * point.load_factor)
        for probe, s in zip(probes, stations, strict=True):
            exact = [radius * np.sin(s / radius), width / 2, radius * (1 - np.cos(s / radius))]
            assert np.linalg.norm(point.probes[probe.name]["position"] - exact) < 1e-4 * length, (point.step, s)
    assert np.linalg.norm(points[-1].probes["s8"]["position"] - [0.0, width / 2, 0.0]) < 1e-4  # closed


def test_an_edge_moment_rolls_a_strip_into_a_circle_at_every_level(comm):
    """A moment per width ``m = 2 pi lambda D / L`` at the free end: a uniform state along the strip,
    so a circular arc through the clamp, tangent to the strip there, at every level; its radius is
    ``D / m`` to the order ``(h kappa)^2`` of the shell's membrane-bending coupling (the
    bending measure ``b_11 = kappa a_11`` stretches the midsurface by about ``-(h kappa)^2 / 12``)."""
    from bhem_hpc.geometry import surface as S
    from bhem_hpc.model import bcs
    from bhem_hpc.model.material import Material
    from bhem_hpc.model.shell import EdgeMoment, Loads, ShellModel

    length, width, thickness, young = 1.0, 0.05, 0.01, 1e7
    bending = young * thickness**3 / 12
    rest = S.flat_rectangle(length, width, 16, 1)
    loads = Loads(edge_moments=(EdgeMoment("xi1_max", 2 * np.pi * bending / length),))
    model = ShellModel(rest, Material(young, 0.0, thickness, 1.0), loads, [bcs.clamp_edge(rest, "xi1_min")], comm=comm)
    stations = np.linspace(0.0, length, 9)[1:]
    with ShellSolver(model) as solver:
        probes = [Probe(f"s{k}", s, width / 2) for k, s in enumerate(stations)]
        with PathFollower(solver, probes) as follower:
            follower.load_control(np.arange(1, 9) / 8)
            points = follower.path[1:]
    for point in points:
        positions = np.array([point.probes[p.name]["position"] for p in probes])
        x, z = positions[:, 0], positions[:, 2]
        radius = np.sum(z * (x**2 + z**2)) / (2 * np.sum(z**2))  # circle through 0, tangent to x there
        exact = length / (2 * np.pi * point.load_factor)
        deviation = np.abs(np.hypot(x, z - radius) - radius).max()
        assert deviation < 1e-4 * radius, point.load_factor  # one circle, to the cubic patches' (h kappa)^4 / 384
        assert abs(radius / exact - 1) < 1.5e-3, (point.load_factor, radius, exact)
        np.testing.assert_allclose(positions[:, 1], width / 2, atol=1e-12)  # in its plane
    assert np.hypot(*positions[-1][[0, 2]]) < 1e-3 * length  # at lambda = 1 the end meets the clamp
    assert not model.symmetric and points[-1].negative_pivots == -1  # a follower axis: LU, inertia unknown


def panel_landmarks(comm, patches: int) -> dict[str, float]:
    """The thin cylindrical panel's path by arc length, reduced to its landmarks."""
    from bhem_hpc.studies.paths import CylindricalPanel, snap_landmarks

    settings = ArcLength(0.1, max_step=0.1, max_steps=200, load_factor_range=(-2.0, 1.0))
    points = CylindricalPanel().follow(patches, settings, comm)
    assert [p.event for p in points if p.event] == ["limit", "limit"]
    factors = [p.load_factor for p in points]
    return snap_landmarks(factors, [-p.probes["centre"]["displacement"][1] for p in points])


def test_a_thin_cylindrical_panel_snaps_through_and_back_as_on_a_finer_mesh(comm):
    """Arc length passes the limit point and follows the snap-back (the centre deflection turns back
    by about 2.5 mm while the load is negative) on 8 x 8 patches of the quarter; the same landmarks
    on 16 x 16 are the reference (24 x 24 changes them by < 1e-4). Tolerances: about 3 times the
    8-against-16 differences measured."""
    coarse, fine = panel_landmarks(comm, 8), panel_landmarks(comm, 16)
    tolerances = {"limit load": 3e-4, "lowest load": 2e-4, "turning deflection": 3e-4, "snap-back deflection": 2e-3}
    for name, tolerance in tolerances.items():
        assert abs(coarse[name] / fine[name] - 1) < tolerance, (name, coarse[name], fine[name])
    assert fine["limit load"] > 0 > fine["lowest load"]
    assert fine["turning deflection"] - fine["snap-back deflection"] > 2.0  # mm: a snap-back


def test_displacement_control_cuts_back_a_step_that_jumps_past_a_snap_back_and_then_fails(comm):
    """The thin panel's centre deflection turns back at about 17.1 mm (the snap-back): the step from
    17.0 to 17.25 mm converges only on the branch after it (at a negative load). It is cut back,
    never accepted: the path stops at 17.0 mm with an error that names the jump and arc length."""
    from bhem_hpc.solver.path import PathError
    from bhem_hpc.studies.paths import CylindricalPanel

    panel = CylindricalPanel()
    with ShellSolver(panel.model(8, comm)) as solver:
        with PathFollower(solver, [Probe("centre", *panel.centre())]) as follower:
            with pytest.raises(PathError, match=r"-17.25 not reached .*jumped to another branch.*arc length"):
                follower.displacement_control("centre", 1, -np.arange(0.25, 20.01, 0.25), max_cuts=4)
            deflections = [-p.probes["centre"]["displacement"][1] for p in follower.path]
            factors = [p.load_factor for p in follower.path]
    assert deflections[-1] == pytest.approx(17.0, abs=1e-9) and len(deflections) == 69
    assert min(factors[1:]) > 0  # every accepted point on the loaded branch before the snap-back


def test_loads_change_through_the_api_and_the_solve_continues(comm):
    """set_load on a point load and an area load: the next solve, from the current state, lands where
    a model built with the new loads lands; the DOF count and displacement accessors."""
    from bhem_hpc.geometry import surface as S
    from bhem_hpc.model import bcs
    from bhem_hpc.model.material import Material
    from bhem_hpc.model.shell import AreaLoad, Loads, ModelError, PointLoad, ShellModel

    rest = S.flat_rectangle(1.0, 0.1, 8, 1)

    def cantilever(force, pressure):
        loads = Loads(point_loads=(PointLoad(1.0, 0.05, force),), area_loads=(AreaLoad(pressure),))
        return ShellModel(rest, Material(1e6, 0.0, 0.01, 1.0), loads, [bcs.clamp_edge(rest, "xi1_min")], comm=comm)

    model = cantilever((0.0, 0.0, -1e-4), (0.0, 0.0, 0.0))
    assert model.num_dofs == 3 * 4 * 9 * 2 and model.load_names() == ["point_load_0", "area_load_0"]
    with ShellSolver(model) as solver:
        solver.solve()
        first = model.displacement(1.0, 0.05)
        model.set_load("point_load_0", (0.0, 0.0, -3e-4))
        model.set_load("area_load_0", (0.0, 0.0, -1e-3))
        assert solver.solve_at(1.0)  # from the current state
        changed = model.displacement(1.0, 0.05)
    with ShellSolver(fresh := cantilever((0.0, 0.0, -3e-4), (0.0, 0.0, -1e-3))) as solver:
        solver.solve()
    np.testing.assert_allclose(changed, fresh.displacement(1.0, 0.05), rtol=1e-8, atol=1e-14)
    assert first[2] < 0 and changed[2] < 2 * first[2]
    with pytest.raises(ModelError, match=r"load 'point_load_1' does not exist"):
        model.set_load("point_load_1", (0.0, 0.0, 1.0))
    with pytest.raises(ModelError, match=r"load 'point_load_0' must be 3 numbers"):
        model.set_load("point_load_0", 1.0)
