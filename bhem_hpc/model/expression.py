"""Scalar expressions of the surface parameters written in scene files, e.g. ``"sin(pi * xi1)"``,
checked when the scene is read and turned into UFL expressions when the model is built.

Only arithmetic (``+ - * / **``, unary minus), numbers, the names ``xi1``, ``xi2``, ``pi`` and the
functions in :data:`FUNCTIONS` are accepted: the text is parsed, never evaluated as Python.
"""

from __future__ import annotations

import ast
import math
import operator
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from bhem_hpc.errors import UserError

if TYPE_CHECKING:
    import ufl

FUNCTIONS = ("sin", "cos", "tan", "exp", "ln", "sqrt", "abs", "sinh", "cosh", "tanh", "atan")
_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
           ast.Pow: operator.pow}  # fmt: skip
_UNARY = {ast.USub: operator.neg, ast.UAdd: operator.pos}
MAX_LENGTH = 1000
#: Deepest nesting of an expression's syntax tree (its evaluation recurses through it).
MAX_DEPTH = 100
#: Points per direction evaluated at once by :func:`finite_on_tensor` (bounds its memory).
_CHUNK = 1 << 20


class ExpressionError(UserError, ValueError):
    """Text that is not an accepted expression of the parameters."""


def _quoted(text: str) -> str:
    """The expression for a message: whole if short, else its start and its length."""
    return repr(text) if len(text) <= 60 else f"{text[:40]!r}... ({len(text)} characters)"


def _check_node(node: ast.AST, text: str) -> None:
    """Raise :class:`ExpressionError` unless ``node`` is an accepted piece of an expression."""
    refused = None
    if isinstance(node, ast.operator | ast.unaryop):
        refused = None if type(node) in (*_BINARY, *_UNARY) else f"operator {type(node).__name__}"
    elif isinstance(node, ast.Constant):
        number = isinstance(node.value, int | float) and not isinstance(node.value, bool)
        if not number:
            refused = f"{node.value!r}, which is not a number,"
        elif isinstance(node.value, int) and abs(node.value) > sys.float_info.max:
            refused = f"an integer of {len(str(abs(node.value)))} digits (beyond floating point)"
    elif isinstance(node, ast.Name):
        refused = None if node.id in ("xi1", "xi2", "pi", *FUNCTIONS) else f"the unknown name {node.id!r}"
    elif isinstance(node, ast.Call):
        simple = isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS and len(node.args) == 1
        refused = None if simple and not node.keywords else "a call other than a one-argument function"
    elif not isinstance(node, ast.BinOp | ast.UnaryOp | ast.Load):
        refused = f"{type(node).__name__} syntax"
    if refused:
        raise ExpressionError(
            f"{_quoted(text)} holds {refused}; accepted: numbers, xi1, xi2, pi, + - * / **, {', '.join(FUNCTIONS)}"
        )


def parse_expression(text: str) -> ast.expr:
    """The checked syntax tree of ``text``; raises :class:`ExpressionError` naming what is refused."""
    if not isinstance(text, str) or not text.strip() or len(text) > MAX_LENGTH:
        raise ExpressionError(f"an expression of xi1 and xi2 (at most {MAX_LENGTH} characters) is needed")
    try:
        tree = ast.parse(text.strip(), mode="eval").body
    except (SyntaxError, RecursionError, ValueError, MemoryError) as exc:
        raise ExpressionError(f"{_quoted(text)} is not an expression ({type(exc).__name__})") from None
    depth, level = 0, [tree]
    while level:  # breadth first, without recursion
        depth += 1
        if depth > MAX_DEPTH:
            raise ExpressionError(f"{_quoted(text)} nests more than {MAX_DEPTH} levels deep")
        level = [child for node in level for child in ast.iter_child_nodes(node)]
    for node in ast.walk(tree):
        _check_node(node, text)
    return tree


