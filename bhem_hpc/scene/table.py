"""Typed access to scene tables with errors that name the file and the key, and the registries
through which each kind of table (surface, motion, collider) parses itself (pbrt-v4's ``Create``)."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bhem_hpc.errors import UserError

#: Characters of a refused value an error message shows (a long one is cut in the middle).
SHOWN_VALUE_LENGTH = 120


def _shown(value: Any) -> str:
    """``repr(value)``, cut to :data:`SHOWN_VALUE_LENGTH` characters around an ellipsis with its length."""
    text = repr(value)
    if len(text) <= SHOWN_VALUE_LENGTH:
        return text
    half = SHOWN_VALUE_LENGTH // 2
    return f"{text[:half]}...{text[-half // 2:]} ({len(text)} characters)"


class SceneError(UserError, ValueError):
    """A scene file is malformed; the message names the file, the key and the expectation."""


class Table:
    """Typed access to one TOML table with errors that name file and key."""

    def __init__(self, path: Path, name: str, data: Any):
        self.path, self.name = path, name
        if not isinstance(data, dict):
            self.fail("", "a table", data)
        self.data = data
        self.used: set[str] = set()

    def key(self, key: str) -> str:
        return f"{self.name}.{key}" if self.name else key

    def fail(self, key: str, expected: str, got: Any) -> None:
        where = self.key(key) if key else self.name
        raise SceneError(f"{self.path}: key '{where}' must be {expected}, got {_shown(got)}")

    def missing(self, key: str, expected: str) -> None:
        raise SceneError(f"{self.path}: missing key '{self.key(key)}' ({expected})")

    def get(
        self, key: str, kind: str, default: Any = ..., check: Callable[[Any], bool] | None = None, expected: str = ""
    ):
        self.used.add(key)
        if key not in self.data:
            if default is ...:
                self.missing(key, expected or kind)
            return default
        value = self.data[key]
        ok = VALUE_KINDS[kind](value)
        if ok and check is not None:
            ok = check(value)
        if not ok:
            self.fail(key, expected or kind, value)
        return value

    def table(self, key: str, default: Any = ...) -> Table | None:
        self.used.add(key)
        if key not in self.data:
            if default is ...:
                self.missing(key, "a table")
            return default
        return Table(self.path, self.key(key), self.data[key])

    def done(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise SceneError(f"{self.path}: unknown key '{self.key(unknown[0])}' (known: {sorted(self.used)})")


def is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def vector(n: int) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, list) and len(v) == n and all(is_number(c) for c in v)


VALUE_KINDS: dict[str, Callable[[Any], bool]] = {
    "a number": is_number,
    "an integer": is_int,
    "a string": lambda v: isinstance(v, str),
    "an integer or a string": lambda v: is_int(v) or isinstance(v, str),
    "a number or a string": lambda v: is_number(v) or isinstance(v, str),
    "a boolean": lambda v: isinstance(v, bool),
    "3 numbers": vector(3),
    "2 numbers": vector(2),
    "2 integers": lambda v: isinstance(v, list) and len(v) == 2 and all(is_int(c) for c in v),
    "a list": lambda v: isinstance(v, list),
    "a table": lambda v: isinstance(v, dict),
}


def regular_file(t: Table, key: str, file: str, scene: Path) -> Path:
    """``file`` relative to the scene's folder (or absolute): an existing regular file, never a
    FIFO or device that would block or stream forever."""
    target = (scene.parent / file).resolve()
    if not target.is_file():
        what = "not a regular file" if target.exists() else "missing"
        t.fail(key, f"an existing regular file, relative to the scene ({target} is {what})", file)
    return target


class Registry:
    """The parsers of one family of scene tables by name: each kind (a surface kind, a motion type,
    a collider type) parses its own table and registers itself here, in the order its names are
    listed to the user.

    Args:
        family: what the names name (for messages), e.g. ``"collider type"``.
    """

    def __init__(self, family: str):
        self.family = family
        self._parsers: dict[str, Callable[..., Any]] = {}

    def register(self, name: str) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
        """Decorator: ``parser`` parses tables of kind ``name``."""

        def add(parser: Callable[..., Any]) -> Callable[..., Any]:
            if name in self._parsers:
                raise ValueError(f"{self.family} {name!r} is registered twice")
            self._parsers[name] = parser
            return parser

        return add

    @property
    def names(self) -> tuple[str, ...]:
        """The registered names, in registration order."""
        return tuple(self._parsers)

    def __getitem__(self, name: str) -> Callable[..., Any]:
        return self._parsers[name]

