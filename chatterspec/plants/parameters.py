"""Physical parameters of a model: how they enter its matrices (formulas) and the band each may
take in normal operation (tolerances).

Physical parameters of a linear model: which matrix entries they enter, and how.

Fault identification (:mod:`chatterspec.detection.identification`) estimates a physical
parameter (a leakage coefficient in m^3/(s Pa), a natural frequency in Hz) from the
chattering. For that it must know how the parameter enters the discrete matrices A and B
of eq (1). A :class:`ParameterMap` declares it:

* **parameters**: named physical quantities with a nominal value and a unit; these are
  what identification can estimate;
* **constants**: other named values the formulas use (``dt``, the sampling time in s, is
  always available);
* **entries**: for each entry of A or B that depends on a parameter, a formula (text,
  see :func:`compile_formula`), e.g. ``A[3,3] = 1 - dt*bulk_modulus*leakage/volume``;
* **hypotheses**: named sets of parameters that may have changed together (default: one
  hypothesis per parameter).

The catalogue models carry their map (:func:`eha_parameter_map`, :func:`second_order_parameter_map`,
attached by :func:`chatterspec.plants.models.eha_linear` and :func:`~chatterspec.plants.models.second_order`
for explicit Euler); a model file declares one in ``[parameters]``, ``[constants]``,
``[entries]`` and ``[hypotheses]`` (``examples/README.md``), so a user's own model gets
identification without code. :meth:`ParameterMap.check` makes sure the formulas give the
model's own A and B at the nominal values.

Formulas: safe arithmetic over named values, evaluated with numpy.

A model file writes how a physical parameter enters a matrix entry as text, e.g.
``"1 - dt*bulk_modulus*leakage/volume"``. :func:`compile_formula` parses it with
:mod:`ast` and accepts only numbers, names, ``+ - * / **``, unary ``+ -``, parentheses and
the functions of :data:`FUNCTIONS`; anything else (attribute access, calls of other
names, subscripts, comparisons, ...) is refused. The result evaluates on numpy arrays, so
one call covers every Monte Carlo realization.

Every number is evaluated as a float (``2**3`` is ``8.0``): Python's integers have no size limit,
so ``10**10**10`` between literals would run (and fill memory) for ever, where the float
overflows at once and is reported. Formulas are at most :data:`MAX_FORMULA_CHARS` characters.

Operating tolerances of physical parameters: the band a parameter may take in normal operation.

A real actuator's parameters move in normal operation (the bulk modulus with temperature and
entrained air, viscous friction with oil temperature) while its model stays fixed. A
:class:`Tolerance` declares how far a parameter may move from its nominal value before the
change is a fault; fault decisions on the identified parameters
(:mod:`chatterspec.detection.parameter_decision`) compare each estimate with its band.

Forms (the ``tolerance`` key of a model file's ``[parameters]`` entry, ``examples/README.md``;
the same text after ``--tolerance NAME=`` on the command line, with a comma for the pairs):

================================ ====================================== =====================
model file                       band                                   kind
================================ ====================================== =====================
``tolerance = "15%"``            nominal * (1 -+ 0.15)                  ``relative``
``tolerance = ["-10%", "+20%"]`` nominal - 10 % .. nominal + 20 %       ``relative``
``tolerance = 3.0e7``            nominal -+ 3e7 (the parameter's unit)  ``absolute``
``tolerance = [1.8e8, 2.3e8]``   1.8e8 .. 2.3e8 (the parameter's unit)  ``limits``
================================ ====================================== =====================

Relative offsets are fractions of ``|nominal|``, so a relative band moves with the nominal value
(e.g. one refitted from healthy data); absolute offsets move with it too; limits stay put. A
negative tolerance, a lower offset above the nominal or an upper one below it, or limits that
exclude the nominal are refused (:class:`~chatterspec.errors.ParameterError`; the model file
reader turns it into :class:`~chatterspec.errors.ModelFileError` naming the file and parameter).
"""

from __future__ import annotations

import ast
import itertools
import math
import re
import types
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Literal, TypeVar, cast

import numpy as np

from ..errors import ChatterspecError, ModelFileError, ParameterError

if TYPE_CHECKING:
    from .models import LinearModel

__all__ = [
    "FUNCTIONS",
    "NO_FAULT",
    "UNEXPLAINED",
    "Formula",
    "Hypothesis",
    "MatrixEntry",
    "ParameterMap",
    "PhysicalParameter",
    "Tolerance",
    "compile_formula",
    "eha_parameter_map",
    "evaluate_formulas",
    "parse_tolerance",
    "second_order_parameter_map",
    "tolerance_from_text",
    "with_tolerances",
]


# Safe arithmetic formulas.

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


# Operating tolerances.

ToleranceKind = Literal["relative", "absolute", "limits"]

_PERCENT = re.compile(r"^\s*(\+-|±|\+/-)?\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*%\s*$")


