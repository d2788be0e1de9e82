"""Compiled (numba) versions of the geometry package's ray queries on rational Bezier patches, for the
setup stages of solids; the numpy functions of :mod:`bhem_hpc.geometry` are their reference. Ruled
patches (degree 1 along one parameter) are met exactly, as the roots of one polynomial
(:mod:`.ruled_patches`), where the reference searches to a tolerance.

numba caches each compiled function beside its module and checks only that module's own source
when it loads one, not the modules whose functions it compiled in: a changed kernel in
``patch_kernels.py`` would leave the searches that use it compiled with the old one. So every
function of this package caches under a directory named by a hash of all of its sources (and of
numba's version), set before any of them is defined."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numba

_SOURCES = sorted(Path(__file__).parent.glob("*.py"))
_DIGEST = hashlib.sha256(numba.__version__.encode() + b"".join(p.read_bytes() for p in _SOURCES)).hexdigest()[:16]
_HERE = Path(__file__).parent
#: Where this package's compiled functions are cached: under NUMBA_CACHE_DIR where that is set, else
#: beside the sources, or in the user's cache where the sources are not writable (an installed copy).
CACHE_DIRECTORY = Path(
    os.environ.get("NUMBA_CACHE_DIR")
    or (_HERE / "__pycache__" if os.access(_HERE, os.W_OK) else Path.home() / ".cache" / "bhem-hpc")
) / f"numba-{_DIGEST}"
numba.config.CACHE_DIR = str(CACHE_DIRECTORY)
