"""The XDMF files declare every array as stored (type and precision, shape) and exact frame times."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
from helpers import BASE

from bhem_hpc.geometry import surface as S
from bhem_hpc.io import write_surface_xdmf
from bhem_hpc.run import RunOptions, run_scene

_NUMBER_TYPES = {"f": "Float", "i": "Int", "u": "UInt"}


def check_data_items(xdmf: Path) -> int:
    """Every DataItem names NumberType and Precision equal to its HDF5 dataset's, and its
    Dimensions are the dataset's shape; an Attribute's type fits its width. Returns the count."""
    root = ET.parse(xdmf).getroot()
    count = 0
    with h5py.File(xdmf.with_suffix(".h5"), "r") as f:
        for item in root.iter("DataItem"):
            dataset = f[item.text.strip().split(":", 1)[1]]
            assert item.get("NumberType") == _NUMBER_TYPES[dataset.dtype.kind], item.text
            assert item.get("Precision") == str(dataset.dtype.itemsize), item.text
            assert tuple(int(d) for d in item.get("Dimensions").split()) == dataset.shape, item.text
            count += 1
        for attribute in root.iter("Attribute"):
            width = {"Scalar": 1, "Vector": 3}[attribute.get("AttributeType")]
            shape = f[attribute.find("DataItem").text.strip().split(":", 1)[1]].shape
            assert (shape[1] if len(shape) > 1 else 1) == width, attribute.get("Name")
    return count


def test_a_surface_file_declares_its_arrays_and_physical_fields(tmp_path):
    from bhem_hpc.model.material import Material

    grid = S.ParameterGrid(3, 2, (0, 1), (0, 1))
    rest = S.flat_rectangle(1.0, 1.0, 3, 2)
    surface = S.from_callable(lambda a, b: np.stack([a, b, 0.1 * a * b], -1), grid)
    path = write_surface_xdmf(tmp_path / "s.xdmf", surface, density=2)
    assert check_data_items(path) == 6  # topology, geometry, normal, mean curvature, xi1, xi2
    path = write_surface_xdmf(tmp_path / "t.xdmf", surface, 2, "t", rest, Material(1e6, 0.3, 1e-3, 100.0))
    assert check_data_items(path) == 9  # and displacement, membrane and bending energy densities
    with h5py.File(tmp_path / "t.h5", "r") as f:
        np.testing.assert_allclose(f["displacement"][:, 2], 0.1 * f["xi1"][:] * f["xi2"][:], atol=1e-14)
        assert f["bending_energy_density"][:].max() > 0


def test_a_time_series_declares_its_arrays_and_exact_times(comm, shared_tmp_path):
    scene = shared_tmp_path / "scene.toml"
    if comm.rank == 0:
        scene.write_text(BASE.replace("every = 2", "every = 1").replace("dt = 0.01", "dt = 0.1"))
    comm.Barrier()
    run_scene(RunOptions(scene, shared_tmp_path / "out", progress=False), comm)
    if comm.rank == 0:
        xdmf = shared_tmp_path / "out" / "surface.xdmf"
        assert check_data_items(xdmf) == 7 * 6
        frames = ET.parse(xdmf).getroot().findall(".//Grid[@GridType='Uniform']")
        times = [g.find("Time").get("Value") for g in frames]
        assert times == ["0.0", "0.1", "0.2", "0.3", "0.4", "0.5", "0.6"]  # not 0.30000000000000004


def test_tables_append_a_line_per_row_and_a_continuation_drops_a_torn_line(tmp_path):
    from bhem_hpc.io.path_table import CsvTable, read_rows

    path = tmp_path / "t.csv"
    table = CsvTable(path)
    for step in range(3):
        table.add({"step": step, "value": 0.5 * step})
    assert path.read_text() == "step,value\n0,0.0\n1,0.5\n2,1.0\n"
    with open(path, "a") as f:
        f.write("3,")  # a run stopped in the middle of a line
    assert [r["step"] for r in read_rows(path, 10)] == ["0", "1", "2"]
    assert [r["step"] for r in read_rows(path, 1)] == ["0", "1"]