@dataclass(frozen=True)
class Tolerance:
    """The band a parameter may take in normal operation.

    Attributes
    ----------
    kind : {"relative", "absolute", "limits"}
        ``relative``: ``lower`` and ``upper`` are fractions of ``|nominal|`` below and above it;
        ``absolute``: offsets in the parameter's unit; ``limits``: the band's ends themselves.
    lower, upper : float
        Offsets below and above the nominal (>= 0; ``relative``, ``absolute``), or the band's
        lower and upper end (``limits``, in the parameter's unit).
    """

    kind: ToleranceKind
    lower: float
    upper: float

    def __post_init__(self) -> None:
        if self.kind not in ("relative", "absolute", "limits"):
            raise ParameterError(f"tolerance kind must be relative, absolute or limits; got {self.kind!r}")
        lo, hi = float(self.lower), float(self.upper)
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise ParameterError(f"a tolerance must be finite; got {self.text()}")
        if self.kind == "limits":
            if lo > hi:
                raise ParameterError(
                    f"tolerance limits must be [low, high] with low <= high; got [{lo}, {hi}]"
                )
        elif lo < 0 or hi < 0:
            raise ParameterError(f"a tolerance must be >= 0 on both sides; got {self.text()}")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)

    def band(self, nominal: float) -> tuple[float, float]:
        """``(low, high)``: the band around ``nominal`` in the parameter's unit.

        Raises
        ------
        ParameterError
            Limits that exclude ``nominal``; a relative tolerance of a zero nominal (no band).
        """
        x = float(nominal)
        if self.kind == "limits":
            if not self.lower <= x <= self.upper:
                raise ParameterError(
                    f"tolerance limits [{self.lower:.6g}, {self.upper:.6g}] exclude the nominal value {x:.6g}"
                )
            return self.lower, self.upper
        if self.kind == "relative":
            if x == 0.0 and (self.lower or self.upper):
                raise ParameterError(
                    "a relative tolerance of a parameter whose nominal value is 0 is no band: give an "
                    "absolute one (a number in the parameter's unit)"
                )
            return x - self.lower * abs(x), x + self.upper * abs(x)
        return x - self.lower, x + self.upper

    def text(self) -> str:
        """The model-file value: ``"15%"``, ``["-10%", "+20%"]``, ``3e7`` or ``[1.8e8, 2.3e8]`` (TOML)."""
        if self.kind == "limits":
            return f"[{self.lower!r}, {self.upper!r}]"
        if self.kind == "relative":
            lo, hi = _pct(self.lower), _pct(self.upper)
            return f'"{lo}%"' if lo == hi else f'["-{lo}%", "+{hi}%"]'
        return repr(self.lower) if self.lower == self.upper else f'["-{self.lower!r}", "+{self.upper!r}"]'

    def describe(self, unit: str = "") -> str:
        """``"+-15 %"``, ``"-10 %/+20 %"``, ``"+-3e+07 Pa"`` or ``"[1.8e+08, 2.3e+08] Pa"``."""
        u = f" {unit}" if unit else ""
        if self.kind == "limits":
            return f"[{self.lower:.4g}, {self.upper:.4g}]{u}"
        if self.kind == "relative":
            lo, hi = _pct(self.lower), _pct(self.upper)
            return f"+-{lo} %" if lo == hi else f"-{lo} %/+{hi} %"
        if self.lower == self.upper:
            return f"+-{self.lower:.4g}{u}"
        return f"-{self.lower:.4g}/+{self.upper:.4g}{u}"


def _pct(fraction: float) -> str:
    """``0.15`` -> ``"15"`` (percent, shortest text that reads back to the same fraction)."""
    return f"{100 * fraction:.10g}"


def _percent(text: str) -> tuple[float, bool] | None:
    """``"15%"`` -> ``(0.15, False)``; ``"+-15%"`` -> ``(0.15, True)``; None when not a percentage."""
    m = _PERCENT.match(text)
    if m is None:
        return None
    return float(m.group(2)) / 100.0, m.group(1) is not None


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value)


_FORMS = (
    'a percentage "15%", an absolute offset 3e7 (the parameter\'s unit), relative offsets '
    '["-10%", "+20%"], or limits [low, high] (the parameter\'s unit)'
)


def parse_tolerance(value: object, nominal: float, where: str) -> Tolerance:
    """The :class:`Tolerance` of a model file's ``tolerance`` value (see the module docstring).

    Parameters
    ----------
    value : str, float or list of two
        The TOML value.
    nominal : float
        The parameter's nominal value (its band must contain it).
    where : str
        Prefix of error messages (file and parameter).

    Raises
    ------
    ParameterError
        An unreadable form, a negative tolerance, or one that excludes the nominal.
    """
    tol = _parse(value, where)
    try:
        tol.band(nominal)
    except ParameterError as exc:
        raise ParameterError(f"{where}: {exc}") from None
    return tol


