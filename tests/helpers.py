"""Helpers shared by the tests: assembly and gathering (tests may use PETSc directly), random rotations,
ray-triangle references, import checks, a small scene."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import dolfinx.fem as fem
import dolfinx.fem.petsc as fem_petsc
import h5py
import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from bhem_hpc.model.shell import ShellModel

#: The repository (jobs/, meshes/, docs/ beside tests/).
REPO = Path(__file__).resolve().parents[1]
#: The line a cold form cache logs when a command compiles its kernels (INFO).
JIT_LOG_LINE = re.compile(r"^\[rank \d+\] INFO bhem_hpc\.jit: ")


def write_scene(comm, path: Path, text: str) -> Path:
    """Collective: rank 0 writes ``text`` to ``path``; every rank returns ``path`` once it exists."""
    if comm.rank == 0:
        path.write_text(text)
    comm.Barrier()
    return path


def message_lines(stderr: str) -> list[str]:
    """A command's standard error without blank lines and the form compiler's log line: what it says."""
    return [line for line in stderr.splitlines() if line.strip() and not JIT_LOG_LINE.match(line)]


def total_internal_energy(model: ShellModel) -> float:
    e = model.energies()
    return e["membrane"] + e["bending"]


def potential(model: ShellModel) -> float:
    return model.comm.allreduce(fem.assemble_scalar(model.potential_form), op=MPI.SUM)


def residual_open(model: ShellModel) -> np.ndarray:
    """Global open-layout residual gathered on every rank, indexed by global DOF."""
    vec = fem_petsc.assemble_vector(model.residual_form)
    vec.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    out = gather(vec)
    vec.destroy()
    return out


def gather(vec: PETSc.Vec) -> np.ndarray:
    """Owned entries of every rank, concatenated in global order."""
    comm = vec.getComm().tompi4py()
    return np.concatenate(comm.allgather(vec.array_r.copy()))


def jacobian_dense(model: ShellModel, form=None) -> np.ndarray:
    """The global open-layout Jacobian (or another bilinear form) as a dense array."""
    mat = fem_petsc.assemble_matrix(form or model.jacobian_form)
    mat.assemble()
    dense = gather_matrix(mat)
    mat.destroy()
    return dense


def gather_matrix(mat: PETSc.Mat) -> np.ndarray:
    comm = mat.getComm().tompi4py()
    indptr, indices, values = mat.getValuesCSR()
    first, last = mat.getOwnershipRange()
    rows = np.zeros((last - first, mat.getSize()[1]))
    for r in range(last - first):
        rows[r, indices[indptr[r] : indptr[r + 1]]] = values[indptr[r] : indptr[r + 1]]
    return np.vstack(comm.allgather(rows))


def open_state_global(model: ShellModel) -> np.ndarray:
    return gather(model.x.vector)


def set_open_state_global(model: ShellModel, values: np.ndarray) -> None:
    """Set the state from a global open-layout array (owned part, then ghosts)."""
    vec = model.x.vector
    first, last = vec.getOwnershipRange()
    vec.array[:] = values[first:last]
    vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random proper rotation (QR of a Gaussian matrix, signs fixed)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def ray_triangle_distances(origin: np.ndarray, direction: np.ndarray, p0, p1, p2, slack: float = 0.0) -> np.ndarray:
    """Moller-Trumbore for one ray against triangles ``(T, 3)`` each; ``tau`` or ``inf`` per triangle.

    ``slack`` widens the barycentric test (to catch hits on shared edges).
    """
    e1, e2 = p1 - p0, p2 - p0
    s = origin - p0
    h = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, h)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = 1.0 / det
        u = f * np.einsum("ij,ij->i", s, h)
        q = np.cross(s, e1)
        v = f * (q @ direction)
        t = f * np.einsum("ij,ij->i", e2, q)
    ok = (np.abs(det) > 1e-15) & (u >= -slack) & (v >= -slack) & (u + v <= 1 + slack) & (t > 0)
    return np.where(ok, t, np.inf)


def assert_imports_without(module: str, heavy=("dolfinx", "petsc4py", "mpi4py", "ufl", "basix")) -> None:
    """Import ``module`` in a fresh interpreter and check none of ``heavy`` got loaded."""
    import subprocess
    import sys

    code = f"import sys, {module}\nbad = [m for m in {tuple(heavy)!r} if m in sys.modules]\nassert not bad, bad"
    subprocess.run([sys.executable, "-c", code], check=True)


#: A small dynamic scene (TOML) that scene, run and restart tests edit.
BASE = """
[surface]
kind = "rectangle"
size = [0.4, 0.3]
patches = [3, 2]

