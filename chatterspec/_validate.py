"""Small input-validation helpers shared by the public API (private module)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import cast

import numpy as np
import numpy.typing as npt

from .errors import NonFiniteError, ParameterError, ShapeError


def finite_array(
    name: str,
    value: npt.ArrayLike,
    *,
    ndim: int | Sequence[int] | None = None,
    shape: tuple[int | None, ...] | None = None,
    dtype: type = np.float64,
) -> np.ndarray:
    """Convert ``value`` to a float array and check its dimensions and finiteness.

    ``shape`` entries that are ``None`` match any size.
    """
    try:
        arr: np.ndarray = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name} must be numeric array-like; got {type(value).__name__}") from exc
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if arr.ndim not in allowed:
            raise ShapeError(
                f"{name} must have {' or '.join(map(str, allowed))} dimension(s); got shape {arr.shape}"
            )
    if shape is not None:
        if arr.ndim != len(shape) or any(
            s is not None and s != a for s, a in zip(shape, arr.shape, strict=True)
        ):
            want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
            raise ShapeError(f"{name} must have shape {want}; got {arr.shape}")
    if not np.isfinite(arr).all():  # the method: no fromnumeric dispatch (hot in per-push checks)
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise NonFiniteError(f"{name} contains {bad} NaN/inf value(s); all entries must be finite")
    return arr


def readonly(a: np.ndarray) -> np.ndarray:
    """Mark ``a`` (as returned by ``np.asarray``, no copy) read-only and return it.

    Pass a fresh array (``np.array(x)``) when the caller's array must stay writable.
    """
    a = np.asarray(a)
    a.setflags(write=False)
    return a


def positive(name: str, value: float, *, unit: str = "") -> float:
    """Return ``float(value)`` after checking it is finite and > 0."""
    v = finite_scalar(name, value)
    if not v > 0:
        raise ParameterError(f"{name} must be > 0{(' ' + unit) if unit else ''}; got {v!r}")
    return v


def nonnegative(name: str, value: float) -> float:
    """``value`` as a finite float >= 0; a ParameterError naming ``name`` otherwise."""
    v = finite_scalar(name, value)
    if v < 0:
        raise ParameterError(f"{name} must be >= 0; got {v!r}")
    return v


def open_unit(name: str, value: float) -> float:
    """Check ``0 < value < 1`` (used for gamma and alpha)."""
    v = finite_scalar(name, value)
    if not 0.0 < v < 1.0:
        raise ParameterError(f"{name} must lie in the open interval (0, 1); got {v!r}")
    return v


def positive_int(name: str, value: int) -> int:
    """``value`` as an int >= 1 (bools refused); a ParameterError naming ``name`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ParameterError(f"{name} must be an integer >= 1; got {value!r}")
    if value < 1:
        raise ParameterError(f"{name} must be an integer >= 1; got {value!r}")
    return int(value)


def finite_scalar(name: str, value: float) -> float:
    """``value`` as a finite float; a ParameterError naming ``name`` otherwise."""
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be a real number; got {value!r}") from exc
    if not np.isfinite(v):
        raise ParameterError(f"{name} must be finite; got {v!r}")
    return v


def names_of(
    param: str, names: Iterable[object] | None, n: int, prefix: str, *, first: int = 1, what: str = ""
) -> tuple[str, ...]:
    """``names`` (the argument ``param``) as ``n`` strings naming the ``n`` ``what`` (default: ``param``);
    None: ``prefix`` numbered from ``first``.

    Raises :class:`~chatterspec.errors.ShapeError` when ``names`` holds another number of names.
    """
    if names is None:
        return tuple(f"{prefix}{i + first}" for i in range(n))
    given = tuple(str(s) for s in names)
    if len(given) != n:
        raise ShapeError(f"{param} must name the {n} {what or param}; got {len(given)} names")
    return given


def check_no_unknown_kwargs(func_name: str, kwargs: dict[str, object]) -> None:
    """Raise TypeError naming ``func_name`` if ``kwargs`` holds any keyword (Python's own wording)."""
    if kwargs:
        raise TypeError(f"{func_name}() got unexpected keyword argument(s): {', '.join(kwargs)}")


def check_band(band: object) -> tuple[float, float]:  # a validator: any value
    """Validate a frequency band ``(lo, hi)`` in Hz: finite, ``0 <= lo < hi``.

    Re-exported as :func:`chatterspec.detection.thresholds.check_band` (its public home); it lives
    here so that model files (:mod:`chatterspec.plants.modelfile`) check ``[detector] band`` without
    importing the detection layer.

    Parameters
    ----------
    band : pair of float
        Lower and upper edge (Hz), both included.

    Raises
    ------
    ParameterError
        If it is not two finite numbers with ``0 <= lo < hi``.
    """
    try:
        lo, hi = (float(v) for v in cast("Iterable[float]", band))  # anything else raises TypeError here
    except (TypeError, ValueError):
        raise ParameterError(f"band must be two numbers (lo, hi) in Hz; got {band!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo < 0 or hi <= lo:
        raise ParameterError(f"band must satisfy 0 <= lo < hi (Hz, finite); got ({lo:g}, {hi:g})")
    return lo, hi
