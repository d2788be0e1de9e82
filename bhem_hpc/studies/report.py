"""Accuracy-versus-cost studies: every configuration of a study's knobs, its error and its time.

``bhem-hpc study NAME --out DIR`` (or :func:`run_study`) writes ``DIR/NAME.csv`` row by row (an
interrupted study keeps the rows it finished), then ``DIR/NAME.md`` (a table) and ``DIR/NAME.png``
(error against wall time and against DoFs). Wall time is the solve (assembly, factorization,
Newton), not the one-off JIT compilation. Collective: all ranks compute, rank 0 writes.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from mpi4py import MPI

from bhem_hpc.studies.registry import STUDIES
from bhem_hpc.studies.study import METHODS, Study, StudyError, row_method


def run_study(name: str, out: Path, comm: MPI.Comm = MPI.COMM_WORLD, limit: int | None = None) -> list[dict]:
    """Run every configuration of study ``name`` (the first ``limit`` only, if given)."""
    if name not in STUDIES:
        raise StudyError(f"study {name!r} does not exist; known: {sorted(STUDIES)}")
    error = None
    if comm.rank == 0:
        if out.exists() and any(out.iterdir()):
            error = f"output directory {out} exists and is not empty"
        else:
            out.mkdir(parents=True, exist_ok=True)
    error = comm.bcast(error)
    if error:
        raise StudyError(error)
    study = STUDIES[name]
    rows: list[dict] = []
    csv_path = out / f"{name}.csv"
    handle = open(csv_path, "w", newline="") if comm.rank == 0 else None  # noqa: SIM115 - kept open across rows
    try:
        writer = csv.DictWriter(handle, fieldnames=study.columns) if handle else None
        if writer:
            writer.writeheader()
        for k, config in enumerate(study.configurations()):
            if limit is not None and k >= limit:
                break
            row = {"study": name, "ranks": comm.size, **config, **study.run(config, comm)}
            rows.append(row)
            if writer:
                writer.writerow({c: row.get(c, "") for c in study.columns})
                handle.flush()  # an interrupted study keeps the rows it finished
    finally:
        if handle:
            handle.close()
    if comm.rank == 0:
        _write_table(out / f"{name}.md", study, rows)
        _plot(out / f"{name}.png", study, rows)
        if study.figure is not None:
            study.figure(out / f"{name}-shapes.png", rows)
    return rows


def _write_table(path: Path, study: Study, rows: list[dict]) -> None:
    columns = (*study.knobs, "dofs", "error", "wall_s", "newton_iterations", *study.extra)
    header = "| " + " | ".join(columns) + " |\n|" + " --- |" * len(columns) + "\n"

    def cell(value: object) -> str:
        return f"{value:.3g}" if isinstance(value, float) else str(value)

    body = "".join("| " + " | ".join(cell(r[c]) for c in columns) + " |\n" for r in rows)
    path.write_text(f"# Study `{study.name}`: {study.description}\n\n{header}{body}")


def _plot(path: Path, study: Study, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), dpi=110)
    rows = results(rows)
    baseline = [r for r in rows if study.in_plot(r)]
    for label in sorted({study.series_label(r) for r in baseline}):
        series = sorted((r for r in baseline if study.series_label(r) == label), key=lambda r: (r["dofs"], r["wall_s"]))
        errors = [max(r["error"], 1e-16) for r in series]
        axes[0].loglog([r["wall_s"] for r in series], errors, "o-", label=label)
        axes[1].loglog([r["dofs"] for r in series], errors, "o-", label=label)
    axes[0].set_xlabel("wall time of the solve [s]")
    axes[1].set_xlabel("DoFs")
    for ax in axes:
        ax.set_ylabel("relative error")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.suptitle(f"{study.name}: {study.description}")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def results(rows: list[dict]) -> list[dict]:
    """The rows without a study's own reference row (measured against its finest run: error 0)."""
    return [r for r in rows if r["error"] > 0.0 or r["value"] != r["reference"]]


def cheapest(rows: list[dict], tolerance: float) -> dict | None:
    """The fastest configuration whose error is at most ``tolerance`` (None if none reaches it)."""
    good = [r for r in rows if r["error"] <= tolerance]
    return min(good, key=lambda r: r["wall_s"]) if good else None


def read_rows(path: Path) -> list[dict]:
    """The rows of a study CSV, numbers parsed back (int where they are integral, else float)."""

    def parse(text: str) -> object:
        for kind in (int, float):
            try:
                return kind(text)
            except ValueError:
                pass
        return text

    with open(path, newline="") as handle:
        return [{k: parse(v) for k, v in row.items()} for row in csv.DictReader(handle)]


