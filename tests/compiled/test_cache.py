"""The compiled functions' cache is keyed by every source of the package."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numba

import bhem_hpc.compiled as compiled
from bhem_hpc.compiled import line_crossings


def test_the_cache_directory_is_named_by_all_sources_of_the_package():
    sources = sorted(Path(compiled.__file__).parent.glob("*.py"))
    assert {p.name for p in sources} >= {"patch_kernels.py", "line_crossings.py", "ray_hits.py", "projection.py"}
    digest = hashlib.sha256(numba.__version__.encode() + b"".join(p.read_bytes() for p in sources)).hexdigest()[:16]
    assert compiled.CACHE_DIRECTORY.name == f"numba-{digest}"
    # a search compiled with the kernels of another version of patch_kernels.py is not found there
    assert Path(line_crossings._all_crossings._cache._cache_path).is_relative_to(compiled.CACHE_DIRECTORY)
    assert numba.config.CACHE_DIR == str(compiled.CACHE_DIRECTORY)
