"""The contact head-to-head page (``bhem-hpc contact-page --docs DIR`` writes
``DIR/contact-comparison.md`` and its JSON rows): the shipped contact jobs by impulses between steps
and by IPC inside the solve, each timed over a window of steps where contact happens.

Every run is a ``bhem-hpc run`` of its own process, as a user runs it: the job's steps up to its
window without frames, then the window continued from that checkpoint with a frame at every step.
A run that fails or outlasts its time limit is reported with the steps it completed. Serial: the
runs take the machine one after the other.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

JOBS = Path(__file__).resolve().parents[2] / "jobs"
#: The contact of a job by IPC: ipc-toolkit's barrier with its defaults (dhat 1e-3 of the bounding
#: box, adaptive stiffness) and IPC's step test at IPC's tolerance, the job's friction and
#: self-collision settings kept.
IPC_CONTACT = 'contact = { method = "ipc", velocity_tolerance = "auto" }'
#: A contact table of a scene (or ``contact = true``), on a line of its own or inline in a body's ``effects``.
CONTACT_TABLE = re.compile(r"\bcontact\s*=\s*(\{[^{}]*\}|true\b)")
#: A scene's Hessian setting (in its ``[solver]`` table).
HESSIAN_LINE = re.compile(r'^hessian\s*=\s*"[a-z_]+"', flags=re.MULTILINE)
METHODS = ("impulse", "ipc")
#: Runs of each window from the same warm-up checkpoint. Their wall times differ (this machine's other
#: load; the ball's s/step moved by 0.35-0.48 between pages of one code), and so, in a contact-rich
#: step, can their Newton iterations (ipc-toolkit sums over its threads in varying order): the page
#: shows the median s/step of the runs that took the first run's iterations, with their range.
WINDOW_RUNS = 3
#: The parts of a step its record times (``<part>_s``): the Jacobians' and residuals' assembly (with
#: the IPC barrier's gradient and Hessian), the factorizations, the triangular and Krylov solves.
TIMED_PARTS = ("assembly", "factorization", "linear_solve")


@dataclass(frozen=True)
class ContactWindow:
    """Where a job is timed: after ``start`` untimed steps, ``steps`` steps; ``phase``: what happens;
    ``impulse_contact``: the contact table of the impulse run of a job that ships with IPC;
    ``ipc_hessian``: the IPC run's ``solver.hessian`` where it is not the job's own; ``methods``: the
    methods timed there (a job whose methods meet its hard phase at different steps has a window for each);
    ``ipc_contact``: the IPC run's contact table; ``variant``: what sets a second window of a job at the
    same steps apart (its runs' names and its rows' label)."""

    job: str
    start: int
    steps: int
    phase: str
    impulse_contact: str | None = None
    ipc_hessian: str | None = None
    methods: tuple[str, ...] = METHODS
    ipc_contact: str = IPC_CONTACT
    variant: str = ""

    @property
    def label(self) -> str:
        """The job's name, with the variant's where it has one."""
        return f"{self.job} ({self.variant})" if self.variant else self.job

    @property
    def timed_steps(self) -> tuple[int, int]:
        """The first and the last step timed."""
        return self.start + 1, self.start + self.steps


#: The windows of the shipped contact jobs.
CONTACT_WINDOWS = (
    ContactWindow("ball", 70, 20, "the cloth lies on the ball and slides off it"),
    ContactWindow("needles", 240, 10, "the cloth hangs on the needles and folds onto itself"),
    # the same steps with the barrier's stiffness set in the scene: with the adaptive one the contacts
    # rest 2e-6 m from the needles and 1e-5 m apart in the folds, the barrier's Hessian changes much
    # from one iterate to the next there and a kept factorization serves few chord steps (3
    # factorizations a step against 0.2 with this one, 10 steps from one state, measured)
    ContactWindow("needles", 240, 10, "the cloth hangs on the needles and folds onto itself, the barrier's "
                  "stiffness set to 1.7e4 N/m (100 times its adaptive start)", methods=("ipc",),
                  ipc_contact='contact = { method = "ipc", velocity_tolerance = "auto", barrier_stiffness = 1.7e4 }',
                  variant="κ 1.7e4 N/m"),
    ContactWindow("mesh-obstacle", 110, 10, "the cloth lies on the mesh obstacle"),
    # by IPC the rim buckles under the barrier's push in steps 21-30 (line-search Newton crawled along
    # the buckling mode, 100 iterations and 20 recoveries; the trust region follows it in 3 to 10) and
    # the wall snaps in steps 37-39 (10, 13 and 17 iterations, no recovery; started from the inertial
    # prediction, which overshoots the snap, the trust region failed twice there and line search took
    # 35 and then 99 iterations; with TAO's own first radius the snap step took 35); by impulses the
    # wall buckles between steps 90 and 100 (its radius varies by 2.5 mm at a height, then by 26 mm;
    # 13 to 17 iterations a step) and its folds, crushed further, take
    # 12 to 156 a step in steps 116-135 (measured)
    ContactWindow("crushed-can", 20, 25, "the plank presses the rim down; by IPC the wall buckles",
                  ipc_hessian="trust_region"),
    ContactWindow("crushed-can", 115, 20, "by impulses the buckled wall's folds are crushed further",
                  methods=("impulse",)),
    ContactWindow("mandrel", 150, 20, "the buckling wall lands on the mandrel"),
    # the job's trust region takes 20 to 72 iterations a step here by IPC, the line search about 25
    ContactWindow("cloth-pile", 20, 10, "four cloths land on each other and on the held one",
                  ipc_hessian="adaptive"),
    ContactWindow("linked-bands", 35, 25, "the pulled band catches the held one and both stretch",
                  "contact = { push_out = 1.0e-4 }"),
    ContactWindow("cloth-on-sphere", 12, 20, "the cotton cloth lands on the sphere and sags over it",
                  "contact = { push_out = 1.0e-4 }"),
)


@runtime_checkable
class SignedDistance(Protocol):
    """A collider with an exact signed distance (planes, spheres, capsules, cylinders)."""

    def signed_distance(self, points: np.ndarray, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]: ...


@runtime_checkable
class Tessellated(Protocol):
    """A collider given or met as a triangle mesh (mesh and patch models)."""

    def tessellation(self, max_sagitta: float, cover: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


def job_variant(text: str, method: str, every: int, source: str, impulse_contact: str | None = None,
                ipc_hessian: str | None = None, ipc_contact: str = IPC_CONTACT) -> str:  # fmt: skip
    """The scene ``text`` with its contact by ``method`` (``impulse``: as given, or every contact table
    replaced by ``impulse_contact``; ``ipc``: every contact table replaced by ``ipc_contact``, and the
    Hessian set to ``ipc_hessian`` where given) and a frame every ``every`` steps.

    Raises:
        ValueError: the scene has no ``contact = { ... }`` table (named by ``source``).
    """
    if not CONTACT_TABLE.search(text):
        raise ValueError(f"{source}: expected a 'contact = {{ ... }}' table (or 'contact = true') in its effects, "
                         "found none")
    if method == "ipc":
        text = CONTACT_TABLE.sub(ipc_contact, text)
        text = text if ipc_hessian is None else _with_hessian(text, ipc_hessian)
    elif impulse_contact is not None:
        text = CONTACT_TABLE.sub(impulse_contact, text)
    # the variant is written elsewhere: files the job names relative to itself, by absolute path
    text = re.sub(r'^(file\s*=\s*)"([^"/][^"]*)"', lambda m: f'{m.group(1)}"{(JOBS / m.group(2)).resolve()}"', text,
                  flags=re.MULTILINE)  # fmt: skip
    if re.search(r"^every\s*=", text, flags=re.MULTILINE):
        return re.sub(r"^every\s*=.*$", f"every = {every}", text, count=1, flags=re.MULTILINE)
    if re.search(r"^\[output\]\s*$", text, flags=re.MULTILINE):
        return re.sub(r"^\[output\]\s*$", f"[output]\nevery = {every}", text, count=1, flags=re.MULTILINE)
    return text + f"\n[output]\nevery = {every}\n"


def _with_hessian(text: str, hessian: str) -> str:
    """The scene ``text`` with ``solver.hessian = hessian`` (its line replaced, or added)."""
    setting = f'hessian = "{hessian}"'
    if HESSIAN_LINE.search(text):
        return HESSIAN_LINE.sub(setting, text, count=1)
    if re.search(r"^\[solver\]\s*$", text, flags=re.MULTILINE):
        return re.sub(r"^\[solver\]\s*$", f"[solver]\n{setting}", text, count=1, flags=re.MULTILINE)
    return text + f"\n[solver]\n{setting}\n"


def _run(scene: Path, out: Path, steps: int, timeout: float, restart: Path | None = None) -> str:
    """``bhem-hpc -v run`` of ``steps`` steps in a process of its own, its log in ``<out>.log``;
    returns ``completed``, ``failed: <its last message line>`` or ``stopped after <timeout> s``."""
    command = [sys.executable, "-m", "bhem_hpc.cli", "-v", "run", str(scene), "--out", str(out), "--steps",
               str(steps), "--no-progress", "--force"]  # fmt: skip
    command += ["--restart", str(restart)] if restart is not None else []
    log = out.with_name(out.name + ".log")
    try:
        with log.open("w") as stream:
            done = subprocess.run(command, stdout=stream, stderr=subprocess.STDOUT, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return f"stopped after {timeout:g} s"
    if done.returncode == 0:
        return "completed"
    errors = [line for line in log.read_text().splitlines() if line.startswith("bhem-hpc")]
    return "failed: " + (errors[-1] if errors else f"exit code {done.returncode} (see {log.name})")


def _records(out: Path, after: int) -> list[dict]:
    path = out / "steps.jsonl"
    if not path.is_file():
        return []
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return [r for r in rows if r["step"] > after]


def _total_energy(energies: dict[str, float]) -> float:
    """Kinetic plus elastic energy less the dead loads' work (gravity's potential is in it)."""
    return energies["kinetic"] + energies.get("membrane", 0.0) + energies.get("bending", 0.0) - energies.get(
        "external_work", 0.0)  # fmt: skip


def frame_gaps(out: Path, colliders: list, within: float) -> dict:
    """The frames of ``out``: the smallest signed distance [m] of the output meshes' vertices from the
    exact colliders that have one (negative: inside), the smallest distance to colliders given as
    meshes, and the frames whose meshes intersect themselves, each other or a mesh collider
    (ipc-toolkit; a solid not itself); the frames read once for both."""
    from bhem_hpc.contact.audit import audit_frames, read_frames

    meshes = read_frames(out)
    audits = audit_frames(meshes, within)
    signed, mesh_gap, mesh_crossings = _collider_gaps(meshes.faces, meshes.frames, colliders, within) if colliders \
        else (np.inf, np.inf, 0)  # fmt: skip
    return {"frames": len(audits), "min_signed_gap_m": signed, "min_mesh_gap_m": mesh_gap,
            "mesh_collider_crossings": mesh_crossings, "self_intersecting_frames": sum(a.intersecting for a in audits),
            "min_self_distance_m": min((a.min_distance for a in audits), default=np.inf)}  # fmt: skip


def _collider_gaps(faces: np.ndarray, frames: list[tuple[np.ndarray, float]], colliders: list,
                   within: float) -> tuple[float, float, int]:  # fmt: skip
    """The smallest signed gap to the colliders with an exact distance, the smallest distance to mesh colliders and
    the frames crossing one, over a run's output meshes (:func:`~bhem_hpc.contact.audit.read_frames`)."""
    import ipctk

    from bhem_hpc.contact.ipc import minimum_distance

    exact = [c for c in colliders if isinstance(c, SignedDistance)]
    signed, mesh_gap, mesh_crossings = np.inf, np.inf, 0
    count = len(frames[0][0]) if frames else 0
    # a mesh collider and the output meshes as one collision mesh whose two groups only meet each
    # other (the colliders here are given as meshes: the box they cover does not matter)
    meshes = []
    for collider in colliders:
        if isinstance(collider, Tessellated) and not isinstance(collider, SignedDistance):
            vertices, triangles = collider.tessellation(0.25 * within, np.zeros((2, 3)))
            all_faces = np.concatenate([faces, np.asarray(triangles, dtype=np.int32) + count])
            mesh = ipctk.CollisionMesh(np.asfortranarray(np.concatenate([frames[0][0], vertices])),
                                       ipctk.edges(all_faces), all_faces)  # fmt: skip
            mesh.can_collide = ipctk.make_vertex_patches_filter(
                np.r_[np.zeros(count, np.int32), np.ones(len(vertices), np.int32)])
            meshes.append((mesh, np.asarray(vertices, dtype=float)))
    for points, t in frames:
        for collider in exact:
            signed = min(signed, float(np.min(collider.signed_distance(points, t)[0])))
        for mesh, vertices in meshes:
            both = np.asfortranarray(np.concatenate([points, vertices]))
            mesh_gap = min(mesh_gap, minimum_distance(mesh, both, within))
            mesh_crossings += int(ipctk.has_intersections(mesh, both))
    return signed, mesh_gap, mesh_crossings