def _parse(value: object, where: str) -> Tolerance:
    try:
        if isinstance(value, str):
            pct = _percent(value)
            if pct is None:
                raise ParameterError(f"cannot read {value!r}")
            x, _ = pct
            if x < 0:
                raise ParameterError(f"a tolerance must be >= 0; got {value!r}")
            return Tolerance("relative", x, x)
        offset = _number(value)
        if offset is not None:
            if offset < 0:
                raise ParameterError(f"a tolerance must be >= 0; got {offset!r}")
            return Tolerance("absolute", offset, offset)
        if isinstance(value, list | tuple) and len(value) == 2:
            a, b = value
            na, nb = _number(a), _number(b)
            if na is not None and nb is not None:
                return Tolerance("limits", na, nb)
            if isinstance(a, str) and isinstance(b, str):
                pa, pb = _percent(a), _percent(b)
                if pa is not None and pb is not None:
                    return _offsets("relative", pa[0], pb[0], value)
                fa, fb = _float(a), _float(b)
                if fa is not None and fb is not None:
                    return _offsets("absolute", fa, fb, value)
            raise ParameterError(f"cannot read {value!r}")
        raise ParameterError(f"cannot read {value!r}")
    except ParameterError as exc:
        raise ParameterError(f"{where}: tolerance: {exc}; use {_FORMS}") from None


def _float(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def _offsets(kind: ToleranceKind, below: float, above: float, value: object) -> Tolerance:
    """Signed offsets ``[-a, +b]`` -> ``Tolerance(kind, a, b)``; a lower offset above the nominal or an
    upper one below it excludes the nominal."""
    if below > 0 or above < 0:
        raise ParameterError(
            f"{value!r} excludes the nominal value: the first offset must be <= 0 and the second >= 0"
        )
    return Tolerance(kind, -below, above)


def tolerance_from_text(text: str, nominal: float, where: str) -> Tolerance:
    """A command-line tolerance (``--tolerance NAME=SPEC``): ``15%``, ``3e7``, ``-10%,+20%``, ``1.8e8,2.3e8``.

    Parameters
    ----------
    text : str
        The SPEC part (a comma separates the two ends of a pair).
    nominal : float
        The parameter's nominal value.
    where : str
        Prefix of error messages.
    """
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) == 1:
        value: object = parts[0] if _percent(parts[0]) is not None else _float(parts[0])
        if value is None:
            value = parts[0]
    elif len(parts) == 2 and all(_percent(p) is not None for p in parts):
        value = parts
    elif len(parts) == 2 and all(_float(p) is not None for p in parts):
        lo, hi = (float(p) for p in parts)
        # signed offsets read as limits only when they are not offsets around the nominal
        value = [str(lo), str(hi)] if parts[0].startswith("-") and parts[1].startswith("+") else [lo, hi]
    else:
        value = text
    return parse_tolerance(value, nominal, where)


def with_tolerances(model: Any, tolerances: Mapping[str, Tolerance | str]) -> Any:
    """A copy of ``model`` whose parameter map gives the parameters in ``tolerances`` those tolerances.

    Parameters
    ----------
    model : LinearModel
        A model with a parameter map (:mod:`chatterspec.plants.parameters`).
    tolerances : mapping of str to Tolerance or str
        Parameter name -> :class:`Tolerance` or its command-line text (``"15%"``, ``"3e7"``,
        ``"-10%,+20%"``, ``"1.8e8,2.3e8"``).

    Raises
    ------
    ParameterError
        The model declares no parameters, an unknown name, or a bad tolerance.
    """
    pm = getattr(model, "parameter_map", None)
    if pm is None:
        raise ParameterError(
            f"{getattr(model, 'name', 'the model')!r} declares no physical parameters, so it has no "
            "parameter to give a tolerance (a model file's [parameters] table, examples/README.md)"
        )
    return model.replace(parameter_map=pm.with_tolerances(tolerances))


# The parameter map.

#: Name of the hypothesis "nothing changed" (reserved).
NO_FAULT = "no fault"
#: Name selected when the model's data reject "no fault" and every declared hypothesis (reserved).
UNEXPLAINED = "unexplained"

#: Up to this many parameters every combination is a hypothesis (:meth:`ParameterMap.combinations`).
MAX_ALL_COMBINATIONS = 6

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_ENTRY = re.compile(r"^\s*([AB])\s*\[\s*(\d+)\s*,\s*(\d+)\s*\]\s*$")


