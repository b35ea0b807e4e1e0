"""Safe arithmetic formulas over named values, evaluated with numpy (private module).

A model file writes how a physical parameter enters a matrix entry as text, e.g.
``"1 - dt*bulk_modulus*leakage/volume"``. :func:`compile_formula` parses it with
:mod:`ast` and accepts only numbers, names, ``+ - * / **``, unary ``+ -``, parentheses and
the functions of :data:`FUNCTIONS`; anything else (attribute access, calls of other
names, subscripts, comparisons, ...) is refused. The result evaluates on numpy arrays, so
one call covers every Monte Carlo realization.

Every number is evaluated as a float (``2**3`` is ``8.0``): Python's integers have no size limit,
so ``10**10**10`` between literals would run (and fill memory) for ever, where the float
overflows at once and is reported. Formulas are at most :data:`MAX_FORMULA_CHARS` characters.
"""

from __future__ import annotations

import ast
import types
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError

__all__ = ["FUNCTIONS", "Formula", "compile_formula", "evaluate_formulas"]

#: Functions a formula may call (one argument each).
FUNCTIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "sqrt": np.sqrt,
    "exp": np.exp,
    "log": np.log,
    "sin": np.sin,
    "cos": np.cos,
}
#: Constants every formula knows (a name declared by the model takes precedence).
BUILTIN_CONSTANTS: dict[str, float] = {"pi": float(np.pi)}

_BINARY = (ast.Add, ast.Sub, ast.Mult, ast.Div, ast.Pow)
#: Longest formula text accepted (a matrix entry's formula is a line, not a program).
MAX_FORMULA_CHARS = 1000


class _FloatConstants(ast.NodeTransformer):
    """Integer literals as floats: float arithmetic is bounded in time and memory, big-integer is not."""

    def visit_Constant(self, node: ast.Constant) -> ast.Constant:
        if isinstance(node.value, int) and not isinstance(node.value, bool):
            return ast.copy_location(ast.Constant(value=float(node.value)), node)
        return node


@dataclass(frozen=True)
class Formula:
    """A parsed formula: its text, the names it reads, and an evaluator.

    Attributes
    ----------
    text : str
        The formula as written.
    names : frozenset of str
        Names it reads (parameters and constants; not the function names).
    """

    text: str
    names: frozenset[str]
    _code: types.CodeType = field(repr=False, compare=False)

    def __reduce__(self) -> tuple[object, tuple[str]]:
        # code objects do not pickle (models travel to worker processes): rebuild from the text
        return (compile_formula, (self.text,))

    def __call__(self, values: Mapping[str, object]) -> np.ndarray:
        """Evaluate with ``values`` (name -> number or array; arrays broadcast).

        Raises
        ------
        ParameterError
            If a name is missing from ``values`` (and is not ``pi``).
        """
        return evaluate_formulas((self,), values)[0]


def evaluate_formulas(formulas: Sequence[Formula], values: Mapping[str, object]) -> list[np.ndarray]:
    """Each of ``formulas`` evaluated with ``values`` (name -> number or array; arrays broadcast): the
    scope is built once for all of them (the numbers are those of calling each).

    Raises
    ------
    ParameterError
        If a name is missing from ``values`` (and is not ``pi``), or a number overflows.
    """
    names = frozenset().union(*(f.names for f in formulas))
    missing = names - values.keys() - BUILTIN_CONSTANTS.keys()
    if missing:
        f = next(f for f in formulas if f.names & missing)
        raise ParameterError(f"formula {f.text!r}: no value for {sorted(f.names & missing)}")
    scope: dict[str, object] = {**BUILTIN_CONSTANTS, **FUNCTIONS}
    scope.update({k: _operand(values[k]) for k in names if k in values})
    out = []
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for f in formulas:
            try:
                # the tree holds only the whitelisted nodes (compile_formula): no builtins are reachable
                out.append(np.asarray(eval(f._code, {"__builtins__": {}}, scope), dtype=float))
            except OverflowError:  # e.g. 10**10**10 between literal numbers
                raise ParameterError(
                    f"formula {f.text!r} cannot be evaluated: a number overflows (beyond 1.8e308)"
                ) from None
            except ArithmeticError as exc:  # e.g. 1/0 between two literal numbers
                raise ParameterError(f"formula {f.text!r} cannot be evaluated: {exc}") from None
    return out


def _operand(value: object) -> np.ndarray | np.float64:
    """``value`` as a float array, or a numpy float scalar when it has no dimensions: the same float
    operations (and the same overflow and division by zero under ``np.errstate``), without the cost of
    a ufunc call per operation between constants."""
    arr = np.asarray(value, dtype=float)
    return arr[()] if arr.ndim == 0 else arr


def compile_formula(text: str, where: str = "formula") -> Formula:
    """Parse ``text`` into a :class:`Formula`.

    Parameters
    ----------
    text : str
        Arithmetic over names and numbers, e.g. ``"-dt*(2*pi*f0)**2"``.
    where : str
        Prefix of error messages (e.g. the model file and key).

    Raises
    ------
    ParameterError
        On a syntax error or a construct other than numbers, names, ``+ - * / **``,
        unary ``+ -`` and calls of :data:`FUNCTIONS`.
    """
    if not isinstance(text, str) or not text.strip():
        raise ParameterError(f"{where}: a formula must be a non-empty string; got {text!r}")
    if len(text) > MAX_FORMULA_CHARS:
        raise ParameterError(
            f"{where}: a formula has at most {MAX_FORMULA_CHARS} characters; got {len(text)} "
            f"({text[:40]!r}...)"
        )
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except (SyntaxError, MemoryError, RecursionError) as exc:  # e.g. too deeply nested
        why = exc.msg if isinstance(exc, SyntaxError) else "too deeply nested"
        raise ParameterError(f"{where}: {text!r} is not a valid formula ({why})") from None
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            if not (isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS) or len(node.args) != 1:
                raise ParameterError(
                    f"{where}: {text!r}: only one-argument calls of {', '.join(FUNCTIONS)} are allowed"
                )
            if node.keywords:
                raise ParameterError(f"{where}: {text!r}: keyword arguments are not allowed")
        elif isinstance(node, ast.Name):
            if node.id not in FUNCTIONS:
                names.add(node.id)
        elif isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, int | float):
                raise ParameterError(f"{where}: {text!r}: only numbers are allowed as constants")
        elif isinstance(node, ast.BinOp):
            if not isinstance(node.op, _BINARY):
                raise ParameterError(f"{where}: {text!r}: only + - * / ** are allowed")
        elif isinstance(node, ast.UnaryOp):
            if not isinstance(node.op, ast.UAdd | ast.USub):
                raise ParameterError(f"{where}: {text!r}: only unary + and - are allowed")
        elif not isinstance(node, ast.Expression | ast.Load | ast.operator | ast.unaryop):
            raise ParameterError(f"{where}: {text!r}: {type(node).__name__} is not allowed in a formula")
    tree = ast.fix_missing_locations(_FloatConstants().visit(tree))
    code = compile(tree, "<formula>", "eval")
    return Formula(text=text.strip(), names=frozenset(names), _code=code)
