"""The output directory of a run: checked before anything is computed, replaced whole when the run
starts writing, or continued in place by a restart.

A run never writes into a directory that still holds another run's files: with ``--force`` the old
directory is renamed aside, a fresh one takes its name and the old one is deleted, all at the moment
the new run writes its first file (a run that fails before that leaves the old result untouched).
Files are created anew or replaced by rename, so a symbolic link in the old directory is never
written through. Serial: call on one rank.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from bhem_hpc.errors import UserError

#: The files a run writes; a restart in place refuses to continue through a symbolic link among them.
RUN_FILES = (
    "scene.toml", "surface.xdmf", "surface.h5", "surface.pvd", "surface_frames", "checkpoint.h5", "summary.json",
    "last.png", "path.csv", "path.png", "probes.csv",
)  # fmt: skip


class OutputDirectoryError(UserError, ValueError):
    """The output directory cannot be used as asked."""


def check_output_directory(out: Path, force: bool, continuing: bool) -> None:
    """Raise :class:`OutputDirectoryError` unless a run can write ``out``.

    Args:
        force: replace an existing, non-empty directory (when the run starts writing).
        continuing: a restart that continues the run already in ``out``.
    """
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise OutputDirectoryError(f"output directory {out} is not a directory (a file or a symbolic link)")
    if continuing:
        for name in RUN_FILES:
            if (out / name).is_symlink():
                raise OutputDirectoryError(f"{out / name} is a symbolic link: a run does not write through links")
        _probe(out)
        return
    if out.exists() and any(out.iterdir()):
        if not force:
            raise OutputDirectoryError(f"output directory {out} exists and is not empty: pass --force to overwrite it")
        cwd = Path.cwd().resolve()
        if cwd == out.resolve() or out.resolve() in cwd.parents:
            raise OutputDirectoryError(f"--force would replace {out}, which holds the working directory")
    parent = out.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputDirectoryError(f"output directory {out} cannot be written: {exc.strerror}") from None
    _probe(parent)


def _probe(directory: Path) -> None:
    probe = directory / f".bhem-write-test-{os.getpid()}"
    try:
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise OutputDirectoryError(f"output directory {directory} cannot be written: {exc.strerror}") from None


def write_replacing(path: Path, data: str | bytes) -> None:
    """Write ``path`` under a temporary name, then rename it: never half-written, never through a
    symbolic link."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        if isinstance(data, str):
            tmp.write_text(data)
        else:
            tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)  # a full disk leaves no partial file behind
        raise


def start_output_directory(out: Path) -> None:
    """Make ``out`` a fresh, empty directory: an existing one is renamed aside, then deleted."""
    if out.exists():
        aside = out.with_name(f".{out.name}.replaced-{os.getpid()}")
        os.rename(out, aside)
        out.mkdir()
        shutil.rmtree(aside, ignore_errors=True)
    else:
        out.mkdir(parents=True)
