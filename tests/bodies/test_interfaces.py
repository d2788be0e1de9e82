"""Shells of several patches joined along interfaces by the penalty coupling: its derivatives are
the slopes of its energy, rigid motions and constant strain cost nothing, and joined patches give
what one patch gives (a cantilever cut in two, the Scordelis-Lo roof in two halves) or, at a kink,
what beam theory gives for a folded plate, keeping the fold's angle."""

from __future__ import annotations

import numpy as np
import pytest

from bhem_hpc.bodies.coupling import (
    DEFAULT_PENALTY,
    TANGENT_SLOTS,
    InterfaceCoupling,
    angle_residual,
    penalty_stiffness,
    rest_angles,
    rest_frames,
)
from bhem_hpc.bodies.petsc import StackedBlocks
from bhem_hpc.geometry import bspline as B
from bhem_hpc.geometry import surface as S
from bhem_hpc.geometry.grid import ParameterGrid
from bhem_hpc.geometry.interfaces import InterfaceError, element_across, pair_edges
from bhem_hpc.model import bcs
from bhem_hpc.model.loads import AreaLoad, LineLoad, Loads, PointLoad
from bhem_hpc.model.material import Material
from bhem_hpc.model.shell import ShellModel
from bhem_hpc.solver import ShellSolver
from bhem_hpc.studies.references import ROOF_DEFLECTION

DEG = np.pi / 180


def _frames(rng: np.random.Generator, k: int = 4) -> np.ndarray:
    return rng.normal(size=(k, 6, 3))


def _coupling_energy(frames, along, rest, offset, weights, stiffness, stitch_scale=None) -> float:
    """The module's energy written out: a joint's (``stitch_scale`` None) or a seam's."""
    scale = 1.0 if stitch_scale is None else stitch_scale
    stretch = np.sum((frames[:, 0] - frames[:, 3] - scale * offset) ** 2, 1)
    r, _ = angle_residual(frames, along, rest)
    return float(0.5 * np.sum(weights * (stiffness[0] * stretch + stiffness[1] * np.sum(r * r, 1))))


def _central_slopes(function, frames: np.ndarray, eps: float = 1e-6):
    """``((slot, component), slope)`` of ``function`` along each slot's component of every point
    at once, by central differences."""
    for slot in range(6):
        for c in range(3):
            step = np.zeros_like(frames)
            step[:, slot, c] = eps
            yield (slot, c), (function(frames + step) - function(frames - step)) / (2 * eps)


class _Slots:
    """The coupling's slot-level energy, gradient and Hessian for frames given directly."""

    def __init__(self, rest_frames_: np.ndarray, along: int, stiffness=(3.0, 2.0), stitch_scale=None):
        self.along, self.stiffness, self.stitch_scale = along, stiffness, stitch_scale
        self.rest = rest_angles(rest_frames_, along)
        self.offset = rest_frames_[:, 0] - rest_frames_[:, 3]
        self.weights = np.linspace(0.5, 1.5, len(rest_frames_))
        coupling = object.__new__(InterfaceCoupling)  # its slot methods need these attributes only
        coupling.along, coupling.rest, coupling.rest_offset, coupling.weights = (
            along,
            self.rest,
            self.offset,
            self.weights,
        )
        coupling.displacement_stiffness, coupling.rotation_stiffness = stiffness
        coupling.sewing_time = None if stitch_scale is None else 1.0
        coupling.stitch_scale = 1.0 if stitch_scale is None else stitch_scale
        self.coupling = coupling

    def energy(self, frames):
        return _coupling_energy(frames, self.along, self.rest, self.offset, self.weights, self.stiffness,
                                self.stitch_scale)  # fmt: skip


@pytest.mark.parametrize(("seed", "along", "stitch_scale"),
                         [(0, 0, None), (1, 1, None), (2, 0, 0.5), (3, 1, 0.0), (4, "curve", None)])  # fmt: skip