[material]
young = 1.0e4
poisson = 0.3
thickness = 1.0e-3
density = 200.0

[time]
dt = 0.01
steps = 6

[output]
every = 2
density = 2

[effects]
gravity = [0.0, 0.0, -9.81]
damping = { mass = 0.5 }

[[constraints]]
type = "clamp"
corners = ["min_min"]

[[constraints]]
type = "fix"
corners = ["max_min"]
kinds = ["x"]
motion = { type = "linear", velocity = [-0.5, 0.0, 0.0] }
"""


def newton_tolerance(scene, reference: np.ndarray) -> float:
    """How far two runs of ``scene`` that each stop once ``|F| <= rtol |F0|`` (the Newton tolerance)
    may end apart: what such a residual moves, a small multiple of rtol times the cloth's size
    (``reference``: gathered raw DOFs of one of them)."""
    size = np.ptp(reference.reshape(-1, 3)[:, :2], axis=0).max()
    return 100 * float(scene.petsc_options.get("snes_rtol", 1e-9)) * size


def central_difference(model, q0, direction, eps, evaluate):
    """``(evaluate(q0 + eps d) - evaluate(q0 - eps d)) / (2 eps)``, restoring the state."""
    set_open_state_global(model, q0 + eps * direction)
    plus = evaluate(model)
    set_open_state_global(model, q0 - eps * direction)
    minus = evaluate(model)
    set_open_state_global(model, q0)
    return (plus - minus) / (2 * eps)


def closed_energy_and_gradient(solver, values: np.ndarray) -> tuple[float, np.ndarray]:
    """Total potential and closed residual at owned closed values (collective)."""
    problem = solver.problem
    x, f = solver.x.duplicate(), solver.x.duplicate()
    x.array[:] = values
    problem.update_state(x)
    energy = problem.potential_energy()
    problem.assemble_residual(x, f)
    gradient = f.array.copy()
    x.destroy()
    f.destroy()
    return energy, gradient


def assert_falls_freely(rest, material, comm, steps: int, rtol: float) -> None:
    """Implicit Euler under gravity alone (dt 10 ms): every control point of ``rest`` drops by
    ``g dt^2 N (N + 1) / 2`` within ``rtol`` and keeps its x and y."""
    from bhem_hpc.model.shell import Dynamics, Loads
    from bhem_hpc.solver import ShellSolver
    from bhem_hpc.solver.dynamics import TimeStepper

    model = ShellModel(rest, material, Loads(gravity=(0.0, 0.0, -9.81)), comm=comm, dynamics=Dynamics(0.01))
    with ShellSolver(model, prefix="fall_") as solver:
        stepper = TimeStepper(model, solver)
        for _ in range(steps):
            stepper.advance()
    moved = model.state_surface().control - rest.control
    np.testing.assert_allclose(moved[..., 2], -9.81 * 0.01**2 * steps * (steps + 1) / 2, rtol=rtol)
    np.testing.assert_allclose(moved[..., :2], 0.0, atol=1e-10)


def assert_rigid_motion_has_no_energy(rest, moved, material, comm, quadrature=None) -> None:
    """A shell moved rigidly from ``rest``: no membrane or bending energy (1e-12 of E t) and no
    closed residual (1e-9 of E t)."""
    from bhem_hpc.solver import ShellSolver

    model = ShellModel(rest, material, comm=comm, initial=moved, quadrature_points=quadrature)
    energies = model.energies()
    scale = material.young * material.thickness
    assert abs(energies["membrane"]) < 1e-12 * scale and abs(energies["bending"]) < 1e-12 * scale
    with ShellSolver(model, prefix="rigid_") as solver:
        _, gradient = closed_energy_and_gradient(solver, model.discretization.surface_to_closed(moved))
    assert comm.allreduce(float(np.abs(gradient).max(initial=0.0)), op=MPI.MAX) < 1e-9 * scale


def assert_closed_derivatives(solver, disc, x0: np.ndarray, rng, directions: int, comm) -> None:
    """The closed residual and Jacobian at owned closed values ``x0`` against central differences
    (eps 1e-6) of the potential and of the residual in ``directions`` random directions: the
    slope within 1e-6 (relative, at least 1e-3 absolute), the Jacobian's action within 1e-5 of its
    largest entry."""
    _, gradient = closed_energy_and_gradient(solver, x0)
    solver.x.array[:] = x0
    solver.problem.update_state(solver.x)
    solver.problem.assemble_jacobian(solver.jacobian)
    eps = 1e-6
    for _ in range(directions):
        direction = comm.bcast(rng.normal(size=3 * disc.num_closed) if comm.rank == 0 else None)
        local = direction[3 * disc.closed_offset : 3 * (disc.closed_offset + disc.num_owned_closed)]
        plus, g_plus = closed_energy_and_gradient(solver, x0 + eps * local)
        minus, g_minus = closed_energy_and_gradient(solver, x0 - eps * local)
        slope = comm.allreduce(float(gradient @ local))
        assert abs((plus - minus) / (2 * eps) - slope) <= 1e-6 * max(abs(slope), 1e-3)
        d, jd = solver.x.duplicate(), solver.x.duplicate()
        d.array[:] = local
        solver.jacobian.mult(d, jd)
        difference = (g_plus - g_minus) / (2 * eps)
        scale = comm.allreduce(float(np.abs(jd.array).max()), op=MPI.MAX)
        assert comm.allreduce(float(np.abs(jd.array - difference).max()), op=MPI.MAX) <= 1e-5 * scale
        d.destroy()
        jd.destroy()


class PointSpring:
    """``k/2 (|x_p - x_q| - L)^2`` between two material points, an energy contribution (Hessian: the
    exact one in tension, its transverse part dropped in compression, so it stays positive
    semi-definite).

    Args:
        comm: the communicator.
        points: the two points' ``(rows, basis values)`` in the contributions' layout, on the rank
            owning each (empty elsewhere).
        shared: the two points' ``(global blocks, basis values)``, on every rank.
        stiffness, rest_length: k [N/m] and L [m].
    """

    name = "spring"

    def __init__(self, comm, points, shared, stiffness: float, rest_length: float):
        self.comm, self.k, self.length = comm, stiffness, rest_length
        self.points = list(points)
        self._owns = tuple(len(rows) > 0 for rows, _ in self.points)
        blocks = [g for g, _ in shared]
        self.signed_values = [shared[0][1], -shared[1][1]]
        rows, cols = [], []
        for owns, g in zip(self._owns, blocks, strict=True):
            if owns:  # this rank adds the rows of the points it owns, coupled to both points' columns
                for other in blocks:
                    rows.append(np.repeat(g, len(other)))
                    cols.append(np.tile(other, len(g)))
        empty = np.zeros(0, np.int64)
        self._pattern = (np.concatenate(rows), np.concatenate(cols)) if rows else (empty, empty)

    def _d(self, state):
        xp, xq = state.point_positions(self.points)
        return xp - xq

    def hessian_pattern(self):
        return self._pattern

    def energy(self, state):
        stretch = np.linalg.norm(self._d(state)) - self.length
        return 0.5 * self.k * stretch**2 if self.comm.rank == 0 else 0.0

    def force(self, state) -> np.ndarray:
        """The force ``(3,)`` [N] the spring pulls point q with (and p with its opposite)."""
        d = self._d(state)
        return self.k * (np.linalg.norm(d) - self.length) * d / np.linalg.norm(d)

    def add_gradient(self, state, gradient):
        force = self.force(state)
        for (rows, values), sign in zip(self.points, (1.0, -1.0), strict=True):
            gradient[rows] += sign * values[:, None] * force

    def hessian(self, state):
        d = self._d(state)
        r = np.linalg.norm(d)
        n = d / r
        block = self.k * (np.outer(n, n) + max(0.0, 1 - self.length / r) * (np.eye(3) - np.outer(n, n)))
        parts = [np.outer(v, other).ravel()[:, None, None] * block
                 for owns, v in zip(self._owns, self.signed_values, strict=True) if owns
                 for other in self.signed_values]  # fmt: skip
        return np.concatenate(parts) if parts else np.zeros((0, 3, 3))


class CouplingBeyondPattern:
    """For a :class:`PointSpring`: only each point's own blocks in its fixed pattern; the blocks that
    couple the two points come beyond it (:class:`~bhem_hpc.solver.contributions.GrowingPattern`),
    as a contact barrier's between parts far apart do."""

    def _split_pattern(self, first_point_blocks: np.ndarray) -> None:
        from bhem_hpc.solver.contributions import no_blocks

        rows, cols = self._full = self._pattern
        self._own = np.isin(rows, first_point_blocks) == np.isin(cols, first_point_blocks)  # the points are apart
        self._pattern = (rows[self._own], cols[self._own])
        self._beyond = no_blocks()

    def hessian(self, state):
        full = super().hessian(state)
        rows, cols = self._full
        self._beyond = (rows[~self._own], cols[~self._own], full[~self._own])
        return full[self._own]

    def hessian_beyond_pattern(self):
        return self._beyond