def write_accuracy_cost(docs: Path, comm: MPI.Comm = MPI.COMM_WORLD) -> Path:
    """Run every study into ``docs/studies/ranks-N/NAME`` (N = this run's rank count) and write
    ``docs/accuracy-cost.md`` from the rows of every rank count found there: a serial run and one
    under ``mpirun -n 2`` (``make docs`` runs both) give the 1- and 2-rank rows side by side."""
    import shutil

    target = docs / "studies" / f"ranks-{comm.size}"
    if comm.rank == 0 and target.exists():
        shutil.rmtree(target)
    comm.Barrier()
    for name in STUDIES:
        run_study(name, target / name, comm)
    out = docs / "accuracy-cost.md"
    if comm.rank == 0:
        out.write_text(_accuracy_cost_markdown(docs))
    comm.Barrier()
    return out


def _accuracy_cost_markdown(docs: Path) -> str:
    runs = sorted(int(p.name.split("-")[1]) for p in (docs / "studies").glob("ranks-*") if p.is_dir())
    sections, serial_rows = [], {}
    for name, study in STUDIES.items():
        by_ranks = {
            n: read_rows(docs / "studies" / f"ranks-{n}" / name / f"{name}.csv")
            for n in runs
            if (docs / "studies" / f"ranks-{n}" / name / f"{name}.csv").exists()
        }
        if not by_ranks:
            continue
        first = min(by_ranks)
        serial_rows[name] = results(by_ranks[first])
        picture = f"studies/ranks-{first}/{name}/{name}.png"
        lines = [f"## `{name}`: {study.description}", "", f"![{name}]({picture})", ""]
        if (docs / picture.replace(".png", "-shapes.png")).exists():
            lines += [f"![{name} shapes]({picture.replace('.png', '-shapes.png')})", ""]
        if study.note:
            lines += [study.note, ""]
        rows = results([r for n in sorted(by_ranks) for r in by_ranks[n]])
        lines += _cheapest_table(study, rows)
        if "discretization" in study.knobs:
            lines += ["", _head_to_head(study, rows)]
            effects = _reduced_rule_effects(study, results(by_ranks[first]))
            lines += ["", effects] if effects else []
        lines += ["", _knob_effects(study, results(by_ranks[first])), ""]
        if len(by_ranks) > 1:
            lines += [_rank_comparison(study, by_ranks), ""]
        links = ", ".join(
            f"[{n} rank{'s' if n > 1 else ''}](studies/ranks-{n}/{name}/{name}.csv)" for n in sorted(by_ranks)
        )
        lines += [f"All rows: {links} (CSV; tables beside them).", ""]
        sections.append("\n".join(lines))
    counts = " and ".join(str(n) for n in runs)
    header = (
        "# What accuracy costs in time\n\n"
        "Generated by `make docs` (`bhem-hpc study --docs docs`, serially and under `mpirun -n 2`); every number "
        f"below was measured in those runs, on {counts} rank(s), on one 2-core machine. Errors are relative to "
        "independent references (Navier series, tabulated clamped-plate value, heavy elastica, Michell-Prandtl "
        "lateral buckling, a measured wrinkle amplitude) or, for the drape, to the finest run; times are the "
        "solve only (assembly, factorization, Newton; for the drape and the wrinkles every time step), without "
        "the one-off JIT compilation.\n\n"
    )
    return header + "\n".join(_paper_claims(serial_rows)) + "\n" + "\n".join(sections)


def _groups(study: Study) -> list[str]:
    """The columns a study's rows are grouped by in its tables: the problem, and the method where
    the discretization is a knob."""
    return [study.problem] + (["method"] if "discretization" in study.knobs else [])


def _group_key(row: dict, groups: list[str]) -> tuple:
    return tuple(row_method(row) if g == "method" else row[g] for g in groups)