def job_bodies(path: Path) -> tuple:
    """The scene of each body of the scene file ``path`` (one body's: itself)."""
    from bhem_hpc.scene.bodies import BodiesScene
    from bhem_hpc.scene.loader import load_any_scene

    scene = load_any_scene(path)
    return scene.bodies if isinstance(scene, BodiesScene) else (scene,)


def run_name(window: ContactWindow, method: str) -> str:
    """The stem of the run directories and scene files of ``window`` by ``method``: job, variant (in
    letters, digits and dots), method, start."""
    variant = re.sub(r"[^0-9A-Za-z.]+", "-", window.variant).strip("-")
    return "-".join(filter(None, (window.job, variant, method, str(window.start))))


def run_window(window: ContactWindow, method: str, runs: Path, timeout: float) -> dict:
    """Run ``window``'s job by ``method`` into ``runs/<name>-{warm,window}`` (:func:`run_name`; scene
    files beside them); its figures over the window. The window runs :data:`WINDOW_RUNS` times from the
    warm-up (the later runs into ``<name>-window-<k>``); s/step is the median over the runs that took
    the first one's Newton iterations."""
    source = JOBS / f"{window.job}.toml"
    text = source.read_text()
    name = run_name(window, method)
    warm_scene, window_scene = runs / f"{name}-warm.toml", runs / f"{name}-window.toml"
    for scene, every in ((warm_scene, 10**6), (window_scene, 1)):
        scene.write_text(job_variant(text, method, every, str(source), window.impulse_contact, window.ipc_hessian,
                                     window.ipc_contact))  # fmt: skip
    warm, out = runs / f"{name}-warm", runs / f"{name}-window"
    started = time.perf_counter()
    status = _run(warm_scene, warm, window.start, timeout)
    warm_s = time.perf_counter() - started
    row = {"job": window.label, "method": method, "window": list(window.timed_steps),
           "phase": window.phase, "warm_up": status, "warm_up_s": warm_s}  # fmt: skip
    if status != "completed":
        return row | {"status": f"warm-up {status}", "steps": 0}
    row["status"] = _run(window_scene, out, window.steps, timeout, restart=warm)
    records = _window_records(out, window)
    row["steps"] = len(records)
    if not records:
        return row
    wall = sum(r["wall_s"] for r in records)
    step_seconds = [wall / len(records)] + _repeated_step_seconds(window, window_scene, runs / name, warm, records,
                                                                  timeout)  # fmt: skip
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").is_file() else {}
    contact = summary.get("contact") or {}
    contact_s = contact.get("barrier_s", 0.0) if method == "ipc" else sum(r.get("collision_s", 0.0) for r in records)
    energies = [_total_energy(r["energies"]) for r in records if "energies" in r]
    bodies = job_bodies(window_scene)
    # the colliders are the scene's: every body in contact lists them
    colliders = next(([entry.collider for entry in body.contact.colliders] for body in bodies
                      if body.contact is not None), [])  # fmt: skip
    dhat = contact.get("dhat_m") or 1e-3
    row |= {
        "step_s": float(np.median(step_seconds)), "step_s_runs": step_seconds,
        "newton_per_step": sum(r["newton_iterations"] for r in records) / len(records),
        "max_newton": max(r["newton_iterations"] for r in records),
        "factorizations_per_step": sum(r["refactorizations"] for r in records) / len(records),
        **{f"{part}_share": sum(r[f"{part}_s"] for r in records) / wall if wall > 0 else 0.0
           for part in TIMED_PARTS},
        "recoveries": sum(r["recoveries"] for r in records), "dt_halvings": sum(r["dt_halvings"] for r in records),
        "contact_share": contact_s / wall if wall > 0 else 0.0,
        "energy_change": (energies[-1] - energies[0]) / max(abs(e) for e in energies) if len(energies) > 1 else None,
        "stiffness": contact.get("barrier_stiffness"), "stiffness_doublings": contact.get("stiffness_doublings"),
    }  # fmt: skip
    return row | frame_gaps(out, colliders, max(dhat, 1e-3))


