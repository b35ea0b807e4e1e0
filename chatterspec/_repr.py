"""Short ``repr`` for results: shapes and key figures, never whole arrays (private).

:func:`short_repr` is assigned as ``__repr__`` in the body of the result dataclasses (a dataclass
keeps a ``__repr__`` its class body defines). Arrays show as ``array(2, 4001, 3)``, floats with six
significant digits, long sequences and mappings by their length, nested results by their class
name (and ``name``/``scenario`` when they have one), long strings cut. A class may add key figures
(properties such as ``detected``) through ``_repr_extra``: a tuple of attribute names shown first.
"""

from __future__ import annotations

import dataclasses
from typing import Any

__all__ = ["short_repr", "value_repr"]

_MAX_ITEMS = 6
_MAX_STR = 60


def value_repr(value: Any, depth: int = 0) -> str:
    """One field's short text (see the module docstring)."""
    shape = getattr(value, "shape", None)
    if shape is not None and hasattr(value, "dtype"):
        if len(shape) == 0:
            return value_repr(value.item(), depth)
        if getattr(value, "size", 0) <= 4 and len(shape) == 1 and value.dtype.kind in "biuf":
            return "array([" + ", ".join(value_repr(v.item(), depth) for v in value) + "])"
        return f"array({', '.join(str(s) for s in shape)})"
    if isinstance(value, bool) or value is None:
        return repr(value)
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, int):
        return repr(value)
    if isinstance(value, str):
        return repr(value if len(value) <= _MAX_STR else value[: _MAX_STR - 3] + "...")
    if isinstance(value, list | tuple):
        if len(value) > _MAX_ITEMS or depth > 0:
            return f"<{type(value).__name__} of {len(value)}>"
        inner = ", ".join(value_repr(v, depth + 1) for v in value)
        return f"({inner}{',' if len(value) == 1 else ''})" if isinstance(value, tuple) else f"[{inner}]"
    if isinstance(value, dict):
        if len(value) > _MAX_ITEMS or depth > 0:
            return f"<dict of {len(value)}>"
        return "{" + ", ".join(f"{k!r}: {value_repr(v, depth + 1)}" for k, v in value.items()) + "}"
    if dataclasses.is_dataclass(value) or hasattr(value, "__dataclass_fields__"):
        label = getattr(value, "name", None)
        if not isinstance(label, str):
            text = repr(value)
            if len(text) <= _MAX_STR:
                return text
        return (
            f"{type(value).__name__}({label!r})" if isinstance(label, str) else f"{type(value).__name__}(...)"
        )
    text = repr(value)
    return text if len(text) <= _MAX_STR else f"<{type(value).__name__}>"


def short_repr(self: Any) -> str:
    """``ClassName(field=short value, ...)`` of a dataclass: what ``__repr__`` of the results returns.

    Parameters
    ----------
    self : dataclass instance
        The result; its ``_repr_extra`` attribute names (tuple of str), if any, come first.

    Returns
    -------
    str
        One line; no array is printed whole.
    """
    parts = []
    for name in getattr(self, "_repr_extra", ()):
        try:
            parts.append(f"{name}={value_repr(getattr(self, name))}")
        except Exception as exc:  # a key figure that cannot be computed must not break repr()
            parts.append(f"{name}=<{type(exc).__name__}>")
    for f in dataclasses.fields(self):
        if not f.repr:
            continue
        value = getattr(self, f.name)
        if value is None and f.default is None:
            continue  # fields not stored (FilterOutput) or not computed
        parts.append(f"{f.name}={value_repr(value)}")
    return f"{type(self).__name__}({', '.join(parts)})"
