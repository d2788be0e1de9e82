"""OpenBLAS kernels chosen from the CPU's instruction sets before the library loads."""

from __future__ import annotations

import os

import pytest

from bhem_hpc.blas import (
    choose_openblas_kernels,
    cpu_flags,
    generic_kernels_loaded,
    openblas_core,
)

pytestmark = pytest.mark.rank_free  # no communicator: the same computation on every rank

AVX512 = {"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"}


def test_the_best_kernels_the_flags_support():
    for flags, expected in ((AVX512 | {"avx2", "fma", "sse3"}, "SkylakeX"), ({"avx2", "fma", "sse3"}, "Haswell"),
                            ({"avx512f", "avx2", "sse3"}, None), ({"sse3"}, None)):  # fmt: skip
        environ: dict[str, str] = {}
        assert choose_openblas_kernels(environ, frozenset(flags)) == expected
        assert environ == ({"OPENBLAS_CORETYPE": expected} if expected else {})


def test_a_core_type_the_user_set_is_kept():
    environ = {"OPENBLAS_CORETYPE": "Zen"}
    assert choose_openblas_kernels(environ, frozenset(AVX512 | {"avx2", "fma"})) is None
    assert environ == {"OPENBLAS_CORETYPE": "Zen"}


def test_this_process_runs_the_kernels_chosen_for_its_cpu():
    # conftest imports bhem_hpc before numpy: the choice reached OpenBLAS when it loaded
    chosen = choose_openblas_kernels({}, cpu_flags())
    core = openblas_core()
    assert core is not None  # setup installs OpenBLAS as the system BLAS
    if chosen is not None and os.environ.get("OPENBLAS_CORETYPE") == chosen:
        assert core.lower() == chosen.lower()
    assert cpu_flags("/nonexistent/cpuinfo") == frozenset()


def test_generic_kernels_loaded_before_bhem_hpc_are_reported():
    assert generic_kernels_loaded("SkylakeX", "Prescott")  # numpy loaded OpenBLAS first on an unknown model
    assert not generic_kernels_loaded("SkylakeX", "Cooperlake")  # OpenBLAS knew the CPU: wide kernels
    assert not generic_kernels_loaded("Haswell", "Zen")
    assert not generic_kernels_loaded(None, "Prescott")  # the user's choice, or a CPU without AVX2
    assert not generic_kernels_loaded("SkylakeX", None)  # no OpenBLAS loaded yet