@dataclass(frozen=True)
class PhysicalParameter:
    """A named physical parameter with its nominal value.

    Attributes
    ----------
    name : str
        Identifier used in formulas and hypotheses (letters, digits, ``_``).
    value : float
        Nominal value (the value in the nominal model), in ``unit``.
    unit : str
        Unit of ``value`` and of every estimate (e.g. ``"m^3/(s Pa)"``, ``"Hz"``).
    description : str
        Human-readable meaning.
    tolerance : Tolerance or None
        The band the parameter may take in normal operation
        (:mod:`chatterspec.plants.parameters`); None: none declared.
    """

    name: str
    value: float
    unit: str = ""
    description: str = ""
    tolerance: Tolerance | None = None

    @property
    def band(self) -> tuple[float, float] | None:
        """``(low, high)`` of :attr:`tolerance` around :attr:`value` (None without a tolerance)."""
        return None if self.tolerance is None else self.tolerance.band(self.value)


@dataclass(frozen=True)
class Hypothesis:
    """A fault hypothesis: the parameters that may have changed (all others keep their nominal value).

    Attributes
    ----------
    name : str
    parameters : tuple of str
    """

    name: str
    parameters: tuple[str, ...]


@dataclass(frozen=True)
class MatrixEntry:
    """One entry of the discrete A or B written as a formula of parameters and constants.

    Attributes
    ----------
    matrix : {"A", "B"}
    row, col : int
        0-based indices (written 1-based, ``A[row+1,col+1]``, in files and messages).
    formula : Formula
    """

    matrix: Literal["A", "B"]
    row: int
    col: int
    formula: Formula

    @property
    def label(self) -> str:
        """``"A[3,3]"``: the entry, 1-based as in files and messages."""
        return f"{self.matrix}[{self.row + 1},{self.col + 1}]"


_Named = TypeVar("_Named", bound="PhysicalParameter | Hypothesis")


def _named(items: Sequence[_Named], name: str, missing: str) -> _Named:
    """The item of ``items`` called ``name``; :class:`ParameterError` with ``missing`` otherwise."""
    for item in items:
        if item.name == name:
            return item
    raise ParameterError(missing)


