"""The output directory of a run: locked and checked before anything is computed, replaced whole
when the run starts writing, or continued in place by a restart.

One writer at a time: a run holds :class:`OutputLock`, a file beside the directory
(``.OUT.lock``) naming its process and host, from its checks to its end; a second run, a
``--force`` run or a resubmitted job into the same directory is refused while the lock is held,
and a lock whose process is gone (on this host) is stale and taken over.

A run never writes into a directory that still holds another run's files: with ``--force`` the old
directory is renamed aside, a fresh one takes its name and the old one is deleted, all at the moment
the new run writes its first file (a run that fails before that leaves the old result untouched).
``--force`` replaces only what a run writes (:data:`RUN_FILES`, frames, the manifest): a directory
holding anything else is refused, its files named. Files are created anew or replaced by rename, so
a symbolic link in the old directory is never written through. Serial: call on one rank.
"""

from __future__ import annotations

import atexit
import json
import os
import re
import shutil
import socket
import time
from pathlib import Path

from bhem_hpc.errors import UserError

#: The files a run writes; a restart in place refuses to continue through a symbolic link among them.
RUN_FILES = (
    "scene.toml", "surface.xdmf", "surface.h5", "surface.pvd", "surface_frames", "checkpoint.h5", "summary.json",
    "last.png", "path.csv", "path.png", "probes.csv", "steps.jsonl", "bodies.pvd", "surface_points.pvd",
)  # fmt: skip


#: The manifest a run writes first: it marks the directory as a bhem-hpc run's output.
MANIFEST = ".bhem-run"
#: Files of the frames folder a run writes (a solid's: its boundary and its quadrature points).
FRAME_FILE = re.compile(r"frame_\d+((_boundary|_points)?\.vtu|\.igs)(\.tmp)?")
#: A lock file younger than this whose content cannot be read yet is being written: held.
LOCK_WRITE_SECONDS = 60.0


class OutputDirectoryError(UserError, ValueError):
    """The output directory cannot be used as asked."""


def foreign_entries(out: Path, most: int = 5) -> list[str]:
    """Up to ``most`` entries of ``out`` (relative paths) that no run of this tool writes (a run of
    several bodies writes a folder per body, and one of model frames per CAD shell, named in its
    manifest)."""
    return _foreign_in(out, "", set(manifest_bodies(out)), most, set(manifest_bodies(out, "models")))


def run_series(out: Path) -> list[Path]:
    """The series of the run in ``out``: its own (``surface.h5``), or each body's of a run of several
    bodies (in the scene's order): a shell's ``surface.h5``, a solid's ``surface.pvd``.

    Raises:
        OutputDirectoryError: ``out`` holds no run's series.
    """
    bodies = manifest_bodies(out) if not (out / "surface.h5").is_file() else []
    series = [out / body / "surface.h5" for body in bodies] or [out / "surface.h5"]
    for k, h5 in enumerate(series):
        if not h5.is_file() and h5.with_name("surface_points.pvd").is_file():
            series[k] = h5.with_suffix(".pvd")  # a solid's
        elif not h5.is_file():
            raise OutputDirectoryError(f"{h5} does not exist: {out} is not the output directory of `bhem-hpc run`")
    return series


def manifest_bodies(out: Path, key: str = "bodies") -> list[str]:
    """The body folders the manifest of ``out`` names, in the scene's order (none: a run of one
    body, or no manifest); ``key = "models"``: the CAD shells' folders of model frames."""
    try:
        bodies = json.loads((out / MANIFEST).read_text()).get(key, [])
    except (OSError, ValueError, AttributeError):
        return []
    return [b for b in bodies if isinstance(b, str) and b.isidentifier()] if isinstance(bodies, list) else []


