"""The explicit Euler discretization of a continuous nonlinear model ``x' = g(x, u)``.

The estimator papers print their nonlinear plants in discrete time as the explicit Euler step of the
continuous equations (e.g. eq 4.1-4.3 of the SMM paper): ``f = x + dt g`` and ``F = I + dt dg/dx``.
:meth:`~chatterspec.plants.nonlinear.NonlinearModel.from_continuous` builds a model from these two
callables. Each exposes the wrapped function as ``func`` (as :func:`functools.partial` does), so the
model's fingerprint names ``g`` itself.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Self, Unpack

import numpy as np

from .._validate import positive
from ..errors import ShapeError

if TYPE_CHECKING:  # pragma: no cover
    from .nonlinear import NonlinearModelOptions

__all__ = ["ContinuousEuler", "EulerJacobian", "EulerStep", "Transition"]

Transition = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _name(fn: object, default: str) -> str:
    """How messages name ``fn``: a model file's ``[dynamics] KEY = 'file.py:function'``, else ``default``."""
    ref = getattr(fn, "ref", "")
    return f"[dynamics] {getattr(fn, 'key', 'f')} = {ref!r}" if ref else default


@dataclass(frozen=True)
class EulerStep:
    """``f(x, u) = x + dt g(x, u)``: the explicit Euler step of ``x' = g(x, u)`` (picklable).

    Attributes
    ----------
    g : callable
        Continuous dynamics ``g(x, u) -> (..., n)`` (units of the state per second).
    dt : float
        Sampling time in seconds.
    """

    g: Transition
    dt: float

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        g = np.asarray(self.g(x, u))
        if g.shape[-1:] != np.shape(x)[-1:]:  # x + dt g would broadcast a wrong shape silently
            raise ShapeError(
                f"{_name(self.g, 'the continuous dynamics g(x, u)')} returned shape {g.shape} for x of shape "
                f"{np.shape(x)}; expected (..., {np.shape(x)[-1]})"
            )
        return x + self.dt * g

    @property
    def func(self) -> Transition:
        """``g`` (named as :func:`functools.partial` names its function: the model's fingerprint reads it)."""
        return self.g


@dataclass(frozen=True)
class EulerJacobian:
    """``F(x, u) = I + dt dg/dx``: the Jacobian of :class:`EulerStep` (picklable).

    Attributes
    ----------
    g_jac : callable
        Jacobian of the continuous dynamics, ``dg/dx -> (..., n, n)`` (1/s).
    dt : float
        Sampling time in seconds.
    """

    g_jac: Transition
    dt: float

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        J = self.dt * np.asarray(self.g_jac(x, u))
        n = np.shape(x)[-1]
        if J.shape[-2:] != (n, n):
            raise ShapeError(
                f"{_name(self.g_jac, 'the Jacobian dg/dx')} returned shape {J.shape} for x of shape "
                f"{np.shape(x)}; expected (..., {n}, {n})"
            )
        return J + np.eye(n)

    @property
    def func(self) -> Transition:
        """``g_jac`` (as :attr:`EulerStep.func`)."""
        return self.g_jac


class ContinuousEuler:
    """``from_continuous``, mixed into :class:`~chatterspec.plants.nonlinear.NonlinearModel`."""

    if TYPE_CHECKING:  # the constructor of the model it is mixed into

        def __init__(
            self,
            *,
            f: Transition,
            jac: Transition,
            C: np.ndarray,
            Q: np.ndarray,
            R: np.ndarray,
            dt: float,
            **kwargs: Unpack[NonlinearModelOptions],
        ) -> None: ...

    @classmethod
    def from_continuous(
        cls,
        g: Transition,
        g_jac: Transition,
        C: np.ndarray,
        Q: np.ndarray,
        R: np.ndarray,
        dt: float,
        **kwargs: Unpack[NonlinearModelOptions],
    ) -> Self:
        """Explicit Euler discretization of ``x' = g(x, u)``: ``f = x + dt g``, ``F = I + dt dg/dx``.

        The papers discretize this way (e.g. eq 4.1-4.3 of the SMM paper). ``Q`` and ``R`` are
        the *discrete* covariances. Euler is only stable while ``dt`` is small against the local
        time constants (for the EHA's quadratic friction: ``2 dt a1 |v| / M < 1``).

        Parameters
        ----------
        g : callable
            Continuous dynamics ``g(x, u) -> (..., n)`` (units of the state per second).
        g_jac : callable
            Its Jacobian ``dg/dx`` ``-> (..., n, n)``.
        C, Q, R : arrays
            As in :class:`~chatterspec.plants.nonlinear.NonlinearModel`.
        dt : float
            Sampling time in seconds (> 0).
        **kwargs
            The other ``NonlinearModel`` fields (names, units, ``n_inputs``, ...).
        """
        dt = positive("dt", dt, unit="s")
        return cls(
            f=EulerStep(g, dt),
            jac=EulerJacobian(g_jac, dt),
            C=C,
            Q=Q,
            R=R,
            dt=dt,
            **kwargs,
        )