class TwoBodySpring(PointSpring):
    """The spring between material point ``p`` of body 0 and ``q`` of body 1, named through the
    public layout of several bodies only (``blocks``: a stacked problem or its
    :class:`~bhem_hpc.bodies.petsc.StackedBlocks`, with ``comm``, ``point_basis`` and
    ``global_open_blocks``)."""

    name = "two-body spring"

    def __init__(self, blocks, p, q, stiffness: float, rest_length: float):
        points = (blocks.point_basis(0, *p), blocks.point_basis(1, *q))
        gathered = [blocks.comm.allgather((blocks.global_open_blocks[rows], values)) for rows, values in points]
        shared = [next(part for part in parts if len(part[0])) for parts in gathered]
        super().__init__(blocks.comm, points, shared, stiffness, rest_length)


def momentum(model: ShellModel) -> np.ndarray:
    """``int rho h v dOmega_rest`` [kg m/s] of a dynamic model, on every rank."""
    from dolfinx import fem

    from bhem_hpc.forms.kinematics import area_density

    parts = [fem.form(model.density * model.thickness * model.velocity[i] * area_density(model.x_rest) * model.dx)
             for i in range(3)]  # fmt: skip
    return np.array([model.comm.allreduce(fem.assemble_scalar(form)) for form in parts])