def test_the_couplings_gradient_and_angle_jacobian_are_the_slopes_of_its_energy_and_residual(seed, along,
                                                                                            stitch_scale):  # fmt: skip
    """A joint and a seam (stitches at half their rest length, and sewn); a joint along a curve
    (a trim curve: each point's own direction in the first patch's parameters)."""
    rng = np.random.default_rng(seed)
    if along == "curve":
        along = rng.normal(size=(4, 2))
    rest = _frames(rng)
    slots = _Slots(rest, along, stitch_scale=stitch_scale)
    frames = rest + 0.2 * rng.normal(size=rest.shape)
    r, jacobian = angle_residual(frames, along, slots.rest)
    gradient = slots.coupling.slot_gradients(frames)
    for (slot, c), slope in _central_slopes(slots.energy, frames):
        assert abs(slope - gradient[:, slot, c].sum()) <= 1e-6 * max(1.0, abs(slope))
    for (slot, c), slope in _central_slopes(lambda f: angle_residual(f, along, slots.rest)[0], frames):
        if slot in TANGENT_SLOTS:
            np.testing.assert_allclose(jacobian[:, TANGENT_SLOTS.index(slot), :, c], slope, atol=1e-7)
    assert np.abs(angle_residual(rest, along, slots.rest)[0]).max() < 1e-14


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.linalg.det(q)  # a proper rotation: det +1


@pytest.mark.parametrize("seed", range(3))
def test_rigid_motions_and_constant_strain_cost_nothing_and_the_hessian_is_exact_there(seed):
    """A fold of angle f0 along x between two flat strips: rotating and moving it rigidly, or
    stretching both sides alike in the plane of one of them, leaves energy and gradient zero; there
    the Gauss-Newton Hessian is the gradient's slope, and it is positive semi-definite anywhere."""
    rng = np.random.default_rng(seed)
    fold = rng.uniform(20, 160) * DEG
    k = 3
    x = np.stack([rng.uniform(0, 1, k), np.zeros(k), np.zeros(k)], axis=1)
    a_along, a_across = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    b_across = np.array([0.0, np.cos(fold), np.sin(fold)])
    rest = np.stack([x, np.tile(a_along, (k, 1)), np.tile(a_across, (k, 1)), x, np.tile(a_along, (k, 1)),
                     np.tile(-b_across, (k, 1))], axis=1)  # fmt: skip
    slots = _Slots(rest, along=0)
    rotation, shift = _rotation(rng), rng.normal(size=3)
    moved = rest @ rotation.T
    moved[:, (0, 3)] += shift
    stretch = np.diag([1.2, 1.0, 1.0])  # along the fold: both sides alike
    strained = rest @ stretch.T
    for frames in (moved, strained):
        assert slots.energy(frames) < 1e-24
        assert np.abs(slots.coupling.slot_gradients(frames)).max() < 1e-12
        hessian = slots.coupling.slot_hessians(frames)
        for (slot, c), slope in _central_slopes(slots.coupling.slot_gradients, frames):
            np.testing.assert_allclose(hessian[:, :, slot, :, c], slope, atol=1e-6)
    anywhere = rest + 0.3 * rng.normal(size=rest.shape)
    matrices = slots.coupling.slot_hessians(anywhere).transpose(0, 1, 3, 2, 4).reshape(k, 18, 18)
    assert np.linalg.eigvalsh(matrices).min() > -1e-10 * np.abs(matrices).max()


def _strip(discretization: str, position, grid: ParameterGrid):
    if discretization == "hermite":
        return S.from_callable(position, grid)
    return B.from_callable(position, grid, degree=int(discretization[-1]))


