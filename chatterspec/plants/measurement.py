"""The measurement of a :class:`~chatterspec.plants.nonlinear.NonlinearModel`: ``C x`` or a user ``h(x)``.

A model with a nonlinear measurement carries ``h(x) -> (..., m)`` and its Jacobian
``h_jac(x) -> (..., m, n)``; its ``C`` is ``h_jac`` at the rest state (sizes, linearization).
The extended Kalman filter and the simulation call :func:`measure` and :func:`measurement_jacobian`;
the SVSF family needs a linear ``C`` and refuses such a model (:func:`require_linear_measurement`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from .._validate import finite_array
from ..errors import ModelKindError, ParameterError, ShapeError

if TYPE_CHECKING:  # pragma: no cover
    from .nonlinear import Model, NonlinearModel

__all__ = [
    "Measurement",
    "has_measurement_function",
    "measure",
    "measurement_jacobian",
    "measurement_matrix",
    "require_linear_measurement",
]

Measurement = Callable[[np.ndarray], np.ndarray]


def has_measurement_function(model: object) -> bool:  # a predicate: any value
    """True when ``model`` measures through a function ``h(x)`` rather than a matrix ``C``.

    Parameters
    ----------
    model : model object
        Any model (LinearModel, NonlinearModel, a duck-typed model).
    """
    return getattr(model, "h", None) is not None


def require_linear_measurement(model: Model, who: str) -> None:
    """Raise :class:`~chatterspec.errors.ModelKindError` when ``model`` has a nonlinear measurement.

    Parameters
    ----------
    model : model object
        The filter's model.
    who : str
        The filter's name, for the message.
    """
    if has_measurement_function(model):
        raise ModelKindError(
            f"{who} needs a linear measurement z = C x (its switching term maps output errors through C); "
            "this model measures through h(x): use ExtendedKalmanFilter (or an IMM of EKFs)"
        )


def measurement_matrix(model: NonlinearModel) -> np.ndarray:
    """``h_jac`` at the rest state: the ``C`` of a model with a nonlinear measurement ``h``.

    Parameters
    ----------
    model : NonlinearModel
        Being validated (``h``, ``h_jac``, ``Q``, ``R``, ``rest_state``, ``C`` None or equal to the result).

    Returns
    -------
    (m, n) array
    """
    h, h_jac, C = model.h, model.h_jac, model.C
    if not callable(h) or not callable(h_jac):
        raise ModelKindError("h and h_jac must be callables h(x) -> (..., m), h_jac(x) -> (..., m, n)")
    n = finite_array("Q", model.Q, ndim=2).shape[0]
    rest = model.rest_state
    rest = np.zeros(n) if rest is None else np.asarray(rest, dtype=float)
    H = np.asarray(h_jac(rest), dtype=float)
    m = np.shape(model.R)[0] if np.ndim(model.R) == 2 else 1
    if H.shape != (m, n):
        raise ShapeError(
            f"h_jac(x) must return ({m}, {n}) for one state (m = R's size, n = Q's); got {H.shape}"
        )
    if C is not None and not np.array_equal(np.asarray(C, dtype=float), H):
        # (a copy by dataclasses.replace passes the C computed here: that one is accepted)
        raise ParameterError("give either C (linear measurement) or h and h_jac (nonlinear), not both")
    return H


def measure(model: Model, x: np.ndarray) -> np.ndarray:
    """Noise-free measurement ``h(x)`` (or ``x C^T``), batched ``(..., n) -> (..., m)``.

    Parameters
    ----------
    model : model object
        With ``C`` and optionally ``h``.
    x : (..., n) array
        States.

    Returns
    -------
    (..., m) array
    """
    x = np.asarray(x, dtype=float)
    C = np.asarray(model.C)
    h = getattr(model, "h", None)
    if h is None:
        return x @ C.T
    out = np.asarray(h(x), dtype=float)
    want = (*x.shape[:-1], C.shape[0])
    if out.shape != want:
        raise ShapeError(f"h(x) returned shape {out.shape}; expected {want}")
    return out


def measurement_jacobian(model: Model, x: np.ndarray) -> np.ndarray:
    """``H = dh/dx`` at ``x`` (``C`` for a linear measurement), batched ``(..., m, n)``.

    Parameters
    ----------
    model, x
        As in :func:`measure` (``h_jac`` in place of ``h``).

    Returns
    -------
    (..., m, n) array
    """
    x = np.asarray(x, dtype=float)
    C = np.asarray(model.C)
    want = (*x.shape[:-1], *C.shape)
    h_jac: Measurement | None = getattr(model, "h_jac", None)  # (a LinearModel has no h, h_jac)
    if getattr(model, "h", None) is None or h_jac is None:  # (h_jac comes with h: measurement_matrix)
        return np.broadcast_to(C, want)
    out = np.asarray(h_jac(x), dtype=float)
    if out.shape != want:
        raise ShapeError(f"h_jac(x) returned shape {out.shape}; expected {want}")
    return out