def hairpin(arm: float, radius: float):
    """A strip folded into a U: two parallel arms ``2 radius`` apart joined by a half circle."""
    bend = np.pi * radius

    def position(u, v):
        u, v = np.asarray(u, float), np.asarray(v, float)
        phi = np.clip((u - arm) / radius, 0.0, np.pi)
        x = np.where(u < arm, arm - u, np.where(u > arm + bend, u - arm - bend, -radius * np.sin(phi)))
        z = np.where(u < arm, radius, np.where(u > arm + bend, -radius, radius * np.cos(phi)))
        return np.stack([x, v, z], axis=-1)

    def along(u, v):
        u = np.asarray(u, float)
        phi = np.clip((u - arm) / radius, 0.0, np.pi)
        dx = np.where(u < arm, -1.0, np.where(u > arm + bend, 1.0, -np.cos(phi)))
        dz = np.where((u < arm) | (u > arm + bend), 0.0, -np.sin(phi))
        return np.stack([dx, np.zeros_like(dx), dz], axis=-1)

    def across(u, v):
        return np.broadcast_to([0.0, 1.0, 0.0], np.shape(u) + (3,)).copy()

    def twist(u, v):
        return np.zeros(np.shape(u) + (3,))

    return position, (along, across, twist), 2 * arm + bend


def hairpin_model(comm, discretization: str, patches: int) -> tuple[ShellModel, tuple[float, float, float]]:
    """A soft strip folded into a hairpin (arms 0.25 m, 3 cm apart, width 8 cm; ``patches`` patches
    or knot spans along it) whose arms fly at each other at 1 m/s each plus a common drift of
    0.3 m/s along x; dt = 2 ms. On B-splines each control point gets the velocity of its Greville
    point. Returns the model and ``(arm, length, width)``."""
    from bhem_hpc.geometry import bspline as B
    from bhem_hpc.geometry import surface as S
    from bhem_hpc.model.material import Material
    from bhem_hpc.model.shell import Dynamics

    arm, radius, width = 0.25, 0.015, 0.08
    position, derivatives, length = hairpin(arm, radius)
    grid = S.ParameterGrid(patches, 3, (0.0, length), (0.0, width))

    def arm_velocity(xi1: np.ndarray) -> np.ndarray:
        velocity = np.zeros(np.shape(xi1) + (3,))
        velocity[..., 2] = np.where(xi1 < arm, -1.0, np.where(xi1 > length - arm, 1.0, 0.0))
        velocity[..., 0] = 0.3
        return velocity

    if discretization == "hermite":
        rest = S.from_callable(position, grid, derivatives)
        velocity = np.zeros_like(rest.nodal)
        velocity[..., 0, :] = arm_velocity(grid.node_parameters()[0])
        velocity_surface = S.HermiteSurface(grid, velocity)
    else:
        degree = int(discretization[-1])
        rest = B.from_callable(position, grid, degree=degree)
        xi1 = B.greville(grid.n1, degree, False, *grid.xi1_range)
        control = np.broadcast_to(arm_velocity(xi1)[:, None, :], rest.control.shape)
        velocity_surface = B.BSplineSurface(grid, degree, control.copy())
    model = ShellModel(rest, Material(1e5, 0.3, 1e-3, 200.0), comm=comm, dynamics=Dynamics(0.002))
    model.velocity.x.array[:] = model.discretization.surface_to_open(velocity_surface)
    return model, (arm, length, width)


