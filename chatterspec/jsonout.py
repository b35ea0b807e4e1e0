"""JSON documents rounded to meaningful digits: the one writer behind every ``--json`` and ``jsonl`` line.

A float computed in binary carries rounding noise in its last digits (``0.1 + 0.1 + 0.1 - 0.1`` is
``0.20000000000000018``); a report that prints it suggests a precision nobody has. :func:`rounded`
rounds every float of a document to :data:`DIGITS` significant digits and :func:`dumps` writes the
result. Integers (Python or numpy) stay exact integers, booleans stay booleans, strings and None
are kept; numpy scalars and arrays become Python numbers and lists. Twelve significant digits
remove the noise of a few operations (relative size ~1e-16 each) and keep far more than any
threshold, frequency (Hz) or time (s) printed by the toolkit needs: a threshold read back from the
JSON equals the computed one to a relative 5e-13.

The two small helpers below build the JSON-ready dicts of results before they are written:
:func:`fields_dict` is the ``to_dict`` of a result that prints its fields as they are (keys = the
attribute names, in the order given), and :func:`finite_or_none` writes a float that may be NaN or
infinite (a delay never reached, an empty fraction) as ``null``.

This module imports only the standard library (``import chatterspec`` stays light); numpy
objects are recognised by duck typing.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterable
from typing import Any

__all__ = ["DIGITS", "dumps", "fields_dict", "finite_or_none", "rounded"]

#: Significant digits kept for every float.
DIGITS = 12


def _round_float(value: float, digits: int) -> float | None:
    if not math.isfinite(value):
        return value  # json.dumps(allow_nan=False) refuses it: the caller decides
    if value == 0.0:
        return 0.0
    return float(f"{value:.{digits}g}")


def rounded(doc: Any, digits: int = DIGITS) -> Any:
    """A copy of ``doc`` with every float rounded to ``digits`` significant digits.

    Parameters
    ----------
    doc : object
        A JSON-like document: dicts, lists, tuples, str, int, float, bool, None, numpy scalars
        and arrays (converted with ``tolist``/``item``).
    digits : int
        Significant digits kept (default :data:`DIGITS`, 12).

    Returns
    -------
    object
        The same structure with Python types only (tuples become lists); ints and bools exact.

    Raises
    ------
    TypeError
        For an object JSON cannot represent (the message names its type).

    Examples
    --------
    >>> rounded({"alpha": 0.1 + 0.1 + 0.1 - 0.1, "runs": 64, "ok": True})
    {'alpha': 0.2, 'runs': 64, 'ok': True}
    """
    if isinstance(doc, bool) or doc is None or isinstance(doc, str):
        return doc
    if isinstance(doc, int):
        return int(doc)
    if isinstance(doc, float):
        return _round_float(doc, digits)
    if isinstance(doc, dict):
        return {str(k) if not isinstance(k, str) else k: rounded(v, digits) for k, v in doc.items()}
    if isinstance(doc, list | tuple):
        return [rounded(v, digits) for v in doc]
    if hasattr(doc, "tolist") and callable(doc.tolist):  # numpy array or scalar
        return rounded(doc.tolist(), digits)
    if hasattr(doc, "item") and callable(doc.item):
        return rounded(doc.item(), digits)
    raise TypeError(f"not JSON serializable: {type(doc).__name__}")


def dumps(doc: Any, *, indent: int | None = None, digits: int = DIGITS, allow_nan: bool = False) -> str:
    """``json.dumps`` of :func:`rounded` ``(doc)``; NaN and infinity are refused unless ``allow_nan``.

    Parameters
    ----------
    doc : object
        The document (see :func:`rounded`).
    indent : int, optional
        Indentation of the JSON text (None: one line, as for ``jsonl`` events).
    digits : int
        Significant digits kept for floats (default :data:`DIGITS`).
    allow_nan : bool
        Write NaN/Infinity tokens (not strict JSON; kept for the study commands that printed them
        before). Default False.

    Returns
    -------
    str
        The JSON text.

    Raises
    ------
    ValueError
        If the document holds NaN or infinity and ``allow_nan`` is False.
    """
    return json.dumps(rounded(doc, digits), indent=indent, allow_nan=allow_nan)


def fields_dict(obj: Any, names: Iterable[str] | None = None) -> dict[str, Any]:
    """``{name: getattr(obj, name)}`` for each name, in order: the ``to_dict`` of a result printed as it is.

    Values are not converted (a tuple stays a tuple, a numpy scalar a numpy scalar): use it where a
    ``to_dict`` would list ``"name": self.name`` lines only, and write the dict out where a value is
    transformed or a key renamed.

    Parameters
    ----------
    obj : object
        A dataclass instance (or any object with the attributes ``names``).
    names : iterable of str, optional
        Attribute names (fields or properties) in the order of the keys; default: every dataclass
        field of ``obj`` in declaration order.

    Returns
    -------
    dict
        A new dict (the caller may add keys to it).

    Raises
    ------
    TypeError
        When ``names`` is omitted and ``obj`` is not a dataclass instance.

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> @dataclass
    ... class Point:
    ...     x: float
    ...     y: float
    ...
    ...     @property
    ...     def norm(self) -> float:
    ...         return (self.x**2 + self.y**2) ** 0.5
    >>> fields_dict(Point(3.0, 4.0))
    {'x': 3.0, 'y': 4.0}
    >>> fields_dict(Point(3.0, 4.0), ("norm", "x"))
    {'norm': 5.0, 'x': 3.0}
    """
    if names is None:
        names = (f.name for f in dataclasses.fields(obj))
    return {name: getattr(obj, name) for name in names}


def finite_or_none(value: float) -> float | None:
    """``float(value)``, or None when it is NaN or infinite (JSON has no token for them).

    Parameters
    ----------
    value : float
        A Python or numpy real scalar.

    Returns
    -------
    float or None

    Examples
    --------
    >>> finite_or_none(0.25), finite_or_none(float("nan")), finite_or_none(float("inf"))
    (0.25, None, None)
    """
    x = float(value)
    return x if math.isfinite(x) else None
