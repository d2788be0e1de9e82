"""Checkpoints: raw DOF arrays and attributes in one HDF5 file, written atomically (restart is bit-exact)."""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np


def write_checkpoint(path: str | Path, state: dict[str, np.ndarray], attributes: dict[str, object]) -> None:
    """Write arrays and attributes to ``path`` atomically (temporary file, then rename)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        with h5py.File(tmp, "w") as f:
            for name, array in state.items():
                f[name] = array
            for name, value in attributes.items():
                f.attrs[name] = value
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)  # the previous checkpoint stays as it was
        raise


def read_checkpoint(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, object]]:
    """Arrays and attributes of a checkpoint written by :func:`write_checkpoint`."""
    with h5py.File(path, "r") as f:
        return {name: f[name][()] for name in f}, dict(f.attrs)
