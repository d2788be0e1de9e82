"""``bhem-hpc bench --scaling``: time steps of one cloth scene over rank counts, sizes and linear solvers.

Every case runs in its own ``mpirun`` (so each rank count gets a fresh MPI job and its peak memory
is its own) as ``bhem-hpc bench --scene S --patches N --linear L --json``; this driver collects
the rows and writes ``scaling.csv``, ``scaling.md`` and ``scaling.png``, and with ``--docs D`` the
page ``D/scaling.md`` with its figures in ``D/scaling/``. Strong scaling: each size on every rank
count; weak scaling (``--weak N``): ``N sqrt(ranks)`` patches per side, so the DoFs per rank stay
about constant. A case that fails (out of memory, over ``--timeout``) keeps a row with its error.
"""

from __future__ import annotations

import csv
import json
import math
import os
import shlex
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from bhem_hpc.blas import blas_label
from bhem_hpc.errors import UserError

#: Columns of ``scaling.csv`` (a case's row of ``bhem-hpc bench --scene --json`` plus the case).
COLUMNS = (
    "kind", "ranks", "patches", "linear", "factorization", "dt", "mass_dominance", "dofs", "status", "step_s",
    "newton_per_step", "newton_iteration_s",
    "assembly_per_iteration_s", "solve_per_iteration_s", "krylov_per_solve", "refactorizations_per_step",
    "peak_memory_per_rank_gb", "linear_fallbacks", "blas", "wall_s", "error",
)  # fmt: skip


class ScalingError(UserError, ValueError):
    """Bad arguments of the scaling command."""


@dataclass(frozen=True)
class ScalingCase:
    """One timed run: ``ranks`` MPI ranks, ``patches`` x ``patches``, a linear solver, strong or weak."""

    kind: str
    ranks: int
    patches: int
    linear: str
    dt: float | None = None  # None: the scene's
    factorization: str | None = None  # None: the scene's; "fresh": a factorization at every Newton iteration


def scaling_cases(
    ranks: list[int],
    sizes: list[int],
    linears: list[str],
    weak: int | None,
    dts: list[float] | None = None,
    fresh: list[int] | None = None,
) -> list[ScalingCase]:
    """Strong scaling (every size on every rank count), with ``weak`` weak scaling, with ``dts``
    the iterative solver at the first size on one rank for each time step, and with ``fresh`` MUMPS
    factoring the Jacobian at every Newton iteration (full Newton) on one rank at those sizes."""
    if not ranks or min(ranks) < 1:
        raise ScalingError(f"--ranks must be integers >= 1, got {ranks}")
    if not sizes or min(sizes) < 1:
        raise ScalingError(f"--patches must be integers >= 1, got {sizes}")
    if weak is not None and weak < 1:
        raise ScalingError(f"--weak must be an integer >= 1, got {weak}")
    cases = [ScalingCase("strong", r, n, lin) for n in sizes for lin in linears for r in sorted(set(ranks))]
    if weak is not None:
        cases += [
            ScalingCase("weak", r, round(weak * math.sqrt(r)), lin) for lin in linears for r in sorted(set(ranks))
        ]
    if dts and min(dts) <= 0:
        raise ScalingError(f"--dt must be > 0, got {dts}")
    cases += [ScalingCase("dt", 1, sizes[0], "iterative", dt) for dt in dts or ()]
    if fresh and min(fresh) < 1:
        raise ScalingError(f"--fresh must be integers >= 1, got {fresh}")
    cases += [ScalingCase("fresh", 1, n, "direct", factorization="fresh") for n in fresh or ()]
    return cases


