"""OpenBLAS kernels chosen by the CPU's instruction sets, before the library loads.

MUMPS spends its factorizations and triangular solves in BLAS. OpenBLAS picks its kernels from the
CPU's model number; on a model its table does not list (common on virtual machines, which report a
generic "Intel Xeon Processor") it falls back to its generic SSE3 kernels ("Prescott"), far slower
for an LDL^T than the AVX-512 or AVX2 ones on the same CPU. OpenBLAS reads
``OPENBLAS_CORETYPE`` once, when it loads; :func:`choose_openblas_kernels` sets it from the
instruction sets the CPU reports, unless the user set it. :func:`use_best_kernels` applies it to this
process: the command line calls it first; a script calls it before it imports numpy, PETSc or
anything else that loads BLAS.

No numpy here: importing it would load the BLAS this module is meant to configure.
"""

from __future__ import annotations

import ctypes
import logging
import os
from collections.abc import MutableMapping

#: OpenBLAS core types and the CPU flags (as in /proc/cpuinfo) their kernels need, best first.
KERNELS_BY_FLAGS: tuple[tuple[str, frozenset[str]], ...] = (
    ("SkylakeX", frozenset({"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"})),
    ("Haswell", frozenset({"avx2", "fma"})),
)

#: OpenBLAS core types with AVX2 or wider kernels: a BLAS already loaded with one of these is fine.
VECTOR_CORES = frozenset({"haswell", "zen", "skylakex", "cooperlake", "sapphirerapids"})

log = logging.getLogger("bhem_hpc.blas")


def cpu_flags(cpuinfo: str = "/proc/cpuinfo") -> frozenset[str]:
    """The instruction-set flags of the first processor listed in ``cpuinfo`` (empty if unreadable)."""
    try:
        with open(cpuinfo) as f:
            for line in f:
                if line.startswith("flags"):
                    return frozenset(line.partition(":")[2].split())
    except OSError:
        pass
    return frozenset()


def choose_openblas_kernels(
    environ: MutableMapping[str, str] = os.environ, flags: frozenset[str] | None = None
) -> str | None:
    """Set ``OPENBLAS_CORETYPE`` in ``environ`` to the best kernels the CPU's ``flags`` support.

    Returns the core type set, or None when the user already set one or no listed kernels fit
    (OpenBLAS then detects as usual). Child processes (``mpirun`` ranks) inherit the choice.
    """
    if environ.get("OPENBLAS_CORETYPE"):
        return None
    available = cpu_flags() if flags is None else flags
    for core, needed in KERNELS_BY_FLAGS:
        if needed <= available:
            environ["OPENBLAS_CORETYPE"] = core
            return core
    return None


def generic_kernels_loaded(chosen: str | None, loaded: str | None) -> bool:
    """Whether OpenBLAS was ``loaded`` (its core type, None: not loaded) with kernels narrower than
    AVX2 although the CPU supports the ``chosen`` ones: numpy or PETSc loaded it before bhem_hpc
    could set ``OPENBLAS_CORETYPE``."""
    return chosen is not None and loaded is not None and loaded.lower() not in VECTOR_CORES


def warn_about_generic_kernels(chosen: str | None) -> None:
    """Log a warning when this process's OpenBLAS runs generic kernels that ``chosen`` would replace."""
    if chosen is None:
        return  # the user's choice, or no wider kernels to offer: nothing to look up
    loaded = openblas_core()
    if generic_kernels_loaded(chosen, loaded):
        log.warning(
            "OpenBLAS runs its generic %s kernels, loaded before bhem_hpc was imported; MUMPS runs faster with "
            "OPENBLAS_CORETYPE=%s set before Python starts (or bhem_hpc imported before numpy and PETSc)",
            loaded, chosen,
        )  # fmt: skip


def openblas_core() -> str | None:
    """The kernels the loaded OpenBLAS uses (``openblas_get_corename``), or None when no OpenBLAS
    is loaded in this process."""
    try:
        with open("/proc/self/maps") as f:
            mapped = {line.split()[-1] for line in f}
        paths = {path for path in mapped if os.path.basename(path).startswith("libopenblas")}
    except OSError:
        return None
    for path in sorted(paths):
        try:
            library = ctypes.CDLL(path)
            corename = library.openblas_get_corename
        except (OSError, AttributeError):
            continue
        corename.restype = ctypes.c_char_p
        return corename().decode()
    return None


def blas_label(core: str | None) -> str:
    """How a measured page names the BLAS: ``core`` as :func:`openblas_core` returned it."""
    return f"OpenBLAS with its {core} kernels" if core else "not OpenBLAS"


def use_best_kernels() -> str | None:
    """Set this process's ``OPENBLAS_CORETYPE`` from its CPU (unless set) and warn when OpenBLAS was
    already loaded with generic kernels. Returns the kernels chosen (None: the user's or none wider)."""
    chosen = choose_openblas_kernels()
    warn_about_generic_kernels(chosen)
    return chosen
