"""``python -m bhem_hpc.compiled``: compile every compiled function once and cache it (``make setup``
runs it, so that the test processes load them instead of each compiling them for a minute), and
remove the caches of other versions of the package's sources beside it."""

from __future__ import annotations

import shutil

from bhem_hpc.compiled import CACHE_DIRECTORY
from bhem_hpc.compiled.warm import load_all

if __name__ == "__main__":
    print(f"bhem_hpc.compiled: compiled and cached in {load_all():.0f} s", flush=True)
    for stale in CACHE_DIRECTORY.parent.glob("numba-*"):
        if stale != CACHE_DIRECTORY and stale.is_dir():
            shutil.rmtree(stale, ignore_errors=True)
