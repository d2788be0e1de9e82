"""The command line, run in-process so that it also runs under mpirun."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import h5py
import meshio
import numpy as np
import pytest

from bhem_hpc import cli
from bhem_hpc.geometry.surface import HermiteSurface


def test_cantilever_job_writes_paraview_png_and_summary(comm, shared_tmp_path, capsys):
    out = shared_tmp_path / "cantilever"
    assert cli.main(["cantilever", "--gamma", "2", "--patches", "12", "--out", str(out)]) == 0
    comm.Barrier()
    summary = json.loads((out / "summary.json").read_text())
    assert abs(summary["relative_error_H"]) < 1e-3 and summary["ranks"] == comm.size
    assert (out / "cantilever.png").stat().st_size > 10_000
    surface = HermiteSurface.load(out / "cantilever.npz")
    assert surface.grid.n1 == 12
    # ParaView's XDMF: parse the XML and read the heavy data independently, then with meshio
    root = ET.parse(out / "cantilever.xdmf").getroot()
    topology = root.find(".//Topology")
    assert topology.get("TopologyType") == "Quadrilateral"
    with h5py.File(out / "cantilever.h5") as f:
        points, quads = f["geometry"][:], f["topology"][:]
    assert int(topology.get("NumberOfElements")) == len(quads) == 12 * 4 * 4
    mesh = meshio.read(out / "cantilever.xdmf")
    np.testing.assert_allclose(mesh.points, points)
    assert {"displacement", "membrane_energy_density", "bending_energy_density"} <= set(mesh.point_data)
    tip = points[np.argmax(-points[:, 2])]
    assert abs(-tip[2] - summary["tip_H_over_L"]) < 0.01
    if comm.rank == 0:
        assert "tip drop H/L" in capsys.readouterr().out


def test_bench_json(comm, capsys):
    assert cli.main(["bench", "--patches", "4", "--repeats", "1", "--json"]) == 0
    if comm.rank == 0:
        row = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        for key in (
            "patches",
            "dofs",
            "nnz",
            "newton_iteration_s",
            "assemble_residual_s",
            "assemble_jacobian_s",
            "factor_s",
            "solve_s",
            "factor_gflops",
        ):
            assert key in row
        assert row["dofs"] == 3 * 4 * 25 and row["nnz"] > 0 and row["factor_gflops"] > 0


def test_bench_times_a_b_spline_sheet(comm, capsys):
    """Degree-2 B-splines on 4 x 4 knot spans: (4 + 2)^2 control points, 3 x 3 Gauss points per span."""
    assert cli.main(["bench", "--patches", "4", "--discretization", "bspline2", "--repeats", "1", "--json"]) == 0
    if comm.rank == 0:
        row = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert row["discretization"] == "bspline2" and row["dofs"] == 3 * 36 and row["membrane_points"] == 9 * 16
        assert row["nnz"] > 0 and row["newton_iteration_s"] > 0


def test_bad_arguments_give_clear_errors(comm, shared_tmp_path, capsys):
    assert cli.main(["cantilever", "--gamma", "-1", "--out", str(shared_tmp_path / "x")]) == 2
    if comm.rank == 0:
        assert "--gamma must be in (0, 1e4], got -1.0" in capsys.readouterr().err
    assert not (shared_tmp_path / "x").exists()
    with pytest.raises(SystemExit):
        cli.main(["cantilever", "--no-such-flag"])


def test_hostile_arguments_get_one_line_and_exit_code_2(comm, shared_tmp_path, capsys):
    """A non-UTF-8 byte in an argument (as the shell hands it to Python) and a render into a
    folder that does not exist."""
    assert cli.main(["run", "scene\udcff.toml", "--out", str(shared_tmp_path / "x")]) == 2
    assert "is not UTF-8 text" in capsys.readouterr().err
    directory = shared_tmp_path / "series"
    if comm.rank == 0:
        directory.mkdir()
        (directory / "surface.h5").write_bytes(b"not hdf5")
    comm.Barrier()
    # every rank calls the CLI, as under mpirun; rank 0 renders
    code = cli.main(["render", str(directory), "--out", str(shared_tmp_path / "missing" / "a.png")])
    if comm.rank == 0:
        assert code == 2 and "the folder" in capsys.readouterr().err
    code = cli.main(["render", str(directory)])
    if comm.rank == 0:
        assert code == 2 and "not a readable surface series" in capsys.readouterr().err


def test_debug_shows_the_traceback_behind_the_error_line(comm, shared_tmp_path, capsys):
    missing = str(shared_tmp_path / "missing.toml")
    assert cli.main(["run", missing, "--out", str(shared_tmp_path / "o")]) == 2
    plain = capsys.readouterr().err
    assert cli.main(["--debug", "run", missing, "--out", str(shared_tmp_path / "o")]) == 2
    debug = capsys.readouterr().err
    if comm.rank == 0:
        assert "Traceback" not in plain and "bhem-hpc: error:" in plain
        assert "Traceback" in debug and "SceneError" in debug and "bhem-hpc: error:" in debug


def test_the_cloth_page_refuses_a_whole_run_of_a_case_it_does_not_run(comm, shared_tmp_path, capsys):
    code = cli.main(["cloth", "--docs", str(shared_tmp_path / "d"), "--jobs", "shear", "--hermite", "25",
                     "--bspline2", "--bspline3", "--whole", "shear-hermite-26"])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    if comm.rank == 0:  # the error line is printed once
        assert "--whole" in err and "shear-hermite-26" in err and "shear-hermite-25" in err
