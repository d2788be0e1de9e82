"""Shared fixtures. Every test runs serially and under ``mpirun -n 2`` (each rank runs the suite)."""

from __future__ import annotations

import logging
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
