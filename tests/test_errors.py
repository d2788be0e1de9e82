"""One family of user errors: the command line prints them on one line (exit 2); anything else is a
bug and keeps its traceback. Importing the package leaves the process's environment alone."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest
from mpi4py import MPI

from bhem_hpc import cli
from bhem_hpc.errors import InputError, UserError

PACKAGE = Path(__file__).resolve().parents[1] / "bhem_hpc"
#: Exception classes that are not the user's to act on: an internal consistency check.
NOT_USER_ERRORS: set[str] = set()


def _exception_classes() -> dict[str, list[str]]:
    """``name -> base names`` of every class in the package whose name ends in Error or Failure."""
    found = {}
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef) and node.name.endswith(("Error", "Failure")):
                found[f"{path.relative_to(PACKAGE)}:{node.name}"] = [ast.unparse(b) for b in node.bases]
    return found


def test_every_error_class_of_the_package_is_a_user_error():
    classes = _exception_classes()
    assert len(classes) >= 20
    user_families = {"UserError", "InputError"} | {key.split(":")[1] for key in classes}
    outside = {key: bases for key, bases in classes.items()
               if key.split(":")[1] not in NOT_USER_ERRORS and key != "errors.py:UserError"
               and not set(bases) & user_families}  # fmt: skip
    assert not outside, outside


def test_a_user_error_is_one_line_and_exit_2(monkeypatch, capsys):
    def refuse(args, comm):
        raise InputError("scene.toml: key 'time.dt' must be > 0, got -1")

    monkeypatch.setitem(cli.HANDLERS, "render", refuse)
    assert cli.main(["render", "nowhere"]) == 2
    err = capsys.readouterr().err
    expected = "bhem-hpc: error: scene.toml: key 'time.dt' must be > 0, got -1" if MPI.COMM_WORLD.rank == 0 else ""
    assert err.strip() == expected  # rank 0 reports for all


def test_a_bug_is_not_reported_as_bad_input(monkeypatch, capsys):
    def broken(args, comm):
        return [][1]  # an IndexError: no user could fix this by changing the input

    monkeypatch.setitem(cli.HANDLERS, "render", broken)
    with pytest.raises(IndexError):
        cli.main(["render", "nowhere"])
    err = capsys.readouterr().err
    assert "internal error" in err and "bug" in err and "bhem-hpc: error:" not in err


def test_a_numpy_value_error_from_a_bug_is_not_a_user_error():
    assert not issubclass(ValueError, UserError)
    assert issubclass(InputError, ValueError)  # callers that catch ValueError keep working


def test_importing_the_package_changes_no_environment():
    code = (
        "import os, sys; before = dict(os.environ); import bhem_hpc, bhem_hpc.cli, bhem_hpc.model.hessian; "
        "sys.exit(0 if dict(os.environ) == before else 1)"
    )
    env = {k: v for k, v in __import__("os").environ.items() if k != "OPENBLAS_CORETYPE"}
    assert subprocess.run([sys.executable, "-c", code], env=env).returncode == 0
