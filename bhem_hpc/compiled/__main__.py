"""``python -m bhem_hpc.compiled``: compile every compiled function once and cache it (``make setup``
runs it, so that the test processes load them instead of each compiling them for a minute)."""

from __future__ import annotations

from bhem_hpc.compiled.warm import load_all

if __name__ == "__main__":
    print(f"bhem_hpc.compiled: compiled and cached in {load_all():.0f} s", flush=True)