def _evaluator(text: str, functions: dict[str, Callable], number: Callable = float) -> Callable:
    """``(xi1, xi2) -> value`` of the checked expression ``text`` with the given functions and
    ``number`` for its constants."""
    tree = parse_expression(text)

    def build(node: ast.expr, xi1, xi2):
        if isinstance(node, ast.Constant):
            return number(node.value)
        if isinstance(node, ast.Name):
            return {"xi1": xi1, "xi2": xi2, "pi": number(math.pi)}[node.id]
        if isinstance(node, ast.BinOp):
            return _BINARY[type(node.op)](build(node.left, xi1, xi2), build(node.right, xi1, xi2))
        if isinstance(node, ast.UnaryOp):
            return _UNARY[type(node.op)](build(node.operand, xi1, xi2))
        return functions[node.func.id](build(node.args[0], xi1, xi2))

    return lambda xi1, xi2: build(tree, xi1, xi2)


def ufl_expression(text: str) -> Callable[[ufl.core.expr.Expr], ufl.core.expr.Expr]:
    """``xi -> expression`` with ``xi`` the parameters as a UFL 2-vector (a load profile)."""
    import ufl

    evaluate = _evaluator(text, {name: abs if name == "abs" else getattr(ufl, name) for name in FUNCTIONS})
    return lambda xi: evaluate(xi[0], xi[1])


def numpy_expression(text: str) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``(xi1, xi2) -> values`` on arrays (a surface's shape); real or complex (complex-step
    derivatives: ``abs`` keeps the imaginary part's sign rule of the real part)."""
    functions = {"ln": np.log, "atan": np.arctan, "abs": lambda z: np.where(np.real(z) < 0, -z, z)}
    functions |= {name: getattr(np, name) for name in FUNCTIONS if name not in functions}
    evaluate = _evaluator(text, functions, np.float64)  # 1 / 0 is inf, not an exception

    def values(xi1, xi2):
        with np.errstate(all="ignore"):
            return evaluate(xi1, xi2) + 0 * xi1  # a constant broadcasts to the arrays' shape

    return values


def finite_on_tensor(text: str, xi1: np.ndarray, xi2: np.ndarray) -> bool:
    """Whether the expression is finite at every pair of the 1-D parameter arrays ``xi1 (m1,)`` and
    ``xi2 (m2,)`` (a tensor grid, evaluated in slabs of bounded size)."""
    evaluate = numpy_expression(text)
    rows = max(1, _CHUNK // max(len(xi2), 1))
    for start in range(0, len(xi1), rows):
        a, b = np.meshgrid(xi1[start : start + rows], xi2, indexing="ij")
        if not np.all(np.isfinite(evaluate(a, b))):
            return False
    return True


def patch_samples(lo: float, hi: float, intervals: int) -> np.ndarray:
    """Parameters ``(m,)`` along one direction of ``intervals`` equal patches of ``[lo, hi]``: the
    patch boundaries and, inside every patch, the points of the 1- to 5-point Gauss rules (where
    any quadrature of a shell evaluates a load or shape)."""
    inside = np.concatenate([np.polynomial.legendre.leggauss(n)[0] for n in range(1, 6)])
    h = (hi - lo) / intervals
    centres = lo + h * (np.arange(intervals) + 0.5)
    points = (centres[:, None] + 0.5 * h * inside[None, :]).ravel()
    return np.concatenate([lo + h * np.arange(intervals + 1), points])


def finite_on_patches(text: str, ranges: tuple[tuple[float, float], tuple[float, float]],
                      intervals: tuple[int, int]) -> bool:  # fmt: skip
    """Whether the expression is finite on a grid of patches (``ranges`` of xi1 and xi2, patch
    counts ``intervals``) at every point :func:`patch_samples` gives: also between the nodes."""
    samples = [patch_samples(lo, hi, n) for (lo, hi), n in zip(ranges, intervals, strict=True)]
    return finite_on_tensor(text, *samples)
