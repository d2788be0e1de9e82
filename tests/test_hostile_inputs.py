"""Hostile inputs through the command line: each ends in one ``bhem-hpc: error:`` line that names
the file, key or option and the value, exit code 2, no traceback, and nothing written."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from helpers import BASE, REPO, message_lines

from bhem_hpc import cli
from bhem_hpc.geometry import bspline as B

#: The base scene's surface table, replaced by the file cases.
RECTANGLE = 'kind = "rectangle"\nsize = [0.4, 0.3]\npatches = [3, 2]'


def effect(line: str) -> str:
    return BASE.replace("damping = { mass = 0.5 }", "damping = { mass = 0.5 }\n" + line)


SCENE_CASES = {
    "deep profile": (effect('area_loads = [{ force = [0, 0, -1], profile = "' + "-" * 990 + 'xi1" }]'),
                     r"'effects.area_loads\[0\].profile' .*nests more than 100 levels deep"),
    "huge integer in a profile": (effect('area_loads = [{ force = [0, 0, -1], profile = "' + "9" * 401 + '" }]'),
                                  r"'effects.area_loads\[0\].profile' .*an integer of 401 digits"),
    "huge integer in a height": (BASE.replace("[3, 2]", '[3, 2]\nheight = "' + "9" * 401 + ' * xi1"'),
                                 r"'surface.height' .*an integer of 401 digits"),
    "profile NaN between the nodes": (effect('area_loads = [{ force = [0, 0, -1], profile = "sqrt(cos(16*pi*xi1))" }]'),
                                      r"'effects.area_loads\[0\].profile' must be an expression finite on the whole"),
    "keyframes at one time": (BASE + '\n[[constraints]]\ntype = "clamp"\nedge = "xi1_max"\n'
                              'motion = { type = "keyframes", times = [0.0, 0.0], values = [0.0, 0.1] }\n',
                              r"'constraints\[2\].motion.times' must be at least 2 increasing numbers, got \[0.0, 0.0"),
    "keyframe value NaN": (BASE + '\n[[constraints]]\ntype = "fix"\ncorners = ["max_max"]\nkinds = ["x"]\n'
                           'motion = { type = "keyframes", times = [0.0, 1.0], values = [0, nan] }\n',
                           r"'constraints\[2\].motion.values' must be finite numbers, got \[0, nan\]"),
    "point load outside": (effect("point_loads = [{ at = [2, 0.5], force = [0.0, 0.0, 1.0] }]"),
                           r"'effects.point_loads\[0\].at' must be 2 numbers \(xi1, xi2\) in \[0.0, 0.4\]"),
    "vanishing size": (BASE.replace("size = [0.4, 0.3]", "size = [1e-300, 1e-300]"),
                       r"'surface.size' must be 2 numbers in \[1e-09, 1e\+09\], got \[1e-300, 1e-300\]"),
    "100,000-letter probe name": (BASE + '\n[[probes]]\nname = "' + "a" * 100_000 + '"\nat = [0.1, 0.1]\n',
                                  r"'probes\[0\].name' must be a name .*at most 64 characters.*\(100002 characters\)"),
    "negative tolerance in the scene": (BASE + "\n[solver]\noptions = { snes_rtol = -1 }\n",
                                        r"'solver.options.snes_rtol' must be a finite number >= 0, got -1"),
}  # fmt: skip


def one_error_line(comm, capsys, code: int) -> str:
    """The error line of a failed command (rank 0; other ranks print nothing)."""
    err = capsys.readouterr().err
    lines = message_lines(err)  # a cold form cache logs its compilations; every other line counts
    assert code == 2 and "Traceback" not in err, err[-3000:]
    if comm.rank != 0:
        assert not lines, err
        return ""
    assert len(lines) == 1 and lines[0].startswith("bhem-hpc: error: "), err[-3000:]
    return lines[0]


@pytest.mark.parametrize("name", SCENE_CASES)
def test_a_hostile_scene_gets_one_error_line_naming_its_key_and_nothing_is_written(comm, shared_tmp_path, capsys,
                                                                                 name):  # fmt: skip
    text, message = SCENE_CASES[name]
    scene = shared_tmp_path / "scene.toml"
    if comm.rank == 0:
        scene.write_text(text)
    comm.Barrier()
    out = shared_tmp_path / "out"
    line = one_error_line(comm, capsys, cli.main(["run", str(scene), "--out", str(out), "--no-progress"]))
    assert comm.rank != 0 or (str(scene) in line and re.search(message, line)), line
    assert not out.exists()


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["-bhem_snes_max_it", "-5"], r"PETSc option -bhem_snes_max_it must be an integer >= 0, got '-5'"),
        (["-bhem_snes_rtol", "abc"], r"PETSc option -bhem_snes_rtol must be a number >= 0, got 'abc'"),
    ],
)
def test_a_bad_petsc_option_value_is_named_before_any_solver_reads_it(comm, shared_tmp_path, capsys, arguments,
                                                                      message):  # fmt: skip
    scene = shared_tmp_path / "scene.toml"
    if comm.rank == 0:
        scene.write_text(BASE)
    comm.Barrier()
    out = shared_tmp_path / "out"
    line = one_error_line(comm, capsys, cli.main(["run", str(scene), "--out", str(out), "--no-progress", *arguments]))
    assert comm.rank != 0 or re.search(message, line), line
    assert not out.exists()


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--patches", "100000"], r"--patches takes sizes in 1..1000 \(patches per side\), got \[100000\]"),
        (["--patches", "3000"], r"--patches takes sizes in 1..1000"),
        (["--patches", "900"], r"--patches 900 needs about \d+ GiB for one Newton iteration with MUMPS"),
        (["--repeats", "0"], r"--repeats must be an integer in 1..100000, got 0"),
        (["--repeats", "-2"], r"--repeats must be an integer in 1..100000, got -2"),
    ],
)
def test_bench_sizes_and_counts_are_refused_before_allocating(comm, capsys, arguments, message):
    line = one_error_line(comm, capsys, cli.main(["bench", *arguments]))
    assert comm.rank != 0 or re.search(message, line), line


def _bspline_files(directory: Path) -> dict[str, str]:
    """B-spline surface files, each broken in one way, and the message each must give."""
    good = directory / "good.npz"
    B.flat_rectangle(0.4, 0.3, 3, 2, degree=2).save(good)
    data = dict(np.load(good))
    broken = {"version-list": ({"version": np.array([1, 1])}, r"key 'version' must be an integer, got \[1, 1\]"),
              "version-text": ({"version": np.array("abc")}, r"key 'version' must be an integer, got 'abc'"),
              "degree-fraction": ({"degree": np.array(2.5)}, r"key 'degree' must be an integer, got 2.5")}  # fmt: skip
    messages = {}
    for name, (change, message) in broken.items():
        np.savez(directory / f"{name}.npz", **(data | change))
        messages[name] = message
    (directory / "truncated.npz").write_bytes(good.read_bytes()[:2000])
    messages["truncated"] = r"cannot read B-spline surface file \(BadZipFile"
    return messages


def test_a_broken_surface_file_is_named_with_its_key(comm, shared_tmp_path, capsys):
    messages = _bspline_files(shared_tmp_path) if comm.rank == 0 else None
    messages = comm.bcast(messages)
    for name, message in messages.items():
        scene = shared_tmp_path / f"{name}.toml"
        if comm.rank == 0:
            surface = f'kind = "file"\npath = "{name}.npz"\ndiscretization = "bspline2"'
            scene.write_text(BASE.replace(RECTANGLE, surface))
        comm.Barrier()
        out = shared_tmp_path / f"out-{name}"
        line = one_error_line(comm, capsys, cli.main(["run", str(scene), "--out", str(out), "--no-progress"]))
        assert comm.rank != 0 or (f"{name}.npz" in line and re.search(message, line)), (name, line)
        assert not out.exists()


def test_a_path_continued_with_other_probes_is_refused_and_left_as_it_was(comm, shared_tmp_path, capsys):
    out = shared_tmp_path / "arch"
    arch = REPO / "jobs" / "shallow-arch.toml"
    assert cli.main(["run", str(arch), "--out", str(out), "--steps", "3", "--no-progress"]) == 0
    capsys.readouterr()
    renamed = shared_tmp_path / "renamed.toml"
    if comm.rank == 0:
        renamed.write_text(arch.read_text().replace('name = "mid"', 'name = "centre"'))
    comm.Barrier()
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    code = cli.main(["run", str(renamed), "--out", str(out), "--restart", str(out), "--no-progress"])
    line = one_error_line(comm, capsys, code)
    assert comm.rank != 0 or "the scene's probes ['centre'] are not those of the run it continues" in line, line
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before


@pytest.mark.serial_child
@pytest.mark.parametrize("ranks", ["abc", "0", "-3", "1.5"])
def test_the_workstation_script_names_a_bad_rank_count(comm, shared_tmp_path, ranks):
    if comm.rank == 0:
        env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "PMI_"))}
        done = subprocess.run(["bash", str(REPO / "jobs" / "run.sh"), "s.toml", str(shared_tmp_path / "o"), ranks],
                              env=env, capture_output=True, text=True, timeout=60)  # fmt: skip
        expected = f"RANKS must be an integer in 1..100000, got '{ranks}'"
        assert done.returncode == 2 and done.stderr.strip().endswith(expected), done.stderr
        assert not (shared_tmp_path / "o").exists()


def test_bench_of_a_scene_whose_first_step_fails_names_the_scene(comm, shared_tmp_path, capsys):
    scene = shared_tmp_path / "hopeless.toml"
    if comm.rank == 0:  # a tolerance no Newton iteration reaches
        scene.write_text(BASE + "\n[solver]\noptions = { snes_rtol = 1e-300, snes_atol = 1e-300, snes_stol = 0, "
                         "snes_max_it = 2 }\n")  # fmt: skip
    comm.Barrier()
    line = one_error_line(comm, capsys, cli.main(["bench", "--scene", str(scene), "--steps", "1", "--warmup", "0"]))
    assert comm.rank != 0 or (f"{scene}: cannot be benchmarked: time step 1" in line and "failed after" in line), line
