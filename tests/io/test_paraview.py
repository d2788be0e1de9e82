"""ParaView's own readers (Debian's python3-paraview, in a separate process) read every file a run
and the surface writer produce: float64 points bit for bit, exact times, attribute widths as declared,
the physical fields, and the normals active in the VTK XML files."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from helpers import BASE, paraview_read

from bhem_hpc.geometry import nurbs
from bhem_hpc.geometry import surface as S
from bhem_hpc.geometry.nurbs import knot_aligned_grid
from bhem_hpc.io import write_surface_xdmf
from bhem_hpc.io.solid_output import tessellate_parts, write_solid_files
from bhem_hpc.io.vtu import read_vtu
from bhem_hpc.model.material import Material
from bhem_hpc.run import RunOptions, run_scene
from bhem_hpc.solids.elasticity import Lame, neo_hookean
from bhem_hpc.solids.sem import ShapeMatchingSolid, SolidMaterial, SolidOptions

WIDTHS = {"normal": 3, "mean_curvature": 1, "membrane_energy_density": 1, "bending_energy_density": 1}


def _check_arrays(frame: dict, widths: dict[str, int], normals_active: bool) -> None:
    assert frame["point_type"] == "double"
    for name, width in widths.items():
        array = frame["arrays"][name]
        assert (array["type"], array["components"]) == ("double", width), name
    assert frame["arrays"]["normal"]["normals"] is normals_active


def test_paraview_reads_a_run_at_full_precision_with_exact_times(comm, shared_tmp_path):
    scene = shared_tmp_path / "scene.toml"
    if comm.rank == 0:
        scene.write_text(BASE.replace("every = 2", "every = 1").replace("dt = 0.01", "dt = 0.1"))
    comm.Barrier()
    out = shared_tmp_path / "out"
    run_scene(RunOptions(scene, out, progress=False), comm)
    if comm.rank != 0:
        return
    read = paraview_read(out / "surface.xdmf", out / "surface.pvd")
    with h5py.File(out / "surface.h5", "r") as f:
        count, cells = len(f["frames"]), len(f["topology"])
        geometry = [f[f"frames/{k}/geometry"][0] for k in range(count)]
        normal = [f[f"frames/{k}/normal"][0] for k in range(count)]
        times = [float(f[f"frames/{k}"].attrs["time"]) for k in range(count)]
    assert times == [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    readers = {**read[str(out / "surface.xdmf")], **read[str(out / "surface.pvd")]}
    assert set(readers) == {"XDMFReader", "Xdmf3ReaderS", "Xdmf3ReaderT", ".pvd"}
    for name, result in readers.items():
        assert result["times"] == times, name
        for k, frame in enumerate(result["frames"].values()):
            assert frame["cells"] == cells and frame["connectivity_type"] in ("long long", "long"), name
            assert frame["first_point"] == list(geometry[k]), (name, k)  # float64 bit for bit
            assert frame["arrays"]["normal"]["first"] == list(normal[k]), (name, k)
            _check_arrays(frame, WIDTHS, normals_active=name == ".pvd")


def test_paraview_reads_a_surface_file_with_its_physical_fields(tmp_path):
    grid = S.ParameterGrid(3, 2, (0, 1), (0, 1))
    rest = S.flat_rectangle(1.0, 1.0, 3, 2)
    surface = S.from_callable(lambda a, b: np.stack([a, b, 0.1 * a * b], -1), grid)
    path = write_surface_xdmf(tmp_path / "t.xdmf", surface, 2, "t", rest, Material(1e6, 0.3, 1e-3, 100.0))
    read = paraview_read(path, path.with_suffix(".vtu"))
    widths = WIDTHS | {"displacement": 3, "xi1": 1, "xi2": 1}
    readers = {**read[str(path)], **read[str(path.with_suffix(".vtu"))]}
    with h5py.File(path.with_suffix(".h5"), "r") as f:
        first_displacement = list(f["displacement"][0])
    for name, result in readers.items():
        (frame,) = result["frames"].values()
        assert (frame["points"], frame["cells"]) == ((3 * 2 + 1) * (2 * 2 + 1), 3 * 2 * 4), name
        _check_arrays(frame, widths, normals_active=name == ".vtu")
        assert frame["arrays"]["displacement"]["first"] == first_displacement, name


def test_paraview_reads_a_solid_boundary_and_its_stressed_quadrature_points(tmp_path):
    """A box solid stretched 10 % along x: its six parts as one quadrilateral surface with normals,
    displacements and part indices; its quadrature points with the homogeneous Cauchy stress of the
    Neo-Hookean material (checked against the energy density's own stress) and von Mises."""
    material = SolidMaterial(density=1000.0, young=1e6, poisson=0.45)
    solid = ShapeMatchingSolid(nurbs.box_faces([0, 0, 0], [2.0, 1.0, 0.5]), material,
                               SolidOptions(degree=1, lines_per_side=8, sparsity=0.5), name="box")  # fmt: skip
    stretch = np.diag([1.1, 1.0, 1.0])
    q = solid.reference @ stretch.T
    stresses = solid.cauchy_stresses(q)
    lame = Lame.of(material.young, material.poisson)
    _, first_piola, _ = neo_hookean(stretch[None], lame.mu, lame.lam, tangent=False)
    expected = first_piola.reshape(3, 3) @ stretch.T / np.linalg.det(stretch)
    np.testing.assert_allclose(stresses, np.broadcast_to(expected, stresses.shape), atol=1e-6 * abs(expected).max())
    boundary, cloud = write_solid_files(tmp_path, solid.deformed_parts(q), solid.parts, solid.positions(q), stresses,
                                        solid.quadrature.weights, samples=5)  # fmt: skip
    read = paraview_read(boundary, cloud)
    (surface,) = read[str(boundary)][".vtu"]["frames"].values()
    assert (surface["points"], surface["cells"]) == (6 * 25, 6 * 16)
    assert surface["arrays"]["normal"]["normals"] is True
    assert surface["arrays"]["displacement"]["components"] == 3 and surface["arrays"]["part"]["components"] == 1
    (points,) = read[str(cloud)][".vtu"]["frames"].values()
    assert (points["points"], points["cells"]) == (len(solid.quadrature.weights),) * 2
    assert points["arrays"]["stress"]["components"] == 9
    np.testing.assert_allclose(
        points["arrays"]["stress"]["first"], expected.reshape(-1), atol=1e-6 * abs(expected).max()
    )
    assert points["arrays"]["von_mises"]["first"][0] == pytest.approx(abs(expected[0, 0] - expected[1, 1]), rel=1e-6)


def test_a_solid_boundary_on_its_own_grids_reads_back_point_for_point(tmp_path):
    """Parts tessellated on grids of their own (a contact mesh's knot-aligned lines) write the points
    and quadrilaterals that :func:`read_vtu` reads back, and ParaView counts them alike."""
    parts = nurbs.box_faces([0, 0, 0], [2.0, 1.0, 0.5], degree=2, spans=(2, 1))
    grids = [(knot_aligned_grid(p.u, 5), knot_aligned_grid(p.v, 3)) for p in parts]
    points, quads, _, _ = tessellate_parts(parts, grids)
    assert [len(u) for u, _ in grids] == [7] * 6 and [len(v) for _, v in grids] == [4] * 6  # 2 spans x 3, 3 cells
    boundary, _ = write_solid_files(tmp_path, parts, parts, np.zeros((1, 3)), np.zeros((1, 3, 3)), np.ones(1),
                                    samples=grids)  # fmt: skip
    read_points, read_quads = read_vtu(boundary)
    np.testing.assert_array_equal(read_points, points)
    np.testing.assert_array_equal(read_quads, quads)
    (surface,) = paraview_read(boundary)[str(boundary)][".vtu"]["frames"].values()
    assert (surface["points"], surface["cells"]) == (6 * 28, 6 * 18)
    # a uniform grid is the same tessellation as the point count it replaces
    uniform = [(np.linspace(0.0, 1.0, 5),) * 2] * 6
    np.testing.assert_array_equal(tessellate_parts(parts, 5)[0], tessellate_parts(parts, uniform)[0])