def _repeated_step_seconds(window: ContactWindow, scene: Path, stem: Path, warm: Path, records: list[dict],
                           timeout: float) -> list[float]:  # fmt: skip
    """The mean s/step of the window's runs after the first (into ``<stem>-window-<k>``) that took the
    first run's Newton iterations (its ``records``) in every step."""
    iterations = [r["newton_iterations"] for r in records]
    seconds = []
    for k in range(2, WINDOW_RUNS + 1):
        again = stem.with_name(f"{stem.name}-window-{k}")
        status = _run(scene, again, window.steps, timeout, restart=warm)
        repeated = _window_records(again, window) if status == "completed" else []
        if [r["newton_iterations"] for r in repeated] == iterations:
            seconds.append(sum(r["wall_s"] for r in repeated) / len(repeated))
    return seconds


def _window_records(out: Path, window: ContactWindow) -> list[dict]:
    """The step records of the window's timed steps in the run ``out``."""
    return [r for r in _records(out, window.start) if r["step"] <= window.timed_steps[1]]


def _seconds(row: dict) -> str:
    """The median s/step of a row's window runs, with their range where there are several."""
    runs = row.get("step_s_runs") or [row["step_s"]]
    spread = f" ({min(runs):.3g}–{max(runs):.3g})" if len(runs) > 1 else ""
    return f"{row['step_s']:.3g}{spread}"