def default_launcher() -> list[str]:
    """``mpirun``, with Open MPI's flags for running as root and more ranks than cores where they apply."""
    mpirun = shutil.which("mpirun")
    if mpirun is None:
        raise ScalingError("--scaling needs mpirun on the PATH (or --mpirun 'LAUNCHER')")
    launcher = [mpirun]
    try:
        version = subprocess.run([mpirun, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        version = ""
    if "Open MPI" in version or "OpenRTE" in version:
        launcher += ["--oversubscribe", "-x", "OPENBLAS_NUM_THREADS"]
        if os.geteuid() == 0:
            launcher.append("--allow-run-as-root")
    return launcher


def run_case(case: ScalingCase, scene: Path, steps: int, warmup: int, launcher: list[str], timeout: float) -> dict:
    """Run one case in its own MPI job; its row (``status`` ok, or failed with the error)."""
    command = [
        *launcher, "-n", str(case.ranks), sys.executable, "-m", "bhem_hpc.cli", "bench", "--scene", str(scene),
        "--patches", str(case.patches), "--linear", case.linear, "--steps", str(steps), "--warmup", str(warmup),
        "--json", *(("--dt", repr(case.dt)) if case.dt is not None else ()),
        *(("--factorization", case.factorization) if case.factorization is not None else ()),
    ]  # fmt: skip
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")  # one BLAS thread per rank
    row = {"kind": case.kind, "ranks": case.ranks, "patches": case.patches, "linear": case.linear, "dt": case.dt,
           "factorization": case.factorization}  # fmt: skip
    start = time.perf_counter()
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        return row | {"status": "failed", "error": f"over the timeout of {timeout:g} s", "wall_s": timeout}
    row["wall_s"] = time.perf_counter() - start
    result = _json_line(done.stdout)
    if done.returncode != 0 or result is None:
        lines = [line for line in (done.stderr or "").splitlines() if line.strip()]
        reason = lines[-1] if lines else f"exit code {done.returncode}"
        return row | {"status": "failed", "error": reason}
    newton = max(result["newton_per_step"], 1e-300)
    return row | {
        "status": "ok",
        "linear": result["linear"],
        "factorization": result["factorization"],
        "dofs": result["dofs"],
        "step_s": result["step_s"],
        "newton_per_step": result["newton_per_step"],
        "newton_iteration_s": result["newton_iteration_s"],
        "assembly_per_iteration_s": result["assembly_per_step_s"] / newton,
        "solve_per_iteration_s": (result["factor_per_step_s"] + result["linear_solve_per_step_s"]) / newton,
        "krylov_per_solve": result["krylov_per_solve"],
        "dt": result["dt"],
        "mass_dominance": result["mass_dominance"],
        "refactorizations_per_step": result["refactorizations_per_step"],
        "peak_memory_per_rank_gb": result["peak_memory_per_rank_gb"],
        "linear_fallbacks": result["linear_fallbacks"],
        "blas": result["blas"],
    }


def _json_line(stdout: str) -> dict | None:
    for line in reversed(stdout.splitlines()):
        if line.startswith("{"):
            try:
                return json.loads(line)
            except json.JSONDecodeError:
                return None
    return None


def write_csv(rows: list[dict], path: Path) -> None:
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def speedups(rows: list[dict]) -> dict[tuple[str, int, str], float]:
    """Strong-scaling speedup of each ``(kind, patches, linear)`` at its largest rank count over one rank."""
    out = {}
    ok = [r for r in rows if r["status"] == "ok" and r["kind"] == "strong"]
    for key in {(r["patches"], r["linear"]) for r in ok}:
        series = {r["ranks"]: r["step_s"] for r in ok if (r["patches"], r["linear"]) == key}
        if 1 in series and len(series) > 1:
            top = max(series)
            out[(key[0], top, key[1])] = series[1] / series[top]
    return out


def scaling_markdown(rows: list[dict], meta: dict, figure: str) -> str:
    """The scaling page: setup, the table of every case, speedups and the paths' ratio per size."""

    def num(value, fmt: str) -> str:
        return "-" if value is None or value == "" else format(value, fmt)

    lines = [
        "# Scaling",
        "",
        f"Generated by `{meta['command']}` on {meta['host']} ({meta['cores']} cores, BLAS: "
        f"{blas_label(next((r.get('blas') for r in rows if r['status'] == 'ok'), None))}), every figure from that "
        "one run. "
        f"Scene: `{meta['scene']}` with its patches replaced per case; {meta['steps']} time steps timed after "
        f"{meta['warmup']} untimed, each case its own `mpirun` with one BLAS thread per rank. Time per Newton "
        "iteration is split into assembly (residual and Jacobian) and linear solve (factorization or preconditioner "
        "setup, and the solves); memory is the largest resident set of any rank. MUMPS keeps its factorizations "
        "across Newton iterations and time steps (the default) except in the rows marked factored every iteration.",
        "",
        f"![scaling]({figure})",
        "",
        "| kind | ranks | patches | DoFs | linear solver | s / step | Newton / step | s / Newton iteration | "
        "assembly | linear solve | Krylov / solve | refactorizations / step | peak GB / rank | status |",
        "| --- | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for r in rows:
        ok = r["status"] == "ok"
        lines.append(
            f"| {r['kind']} | {r['ranks']} | {r['patches']} | {num(r.get('dofs'), 'd')} | {r['linear']}"
            f"{', factored every iteration' if r.get('factorization') == 'fresh' else ''} | "
            f"{num(r.get('step_s'), '.3g')} | {num(r.get('newton_per_step'), '.2f')} | "
            f"{num(r.get('newton_iteration_s'), '.3g')} | {num(r.get('assembly_per_iteration_s'), '.3g')} | "
            f"{num(r.get('solve_per_iteration_s'), '.3g')} | "
            f"{num(r.get('krylov_per_solve'), '.1f') if r['linear'] == 'iterative' else '-'} | "
            f"{num(r.get('refactorizations_per_step'), '.2f')} | {num(r.get('peak_memory_per_rank_gb'), '.2f')} | "
            f"{'ok' if ok else 'failed: ' + str(r.get('error', ''))} |"
        )
    lines += ["", "## Strong scaling", ""]
    gains = speedups(rows)
    lines += [f"- {n} x {n} patches, {lin}: {top} ranks {s:.2f}x faster per step than 1" for (n, top, lin), s in
              sorted(gains.items())] or ["- (one rank count only)"]  # fmt: skip
    by_dt = sorted((r for r in rows if r["kind"] == "dt" and r["status"] == "ok"), key=lambda r: r["dt"])
    if by_dt:
        lines += ["", "## Krylov iterations against the time step", "",
                  f"The iterative solver on {by_dt[0]['patches']} x {by_dt[0]['patches']} patches, one rank.", "",
                  "| dt [s] | mass dominance | Krylov / solve | Newton / step | s / step |",
                  "| ---: | ---: | ---: | ---: | ---: |"]  # fmt: skip
        lines += [f"| {r['dt']:g} | {r['mass_dominance']:.3g} | {r['krylov_per_solve']:.1f} | "
                  f"{r['newton_per_step']:.2f} | {r['step_s']:.3g} |" for r in by_dt]  # fmt: skip
    lines += ["", "## Iterative against direct (same ranks, same size)", ""]
    ok = {(r["kind"], r["ranks"], r["patches"], r["linear"]): r for r in rows if r["status"] == "ok"}
    pairs = [(k, ok[k[:3] + ("direct",)]) for k in ok if k[3] == "iterative" and k[:3] + ("direct",) in ok]
    lines += [
        f"- {k[2]} x {k[2]} patches, {k[1]} rank(s){' (the weak-scaling runs)' if k[0] == 'weak' else ''}: the "
        f"iterative path's step takes {ok[k]['step_s'] / direct['step_s']:.2f}x the time of MUMPS' "
        f"({direct['step_s'] / ok[k]['step_s']:.2f}x as fast), "
        f"{ok[k]['peak_memory_per_rank_gb'] / direct['peak_memory_per_rank_gb']:.2f}x its memory per rank; "
        f"a linear solve that took no time would make MUMPS' step {_free_solve_gain(direct):.2f}x as fast"
        for k, direct in sorted(pairs)
    ] or ["- (no size ran with both solvers)"]
    lines += _against_fresh(ok)
    return "\n".join(lines) + "\n"


def _free_solve_gain(row: dict) -> float:
    """How much faster a row's step would be if its linear solves (factorizations included) took
    no time, with the same Newton iterations: the most any linear solver could gain over it."""
    solve = row["newton_per_step"] * row["solve_per_iteration_s"]
    return row["step_s"] / max(row["step_s"] - solve, 1e-300)


def _against_fresh(ok: dict[tuple, dict]) -> list[str]:
    """The section comparing both paths with MUMPS factoring at every Newton iteration (``fresh``
    cases), at the same size on one rank; empty without such cases. ``ok``: the rows that ran,
    by ``(kind, ranks, patches, linear)``."""
    fresh = sorted((r for key, r in ok.items() if key[0] == "fresh"), key=lambda r: r["patches"])
    if not fresh:
        return []
    lines = ["", "## Against MUMPS with a factorization at every Newton iteration (one rank)", ""]
    for r in fresh:
        n = r["patches"]
        text = f"- {n} x {n} patches: MUMPS factoring at every Newton iteration {r['step_s']:.3g} s / step"
        for linear, label in (("iterative", "the iterative path"), ("direct", "MUMPS keeping its factorizations")):
            other = ok.get(("strong", 1, n, linear))
            if other is not None:
                text += f"; {label} {other['step_s']:.3g} s / step ({r['step_s'] / other['step_s']:.2f}x as fast)"
        lines.append(text)
    return lines


def plot_scaling(rows: list[dict], path: Path) -> None:
    """Time per Newton iteration (assembly and solve) against ranks, Krylov iterations and memory
    against DoFs, per linear solver."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if r["status"] == "ok" and r["kind"] in ("strong", "weak")]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    styles = {"direct": "tab:blue", "iterative": "tab:orange"}
    for (n, lin) in sorted({(r["patches"], r["linear"]) for r in ok if r["kind"] == "strong"}):
        series = sorted((r for r in ok if r["kind"] == "strong" and (r["patches"], r["linear"]) == (n, lin)),
                        key=lambda r: r["ranks"])  # fmt: skip
        ranks = [r["ranks"] for r in series]
        marker = "o" if lin == "direct" else "s"
        axes[0].plot(ranks, [r["newton_iteration_s"] for r in series], marker=marker, color=styles.get(lin),
                     label=f"{n}x{n} {lin}: total", alpha=0.4 + 0.6 * n / max(r["patches"] for r in ok))  # fmt: skip
        axes[0].plot(ranks, [r["solve_per_iteration_s"] for r in series], linestyle=":", marker=marker,
                     color=styles.get(lin))  # fmt: skip
    axes[0].set(xlabel="MPI ranks", ylabel="s per Newton iteration (dotted: linear solve)", yscale="log",
                title="strong scaling")  # fmt: skip
    axes[0].legend(fontsize=7)
    for lin, color in styles.items():
        chosen = sorted((r for r in ok if r["linear"] == lin), key=lambda r: r["dofs"])
        if not chosen:
            continue
        dofs = [r["dofs"] for r in chosen]
        axes[2].plot(dofs, [r["peak_memory_per_rank_gb"] for r in chosen], "o", color=color, label=lin)
        if lin == "iterative":
            axes[1].plot(dofs, [r["krylov_per_solve"] for r in chosen], "s", color=color, label=lin)
    axes[1].set(xlabel="DoFs", ylabel="Krylov iterations per linear solve", xscale="log", title="Krylov iterations")
    axes[2].set(xlabel="DoFs", ylabel="peak memory per rank [GB]", xscale="log", yscale="log", title="memory")
    axes[2].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_scaling_command(args, comm) -> None:
    """The ``bench --scaling`` command (one process: it launches the MPI jobs itself)."""
    if comm.size != 1:
        raise ScalingError("run `bhem-hpc bench --scaling` without mpirun: it starts an MPI job per case")
    scene = args.scene or Path(__file__).resolve().parents[2] / "jobs" / "million-cloth.toml"
    if not Path(scene).is_file():
        raise ScalingError(f"--scene {scene}: no such scene file")
    linears = [args.linear] if args.linear and args.linear != "auto" else ["direct", "iterative"]
    cases = scaling_cases(args.ranks, args.patches, linears, args.weak, args.dt, args.fresh)
    launcher = shlex.split(args.mpirun) if args.mpirun else default_launcher()
    steps, warmup = args.steps or 3, args.warmup
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for case in cases:
        row = run_case(case, Path(scene), steps, warmup, launcher, args.timeout)
        rows.append(row)
        print(_progress_line(row), flush=True)
        write_csv(rows, out / "scaling.csv")  # after every case: a long run keeps what it measured
    meta = {
        "command": "bhem-hpc " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
        "host": os.uname().nodename,
        "cores": os.cpu_count(),
        "scene": os.path.relpath(scene),
        "steps": steps,
        "warmup": warmup,
    }
    plot_scaling(rows, out / "scaling.png")
    (out / "scaling.md").write_text(scaling_markdown(rows, meta, "scaling.png"))
    (out / "scaling.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    if args.docs is not None:
        figures = args.docs / "scaling"
        figures.mkdir(parents=True, exist_ok=True)
        for name in ("scaling.csv", "scaling.png", "scaling.json"):
            shutil.copyfile(out / name, figures / name)
        (args.docs / "scaling.md").write_text(scaling_markdown(rows, meta, "scaling/scaling.png"))
        print(f"wrote {args.docs / 'scaling.md'}")
    print(f"wrote {out / 'scaling.csv'}, scaling.md, scaling.png")


def _progress_line(row: dict) -> str:
    head = f"{row['kind']:6s} ranks {row['ranks']:2d} patches {row['patches']:4d} {row['linear']:9s}"
    if row.get("factorization") == "fresh":
        head += " (fresh)"
    if row["status"] != "ok":
        return f"{head} failed: {row.get('error')}"
    return (
        f"{head} {row['dofs']:8d} DoFs {row['step_s']:8.3f} s/step {row['newton_per_step']:5.2f} Newton/step "
        f"{row['newton_iteration_s']:8.3f} s/iteration (assembly {row['assembly_per_iteration_s']:.3f}, solve "
        f"{row['solve_per_iteration_s']:.3f}) Krylov/solve {row['krylov_per_solve']:5.1f} "
        f"peak {row['peak_memory_per_rank_gb']:.2f} GB/rank"
    )