def _cheapest_table(study: Study, rows: list[dict]) -> list[str]:
    """Per problem (and per method, where the discretization is a knob) and error target: the
    cheapest configuration that reaches it, with its error, solve time, DoFs and nonzeros."""
    groups = _groups(study)
    hidden = {study.problem, "discretization"} | ({"quadrature"} if "method" in groups else set())
    lines = [
        f"| {' | '.join(groups)} | target error | cheapest configuration | ranks | error | solve time [s] | DoFs "
        "| nonzeros |",
        "| " + " | ".join("---" for _ in groups) + " | --- | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    order = {name: k for k, name in enumerate(METHODS)}
    keys = sorted({_group_key(r, groups) for r in rows}, key=lambda k: (str(k[0]), *(order.get(v, 0) for v in k[1:])))
    for key in keys:
        subset = [r for r in rows if _group_key(r, groups) == key]
        best = min(subset, key=lambda r: r["error"])
        label = " | ".join(str(v) for v in key)
        for tolerance in (1e-2, 1e-3):
            row = cheapest(subset, tolerance)
            if row is None:
                lines.append(f"| {label} | {tolerance:g} | not reached; best {best['error']:.2e} | | | | | |")
                continue
            knobs = ", ".join(f"{k} = {row[k]}" for k in study.knobs if k not in hidden)
            lines.append(
                f"| {label} | {tolerance:g} | {knobs} | {row['ranks']} | {row['error']:.2e} | "
                f"{row['wall_s']:.4f} | {row['dofs']} | {row['nonzeros']} |"
            )
    return lines


def head_to_head_cases(study: Study, rows: list[dict]) -> list[dict]:
    """Per problem and error target (1 %, 0.1 %): the cheapest row of each method that reaches it
    (None where none does)."""
    cases = []
    for problem in sorted({r[study.problem] for r in rows}, key=str):
        subset = [r for r in rows if r[study.problem] == problem]
        for tolerance in (1e-2, 1e-3):
            reached = {name: cheapest([r for r in subset if row_method(r) == name], tolerance) for name in METHODS}
            cases.append({"study": study.name, "problem": problem, "tolerance": tolerance, "reached": reached})
    return cases


def quadratic_beats_hermite(case: dict) -> bool | None:
    """Whether quadratic B-splines (either rule) reach the case's error sooner than Hermite; None
    when neither reaches it."""
    hermite = case["reached"]["hermite"]
    quadratic = [case["reached"][m] for m in ("bspline2", "bspline2 reduced") if case["reached"][m]]
    if hermite is None and not quadratic:
        return None
    return bool(quadratic) and (hermite is None or min(r["wall_s"] for r in quadratic) < hermite["wall_s"])


def _head_to_head(study: Study, rows: list[dict]) -> str:
    """Measured, per problem: which method reaches 1 % and 0.1 % first, against the B-spline paper's
    claim that quadratic B-splines are cheaper than bicubic Hermite elements at equal accuracy."""
    sentences = []
    for case in head_to_head_cases(study, rows):
        words = ", ".join(
            f"{name} {row['wall_s']:.3g} s ({row['dofs']} DoFs)" if row else f"{name} not reached"
            for name, row in case["reached"].items()
        )
        verdict = quadratic_beats_hermite(case)
        claim = {True: "yes", False: "no", None: "neither reaches it"}[verdict]
        sentences.append(
            f"{study.problem} = {case['problem']}, error {case['tolerance']:g}: {words}; "
            f"quadratic B-splines cheaper than Hermite: {claim}."
        )
    head = "Head-to-head (the cheapest solve time that reaches each error):"
    return head + "\n\n" + "\n".join(f"- {s}" for s in sentences)


def reduced_rule_pairs(study: Study, rows: list[dict]) -> list[tuple[dict, dict]]:
    """Rows of quadratic B-splines with 3 x 3 Gauss and their twins with the reduced rule."""
    pairs = []
    for full in rows:
        if full.get("discretization") != "bspline2" or full.get("quadrature") != 3:
            continue
        twin = next(
            (
                r for r in rows
                if r.get("quadrature") == "reduced" and r["ranks"] == full["ranks"]
                and all(r[k] == full[k] for k in study.knobs if k != "quadrature")
            ),
            None,
        )  # fmt: skip
        if twin is not None:
            pairs.append((full, twin))
    return pairs


def _reduced_rule_effects(study: Study, rows: list[dict]) -> str:
    """Full (3 x 3 Gauss) against reduced quadrature on the same quadratic B-spline configurations."""
    pairs = reduced_rule_pairs(study, rows)
    if not pairs:
        return ""
    shown = [k for k in study.knobs if k not in ("discretization", "quadrature")]
    lines = [
        "The reduced rule against 3 x 3 Gauss on the same quadratic B-splines:",
        "",
        f"| {' | '.join(shown)} | error 3 x 3 | error reduced | Newton 3 x 3 | Newton reduced | time 3 x 3 [s] "
        "| time reduced [s] |",
        "|" + " --- |" * len(shown) + " ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for full, reduced in pairs:
        lines.append(
            "| " + " | ".join(str(full[k]) for k in shown)
            + f" | {full['error']:.2e} | {reduced['error']:.2e} | {full['newton_iterations']} | "
            f"{reduced['newton_iterations']} | {full['wall_s']:.4f} | {reduced['wall_s']:.4f} |"
        )  # fmt: skip
    return "\n".join(lines)


def _paper_claims(rows_by_study: dict[str, list[dict]]) -> list[str]:
    """The B-spline paper's claims, each checked against every study's serial rows."""
    cases, pairs = [], []
    for name, rows in rows_by_study.items():
        study = STUDIES[name]
        if "discretization" not in study.knobs:
            continue
        cases += [c for c in head_to_head_cases(study, rows) if quadratic_beats_hermite(c) is not None]
        pairs += reduced_rule_pairs(study, rows)
    if not cases:
        return []
    wins = [c for c in cases if quadratic_beats_hermite(c)]
    lines = [
        "## The B-spline paper's claims, measured here",
        "",
        f"- *Quadratic B-splines are faster than bicubic Hermite elements at the same accuracy*: quadratic "
        f"B-splines (either rule) reach the error target first in {len(wins)} of {len(cases)} (study, problem, "
        "target) cases that some method reaches"
        + (": " + "; ".join(f"{c['study']} {c['problem']} at {c['tolerance']:g}" for c in wins) if wins else "")
        + ".",
    ]
    if pairs:
        newton = [(f["newton_iterations"], r["newton_iterations"]) for f, r in pairs]
        errors = np.array([r["error"] / f["error"] for f, r in pairs if f["error"] > 0])
        times = np.array([r["wall_s"] / f["wall_s"] for f, r in pairs if f["wall_s"] > 0])
        more = sum(1 for f, r in newton if r > f)
        lines += [
            f"- *Reduced integration does not impair Newton convergence*: over {len(pairs)} paired runs, "
            f"{sum(r for _, r in newton)} Newton iterations with the reduced rule against {sum(f for f, _ in newton)} "
            f"with 3 x 3 Gauss; more iterations in {more} of them.",
            f"- *Reduced integration keeps the accuracy*: error with the reduced rule / error with 3 x 3 Gauss: "
            f"median {np.median(errors):.2f}, range {errors.min():.2f} to {errors.max():.2f}.",
            f"- *Reduced integration is cheaper*: solve time reduced / 3 x 3 Gauss: median {np.median(times):.2f}, "
            f"range {times.min():.2f} to {times.max():.2f} (per Newton iteration see the performance page).",
        ]
    return [*lines, ""]


def _rank_comparison(study: Study, by_ranks: dict[int, list[dict]]) -> str:
    """The configurations run on every rank count: value and time per rank count."""
    counts = sorted(by_ranks)
    first = by_ranks[counts[0]]
    header = (
        "| "
        + " | ".join(study.knobs)
        + " | "
        + " | ".join(f"value ({n})" for n in counts)
        + " | "
        + " | ".join(f"time ({n}) [s]" for n in counts)
        + f" | time {counts[-1]} / {counts[0]} |"
    )
    lines = [
        "Rank counts (same configuration, value and solve time per rank count):",
        "",
        header,
        "|" + " --- |" * len(study.knobs) + " ---: |" * (2 * len(counts) + 1),
    ]
    for row in first:
        twins = [next((r for r in by_ranks[n] if all(r[k] == row[k] for k in study.knobs)), None) for n in counts]
        if any(t is None for t in twins):
            continue
        lines.append(
            "| "
            + " | ".join(str(row[k]) for k in study.knobs)
            + " | "
            + " | ".join(f"{t['value']:.6g}" for t in twins)
            + " | "
            + " | ".join(f"{t['wall_s']:.3f}" for t in twins)
            + f" | {twins[-1]['wall_s'] / twins[0]['wall_s']:.2f} |"
        )
    return "\n".join(lines)


def _knob_effects(study: Study, rows: list[dict]) -> str:
    """One sentence per knob: how error and time change against the baseline configuration."""
    sentences = []
    base = [r for r in rows if study.in_baseline(r)]
    for knob in study.knobs:
        if knob in study.baseline:
            # the reduced rule has its own table
            others = [r for r in rows if r[knob] != study.baseline_value(knob, r) and r.get(knob) != "reduced"]
            for r in others:
                twin = next((b for b in base if all(b[k] == r[k] for k in study.knobs if k != knob)), None)
                if twin is None:
                    continue
                sentences.append(
                    f"{knob} = {r[knob]} instead of {study.baseline_value(knob, r)} "
                    f"({', '.join(f'{k} = {r[k]}' for k in study.knobs if k != knob)}): error "
                    f"{twin['error']:.2e} -> {r['error']:.2e}, time {twin['wall_s']:.4f} -> {r['wall_s']:.4f} s."
                )
    return "What the knobs buy:\n\n" + "\n".join(f"- {s}" for s in sentences) if sentences else ""
