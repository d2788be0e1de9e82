"""Motions of constraints (``motion = { type = ... }``): each type parses its own table and
registers itself in :data:`MOTIONS`."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bhem_hpc.geometry import surface as S
from bhem_hpc.model import bcs
from bhem_hpc.scene.records import Motion, SceneConstraint
from bhem_hpc.scene.table import Registry, SceneError, Table, is_number

#: Parsers of the motion types: ``(table, constraint, moved components) -> Motion``.
MOTIONS = Registry("motion type")


def parse_motion(t: Table, constraint: bcs.NodalConstraint) -> Motion:
    """The motion of ``constraint`` that the table ``t`` describes."""
    types = MOTIONS.names
    kind = t.get("type", "a string", check=lambda v: v in types, expected=f"one of {types}")
    motion = MOTIONS[kind](t, constraint, list(constraint.components))
    t.done()
    return motion


@MOTIONS.register("linear")
def _linear(t: Table, constraint: bcs.NodalConstraint, comps: list[int]) -> Motion:
    velocity = np.array(t.get("velocity", "3 numbers"))[comps]
    until = t.get("until", "a number", math.inf, lambda v: v > 0, "a number > 0 (the time [s] it stops)")
    return Motion("linear", lambda time, initial: initial + velocity * min(time, until))


@MOTIONS.register("rotation")
def _rotating(t: Table, constraint: bcs.NodalConstraint, comps: list[int]) -> Motion:
    if comps != [0, 1, 2]:
        t.fail("type", "used only on constraints of all three components", "rotation")
    axis = np.array(t.get("axis", "3 numbers", check=lambda v: np.linalg.norm(v) > 0, expected="a nonzero 3-vector"))
    center = np.array(t.get("center", "3 numbers", [0.0, 0.0, 0.0]))
    speed = t.get("angular_speed", "a number")
    axis = axis / np.linalg.norm(axis)
    is_position = np.array([k == 0 for k in constraint.kinds])[None, :, None]

    def rotate(time: float, initial: np.ndarray) -> np.ndarray:
        rotation = _rotation(axis, speed * time)
        moved_positions = (initial - center) @ rotation.T + center
        return np.where(is_position, moved_positions, initial @ rotation.T)

    return Motion("rotation", rotate)


@MOTIONS.register("keyframes")
def _keyframes(t: Table, constraint: bcs.NodalConstraint, comps: list[int]) -> Motion:
    times = np.array(
        t.get(
            "times",
            "a list",
            check=lambda v: len(v) >= 2 and all(is_number(x) for x in v) and all(np.diff(v) > 0),
            expected="at least 2 increasing numbers",
        )
    )
    values = t.get(
        "values", "a list", check=lambda v: len(v) == len(times), expected=f"{len(times)} entries, one per time"
    )
    try:
        frames = [
            np.broadcast_to(np.array(v, dtype=float), (len(constraint.nodes), len(constraint.kinds), len(comps)))
            for v in values
        ]
    except (ValueError, TypeError):
        t.fail(
            "values",
            f"entries broadcastable to (nodes={len(constraint.nodes)}, kinds={len(constraint.kinds)}, "
            f"components={len(comps)})",
            values,
        )
    stacked = np.stack(frames)
    if not np.all(np.isfinite(stacked)):
        t.fail("values", "finite numbers", values)

    def keyframes(time: float, initial: np.ndarray) -> np.ndarray:
        k = int(np.clip(np.searchsorted(times, time, side="right") - 1, 0, len(times) - 2))
        w = float(np.clip((time - times[k]) / (times[k + 1] - times[k]), 0.0, 1.0))
        return (1 - w) * stacked[k] + w * stacked[k + 1]

    return Motion("keyframes", keyframes)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def check_motion_conflicts(constraints: list[SceneConstraint], path: Path) -> None:
    """A DOF may be driven by at most one moving constraint and must not also be held fixed."""
    owner: dict[tuple[int, int, int, int], tuple[str, bool]] = {}
    for sc in constraints:
        c = sc.constraint
        for node in np.asarray(c.nodes):
            for kind in c.kinds:
                for comp in c.components:
                    dof = (int(node[0]), int(node[1]), kind, comp)
                    moving = sc.motion is not None
                    if dof in owner and (moving or owner[dof][1]):
                        raise SceneError(
                            f"{path}: {sc.key} and {owner[dof][0]} both constrain node {tuple(dof[:2])}, "
                            f"kind {S.KIND_NAMES[kind]}, component {comp}, and one of them moves it"
                        )
                    owner.setdefault(dof, (sc.key, moving))
