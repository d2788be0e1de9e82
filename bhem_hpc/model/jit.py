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


#: Seconds a process waits for another's compile of the same form (under MPI all ranks wait for one).
JIT_TIMEOUT = 600
#: The cache folders this process has cleared of abandoned compiles.
_checked_caches: set[str] = set()


def default_jit_params() -> dict:
    """JIT settings: a generous timeout, since under MPI all ranks wait for one compile;
    ``BHEM_JIT_CFLAGS`` replaces the compiler flags, ``BHEM_JIT_CACHE`` the cache folder. The
    folder is cleared of abandoned compiles once per process (:func:`remove_abandoned_compiles`)."""
    cache_dir = os.environ.get("BHEM_JIT_CACHE") or _cpu_specific_cache()
    if cache_dir not in _checked_caches:
        _checked_caches.add(cache_dir)
        remove_abandoned_compiles(cache_dir, JIT_TIMEOUT)
    return {
        "timeout": JIT_TIMEOUT,
        "cache_dir": cache_dir,
        "cffi_extra_compile_args": os.environ.get("BHEM_JIT_CFLAGS", JIT_CFLAGS).split(),
    }


def remove_abandoned_compiles(cache_dir: str, age: float) -> list[str]:
    """Remove the compiles a killed process left in ``cache_dir``: ffcx marks a compile under way by
    its ``<module>.c`` and a finished one by ``<module>.c.cached``; a ``.c`` without its mark that is
    older than ``age`` seconds (a waiting process gives up then) would make every later process wait
    ``age`` seconds for it and fail. Its files (``<module>.*``) go, with a warning; returns the
    modules removed."""
    try:
        names = os.listdir(cache_dir)
    except OSError:
        return []
    present, now, removed = set(names), time.time(), []
    for name in names:
        if not name.endswith(".c") or name + ".cached" in present:
            continue
        try:
            if now - os.path.getmtime(os.path.join(cache_dir, name)) <= age:
                continue  # another process may be compiling it
        except OSError:
            continue
        module = name.removesuffix(".c")
        for other in names:
            if other.startswith(module + "."):
                with contextlib.suppress(OSError):  # another rank may have removed it first
                    os.remove(os.path.join(cache_dir, other))
        removed.append(module)
    if removed:
        log.warning("removed %d abandoned JIT compiles from %s (a process was stopped while compiling): %s",
                    len(removed), cache_dir, ", ".join(removed))  # fmt: skip
    return removed


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
