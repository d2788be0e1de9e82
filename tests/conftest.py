"""Shared fixtures. Every test runs serially and under ``mpirun -n 2`` (each rank runs the suite).

Tests marked ``parallel`` compare a run on this process's ranks with a serial one: they can only
fail on more than one rank, so a serial session does not collect them. Tests marked ``serial_child``
start the command line as a serial child process of rank 0 (with no MPI environment) and check only
what it does; tests marked ``rank_free`` use no communicator at all (numpy geometry, collision, the
SEM pipeline, serial dolfinx references on ``COMM_SELF``). A session on several ranks would repeat
either kind as the serial session runs it, on every rank, so it does not collect them.
"""

from __future__ import annotations

# isort: off
from bhem_hpc.blas import use_best_kernels

use_best_kernels()  # first: OpenBLAS reads its kernel choice when numpy loads it
# isort: on

import logging
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

# FFCx configures logging on import; keep the test output readable.
logging.getLogger("ffcx").setLevel(logging.WARNING)
logging.getLogger("UFL").setLevel(logging.WARNING)
logging.getLogger("root").setLevel(logging.WARNING)
logging.getLogger().setLevel(logging.WARNING)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--serial-results",
        type=Path,
        default=None,
        help="stress cases: a serial run saves its final positions here, a 2-rank run compares with them",
    )


@pytest.fixture
def serial_results(request: pytest.FixtureRequest) -> Path | None:
    return request.config.getoption("--serial-results")


@pytest.fixture
def comm() -> MPI.Comm:
    return MPI.COMM_WORLD


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261122)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    left_out = ("serial_child", "rank_free") if MPI.COMM_WORLD.size > 1 else ("parallel",)
    deselected = [item for item in items if any(item.get_closest_marker(name) for name in left_out)]
    if deselected:
        config.hook.pytest_deselected(items=deselected)
        items[:] = [item for item in items if item not in deselected]


@pytest.fixture
def shared_tmp_path(comm):
    """A fresh directory that every rank sees (made on rank 0), removed after the test."""
    path = Path(comm.bcast(tempfile.mkdtemp(prefix="bhem-test-") if comm.rank == 0 else None))
    yield path
    comm.Barrier()
    if comm.rank == 0:
        shutil.rmtree(path, ignore_errors=True)
