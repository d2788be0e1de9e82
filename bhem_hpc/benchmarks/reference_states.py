"""Reference states of the shipped jobs: record them at one commit, compare another against them.

``bhem-hpc states --record FILE`` runs every scene of ``jobs/`` (or the ones named) for its first
``--steps`` time steps (static scenes: path points) with ``bhem-hpc run`` and stores the final
position and velocity DOFs of each in an ``.npz`` file, with the run's Newton iterations.
``bhem-hpc states --compare FILE`` runs the same jobs again and prints, per job, the largest
difference relative to the largest magnitude of the recorded arrays; it fails (exit 1) when one
exceeds ``--tolerance`` or a job's status or iteration count changed. A change of code that must
not change behaviour (moving code, renaming) is checked this way before it lands.

Arrays are the checkpoint's raw DOFs (``position_dofs``, ``velocity_dofs``; shape
``(nodes, nodes, kinds, 3)`` for Hermite grids), gathered on rank 0, so a comparison holds across
rank counts within the solver's tolerance only: compare runs on the same number of ranks for
bit-exactness.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from bhem_hpc.errors import UserError

#: The scene files compared by default: every TOML scene of the repository's ``jobs/``.
JOBS_DIRECTORY = Path(__file__).resolve().parents[2] / "jobs"
#: Arrays of a checkpoint that make a job's state.
STATE_ARRAYS = ("position_dofs", "velocity_dofs")


class ReferenceError(UserError, ValueError):
    """A reference file or job list that cannot be used."""


@dataclass(frozen=True)
class JobState:
    """A job's final state after ``steps`` steps: its arrays and the run's figures."""

    job: str
    steps: int
    status: str
    newton_iterations: int
    arrays: dict[str, np.ndarray]


def job_files(names: list[str] | None, directory: Path = JOBS_DIRECTORY) -> list[Path]:
    """The scene files of ``names`` (``jobs/<name>.toml``), or every scene of ``directory``."""
    if not names:
        return sorted(directory.glob("*.toml"))
    files = [directory / f"{name.removesuffix('.toml')}.toml" for name in names]
    missing = [f.name for f in files if not f.is_file()]
    if missing:
        raise ReferenceError(f"no such job in {directory}: {', '.join(missing)}")
    return files


def run_job(scene_file: Path, runs: Path, steps: int, comm: MPI.Comm) -> JobState | None:
    """Run ``scene_file`` for ``steps`` steps into ``runs/<job>``; its final state (rank 0; None elsewhere):
    the checkpoint's arrays, or for a scene of several bodies each body's last frame
    (``<body>/position_nodal``: nodal data or control points)."""
    from bhem_hpc.io import read_checkpoint, read_frame
    from bhem_hpc.run import RunOptions, run_scene

    out = runs / scene_file.stem
    summary = run_scene(RunOptions(scene_file, out, steps=steps, force=True, progress=False), comm)
    if comm.rank != 0:
        return None
    if "bodies" in summary:
        arrays = {f"{body['name']}_position_nodal": read_frame(out / body["name"] / "surface.h5")[0].nodal
                  for body in summary["bodies"]}  # fmt: skip
    else:
        arrays, _ = read_checkpoint(out / "checkpoint.h5")
        arrays = {name: arrays[name] for name in STATE_ARRAYS if name in arrays}
    records = summary["steps"]
    iterations = sum(int(r.get("newton_iterations", r.get("iterations", 0))) for r in records)
    return JobState(scene_file.stem, len(records), summary["status"], iterations,
                    {name: np.asarray(value) for name, value in arrays.items()})  # fmt: skip


def save_states(path: Path, states: list[JobState]) -> None:
    """Write ``states`` to ``path`` (``.npz``: ``<job>/<array>`` arrays and a ``figures`` JSON string)."""
    figures = {s.job: {"steps": s.steps, "status": s.status, "newton_iterations": s.newton_iterations}
               for s in states}  # fmt: skip
    arrays = {f"{s.job}/{name}": value for s in states for name, value in s.arrays.items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, figures=np.array(json.dumps(figures)), **arrays)


def load_states(path: Path) -> dict[str, JobState]:
    """The states :func:`save_states` wrote, by job."""
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ReferenceError(f"{path}: not a reference-state file ({exc})") from None
    with data:
        if "figures" not in data.files:
            raise ReferenceError(f"{path}: not a reference-state file (no 'figures' entry)")
        figures = json.loads(str(data["figures"]))
        arrays: dict[str, dict[str, np.ndarray]] = {job: {} for job in figures}
        for key in data.files:
            job, _, name = key.partition("/")
            if name:
                arrays.setdefault(job, {})[name] = data[key]
    return {job: JobState(job, f["steps"], f["status"], f["newton_iterations"], arrays[job])
            for job, f in figures.items()}  # fmt: skip


def state_difference(reference: JobState, state: JobState) -> float:
    """The largest entry of ``|state - reference|`` over the largest ``|reference|``, over all arrays
    (inf where the arrays' names or shapes differ)."""
    if reference.arrays.keys() != state.arrays.keys():
        return float("inf")
    worst = 0.0
    for name, ref in reference.arrays.items():
        new = state.arrays[name]
        if new.shape != ref.shape:
            return float("inf")
        scale = float(np.max(np.abs(ref))) if ref.size else 0.0
        difference = float(np.max(np.abs(new - ref))) if ref.size else 0.0
        worst = max(worst, difference / scale if scale > 0 else difference)
    return worst


def compare_states(references: dict[str, JobState], states: list[JobState], tolerance: float) -> list[str]:
    """One line per job; lines of failures start with ``FAIL``."""
    lines = []
    for state in states:
        reference = references.get(state.job)
        if reference is None:
            lines.append(f"FAIL {state.job}: not in the reference file")
            continue
        difference = state_difference(reference, state)
        same_run = (reference.status, reference.steps, reference.newton_iterations) == (
            state.status, state.steps, state.newton_iterations)  # fmt: skip
        verdict = "ok" if difference <= tolerance and same_run else "FAIL"
        lines.append(f"{verdict} {state.job}: relative difference {difference:.3e}, {state.steps} steps "
                     f"({reference.steps}), {state.newton_iterations} Newton iterations "
                     f"({reference.newton_iterations}), {state.status} ({reference.status})")  # fmt: skip
    return lines


def reference_states(record: Path | None, compare: Path | None, jobs: list[str] | None, steps: int,
                     runs: Path, tolerance: float, comm: MPI.Comm = MPI.COMM_WORLD) -> int:  # fmt: skip
    """The ``bhem-hpc states`` command: record or compare; its exit status (0: recorded or all equal)."""
    if (record is None) == (compare is None):
        raise ReferenceError("bhem-hpc states: give exactly one of --record FILE and --compare FILE")
    if steps < 1:
        raise ReferenceError(f"bhem-hpc states: --steps must be >= 1, got {steps}")
    if not tolerance >= 0:
        raise ReferenceError(f"bhem-hpc states: --tolerance must be >= 0, got {tolerance}")
    references = load_states(compare) if compare is not None else {}
    files = job_files(jobs)
    states = []
    for scene_file in files:
        start = time.perf_counter()
        state = run_job(scene_file, runs, steps, comm)
        if state is not None:
            states.append(state)
            print(f"{state.job}: {state.steps} steps, {state.status}, {time.perf_counter() - start:.1f} s", flush=True)
    if comm.rank != 0:
        return 0
    if record is not None:
        save_states(record, states)
        print(f"wrote {record} ({len(states)} jobs)")
        return 0
    lines = compare_states(references, states, tolerance)
    print("\n".join(lines))
    return int(any(line.startswith("FAIL") for line in lines))