def paraview_read(*paths: Path) -> dict:
    """What ParaView's readers give for ``paths`` (see ``io/paraview_reader.py``, run in its own process)."""
    done = subprocess.run([sys.executable, str(REPO / "tests" / "io" / "paraview_reader.py"), *map(str, paths)],
                          capture_output=True, text=True, timeout=300, check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout)


#: Real materials of the sheets the tests of several bodies use: sheet steel and rubber.
STEEL = {"young": 2.1e11, "poisson": 0.3, "thickness": 1e-3, "density": 7850.0}
RUBBER = {"young": 5.0e6, "poisson": 0.49, "thickness": 2e-3, "density": 1100.0}
#: A square sheet of side {size} at {origin} (a scene of one body); ``time`` and ``rest`` are the
#: scene's [time] table and anything after (effects, constraints).
SHEET = """
[surface]
kind = "rectangle"
size = [{size}, {size}]
patches = [4, 4]
discretization = "{discretization}"
origin = {origin}
[material]
young = {young}
poisson = {poisson}
thickness = {thickness}
density = {density}
[time]
{time}
{rest}
"""
#: A sheet's edge xi1 = 0 clamped, under gravity (``rest`` of :data:`SHEET`).
CLAMPED = """
[effects]
gravity = [0.0, 0.0, -9.81]
[[constraints]]
type = "clamp"
edge = "xi1_min"
"""


def frame_times(directory: Path) -> list[float]:
    """The frame times of the series in ``directory`` (``surface.*``), checked to be listed alike in its
    XDMF, HDF5 and PVD files, with no stale frame file."""
    root = ET.parse(directory / "surface.xdmf").getroot()
    listed = [float(g.find("Time").get("Value")) for g in root.findall(".//Grid[@GridType='Uniform']")]
    with h5py.File(directory / "surface.h5", "r") as f:
        stored = [float(f[f"frames/{k}"].attrs["time"]) for k in range(len(f["frames"]))]
    assert listed == stored  # the XDMF lists exactly the frames the HDF5 file holds
    pvd = ET.parse(directory / "surface.pvd").getroot().findall(".//DataSet")
    assert [float(d.get("timestep")) for d in pvd] == listed  # and so does the VTK collection,
    assert sorted(p.name for p in (directory / "surface_frames").iterdir()) == [  # with no stale frame
        Path(d.get("file")).name for d in pvd
    ]
    return listed


class GrowingTwoBodySpring(CouplingBeyondPattern, TwoBodySpring):
    """The :class:`TwoBodySpring` whose coupling blocks come beyond its pattern."""

    def __init__(self, blocks, p, q, stiffness: float, rest_length: float):
        super().__init__(blocks, p, q, stiffness, rest_length)
        rows, _ = blocks.point_basis(0, *p)
        self._split_pattern(np.concatenate(blocks.comm.allgather(blocks.global_open_blocks[rows])))


def wavy_cut_loops() -> tuple[np.ndarray, np.ndarray]:
    """The trim loops (in [0, 1]^2) of two overlapping parts over x in [0, 1.2] and [0.4, 1.6] of a
    1.6 m plate, cut by the same wavy line x = 0.8 + 0.06 sin(2 pi v): the first keeps what lies
    before the cut, the second what lies after."""
    v = np.linspace(0.0, 1.0, 49)
    cut = 0.8 + 0.06 * np.sin(2 * np.pi * v)
    first, second = np.column_stack([cut / 1.2, v]), np.column_stack([(cut - 0.4) / 1.2, v])
    return (np.concatenate([[(0.0, 0.0)], first, [(0.0, 1.0), (0.0, 0.0)]]),
            np.concatenate([second[:1], [(1.0, 0.0), (1.0, 1.0)], second[::-1]]))  # fmt: skip