def _plane(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.stack([u, v, 0 * u], -1)


def _flat(discretization: str, x0: float, x1: float, spans: int, width: float):
    return _strip(discretization, _plane, ParameterGrid(spans, 2, (x0, x1), (0.0, width), False, False))


def _joined(comm, models, rests, edges, element: float, material: Material, factor: float = DEFAULT_PENALTY):
    """Solve the statics of two patches joined along ``edges``."""
    quadrature = pair_edges(rests[0], edges[0], rests[1], edges[1], 1e-8)
    stiffness = penalty_stiffness(material.young, material.poisson, material.thickness, element, factor)
    coupling = InterfaceCoupling(StackedBlocks(models), (0, 1), quadrature, rest_frames(*rests, quadrature), stiffness)
    with ShellSolver(models, contributions=[coupling]) as solver:
        solver.solve()
    return coupling


@pytest.mark.parametrize("discretization", ["hermite", "bspline3"])
def test_a_cantilever_cut_in_two_patches_bends_as_one_patch_and_the_penalty_does_not_lock(comm, discretization):
    """A steel strip clamped at one end under an end load, as one patch and as two joined halves:
    the tip deflections differ by the penalty's compliance, which falls as 1/alpha towards the one
    patch's (no locking at large alpha)."""
    length, width, spans = 1.0, 0.2, 4
    material = Material(2.0e11, 0.3, 0.01, 7800.0)
    load = Loads(line_loads=(LineLoad("xi1_max", (0.0, 0.0, -5.0)),))
    at = (np.array(length), np.array(width / 2))
    whole = _flat(discretization, 0.0, length, 2 * spans, width)
    one = ShellModel(whole, material, load, [bcs.clamp_edge(whole, "xi1_min")], comm=comm)
    with ShellSolver(one) as solver:
        solver.solve()
    expected = one.state_surface().evaluate(*at).x[2]
    errors = []
    for factor in (1e2, 1e3, 1e4):
        rests = [_flat(discretization, 0.0, length / 2, spans, width), _flat(discretization, length / 2, length, spans,
                                                                             width)]  # fmt: skip
        models = [ShellModel(rests[0], material, Loads(), [bcs.clamp_edge(rests[0], "xi1_min")], comm=comm),
                  ShellModel(rests[1], material, load, [], comm=comm)]  # fmt: skip
        _joined(comm, models, rests, ("xi1_max", "xi1_min"), length / (2 * spans), material, factor)
        errors.append(abs(models[1].state_surface().evaluate(*at).x[2] / expected - 1))
    assert errors[1] < 2e-4, errors  # the default alpha: well inside the discretization error
    if discretization == "hermite":  # joined C1 halves span the one patch's C1 space: the gap is the penalty's
        assert 8 < errors[0] / errors[1] < 12 and 8 < errors[1] / errors[2] < 12, errors
    else:  # C1 halves span more than the one C2 patch: the gap falls to that difference, not below
        assert errors[0] > errors[1] > errors[2], errors


def test_joined_patches_a_kilometre_from_the_origin_bend_as_at_the_origin(comm):
    """The steel cantilever cut in two, 1 km from the origin: the positions' round-off, 1e3 times
    that at the origin, times the joint's penalty is a residual floor above the solver's absolute
    tolerance (without the energy's stopping rule the solve failed after ten halvings of the load);
    Newton stops once a step would lower the energy by less than its round-off, with the tip
    deflection of the cantilever at the origin within 2e-5 (measured 4e-6: the state is resolved
    to the precision the positions' round-off leaves a system this stiff)."""
    length, width, spans = 1.0, 0.2, 4
    material = Material(2.0e11, 0.3, 0.01, 7800.0)
    load = Loads(line_loads=(LineLoad("xi1_max", (0.0, 0.0, -5.0)),))
    tips = []
    for offset in (0.0, 1.0e3):

        def plane(u, v, offset=offset):
            return np.stack([u + offset, v + offset, 0 * u + offset], -1)

        rests = [S.from_callable(plane, ParameterGrid(spans, 2, (x0, x0 + length / 2), (0.0, width), False, False))
                 for x0 in (0.0, length / 2)]  # fmt: skip
        models = [ShellModel(rests[0], material, Loads(), [bcs.clamp_edge(rests[0], "xi1_min")], comm=comm),
                  ShellModel(rests[1], material, load, [], comm=comm)]  # fmt: skip
        _joined(comm, models, rests, ("xi1_max", "xi1_min"), length / (2 * spans), material)
        tips.append(models[1].state_surface().evaluate(np.array(length), np.array(width / 2)).x[2] - offset)
    assert tips[0] < -5e-5
    assert abs(tips[1] / tips[0] - 1) < 2e-5, tips


def test_non_matching_patches_of_two_discretizations_join_as_well(comm):
    """A Hermite half of 4 x 2 spans joined to a cubic B-spline half of 6 x 3 spans (the interface's
    knots do not match): the end load's tip deflection is the one Hermite patch's within 2e-4 (both
    spaces hold the cantilever's cubic deflection exactly)."""
    length, width = 1.0, 0.2
    material = Material(2.0e11, 0.3, 0.01, 7800.0)
    load = Loads(line_loads=(LineLoad("xi1_max", (0.0, 0.0, -5.0)),))
    whole = _flat("hermite", 0.0, length, 8, width)
    one = ShellModel(whole, material, load, [bcs.clamp_edge(whole, "xi1_min")], comm=comm)
    with ShellSolver(one) as solver:
        solver.solve()
    at = (np.array(length), np.array(width / 2))
    halves = (ParameterGrid(4, 2, (0.0, length / 2), (0.0, width), False, False),
              ParameterGrid(6, 3, (length / 2, length), (0.0, width), False, False))  # fmt: skip
    rests = [_strip("hermite", _plane, halves[0]), _strip("bspline3", _plane, halves[1])]
    models = [ShellModel(rests[0], material, Loads(), [bcs.clamp_edge(rests[0], "xi1_min")], comm=comm),
              ShellModel(rests[1], material, load, [], comm=comm)]  # fmt: skip
    coupling = _joined(comm, models, rests, ("xi1_max", "xi1_min"), length / 12, material)
    assert len(coupling.weights) == 4 * 4  # Gauss points in the 4 pieces between the two sides' knots (2 and 3 spans)
    tip, expected = models[1].state_surface().evaluate(*at).x[2], one.state_surface().evaluate(*at).x[2]
    assert abs(tip / expected - 1) < 2e-4, (tip, expected)


def test_a_uniform_stretch_passes_the_interface_with_the_penalty_compliance_as_its_only_error(comm):
    """Patch test across a non-matching interface (Hermite 3 x 2 spans beside cubic B-splines 4 x 3):
    a strip pulled by a uniform traction T at one end, held at the other only along the pull (and
    one corner across it). Each patch stretches exactly uniformly (``sigma x / E`` along,
    ``-nu sigma y / E`` across, to 1e-5 of the end's displacement); the far patch is shifted by the
    joint's compliance ``T / a_d`` (within 1 %): a penalty joint is not variationally consistent,
    its one error falls as 1/alpha (1.1e-4 of the stretch at the default)."""
    length, width, traction = 1.0, 0.2, 2.0e3  # [N/m] on a 1 cm steel strip: strain 1e-6, so linear
    material = Material(2.0e11, 0.3, 0.01, 7800.0)
    halves = (ParameterGrid(3, 2, (0.0, length / 2), (0.0, width), False, False),
              ParameterGrid(4, 3, (length / 2, length), (0.0, width), False, False))  # fmt: skip
    rests = [_strip("hermite", _plane, halves[0]), _strip("bspline3", _plane, halves[1])]
    held = bcs.edge_nodes(rests[0].grid, "xi1_min", rests[0].node_shape)
    # positions and their slopes along the edge (x and z): the edge stays straight, free to contract
    supports = [bcs.NodalConstraint(held, (0, 2), (0, 2)), bcs.NodalConstraint(held[:1], (0,), (1,))]
    models = [ShellModel(rests[0], material, Loads(), supports, comm=comm),
              ShellModel(rests[1], material, Loads(line_loads=(LineLoad("xi1_max", (traction, 0.0, 0.0)),)), [],
                         comm=comm)]  # fmt: skip
    element = length / 8
    coupling = _joined(comm, models, rests, ("xi1_max", "xi1_min"), element, material)
    strain = traction / (material.young * material.thickness)
    offsets = []
    for model, rest in zip(models, rests, strict=True):
        x1, x2 = np.meshgrid(np.linspace(*rest.grid.xi1_range, 5), np.linspace(0.0, width, 4), indexing="ij")
        moved = model.state_surface().evaluate(x1, x2).x - rest.evaluate(x1, x2).x
        error = (moved - np.stack([strain * x1, -material.poisson * strain * x2, 0 * x1], -1)).reshape(-1, 3)
        offsets.append(error.mean(axis=0))
        assert np.abs(error - offsets[-1]).max() < 1e-5 * strain * length
    jump = offsets[1] - offsets[0]
    assert abs(jump[0] / (traction / coupling.displacement_stiffness) - 1) < 0.01, jump
    assert abs(jump[0]) / (strain * length) < 2e-4 and np.abs(jump[1:]).max() < 1e-5 * strain * length


def _folded_plate(comm, discretization: str, load: float, load_steps: int = 1):
    """A steel plate clamped at x = 0, flat to x = a, folded up at right angles there to height b,
    loaded along its free edge by ``load`` [N] along +x: tip displacement, the angle between the
    normals across the fold and the fold's rotation [rad]."""
    a, b, width, spans = 0.5, 0.3, 0.1, 4
    material = Material(2.0e11, 0.0, 0.005, 7800.0)
    rests = [_strip(discretization, lambda u, v: np.stack([u, v, 0 * u], -1),
                    ParameterGrid(spans, 2, (0, a), (0, width), False, False)),
             _strip(discretization, lambda u, v: np.stack([a + 0 * u, v, u], -1),
                    ParameterGrid(spans, 2, (0, b), (0, width), False, False))]  # fmt: skip
    models = [ShellModel(rests[0], material, Loads(), [bcs.clamp_edge(rests[0], "xi1_min")], comm=comm),
              ShellModel(rests[1], material, Loads(line_loads=(LineLoad("xi1_max", (load / width, 0.0, 0.0)),)), [],
                         comm=comm)]  # fmt: skip
    quadrature = pair_edges(rests[0], "xi1_max", rests[1], "xi1_min", 1e-8)
    stiffness = penalty_stiffness(material.young, 0.0, material.thickness, min(a, b) / spans)
    coupling = InterfaceCoupling(StackedBlocks(models), (0, 1), quadrature, rest_frames(*rests, quadrature), stiffness)
    with ShellSolver(models, contributions=[coupling]) as solver:
        solver.solve(load_steps=load_steps)
    middle = np.array(width / 2)
    tip = models[1].state_surface().evaluate(np.array(b), middle).x - rests[1].evaluate(np.array(b), middle).x
    flat_side = models[0].state_surface().evaluate(np.array(a), middle).normal
    folded_side = models[1].state_surface().evaluate(np.array(0.0), middle).normal
    angle = np.arccos(np.clip(np.dot(flat_side, folded_side), -1, 1))
    return tip, angle, np.arccos(abs(flat_side[2])), (a, b, material.young * width * material.thickness**3 / 12)


@pytest.mark.parametrize(("discretization", "tolerance"), [("hermite", 3e-4), ("bspline3", 3e-4), ("bspline2", 5e-3)])
def test_a_folded_plate_bends_as_a_rigid_jointed_frame_and_keeps_its_fold_angle(comm, discretization, tolerance):
    """Small load: the L-frame of beam theory with a rigid joint (nu = 0, so the plate is a beam):
    tip sway ``P b^3 / 3EI + P a b^2 / EI``, drop ``P b a^2 / 2EI``. Large load (the fold turns by
    about 40 degrees): the angle between the sides stays 90 degrees within 0.02 degrees."""
    load = 0.01
    tip, angle, _, (a, b, bending) = _folded_plate(comm, discretization, load)
    sway, drop = load * b**3 / (3 * bending) + load * a * b**2 / bending, load * b * a**2 / (2 * bending)
    assert abs(tip[0] / sway - 1) < tolerance, (tip, sway)
    assert abs(-tip[2] / drop - 1) < tolerance, (tip, drop)
    assert abs(angle - np.pi / 2) < 1e-6
    if discretization == "hermite":
        tip, angle, turn, _ = _folded_plate(comm, discretization, 5000.0, load_steps=5)
        assert turn > 35 * DEG and abs(angle - np.pi / 2) < 0.02 * DEG, (turn, angle)


#: Scordelis-Lo roof, Kirchhoff-Love theory: midside deflection of the free edge (Kiendl et al. 2009).


def _patch_grid(position, ranges, splits: tuple[int, int], spans: tuple[int, int]):
    """Hermite patches ``splits[0] x splits[1]`` of ``position`` over the parameter ``ranges``,
    ``spans`` in all, and the joints between neighbours ``(a, b, edge of a, edge of b)``."""
    b1, b2 = (np.linspace(*r, n + 1) for r, n in zip(ranges, splits, strict=True))
    rests = {(i, j): S.from_callable(position, ParameterGrid(spans[0] // splits[0], spans[1] // splits[1],
                                                             (b1[i], b1[i + 1]), (b2[j], b2[j + 1]), False, False))
             for i in range(splits[0]) for j in range(splits[1])}  # fmt: skip
    joints = [((i, j), (i + 1, j), "xi1_max", "xi1_min") for i in range(splits[0] - 1) for j in range(splits[1])]
    joints += [((i, j), (i, j + 1), "xi2_max", "xi2_min") for i in range(splits[0]) for j in range(splits[1] - 1)]
    return rests, joints


def _solve_patches(comm, rests: dict, joints: list, material: Material, loads_of, supports_of) -> dict:
    """The statics of the patches joined at their joints (element size: the narrower side's)."""
    keys = list(rests)
    models = [ShellModel(rests[k], material, loads_of(k), supports_of(k, rests[k]), comm=comm) for k in keys]
    blocks = StackedBlocks(models)
    couplings = []
    for a, b, edge_a, edge_b in joints:
        quadrature = pair_edges(rests[a], edge_a, rests[b], edge_b, 1e-8)
        element = min(element_across(rests[a], edge_a), element_across(rests[b], edge_b))
        stiffness = penalty_stiffness(material.young, material.poisson, material.thickness, element)
        couplings.append(InterfaceCoupling(blocks, (keys.index(a), keys.index(b)), quadrature,
                                           rest_frames(rests[a], rests[b], quadrature), stiffness))  # fmt: skip
    with ShellSolver(models, contributions=couplings) as solver:
        solver.solve()
    return dict(zip(keys, models, strict=True))


@pytest.mark.parametrize(("splits", "spans"), [((1, 2), (16, 16)), ((1, 3), (16, 15)), ((2, 2), (16, 16))])
def test_the_scordelis_lo_roof_in_two_three_and_four_patches_gives_the_one_patch_value(comm, splits, spans):
    """The roof (R 25, L 50, 80 degrees, h 0.25, E 4.32e8, nu 0, self-weight 90 per area) as 2, 3
    and 4 Hermite patches (2 x 2, four joints meeting at a point): the free edge's midside deflection is the one
    patch's of the same spans within 3e-4 (measured at most 1e-4), and the reference within 5e-3."""
    radius, load = 25.0, 0.09
    material = Material(4.32e8, 0.0, 0.25, 1.0)

    def roof(z, angle):
        return np.stack([radius * np.cos(angle), radius * np.sin(angle), z], -1)

    def deflection(split: tuple[int, int]) -> float:
        rests, joints = _patch_grid(roof, ((0.0, 50.0), (50 * DEG, 130 * DEG)), split, spans)

        def supports(k, rest):
            ends = [edge for edge, end in (("xi1_min", 0), ("xi1_max", split[0] - 1)) if k[0] == end]
            return [bcs.diaphragm_edge(rest, edge, "z") for edge in ends]

        weight = Loads(area_loads=(AreaLoad((0.0, -load, 0.0)),))
        models = _solve_patches(comm, rests, joints, material, lambda k: weight, supports)
        k, at = (split[0] // 2, 0), (np.array(25.0), np.array(50 * DEG))  # the patch holding the midside point
        return float(models[k].state_surface().evaluate(*at).x[1] - rests[k].evaluate(*at).x[1]) * 90.0 / load

    one, joined = deflection((1, 1)), deflection(splits)
    assert abs(joined / one - 1) < 3e-4, (joined, one)
    assert abs(-joined / ROOF_DEFLECTION - 1) < 5e-3, joined


@pytest.mark.parametrize(("splits", "spans"), [((1, 2), (16, 16)), ((3, 1), (15, 16)), ((2, 2), (16, 16))])
def test_the_pinched_hemisphere_in_two_three_and_four_patches_gives_the_one_patch_value(comm, splits, spans):
    """The quarter of the pinched hemisphere with an 18-degree hole (R 10, h 0.04, E 6.825e7,
    nu 0.3; unit loads in and out at the equator, symmetry planes) as 2, 3 and 4 (2 x 2) Hermite patches:
    the loaded point's radial displacement per unit load is the one patch's of the same spans
    within 1e-3 (measured at most 6e-5; one patch of 16 x 16 gives 0.0934, 24 x 24 0.0935)."""
    radius, force = 10.0, 1e-3
    material = Material(6.825e7, 0.3, 0.04, 1.0)

    def hemisphere(polar, azimuth):
        return radius * np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)], -1)

    def displacement(split: tuple[int, int]) -> float:
        rests, joints = _patch_grid(hemisphere, ((18 * DEG, 90 * DEG), (0.0, 90 * DEG)), split, spans)
        last1, last2 = split[0] - 1, split[1] - 1

        def supports(k, rest):
            held = [*bcs.symmetry_edge(rest, "xi2_min", "y")] if k[1] == 0 else []
            held += [*bcs.symmetry_edge(rest, "xi2_max", "x")] if k[1] == last2 else []
            if k == (0, 0):  # the one free rigid motion: along the axis
                held.append(bcs.NodalConstraint(np.array([[0, 0]]), (0,), (2,)))
            return held

        def loads(k):
            out = [PointLoad(90 * DEG, 0.0, (force, 0.0, 0.0))] if k == (last1, 0) else []
            out += [PointLoad(90 * DEG, 90 * DEG, (0.0, -force, 0.0))] if k == (last1, last2) else []
            return Loads(point_loads=tuple(out))

        models = _solve_patches(comm, rests, joints, material, loads, supports)
        at = (np.array(90 * DEG), np.array(0.0))
        return float(models[last1, 0].state_surface().evaluate(*at).x[0] - rests[last1, 0].evaluate(*at).x[0]) / force

    one, joined = displacement((1, 1)), displacement(splits)
    assert abs(joined / one - 1) < 1e-3, (joined, one)
    assert 0.092 < one < 0.095


