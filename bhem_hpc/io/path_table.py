"""Tables of recorded states: ``path.csv`` of a static run (one row per converged path point, with a
PNG of the load against the probes' displacements), ``probes.csv`` of a dynamic run (one row per
time step) and ``steps.jsonl`` of either (a step's record of ``summary.json``, one JSON object per
line). Serial: call on one rank. A table is written by rename when its first row comes (with the
rows of the run it continues), then each row is appended as one line: a run that stops keeps every
row it completed, and a long run does not rewrite its whole table per step. A run writes a step's
rows before the checkpoint of that step, so a restart from any checkpoint finds all of its rows
(and drops the later ones, of steps it computes again).
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from bhem_hpc.io.run_directory import write_replacing

AXES = "xyz"


def probe_columns(probes: Mapping[str, Mapping[str, Sequence[float]]]) -> dict[str, float]:
    """``<name>_x, _y, _z`` (position) and ``<name>_ux, _uy, _uz`` (displacement) of every probe."""
    row: dict[str, float] = {}
    for name, record in probes.items():
        row |= {f"{name}_{a}": float(v) for a, v in zip(AXES, record["position"], strict=True)}
        row |= {f"{name}_u{a}": float(v) for a, v in zip(AXES, record["displacement"], strict=True)}
    return row


class _AppendedTable:
    """A file of one line per row; rows are kept in memory (for plots and summaries).

    Args:
        path: the file.
        keep: rows of an earlier run to start with (a continued run), as read back from the file.
    """

    def __init__(self, path: Path, keep: Sequence[dict] = ()):
        self.path = path
        self.rows: list[dict] = [dict(row) for row in keep]
        self._written = False

    def _lines(self, rows: Sequence[Mapping[str, object]], header: bool) -> str:
        raise NotImplementedError

    def add(self, row: Mapping[str, object]) -> None:
        self.rows.append(dict(row))
        if self._written:
            with open(self.path, "a", newline="") as f:
                f.write(self._lines(self.rows[-1:], header=False))  # one whole line per write
        else:
            write_replacing(self.path, self._lines(self.rows, header=True))
            self._written = True


class CsvTable(_AppendedTable):
    """A CSV file whose columns are those of its first row."""

    def _lines(self, rows: Sequence[Mapping[str, object]], header: bool) -> str:
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=list(self.rows[0]), extrasaction="ignore", lineterminator="\n")
        if header:
            writer.writeheader()
        writer.writerows(rows)
        return buffer.getvalue()


class JsonLinesTable(_AppendedTable):
    """A file of one JSON object per line (rows of any keys: a step's record)."""

    def _lines(self, rows: Sequence[Mapping[str, object]], header: bool) -> str:
        return "".join(json.dumps(row, separators=(",", ":")) + "\n" for row in rows)


def _complete_lines(path: Path) -> str:
    """The text of ``path`` without a last line a stopped run left incomplete (OSError, UnicodeDecodeError)."""
    text = path.read_text()
    return text[: text.rfind("\n") + 1]


def _up_to_step(rows: Sequence[Any], last_step: int) -> list[dict]:
    """The rows with ``step <= last_step``; none if any row has no readable step."""
    kept = []
    for row in rows:
        try:
            if int(row["step"]) <= last_step:
                kept.append(dict(row))
        except (KeyError, TypeError, ValueError):
            return []
    return kept


def read_rows(path: Path, last_step: int) -> list[dict]:
    """Rows of an earlier ``path.csv`` or ``probes.csv`` up to step ``last_step`` (none if it is
    missing or unreadable)."""
    try:
        rows = list(csv.DictReader(io.StringIO(_complete_lines(path), newline="")))
    except (OSError, csv.Error, UnicodeDecodeError):
        return []
    return _up_to_step(rows, last_step)


def read_json_rows(path: Path, last_step: int) -> list[dict]:
    """Rows of an earlier ``steps.jsonl`` up to step ``last_step`` (none if it is missing or
    unreadable)."""
    try:
        rows = [json.loads(line) for line in _complete_lines(path).splitlines()]
    except (OSError, UnicodeDecodeError, ValueError):
        return []
    return _up_to_step(rows, last_step)


def plot_path(rows: Sequence[Mapping[str, object]], probes: Sequence[str], png: Path, title: str) -> Path:
    """Load factor against every displacement component of the probes that moves (against the arc
    length without probes), limit points and bifurcations marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    factor = [float(r["load_factor"]) for r in rows]
    components = {f"{name} u{axis}": [float(r[f"{name}_u{axis}"]) for r in rows] for name in probes for axis in AXES}
    spans = {label: max(values) - min(values) for label, values in components.items()}
    largest = max(spans.values(), default=0.0)
    # components that move (not round-off beside the largest motion)
    curves = {label: values for label, values in components.items() if largest > 0 and spans[label] > 1e-6 * largest}
    if not curves:
        curves["arc length"] = [float(r["arc_length"]) for r in rows]
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=100)
    for label, values in curves.items():
        ax.plot(values, factor, ".-", label=label, linewidth=1)
        for marker, event in (("^", "limit"), ("s", "bifurcation")):
            points = [(v, f) for v, f, r in zip(values, factor, rows, strict=True) if r.get("event") == event]
            if points:
                ax.plot(*zip(*points, strict=True), marker, color="red", markersize=7, fillstyle="none",
                        label=f"{event} point" if label == next(iter(curves)) else None)  # fmt: skip
    ax.set_xlabel("displacement [m]" if probes else "arc length [m]")
    ax.set_ylabel("load factor")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)
    return png
