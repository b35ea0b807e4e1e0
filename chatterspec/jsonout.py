"""JSON documents rounded to meaningful digits: the one writer behind every ``--json`` and ``jsonl`` line.

A float computed in binary carries rounding noise in its last digits (``0.1 + 0.1 + 0.1 - 0.1`` is
``0.20000000000000018``); a report that prints it suggests a precision nobody has. :func:`rounded`
rounds every float of a document to :data:`DIGITS` significant digits and :func:`dumps` writes the
result. Integers (Python or numpy) stay exact integers, booleans stay booleans, strings and None
are kept; numpy scalars and arrays become Python numbers and lists. Twelve significant digits
remove the noise of a few operations (relative size ~1e-16 each) and keep far more than any
threshold, frequency (Hz) or time (s) printed by the toolkit needs: a threshold read back from the
JSON equals the computed one to a relative 5e-13.

This module imports only the standard library (``import chatterspec`` stays light); numpy
objects are recognised by duck typing.
"""

from __future__ import annotations

import json
import math
from typing import Any

__all__ = ["DIGITS", "dumps", "rounded"]

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