def _gap(row: dict) -> str:
    values = [row.get("min_signed_gap_m", np.inf), row.get("min_mesh_gap_m", np.inf)]
    finite = [v for v in values if np.isfinite(v)]
    return f"{min(finite):.2e}" if finite else "> 1e-3"


def contact_markdown(rows: list[dict], command: str, machine: str) -> str:
    """The page: how it was made, then a row per job and method."""
    lines = [
        "# Contact by impulses and by IPC, head to head",
        "",
        f"Generated by `{command}` in one run on {machine}. Each job of `jobs/` runs twice, with its "
        f"impulse contact as shipped and with `{IPC_CONTACT}` (dhat 1e-3 of the bounding box, the adaptive "
        "barrier stiffness, IPC's step test at 1e-2 of the bounding-box diagonal per second besides the "
        "acceleration test; the job's Hessian, or the one its window names for IPC: the crushed can's "
        "trust region, which does not take the step test, the cloth pile's line search; fresh factorizations "
        "unless the job keeps them, as the ball and the needles do); a job that ships "
        "with IPC (linked-bands, cloth-on-sphere) runs by impulses with the contact table its window names. "
        "The needles run by IPC a second time over the same steps with the barrier's stiffness set in the scene "
        "(its row's label): the contacts rest farther apart, within dhat, and a kept factorization serves more "
        "chord steps. "
        "The crushed can's wall buckles at different steps by the two methods (by IPC in steps 37-39, by impulses "
        "between steps 90 and 100): a second window times the impulse run where its folds are crushed "
        "further and its Newton iterations peak. "
        "Each run is a `bhem-hpc run` in a process of its own: the steps before the window without frames, then the "
        f"window, continued from that checkpoint, with a frame at every step, {WINDOW_RUNS} times. s/step is the "
        "median of the means over the window's steps of the runs that took the first run's Newton iterations (in "
        "brackets the fastest and the slowest of them; the figures besides are the first run's); where no other "
        "run took them (ipc-toolkit sums over its threads in varying order, and a contact-rich step can then take "
        "other iterations), the first run's alone. "
        "Newton/step is a mean over the window's steps; a step counts the Newton iterations of "
        "the solve that converged, and a step that recovered (recoveries) spent more in the attempts that "
        "failed before it (a trust region that failed ran to its iteration limit). Contact share: the impulse step's "
        "collision detection and response, or the IPC barrier's energy, gradient, Hessian, step bounds and "
        "stiffness updates, as a share of the step's wall time. Smallest gap: the output meshes' vertices "
        "against the exact colliders (negative: inside one) or, for mesh colliders, the distance between "
        "the meshes. IPC meets a sphere, capsule or cylinder at rest without friction through its exact "
        "distance; one that moves, has friction or is thin for the collision mesh's triangles as triangles "
        "within dhat/4 inside it, so a negative gap down to dhat/4 is the surface resting on those triangles. "
        "Intersecting frames: frames "
        "whose output meshes intersect themselves or a mesh collider (ipc-toolkit's test). ΔE: the change "
        "of kinetic plus elastic energy less the dead loads' work over the window, relative to its largest "
        "value; implicit Euler dissipates, and prescribed motions, colliders, damping and the barrier do work, "
        "so it is not a conservation figure for these scenes. κ: the IPC barrier's stiffness at the window's "
        "end and its doublings within the window (a window continues from the warm-up's κ).",
        "",
        "| job | method | window (steps) | status | s/step | Newton/step (max) | recoveries | contact share | "
        "smallest gap [m] | intersecting frames | ΔE | κ [N/m] (doublings) |",
        "| --- | --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        window = f"{r['window'][0]}–{r['window'][1]} ({r['steps']} done)"
        status = r["status"] if len(r["status"]) < 90 else r["status"][:87] + "..."
        if not r["steps"]:
            lines.append(f"| {r['job']} | {r['method']} | {window} | {status} | | | | | | | | |")
            continue
        crossings = r["self_intersecting_frames"] + r["mesh_collider_crossings"]
        stiffness = "" if r["stiffness"] is None else f"{r['stiffness']:.3g} ({r['stiffness_doublings']})"
        energy = "" if r["energy_change"] is None else f"{r['energy_change']:+.2e}"  # (runs of several bodies: none)
        lines.append(
            f"| {r['job']} | {r['method']} | {window} | {status} | {_seconds(r)} | "
            f"{r['newton_per_step']:.1f} ({r['max_newton']}) | {r['recoveries']} | {100 * r['contact_share']:.0f} % | "
            f"{_gap(r)} | {crossings} of {r['frames']} | {energy} | {stiffness} |"
        )
    lines += _time_table(rows)
    timed = {(r["job"], r["window"][0]) for r in rows}
    lines += ["", "Windows:", ""] + [f"- {w.label}: steps {w.timed_steps[0]}–{w.timed_steps[1]}, {w.phase}."
                                     for w in CONTACT_WINDOWS if (w.label, w.timed_steps[0]) in timed]  # fmt: skip
    return "\n".join(lines) + "\n"


def _time_table(rows: list[dict]) -> list[str]:
    """Where a step's time goes, per job and method (rows that timed steps)."""
    lines = ["", "Where the time goes: shares of the first window run's wall time. Assembly: Jacobians and "
             "residuals (by IPC with the barrier's gradient and Hessian, which its contact share counts as well); "
             "factorization: the LDLᵀ factorizations (factorizations/step of them; a kept one serves chord "
             "steps); solves: the triangular and Krylov solves.", "",
             "| job | method | window (steps) | s/step | factorizations/step | assembly | factorization | solves | "
             "contact |",
             "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for r in rows:
        if r["steps"]:
            shares = " | ".join(f"{100 * r[f'{part}_share']:.0f} %" for part in (*TIMED_PARTS, "contact"))
            lines.append(f"| {r['job']} | {r['method']} | {r['window'][0]}–{r['window'][1]} | {r['step_s']:.3g} | "
                         f"{r['factorizations_per_step']:.1f} | {shares} |")  # fmt: skip
    return lines


def write_contact_page(docs: Path, runs: Path, windows: tuple[ContactWindow, ...], timeout: float, command: str,
                       machine: str) -> Path:  # fmt: skip
    """Run every window by the methods it names and write ``docs/contact-comparison.md`` and ``.json``."""
    runs.mkdir(parents=True, exist_ok=True)
    rows = [run_window(window, method, runs, timeout) for window in windows for method in window.methods]
    docs.mkdir(parents=True, exist_ok=True)
    finite = [{k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in r.items()} for r in rows]
    (docs / "contact-comparison.json").write_text(json.dumps(finite, indent=1) + "\n")
    page = docs / "contact-comparison.md"
    page.write_text(contact_markdown(rows, command, machine))
    return page