def _foreign_in(folder: Path, prefix: str, bodies: set[str], most: int, models: frozenset | set = frozenset()
                ) -> list[str]:  # fmt: skip
    own = {*RUN_FILES, MANIFEST, *(f"{name}.tmp" for name in RUN_FILES)}
    found = []
    for entry in sorted(folder.iterdir()):
        name = entry.name
        is_dir = entry.is_dir() and not entry.is_symlink()
        if (name == "surface_frames" or name in models) and is_dir:
            found += [f"{prefix}{name}/{f.name}" for f in sorted(entry.iterdir()) if not FRAME_FILE.fullmatch(f.name)]
        elif name in bodies and is_dir:
            found += _foreign_in(entry, f"{prefix}{name}/", set(), most - len(found))
        elif name not in own and not name.startswith(".bhem-write-test-"):
            found.append(prefix + name + ("/" if is_dir else ""))
        if len(found) >= most:
            break
    return found[:most]


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
        foreign = foreign_entries(out)
        if foreign:
            raise OutputDirectoryError(
                f"output directory {out} holds files bhem-hpc did not write ({', '.join(foreign)}): --force replaces "
                "only a run's own output; move them or choose another --out"
            )
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


def start_output_directory(out: Path, bodies: list[str] | None = None, models: list[str] | None = None) -> None:
    """Make ``out`` a fresh directory holding only the manifest (naming the folders of ``bodies``, a
    run of several, and of ``models``, its CAD shells' model frames): an existing one is renamed
    aside, then deleted."""
    if out.exists():
        aside = out.with_name(f".{out.name}.replaced-{os.getpid()}")
        os.rename(out, aside)
        out.mkdir()
        shutil.rmtree(aside, ignore_errors=True)
    else:
        out.mkdir(parents=True)
    manifest = ({"tool": "bhem-hpc", "files": list(RUN_FILES)} | ({"bodies": list(bodies)} if bodies else {})
                | ({"models": list(models)} if models else {}))  # fmt: skip
    write_replacing(out / MANIFEST, json.dumps(manifest) + "\n")


class OutputLock:
    """The lock of one output directory: the file ``.NAME.lock`` beside it (it survives the
    directory's replacement), created exclusively, holding ``{"pid", "host", "since"}``.

    :meth:`acquire` takes it or raises :class:`OutputDirectoryError` naming the holder; a lock of
    this host whose process no longer exists (a killed run) is stale and taken over. :meth:`release`
    removes it if it is still this process's (also at interpreter exit, on any error).
    """

    def __init__(self, out: Path):
        self.out = out
        self.path = out.parent / f".{out.name}.lock"
        self.held = False

    def acquire(self) -> None:
        """Take the lock (the directory's parent is made if missing)."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputDirectoryError(f"output directory {self.out} cannot be written: {exc.strerror}") from None
        for _ in range(2):  # a stale lock is removed once, then taken
            try:
                descriptor = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._holder()
                if holder is not None:
                    raise OutputDirectoryError(
                        f"output directory {self.out} is being written by another run "
                        f"({holder}): wait for it to end, or remove {self.path} if that run is gone"
                    ) from None
                self.path.unlink(missing_ok=True)  # stale: its process is gone
                continue
            except OSError as exc:  # its lock beside it cannot be made: the folder cannot be written either
                raise OutputDirectoryError(f"output directory {self.out} cannot be written: {exc.strerror}") from None
            with os.fdopen(descriptor, "w") as f:
                json.dump({"pid": os.getpid(), "host": socket.gethostname(), "since": time.time()}, f)
            self.held = True
            atexit.register(self.release)  # an error that escapes the run still frees it
            return
        raise OutputDirectoryError(f"cannot lock {self.path}: another run keeps taking it")

    def _holder(self) -> str | None:
        """Who holds the existing lock (None: nobody, the lock is stale)."""
        try:
            record = json.loads(self.path.read_text())
            pid, host = int(record["pid"]), str(record["host"])
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError):
            try:  # being written right now, or garbage left by a crash
                young = time.time() - self.path.stat().st_mtime < LOCK_WRITE_SECONDS
            except OSError:
                return None
            return "a lock being written" if young else None
        if host != socket.gethostname():
            return f"process {pid} on host {host}"  # another host's process cannot be checked from here
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None
        except PermissionError:
            pass  # alive, another user's
        return f"process {pid} on this host"

    def release(self) -> None:
        """Remove the lock if this process holds it."""
        if not self.held:
            return
        self.held = False
        try:
            record = json.loads(self.path.read_text())
            if int(record.get("pid", -1)) == os.getpid():
                self.path.unlink()
        except (OSError, ValueError, TypeError):
            pass
