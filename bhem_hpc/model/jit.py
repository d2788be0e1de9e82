"""Form compilation settings: compiler flags and a JIT cache per CPU model."""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import platform
import time
from collections.abc import Iterator

# The shell kernels are long chains of products, sums and square roots. Letting the compiler
# reassociate sums and inline sqrt (no errno) halves the Jacobian kernel's time; unlike
# -ffast-math this keeps IEEE NaN/Inf semantics, so a NaN still reaches the residual norm.
JIT_CFLAGS = (
    "-O3 -march=native -fno-math-errno -fno-trapping-math -fassociative-math -fno-signed-zeros -freciprocal-math -g0"
)


def _cpu_specific_cache() -> str:
    """A JIT cache folder per CPU model: -march=native code must not meet another CPU, e.g.
    through a home directory shared by the nodes of a cluster."""
    signature = platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            lines = [line for line in f if line.startswith(("model name", "flags"))]
        signature += "".join(sorted(set(lines)))
    except OSError:
        pass
    tag = hashlib.sha1(signature.encode()).hexdigest()[:12]
    return os.path.join(os.path.expanduser("~/.cache/bhem-hpc"), f"jit-{tag}")


def default_jit_params() -> dict:
    """JIT settings: a generous timeout, since under MPI all ranks wait for one compile;
    ``BHEM_JIT_CFLAGS`` replaces the compiler flags, ``BHEM_JIT_CACHE`` the cache folder."""
    return {
        "timeout": 600,
        "cache_dir": os.environ.get("BHEM_JIT_CACHE") or _cpu_specific_cache(),
        "cffi_extra_compile_args": os.environ.get("BHEM_JIT_CFLAGS", JIT_CFLAGS).split(),
    }


log = logging.getLogger("bhem_hpc.jit")


@contextlib.contextmanager
def compilation_report(what: str, cache_dir: str) -> Iterator[None]:
    """Log one line (logger ``bhem_hpc.jit``, INFO) when the block compiled new kernels, with the time.

    The compiler's own command lines (setuptools logs them on the root logger) are dropped unless
    ``bhem_hpc.jit`` is enabled for DEBUG (``bhem-hpc --verbose``).
    """
    before = _cached_kernels(cache_dir)
    start = time.perf_counter()
    quiet = not log.isEnabledFor(logging.DEBUG)
    hide = HideCompilerCommands()
    if quiet:
        logging.getLogger().addFilter(hide)
    try:
        yield
    finally:
        logging.getLogger().removeFilter(hide)
    new = _cached_kernels(cache_dir) - before
    if new:
        seconds = time.perf_counter() - start
        log.info("compiled %d new kernels for %s in %.1f s (cache: %s)", new, what, seconds, cache_dir)


def _cached_kernels(cache_dir: str) -> int:
    try:
        return sum(name.endswith(".so") for name in os.listdir(cache_dir))
    except OSError:
        return 0


class HideCompilerCommands(logging.Filter):
    """Drop the INFO records that setuptools writes to the root logger while the JIT builds kernels
    (``running build_ext``, compiler command lines); ``--verbose`` leaves them in."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.name != "root" or record.levelno >= logging.WARNING