@dataclass(frozen=True, eq=False)
class ParameterMap:
    """How named physical parameters enter the discrete matrices A and B of a linear model.

    Parameters
    ----------
    parameters : sequence of PhysicalParameter
        The parameters identification may estimate.
    entries : sequence of MatrixEntry
        Formulas of the entries of A and B that depend on parameters (entries not listed
        keep the model's value).
    constants : mapping of str to float
        Other named values of the formulas (e.g. ``mass``); ``dt`` is supplied by the model.
    hypotheses : sequence of Hypothesis, optional
        Named parameter sets; default one hypothesis per parameter, named after it.

    Raises
    ------
    ParameterError
        On a duplicate or invalid name, an entry listed twice, a formula reading a name
        that is neither a parameter nor a constant, a hypothesis naming a parameter the
        map does not have, or a parameter that enters no entry.
    """

    parameters: tuple[PhysicalParameter, ...]
    entries: tuple[MatrixEntry, ...]
    constants: Mapping[str, float] = field(default_factory=dict)
    hypotheses: tuple[Hypothesis, ...] = ()

    def __post_init__(self) -> None:
        params = tuple(self.parameters)
        names = [p.name for p in params]
        consts = {str(k): float(v) for k, v in dict(self.constants).items()}
        for n in (*names, *consts):
            if not _NAME.match(n) or n in FUNCTIONS or n in BUILTIN_CONSTANTS:
                raise ParameterError(f"{n!r} cannot name a parameter or constant (use letters, digits, _)")
        if n_dup := sorted({n for n in names + list(consts) if (names + list(consts)).count(n) > 1}):
            raise ParameterError(f"names declared twice among parameters and constants: {n_dup}")
        if "dt" in names:
            raise ParameterError("'dt' is the model's sampling time, not a parameter")
        for p in params:
            if not np.isfinite(p.value):
                raise ParameterError(f"parameter {p.name!r} needs a finite nominal value; got {p.value!r}")
            if p.tolerance is not None:
                try:
                    p.tolerance.band(p.value)
                except ParameterError as exc:
                    raise ParameterError(f"parameter {p.name!r}: {exc}") from None
        known = set(names) | set(consts) | {"dt"} | set(BUILTIN_CONSTANTS)
        seen: set[tuple[str, int, int]] = set()
        used: set[str] = set()
        for e in self.entries:
            key = (e.matrix, e.row, e.col)
            if key in seen:
                raise ParameterError(f"entry {e.label} is declared twice")
            seen.add(key)
            unknown = sorted(e.formula.names - known)
            if unknown:
                raise ParameterError(
                    f"entry {e.label} = {e.formula.text!r} reads {unknown}, which are neither parameters "
                    f"({', '.join(names) or 'none'}) nor constants ({', '.join(['dt', *consts])})"
                )
            used |= e.formula.names
        for name in names:
            if name not in used:
                raise ParameterError(
                    f"parameter {name!r} enters no entry of A or B: declare the entries it enters"
                )
        hyps = tuple(self.hypotheses) or tuple(Hypothesis(p, (p,)) for p in names)
        hnames = [h.name for h in hyps]
        if len(set(hnames)) != len(hnames):
            raise ParameterError(f"hypothesis names must be distinct; got {hnames}")
        for h in hyps:
            if h.name in (NO_FAULT, UNEXPLAINED):
                raise ParameterError(f"{h.name!r} is reserved; choose another hypothesis name")
            if not h.parameters or len(set(h.parameters)) != len(h.parameters):
                raise ParameterError(
                    f"hypothesis {h.name!r} must list distinct parameters; got {h.parameters}"
                )
            missing = [q for q in h.parameters if q not in names]
            if missing:
                raise ParameterError(
                    f"hypothesis {h.name!r} names parameter(s) {missing} the model does not have; "
                    f"its parameters: {', '.join(names) or 'none'}"
                )
        object.__setattr__(self, "parameters", params)
        object.__setattr__(self, "entries", tuple(self.entries))
        object.__setattr__(self, "constants", consts)
        object.__setattr__(self, "hypotheses", hyps)

    # -- lookup ----------------------------------------------------------------
    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the physical parameters, in table order."""
        return tuple(p.name for p in self.parameters)

    def parameter(self, name: str) -> PhysicalParameter:
        """The parameter called ``name`` (:class:`ParameterError` listing the names otherwise)."""
        names = ", ".join(self.parameter_names)
        return _named(self.parameters, name, f"the model has no parameter {name!r}; its parameters: {names}")

    def hypothesis(self, name: str) -> Hypothesis:
        """The hypothesis called ``name`` (:class:`ParameterError` listing the names otherwise)."""
        names = ", ".join(h.name for h in self.hypotheses)
        return _named(self.hypotheses, name, f"no hypothesis {name!r}; declared: {names}")

    @property
    def has_tolerances(self) -> bool:
        """Whether any parameter declares an operating tolerance."""
        return any(p.tolerance is not None for p in self.parameters)

    def with_tolerances(self, tolerances: Mapping[str, Tolerance | str]) -> ParameterMap:
        """A copy whose parameters named in ``tolerances`` get that tolerance (the others keep theirs).

        Parameters
        ----------
        tolerances : mapping of str to Tolerance or str
            Parameter name -> a :class:`~chatterspec.plants.parameters.Tolerance` or its command-line
            text (``"15%"``, ``"3e7"``, ``"-10%,+20%"``, ``"1.8e8,2.3e8"``).

        Raises
        ------
        ParameterError
            An unknown parameter (the message lists the model's), an unreadable tolerance, or one
            that excludes the nominal value.
        """
        new = dict(tolerances)
        for name in new:
            self.parameter(name)
        params = []
        for p in self.parameters:
            tol = new.get(p.name, p.tolerance)
            if isinstance(tol, str):
                tol = tolerance_from_text(tol, p.value, f"tolerance of {p.name}")
            params.append(replace(p, tolerance=tol))
        return ParameterMap(tuple(params), self.entries, self.constants, self.hypotheses)

    def with_hypotheses(self, hypotheses: Sequence[Hypothesis | str | Sequence[str]]) -> ParameterMap:
        """A copy with other hypotheses: ``Hypothesis`` objects, parameter names, or lists of names.

        A string is a one-parameter hypothesis named after the parameter; a list of names is a
        combination named ``"a+b"``. Unknown parameter names raise :class:`ParameterError`.
        """
        hyps = []
        for h in hypotheses:
            if isinstance(h, Hypothesis):
                hyps.append(h)
            elif isinstance(h, str):
                hyps.append(Hypothesis(h, (h,)))
            else:
                names = tuple(str(x) for x in h)
                hyps.append(Hypothesis("+".join(names), names))
        return ParameterMap(self.parameters, self.entries, self.constants, tuple(hyps))

    def combinations(self) -> tuple[Hypothesis, ...]:
        """The declared hypotheses, then every other combination of the parameters (joint faults).

        A combination is named ``"a+b"`` (table order) unless a declared hypothesis has the same
        parameters (its name is kept). With more than :data:`MAX_ALL_COMBINATIONS` parameters only the
        single parameters, the pairs and the set of all are added (``2^P - 1`` would grow too fast).
        Sorted by size, then in table order, after the declared ones.
        """
        names = self.parameter_names
        declared = {frozenset(h.parameters) for h in self.hypotheses}
        if len(names) <= MAX_ALL_COMBINATIONS:
            sizes: Sequence[int] = range(1, len(names) + 1)
        else:
            sizes = sorted({1, 2, len(names)})
        extra = [
            Hypothesis("+".join(c), c)
            for k in sizes
            for c in itertools.combinations(names, k)
            if frozenset(c) not in declared
        ]
        return (*self.hypotheses, *extra)

    # -- evaluation --------------------------------------------------------------
    def values(self, dt: float, overrides: Mapping[str, object] | None = None) -> dict[str, object]:
        """Every name of the formulas: constants, ``dt``, nominal parameters updated by ``overrides``."""
        out: dict[str, object] = {**self.constants, "dt": float(dt)}
        out.update({p.name: p.value for p in self.parameters})
        for k, v in (overrides or {}).items():
            self.parameter(k)
            out[k] = v
        return out

    def evaluate(self, dt: float, overrides: Mapping[str, object] | None = None) -> np.ndarray:
        """``(..., n_entries)``: every declared entry at the nominal values updated by ``overrides``.

        Parameters
        ----------
        dt : float
            Sampling time of the model (s).
        overrides : mapping, optional
            Parameter name -> value or array of values (arrays broadcast against each other).
        """
        vals = self.values(dt, overrides)
        cols = [np.asarray(e.formula(vals), dtype=float) for e in self.entries]
        shape = np.broadcast_shapes(*(c.shape for c in cols)) if cols else ()
        return np.stack([np.broadcast_to(c, shape) for c in cols], axis=-1) if cols else np.empty((0,))

    def entry_values(self, indices: Sequence[int], values: Mapping[str, object]) -> list[np.ndarray]:
        """The formulas of the entries ``indices`` (into :attr:`entries`) evaluated with ``values`` (every
        name they read, e.g. :meth:`values` with arrays for some parameters), in one scope: the numbers
        of :meth:`evaluate`'s columns, with less overhead per call."""
        return evaluate_formulas([self.entries[k].formula for k in indices], values)

    def depends(self, parameters: Sequence[str]) -> np.ndarray:
        """``(n_entries,)`` bool: the entries whose formula reads any of ``parameters``."""
        ps = set(parameters)
        return np.array([bool(e.formula.names & ps) for e in self.entries], dtype=bool)

    def check(self, model: LinearModel, *, rtol: float = 1e-9) -> None:
        """Raise :class:`ParameterError` unless the formulas give ``model``'s A and B at the nominal values.

        Also checks that every entry lies inside A (n x n) or B (n x p).
        """
        n, p = model.n_states, model.n_inputs
        for e in self.entries:
            rows, cols = (n, n) if e.matrix == "A" else (n, p)
            if not (0 <= e.row < rows and 0 <= e.col < cols):
                raise ParameterError(f"entry {e.label} lies outside {e.matrix} ({rows} x {cols})")
        vals = self.evaluate(model.dt)
        for e, v in zip(self.entries, np.atleast_1d(vals), strict=True):
            M = model.A if e.matrix == "A" else model.B
            have = float(M[e.row, e.col])
            scale = max(abs(have), float(np.max(np.abs(M[e.row]))) * 1e-12, 1e-300)
            if not np.isfinite(v) or abs(float(v) - have) > rtol * scale:
                raise ParameterError(
                    f"entry {e.label} = {e.formula.text!r} gives {float(v):.12g} at the nominal parameter "
                    f"values, but the model's {e.label} is {have:.12g}: the declaration does not describe "
                    "this model (wrong nominal value, constant or formula)"
                )

    def model_with(
        self, model: LinearModel, overrides: Mapping[str, float], name: str | None = None
    ) -> LinearModel:
        """``model`` with its declared entries of A and B evaluated at the parameters ``overrides``.

        The way a model file's ``[parameters]`` and ``[entries]`` build A and B, at other parameter
        values (e.g. a true plant whose bulk modulus is 10 % low); every other entry, C, Q, R and
        ``dt`` are ``model``'s. The result carries this map with the new values as its nominal ones.

        Parameters
        ----------
        model : LinearModel
            The model the map describes (:meth:`check` holds for it).
        overrides : mapping of str to float
            Parameter name -> value, in the parameter's unit.
        name : str, optional
            The new model's name (default: ``model.name`` with the changed values).

        Raises
        ------
        ParameterError
            An unknown parameter name, a value that is not finite, or one that makes an entry
            non-finite.
        """
        import dataclasses

        vals = {k: float(v) for k, v in overrides.items()}
        for k, v in vals.items():
            self.parameter(k)
            if not np.isfinite(v):
                raise ParameterError(f"parameter {k!r} must be finite; got {v!r}")
        entries = np.atleast_1d(self.evaluate(model.dt, vals))
        A, B = np.array(model.A), np.array(model.B)
        for e, v in zip(self.entries, entries, strict=True):
            if not np.isfinite(v):
                raise ParameterError(f"entry {e.label} = {e.formula.text!r} is not finite at {vals}")
            (A if e.matrix == "A" else B)[e.row, e.col] = float(v)
        params = tuple(dataclasses.replace(p, value=vals.get(p.name, p.value)) for p in self.parameters)
        pmap = ParameterMap(params, self.entries, self.constants, self.hypotheses)
        label = ", ".join(f"{k} = {v:.4g}" for k, v in vals.items())
        return dataclasses.replace(
            model,
            A=A,
            B=B,
            parameter_map=pmap,
            oscillatory_block=None,
            name=name or (f"{model.name} ({label})" if label else model.name),
        )

    def to_toml(self) -> str:
        """The ``[parameters]``, ``[constants]``, ``[entries]`` and ``[hypotheses]`` tables as TOML text."""
        import json

        def num(v: float) -> str:
            return repr(float(v))

        lines = ["[parameters]"]
        for p in self.parameters:
            fields = [f"value = {num(p.value)}", f"unit = {json.dumps(p.unit)}"]
            if p.description:
                fields.append(f"description = {json.dumps(p.description)}")
            if p.tolerance is not None:
                fields.append(f"tolerance = {p.tolerance.text()}")
            lines.append(f"{p.name} = {{ {', '.join(fields)} }}")
        if self.constants:
            lines += ["", "[constants]"] + [f"{k} = {num(v)}" for k, v in self.constants.items()]
        lines += ["", "[entries]"] + [f'"{e.label}" = {json.dumps(e.formula.text)}' for e in self.entries]
        lines += ["", "[hypotheses]"]
        lines += [f"{json.dumps(h.name)} = {json.dumps(list(h.parameters))}" for h in self.hypotheses]
        return "\n".join(lines)


def parse_entry_key(key: str, where: str) -> tuple[Literal["A", "B"], int, int]:
    """``"A[3,3]"`` -> ``("A", 2, 2)`` (1-based in the text, 0-based out)."""
    m = _ENTRY.match(str(key))
    if not m or int(m.group(2)) < 1 or int(m.group(3)) < 1:
        raise ParameterError(f'{where}: entry key {key!r} must look like "A[3,3]" or "B[3,1]" (1-based)')
    return cast(Literal["A", "B"], m.group(1)), int(m.group(2)) - 1, int(m.group(3)) - 1  # (the regex)


def parameter_map_from_tables(
    doc: Mapping[str, Any], where: str, *, continuous: bool = False
) -> ParameterMap | None:
    """Build a :class:`ParameterMap` from a model file's ``[parameters]``, ``[constants]``,
    ``[entries]`` and ``[hypotheses]`` tables (None when the file has no ``[parameters]``).

    With ``continuous=True`` the entry formulas describe the continuous matrices and are
    turned into explicit-Euler discrete entries (``A = I + dt Ac``, ``B = dt Bc``).

    Raises
    ------
    ParameterError
        With ``where`` and the table named, on any malformed declaration.
    """
    raw = doc.get("parameters")
    if raw is None:
        for key in ("entries", "hypotheses"):
            if key in doc:
                raise ParameterError(f"{where}: [{key}] needs a [parameters] table")
        return None
    tables = {}
    for key in ("parameters", "constants", "entries", "hypotheses"):
        value = doc.get(key, {})
        if not isinstance(value, dict):
            raise ParameterError(f"{where}: [{key}] must be a table")
        tables[key] = value
    params = []
    for name, spec in tables["parameters"].items():
        if isinstance(spec, dict):
            unknown = set(spec) - {"value", "unit", "description", "tolerance"}
            if unknown:
                raise ParameterError(
                    f"{where}: [parameters] {name}: unknown key(s) {sorted(unknown)} (keys: value, unit, "
                    "description, tolerance)"
                )
            value, unit, desc = spec.get("value"), spec.get("unit", ""), spec.get("description", "")
        else:
            value, unit, desc = spec, "", ""
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ParameterError(
                f"{where}: [parameters] {name} needs a numeric value, e.g. "
                f'{name} = {{ value = 1.0, unit = "..." }}; got {value!r}'
            )
        tol = None
        if isinstance(spec, dict) and "tolerance" in spec:
            tol = parse_tolerance(spec["tolerance"], float(value), f"{where}: [parameters] {name}")
        params.append(PhysicalParameter(str(name), float(value), str(unit), str(desc), tol))
    consts = {}
    for name, value in tables["constants"].items():
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ParameterError(f"{where}: [constants] {name} must be a number; got {value!r}")
        consts[str(name)] = float(value)
    if not tables["entries"]:
        raise ParameterError(
            f"{where}: [entries] is missing: declare the entries of A and B the parameters enter"
        )
    entries = []
    for key, text in tables["entries"].items():
        matrix, row, col = parse_entry_key(key, f"{where}: [entries]")
        formula = compile_formula(text if isinstance(text, str) else "", f"{where}: [entries] {key}")
        if continuous:
            delta = "1 + " if matrix == "A" and row == col else ""
            formula = compile_formula(f"{delta}dt*({formula.text})", f"{where}: [entries] {key}")
        entries.append(MatrixEntry(matrix, row, col, formula))
    hyps = []
    for name, plist in tables["hypotheses"].items():
        if isinstance(plist, str):
            plist = [plist]
        if not isinstance(plist, list) or not all(isinstance(x, str) for x in plist):
            raise ParameterError(
                f"{where}: [hypotheses] {name} must be a list of parameter names; got {plist!r}"
            )
        hyps.append(Hypothesis(str(name), tuple(plist)))
    try:
        return ParameterMap(tuple(params), tuple(entries), consts, tuple(hyps))
    except ParameterError as exc:
        raise ParameterError(f"{where}: {exc}") from None


def model_file_parameter_map(
    doc: Mapping[str, Any], where: str, form: str, method: str
) -> ParameterMap | None:
    """:func:`parameter_map_from_tables` for :func:`chatterspec.plants.modelfile.load_model`: errors
    become :class:`~chatterspec.errors.ModelFileError`; continuous entries need explicit Euler."""
    if form == "continuous" and method != "euler" and "parameters" in doc:
        raise ModelFileError(
            f"{where}: [entries] of a continuous model are discretized with explicit Euler; with "
            "discretization = 'zoh' the discrete entries have no closed form: write [matrices] in "
            "discrete form"
        )
    try:
        return parameter_map_from_tables(doc, where, continuous=form == "continuous")
    except ChatterspecError as exc:
        raise ModelFileError(str(exc)) from None


# --------------------------------------------------------------------------- catalogue models
def _entries(spec: Mapping[str, str], where: str) -> tuple[MatrixEntry, ...]:
    out = []
    for key, text in spec.items():
        matrix, row, col = parse_entry_key(key, where)
        out.append(MatrixEntry(matrix, row, col, compile_formula(text, f"{where} {key}")))
    return tuple(out)


def eha_parameter_map(
    *,
    leakage: float,
    friction: float,
    bulk_modulus: float,
    piston_area: float,
    pump_displacement: float,
    mass: float,
    volume: float,
) -> ParameterMap:
    """Leakage, friction and bulk modulus of the linear EHA (eq 65/67, explicit Euler).

    ``A[2,2] = 1 - dt a/M``, ``A[2,3] = dt Ac/M``, ``A[3,2] = -dt be Ac/V0``,
    ``A[3,3] = 1 - dt be L/V0``, ``B[3,1] = dt be Dp/V0``: leakage L enters A33, friction a
    enters A22, the bulk modulus be enters A32, A33 and B3 jointly (eq 68-70). Hypotheses:
    one per parameter.

    Parameters
    ----------
    leakage, friction, bulk_modulus : float
        Nominal values of the identifiable parameters: L in m^3/(s Pa), a in N s/m, be in Pa.
    piston_area, pump_displacement, mass, volume : float
        The other Table 1 values, constants of the formulas: Ac in m^2, Dp in m^3/rad, M in kg,
        V0 in m^3.
    """
    params = (
        PhysicalParameter("leakage", leakage, "m^3/(s Pa)", "internal leakage coefficient L"),
        PhysicalParameter("friction", friction, "N s/m", "viscous friction coefficient a"),
        PhysicalParameter("bulk_modulus", bulk_modulus, "Pa", "effective bulk modulus be"),
    )
    constants = {
        "piston_area": piston_area,
        "pump_displacement": pump_displacement,
        "mass": mass,
        "volume": volume,
    }
    entries = _entries(
        {
            "A[2,2]": "1 - dt*friction/mass",
            "A[2,3]": "dt*piston_area/mass",
            "A[3,2]": "-dt*bulk_modulus*piston_area/volume",
            "A[3,3]": "1 - dt*bulk_modulus*leakage/volume",
            "B[3,1]": "dt*bulk_modulus*pump_displacement/volume",
        },
        "EHA parameter map",
    )
    return ParameterMap(params, entries, constants)


def second_order_parameter_map(f0_hz: float, zeta: float) -> ParameterMap:
    """Natural frequency (Hz) and damping ratio of the second-order system of eq (30), explicit Euler.

    ``A[2,1] = -dt (2 pi f0)^2``, ``A[2,2] = 1 - 2 dt zeta (2 pi f0)`` (B does not depend on
    them). Hypotheses: ``natural_frequency`` (f0 alone; with a nominal zeta > 0 it moves A21 and
    A22), ``damping`` (zeta alone).

    Parameters
    ----------
    f0_hz : float
        Nominal natural frequency in Hz.
    zeta : float
        Nominal damping ratio.
    """
    params = (
        PhysicalParameter("natural_frequency", f0_hz, "Hz", "undamped natural frequency f0"),
        PhysicalParameter("damping", zeta, "", "damping ratio zeta"),
    )
    entries = _entries(
        {
            "A[2,1]": "-dt*(2*pi*natural_frequency)**2",
            "A[2,2]": "1 - 2*dt*damping*(2*pi*natural_frequency)",
        },
        "second-order parameter map",
    )
    return ParameterMap(params, entries)
