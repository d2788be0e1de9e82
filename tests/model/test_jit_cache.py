"""The JIT cache: compiles a stopped process abandoned are removed (they would make every later
process wait for them and fail); compiles under way and finished ones stay."""

from __future__ import annotations

import os
import time

import pytest

from bhem_hpc.model.jit import remove_abandoned_compiles


@pytest.mark.rank_free
def test_an_abandoned_compile_is_removed_and_live_or_finished_ones_stay(tmp_path):
    old = time.time() - 3600
    files = {
        "libffcx_forms_abandoned.c": old, "libffcx_forms_abandoned.o": old,  # killed while compiling
        "libffcx_forms_live.c": time.time(),  # another process compiles it now
        "libffcx_forms_done.c": old, "libffcx_forms_done.c.cached": old, "libffcx_forms_done.so": old,
    }  # fmt: skip
    for name, mtime in files.items():
        (tmp_path / name).write_text("")
        os.utime(tmp_path / name, (mtime, mtime))
    assert remove_abandoned_compiles(str(tmp_path), 600) == ["libffcx_forms_abandoned"]
    assert sorted(os.listdir(tmp_path)) == ["libffcx_forms_done.c", "libffcx_forms_done.c.cached",
                                            "libffcx_forms_done.so", "libffcx_forms_live.c"]  # fmt: skip
    assert remove_abandoned_compiles(str(tmp_path / "missing"), 600) == []