def test_edges_that_do_not_meet_are_refused_naming_the_edges_and_the_gap():
    left, right = _flat("hermite", 0.0, 0.5, 2, 0.2), _flat("hermite", 0.5, 1.0, 2, 0.2)
    apart = _flat("hermite", 0.51, 1.0, 2, 0.2)
    assert pair_edges(left, "xi1_max", right, "xi1_min", 1e-9).gap < 1e-12
    assert pair_edges(left, "xi1_max", right, "xi1_min", 1e-9).weights.sum() == pytest.approx(0.2, rel=1e-12)
    with pytest.raises(InterfaceError, match=r"edge xi1_max of the first patch and edge xi1_min .* 0\.01 m"):
        pair_edges(left, "xi1_max", apart, "xi1_min", 1e-3)
    with pytest.raises(InterfaceError, match=r"edge xi2_min of the first patch and edge xi1_min"):
        pair_edges(left, "xi2_min", right, "xi1_min", 1e-3)
    with pytest.raises(InterfaceError, match="edge 'xi3_max' does not exist"):
        pair_edges(left, "xi3_max", right, "xi1_min", 1e-3)
    tube = S.cylinder(1.0, 1.0, 2, 8)
    with pytest.raises(InterfaceError, match="closed in xi2"):
        pair_edges(tube, "xi2_min", right, "xi1_min", 1e-3)
