"""Nonlinear plant models: :class:`NonlinearModel`, its measurement, its linearization, the explicit
Euler form of continuous equations and the one-sample functions the compiled loops inline.

Nonlinear discrete-time plant models: ``x(k+1) = f(x(k), u(k)) + v(k)``, ``z(k) = C x(k) + w(k)``.

The estimator papers ([SMM] eq 4.1-4.5, [IMM] eq 34-38; tags as in ``docs/design.md``) print their
nonlinear plants directly in discrete time, as the explicit Euler step of the continuous equations.
:class:`NonlinearModel` therefore stores the *discrete* transition ``f`` and its Jacobian ``F = df/dx``;
:meth:`NonlinearModel.from_continuous` builds both from continuous-time ``x' = g(x, u)`` by the same
explicit Euler step (``f = x + dt g``, ``F = I + dt dg/dx``).

The measurement is linear (``C``) in every paper; a user model may give a nonlinear measurement
``h(x)`` with its Jacobian ``h_jac`` instead, which :func:`~chatterspec.simulate` and the
:class:`~chatterspec.filters.kalman.ExtendedKalmanFilter` use (the SVSF family, whose switching
term needs a linear ``C``, refuses such a model: :func:`require_linear_measurement`). The filters
only need ``model.transition(x, u)``, ``model.jacobian(x, u)``, ``model.C``, ``model.Q``, ``model.R``,
``model.dt`` and the sizes, which :class:`~chatterspec.plants.models.LinearModel` offers under the
same names. :meth:`NonlinearModel.linearize` returns the small-signal ``LinearModel`` about an
operating point. Callables must be picklable for local workers and Dask (module-level functions or
:func:`functools.partial` of them, as :mod:`chatterspec.plants.eha4` does).
:meth:`NonlinearModel.from_steps` takes the functions written for one sample instead, which the
filters then run compiled (:class:`SampleFunction`, below).

The measurement of a :class:`~chatterspec.plants.nonlinear.NonlinearModel`: ``C x`` or a user ``h(x)``.

A model with a nonlinear measurement carries ``h(x) -> (..., m)`` and its Jacobian
``h_jac(x) -> (..., m, n)``; its ``C`` is ``h_jac`` at the rest state (sizes, linearization).
The extended Kalman filter and the simulation call :func:`measure` and :func:`measurement_jacobian`;
the SVSF family needs a linear ``C`` and refuses such a model (:func:`require_linear_measurement`).

The small-signal linearization of a :class:`~chatterspec.plants.nonlinear.NonlinearModel`.

:class:`Linearization` is the part of the nonlinear model that linearizes it about an operating
point: the input matrix ``G = df/du`` (given or by central differences), the
:class:`~chatterspec.plants.models.LinearModel` ``dx(k+1) = F dx(k) + G du(k)``, and the
natural frequency / damping of the oscillatory block ``(F - I) / dt`` (the continuous-equivalent
block, the inverse of explicit Euler), all evaluated at ``(x0, u0)`` (default: the rest state,
zero input).

The explicit Euler discretization of a continuous nonlinear model ``x' = g(x, u)``.

The estimator papers print their nonlinear plants in discrete time as the explicit Euler step of the
continuous equations (e.g. eq 4.1-4.3 of the SMM paper): ``f = x + dt g`` and ``F = I + dt dg/dx``.
:meth:`~chatterspec.plants.nonlinear.NonlinearModel.from_continuous` builds a model from these two
callables. Each exposes the wrapped function as ``func`` (as :func:`functools.partial` does), so the
model's fingerprint names ``g`` itself.

Model functions written for one sample, which the filters' compiled loops inline.

:meth:`NonlinearModel.from_steps <chatterspec.plants.nonlinear.NonlinearModel.from_steps>` builds a
model from four plain functions of **one** sample that write into an output array::

    def f(x, u, out):        # out (n,)    = f(x, u)       x (n,), u (p,)
    def f_jac(x, u, out):    # out (n, n)  = df/dx
    def h(x, out):           # out (m,)    = h(x)          (optional: a nonlinear measurement)
    def h_jac(x, out):       # out (m, n)  = dh/dx

written as the package's own steps are: element indexing (``x[0]``, ``out[1, 0] = ...``), arithmetic and
numpy ufuncs (``np.sin``, ``np.sqrt``); no ``math`` functions and no ``if`` on values, so that the
same code runs compiled on one sample and, on rows of realizations, in the numpy paths. The model
keeps each as a :class:`SampleFunction`: called batched (``f(x (..., n), u)``, what the simulation,
the numpy paths and the checks call), it runs the function on the ``(channels, ...)`` rows of its
arguments; inside a compiled loop (the covariance filters' batch loop, :meth:`online` filters, the
banks) the function is a step (:func:`chatterspec._jit.step`) inlined at each use, so an EKF on such
a model, ``h`` included, runs entirely compiled (:func:`chatterspec.plants.steps.plant_steps`,
:func:`chatterspec.plants.steps.measurement_steps`). The compiled and row forms evaluate the same
operations; numpy's and LLVM's ``sin``/``exp`` may differ in the last bit, so the two paths agree to
rounding. Functions must be module-level (picklable for workers).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import cache
from typing import TYPE_CHECKING, Any, Literal, Self, TypeAlias, TypedDict, TypeGuard, Unpack

import numpy as np

from .. import _jit
from .._repr import short_repr
from .._validate import finite_array, positive, positive_int, readonly
from ..errors import ModelKindError, NonFiniteError, ParameterError, ShapeError, SingularMatrixError
from .models import (
    LinearModel,
    ModelBase,
    OscillatoryMode,
    check_measurement_matrix,
    check_noise,
    frozen,
    hash_arrays,
    oscillatory_mode,
    set_channel_labels,
)

__all__ = [
    "ContinuousEuler",
    "EulerJacobian",
    "EulerStep",
    "FromSteps",
    "Linearization",
    "Measurement",
    "MeasurementSteps",
    "Model",
    "NonlinearModel",
    "SampleFunction",
    "SampleKind",
    "Transition",
    "has_measurement_function",
    "is_linear",
    "measure",
    "measurement_jacobian",
    "measurement_matrix",
    "measurement_steps",
    "require_linear",
    "require_linear_measurement",
    "same_dynamics",
    "transition_steps",
]


# The explicit Euler discretization of continuous equations.

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


# Model functions written for one sample.

SampleKind = Literal["f", "jac", "h", "h_jac"]
#: The compiled ``(h, h_jac)`` steps of a model measuring through ``h`` (:func:`measurement_steps`).
MeasurementSteps = tuple[Callable[..., None], Callable[..., None]]


@cache
def _step_of(func: Callable[..., None]) -> Callable[..., None]:
    """The compiled step of ``func`` (one per function for the process)."""
    return _jit.step(func)


@dataclass(frozen=True)
class SampleFunction:
    """A model function written for one sample (see the module docstring), callable batched.

    Attributes
    ----------
    func : callable
        ``func(x, u, out)`` (kinds ``"f"``, ``"jac"``) or ``func(x, out)`` (``"h"``, ``"h_jac"``).
    kind : {"f", "jac", "h", "h_jac"}
        Which function of the model it is (fixes the output shape).
    n_states, n_outputs : int
        The model's sizes ``n``, ``m``.
    """

    func: Callable[..., None]
    kind: SampleKind
    n_states: int
    n_outputs: int

    @property
    def shape(self) -> tuple[int, ...]:
        """The output shape of one sample."""
        n, m = self.n_states, self.n_outputs
        return {"f": (n,), "jac": (n, n), "h": (m,), "h_jac": (m, n)}[self.kind]

    @property
    def step(self) -> Callable[..., None]:
        """The function as a compiled step (inlined by the loops that call it)."""
        return _step_of(self.func)

    def __call__(self, x: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Batched: ``x`` (..., n) (and ``u`` (..., p) or (p,)) -> (..., *shape), the function on rows."""
        x = np.asarray(x, dtype=float)
        lead = x.shape[:-1]
        rows = np.moveaxis(x, -1, 0)  # (n, ...): x[i] is state i of every realization
        out = np.empty((*self.shape, *lead))
        if self.kind in ("f", "jac"):
            uu = np.asarray(u, dtype=float)
            ur = np.moveaxis(uu, -1, 0) if uu.ndim > 1 else uu
            self.func(rows, ur, out)
        else:
            self.func(rows, out)
        k = len(self.shape)
        return np.moveaxis(out, tuple(range(k)), tuple(range(out.ndim - k, out.ndim)))


#: Bindings of :func:`_predict` / :func:`_jacobian`: the user's steps.
F_STEP = JAC_STEP = None


def _predict(prm: np.ndarray, x: np.ndarray, u: np.ndarray, xp: np.ndarray, n: int, p: int) -> None:
    """The plant-step interface (:mod:`chatterspec.plants.steps`) around ``F_STEP(x, u, xp)``."""
    F_STEP(x, u, xp)  # type: ignore[misc]


def _jacobian(prm: np.ndarray, x: np.ndarray, u: np.ndarray, F: np.ndarray, n: int, p: int) -> None:
    """The plant-step interface around ``JAC_STEP(x, u, F)``."""
    JAC_STEP(x, u, F)  # type: ignore[misc]


@cache
def _plant_pair(
    f: Callable[..., None], jac: Callable[..., None]
) -> tuple[Callable[..., None], Callable[..., None]]:
    tag = "".join(ch if ch.isalnum() else "_" for ch in getattr(f, "__name__", "f"))
    predict = _jit.specialize(_predict, f"user_{tag}", inline=True, F_STEP=_step_of(f))
    jacobian = _jit.specialize(_jacobian, f"user_{tag}", inline=True, JAC_STEP=_step_of(jac))
    return predict, jacobian


def transition_steps(model: object) -> tuple[str, Callable[..., None], Callable[..., None]] | None:
    """``(name, predict, jacobian)``: plant steps of a model whose ``f``, ``jac`` are sample functions.

    None for any other model. ``name`` names the functions (part of the compiled loops' names).
    """
    f, jac = getattr(model, "f", None), getattr(model, "jac", None)
    if not (isinstance(f, SampleFunction) and isinstance(jac, SampleFunction)):
        return None
    predict, jacobian = _plant_pair(f.func, jac.func)
    name = "".join(ch if ch.isalnum() else "_" for ch in getattr(f.func, "__name__", "f"))
    return f"user_{name}", predict, jacobian


def measurement_steps(model: object) -> MeasurementSteps | None:
    """``(h, h_jac)`` steps (``h(x, out)``, ``h_jac(x, out)``) of a model whose measurement functions are
    :class:`SampleFunction` s, None for any other (a linear ``C``, or Python ``h``)."""
    h, h_jac = getattr(model, "h", None), getattr(model, "h_jac", None)
    if not (isinstance(h, SampleFunction) and isinstance(h_jac, SampleFunction)):
        return None
    return h.step, h_jac.step


class FromSteps:
    """``from_steps``, mixed into :class:`~chatterspec.plants.nonlinear.NonlinearModel`."""

    @classmethod
    def from_steps(
        cls,
        f: Callable[..., None],
        f_jac: Callable[..., None],
        Q: np.ndarray,
        R: np.ndarray,
        dt: float,
        *,
        C: np.ndarray | None = None,
        h: Callable[..., None] | None = None,
        h_jac: Callable[..., None] | None = None,
        **kwargs: Any,
    ) -> Self:
        """A model from one-sample functions that the filters compile (module docstring).

        Parameters
        ----------
        f, f_jac : callable
            ``f(x, u, out)``: ``out (n,) = f(x, u)``; ``f_jac(x, u, out)``: ``out (n, n) = df/dx``.
        Q : (n, n) array
            Process-noise covariance per step.
        R : (m, m) array
            Measurement-noise covariance.
        dt : float
            Sampling time (s), already built into ``f``.
        C : (m, n) array, optional
            Linear measurement (give ``C`` or ``h`` and ``h_jac``).
        h, h_jac : callable, optional
            ``h(x, out)``: ``out (m,) = h(x)``; ``h_jac(x, out)``: ``out (m, n) = dh/dx``.
        **kwargs
            The other ``NonlinearModel`` fields (``n_inputs``, names, units, ``rest_state``, ...).

        Returns
        -------
        NonlinearModel
            Whose ``f``, ``jac``, ``h``, ``h_jac`` are :class:`SampleFunction` s.
        """
        n = int(np.shape(Q)[0])
        m = int(np.shape(R)[0]) if np.ndim(R) == 2 else 1

        def wrap(fn: Callable[..., None] | None, kind: SampleKind) -> SampleFunction | None:
            return None if fn is None else SampleFunction(fn, kind, n, m)

        return cls(  # type: ignore[call-arg]
            wrap(f, "f"),
            wrap(f_jac, "jac"),
            C,
            Q,
            R,
            dt,
            h=wrap(h, "h"),
            h_jac=wrap(h_jac, "h_jac"),
            **kwargs,
        )


# The measurement: C x or a user h(x).

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


# The small-signal linearization.


class Linearization:
    """Linearization of a nonlinear model (mixed into :class:`~chatterspec.plants.nonlinear.NonlinearModel`).

    Uses the model's ``transition``, ``jacobian``, ``measurement_jacobian``, ``input_jacobian``,
    sizes, names, ``rest_state``, ``oscillatory_states`` and ``dt``.
    """

    if TYPE_CHECKING:  # what it reads from the model (fields, properties and methods of NonlinearModel)
        dt: float
        n_inputs: int
        rest_state: np.ndarray
        oscillatory_states: tuple[int, int] | None
        input_jacobian: Callable[[np.ndarray, np.ndarray], np.ndarray] | None
        name: str
        Q: np.ndarray
        R: np.ndarray
        state_names: tuple[str, ...]
        output_names: tuple[str, ...]
        input_names: tuple[str, ...]
        output_units: tuple[str, ...]

        @property
        def n_states(self) -> int: ...

        def transition(self, x: np.ndarray, u: np.ndarray) -> np.ndarray: ...

        def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray: ...

        def measurement_jacobian(self, x: np.ndarray) -> np.ndarray: ...

    def _operating_point(self, x0: np.ndarray | None, u0: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """``(x0, u0)`` checked, or the rest state and zero input."""
        x0 = self.rest_state if x0 is None else finite_array("x0", x0, shape=(self.n_states,))
        u0 = np.zeros(self.n_inputs) if u0 is None else finite_array("u0", u0, shape=(self.n_inputs,))
        return x0, u0

    def input_matrix(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``df/du`` at one point ``(x, u)``: the supplied ``input_jacobian`` or central differences.

        Parameters
        ----------
        x : (n,) array
            State.
        u : (p,) array
            Input.

        Returns
        -------
        (n, p) ndarray
            Central differences use the step ``h = 1e-6 max(1, |u_j|)`` per input (error
            O(h^2) times the third derivative; exact for inputs that enter affinely, as in the EHA).
        """
        x = finite_array("x", x, shape=(self.n_states,))
        u = finite_array("u", u, shape=(self.n_inputs,))
        if self.input_jacobian is not None:
            B = np.asarray(self.input_jacobian(x, u), dtype=float)
            if B.shape != (self.n_states, self.n_inputs):
                raise ShapeError(
                    f"input_jacobian returned shape {B.shape}; expected ({self.n_states}, {self.n_inputs})"
                )
            return B
        B = np.empty((self.n_states, self.n_inputs))
        for j in range(self.n_inputs):
            h = 1e-6 * max(1.0, abs(u[j]))
            up, um = u.copy(), u.copy()
            up[j] += h
            um[j] -= h
            B[:, j] = (self.transition(x, up) - self.transition(x, um)) / (2 * h)
        return B

    def linearize(self, x0: np.ndarray | None = None, u0: np.ndarray | None = None) -> LinearModel:
        """Small-signal linear model about ``(x0, u0)``: ``dx(k+1) = F dx(k) + G du(k)``.

        ``F = jac(x0, u0)`` and ``G = df/du`` (see :meth:`input_matrix`); ``C``, ``Q``, ``R``, ``dt``
        and the names are kept. The returned model acts on *deviations* from the operating point:
        the offset ``f(x0, u0) - x0`` is not represented (it is zero at an equilibrium such as the
        EHA at rest). Its ``oscillatory_block`` is the continuous-equivalent block of
        ``oscillatory_states``, ``(F - I) / dt`` (the inverse of explicit Euler).

        Parameters
        ----------
        x0 : (n,) array, optional
            Operating state (default :attr:`rest_state`).
        u0 : (p,) array, optional
            Operating input (default zeros).

        Returns
        -------
        LinearModel
        """
        x0, u0 = self._operating_point(x0, u0)
        F = self.jacobian(x0, u0)
        if not np.all(np.isfinite(F)):
            raise NonFiniteError(f"{self.name}: the Jacobian at the operating point is not finite")
        G = self.input_matrix(x0, u0)
        return LinearModel(
            A=F,
            B=G,
            C=self.measurement_jacobian(x0),
            Q=self.Q,
            R=self.R,
            dt=self.dt,
            state_names=self.state_names,
            output_names=self.output_names,
            input_names=self.input_names,
            output_units=self.output_units,
            oscillatory_block=self._block(F),
            name=f"{self.name} linearized",
        )

    def _block(self, F: np.ndarray) -> np.ndarray | None:
        if self.oscillatory_states is None:
            return None
        idx = list(self.oscillatory_states)
        return (F[np.ix_(idx, idx)] - np.eye(2)) / self.dt

    def mode_at(self, x0: np.ndarray | None = None, u0: np.ndarray | None = None) -> OscillatoryMode | None:
        """Natural frequency (Hz) and damping of the linearization at ``(x0, u0)``.

        Parameters
        ----------
        x0, u0 : arrays, optional
            The operating point, as in :meth:`linearize`.

        Returns
        -------
        OscillatoryMode or None
            None without ``oscillatory_states`` or when the block has no oscillatory mode
            (non-positive determinant).
        """
        x0, u0 = self._operating_point(x0, u0)
        block = self._block(self.jacobian(x0, u0))
        if block is None or not np.all(np.isfinite(block)) or np.linalg.det(block) <= 0:
            return None
        return oscillatory_mode(block)

    @property
    def mode(self) -> OscillatoryMode | None:
        """:meth:`mode_at` the rest state with zero input (a linearized value)."""
        return self.mode_at()


# The nonlinear model.


def _callable_id(fn: object) -> str:
    """A stable text id of a (partial of a) module-level function, for fingerprints."""
    parts = []
    while hasattr(fn, "func"):  # functools.partial
        kw = getattr(fn, "keywords", {}) or {}
        args = getattr(fn, "args", ())
        parts.append(json.dumps({"args": [repr(a) for a in args], "kw": {k: repr(v) for k, v in kw.items()}}))
        fn = fn.func
    parts.append(f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', repr(fn))}")
    return "|".join(reversed(parts))


class NonlinearModelOptions(TypedDict, total=False):
    """The optional keyword fields of :class:`NonlinearModel` (what ``from_continuous`` passes on)."""

    n_inputs: int
    input_jacobian: Transition | None
    state_names: tuple[str, ...]
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]
    state_units: tuple[str, ...]
    output_units: tuple[str, ...]
    oscillatory_states: tuple[int, int] | None
    rest_state: np.ndarray
    parameters: Mapping[str, float]
    name: str
    h: Measurement | None
    h_jac: Measurement | None


class NonlinearModelFields(NonlinearModelOptions, total=False):
    """Any fields of :class:`NonlinearModel` (what :meth:`NonlinearModel.replace` takes)."""

    f: Transition
    jac: Transition
    C: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    dt: float


@dataclass(frozen=True, eq=False)
class NonlinearModel(ModelBase, Linearization, ContinuousEuler, FromSteps):
    """A validated nonlinear discrete-time model, with a linear (``C``) or nonlinear (``h``) measurement.

    ``x(k+1) = f(x(k), u(k)) + v(k)`` with ``v ~ N(0, Q)`` and ``z(k) = C x(k) + w(k)`` (or
    ``h(x(k)) + w(k)``) with ``w ~ N(0, R)`` (the nonlinear counterpart of eq 1-2 of the chattering
    paper).

    Parameters
    ----------
    f : callable
        Discrete transition ``f(x, u) -> x_next``, batched: ``x`` (..., n), ``u`` (..., p) or (p,),
        returns (..., n). Must not modify its arguments.
    jac : callable
        Jacobian ``jac(x, u) -> (..., n, n)``, ``F[..., i, j] = d f_i / d x_j``, batched like ``f``.
    C : (m, n) array or None
        Measurement matrix (a 1-D array is one measured channel); full row rank, ``m <= n``.
        None with ``h``: then ``C`` becomes ``h_jac`` at ``rest_state`` (sizes, :meth:`linearize`).
    Q : (n, n) array
        Process-noise covariance per step (symmetric positive semi-definite).
    R : (m, m) array
        Measurement-noise covariance (symmetric positive semi-definite).
    dt : float
        Sampling time in seconds (> 0).
    n_inputs : int
        Number of inputs p (>= 1, default 1).
    input_jacobian : callable, optional
        ``input_jacobian(x, u) -> (..., n, p)``, ``d f / d u``; used by :meth:`linearize`. Without
        it :meth:`linearize` takes central differences in ``u``.
    state_names, output_names, input_names : tuple of str, optional
        Channel names; default ``x1..xn``, ``z1..zm``, ``u1..up``.
    state_units, output_units : tuple of str, optional
        Units of the states and of the measured channels (for reports and the viewer).
    oscillatory_states : tuple of two int, optional
        Indices ``(i, j)`` of the states whose continuous-equivalent Jacobian block
        ``(F - I)[[i, j]][:, [i, j]] / dt`` (1/s) holds the plant's oscillatory mode; used by
        :meth:`mode_at` and the linearized natural frequency / damping reported in listings.
    rest_state : (n,) array, optional
        Operating point (default zeros) at which :attr:`natural_frequency_hz` and
        :attr:`damping_ratio` are evaluated (with zero input).
    parameters : mapping of str to float, optional
        Physical parameters (SI units), part of :meth:`fingerprint` and :meth:`to_dict`.
    name : str
        Short human-readable description.
    h : callable, optional
        Nonlinear measurement ``h(x) -> (..., m)``, batched over leading axes (give ``C=None``).
        Only the EKF and the simulation use it; ``m = R.shape[0]``.
    h_jac : callable, optional
        Its Jacobian ``h_jac(x) -> (..., m, n)``, ``H[..., i, j] = d h_i / d x_j`` (required with ``h``).

    Raises
    ------
    ShapeError, NonFiniteError, ParameterError
        On inconsistent shapes (including ``f`` or ``jac`` returning the wrong shape at the rest
        state), non-finite entries, ``dt <= 0`` or covariances that are not symmetric PSD.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    f: Transition
    jac: Transition
    C: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    dt: float
    n_inputs: int = 1
    input_jacobian: Transition | None = None
    state_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()
    state_units: tuple[str, ...] = ()
    output_units: tuple[str, ...] = ()
    oscillatory_states: tuple[int, int] | None = None
    rest_state: np.ndarray = None  # type: ignore[assignment]  # None: zeros (set by __post_init__)
    parameters: Mapping[str, float] = field(default_factory=dict)
    name: str = "nonlinear model"
    h: Measurement | None = None
    h_jac: Measurement | None = None

    def __post_init__(self) -> None:
        if not callable(self.f) or not callable(self.jac):
            raise ModelKindError("f and jac must be callables f(x, u) -> (..., n), jac(x, u) -> (..., n, n)")
        C = self.C if self.h is None else measurement_matrix(self)
        C = check_measurement_matrix(C, full_rank=self.h is None)  # (h_jac may vanish at the rest state)
        m, n = C.shape
        Q, R = check_noise(self.Q, self.R, n, m)
        object.__setattr__(self, "dt", positive("dt", self.dt, unit="s"))
        p = positive_int("n_inputs", self.n_inputs)
        object.__setattr__(self, "n_inputs", p)
        set_channel_labels(self, n, m, p)
        rest = np.zeros(n) if self.rest_state is None else self.rest_state
        rest = readonly(np.array(finite_array("rest_state", rest, shape=(n,))))
        object.__setattr__(self, "rest_state", rest)
        if self.oscillatory_states is not None:
            idx = tuple(int(i) for i in self.oscillatory_states)
            if len(idx) != 2 or len(set(idx)) != 2 or not all(0 <= i < n for i in idx):
                raise ShapeError(
                    f"oscillatory_states must be two distinct state indices in [0, {n}); got {idx}"
                )
            object.__setattr__(self, "oscillatory_states", idx)
        params = {str(k): float(v) for k, v in dict(self.parameters).items()}
        object.__setattr__(self, "parameters", params)
        for attr, val in (("C", C), ("Q", Q), ("R", R)):
            object.__setattr__(self, attr, frozen(val))
        # probe f and jac at the rest state (batched shape (2, n)) so that a wrong model fails here
        x = np.broadcast_to(rest, (2, n)).copy()
        u = np.zeros((2, p))
        if not (np.all(np.isfinite(self.transition(x, u))) and np.all(np.isfinite(self.jacobian(x, u)))):
            raise NonFiniteError(f"{self.name}: f or its Jacobian is not finite at the rest state")
        if self.h is not None and not np.all(np.isfinite(self.measure(x))):
            raise NonFiniteError(f"{self.name}: h is not finite at the rest state")

    # -- measurement (chatterspec.plants.nonlinear) ---------------------------
    def measure(self, x: np.ndarray) -> np.ndarray:
        """Noise-free measurement of states ``x`` (..., n): ``h(x)`` or ``x C^T``, (..., m)."""
        return measure(self, x)

    def measurement_jacobian(self, x: np.ndarray) -> np.ndarray:
        """``H = dh/dx`` at states ``x`` (..., n) (``C`` for a linear measurement): (..., m, n)."""
        return measurement_jacobian(self, x)

    # -- sizes ---------------------------------------------------------------
    @property
    def n_states(self) -> int:
        """Number of states."""
        return self.C.shape[1]

    @property
    def is_linear(self) -> bool:
        """Always False (``LinearModel`` has no such attribute; see :func:`is_linear`)."""
        return False

    @property
    def full_measurement(self) -> bool:
        """True when C is square and well conditioned (all states measured)."""
        return self.n_outputs == self.n_states and np.linalg.cond(self.C) < 1e12

    @property
    def C_inv(self) -> np.ndarray:
        """Inverse of C (full measurement only), as :attr:`LinearModel.C_inv`.

        Raises
        ------
        SingularMatrixError
            If C is not square or is singular (condition number > 1e12).
        """
        if not self.full_measurement:
            raise SingularMatrixError(
                f"C is {self.n_outputs}x{self.n_states} or singular: C^-1 exists only for full measurement"
            )
        return np.linalg.inv(self.C)

    # -- dynamics ------------------------------------------------------------
    def _inputs(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[int, ...]]:
        """Checked float arrays and the broadcast leading shape (kept cheap: called every step)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        if x.shape[-1:] != (self.n_states,):
            raise ShapeError(f"x must have shape (..., {self.n_states}); got {x.shape}")
        if u.shape[-1:] != (self.n_inputs,):
            raise ShapeError(f"u must have shape (..., {self.n_inputs}) or ({self.n_inputs},); got {u.shape}")
        lead = x.shape[:-1] if u.ndim == 1 else np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        return x, u, lead

    def transition(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``f(x, u)``, batched (see :meth:`ModelBase.transition`).

        Raises
        ------
        ShapeError
            If ``x``/``u`` have the wrong trailing size or ``f`` returns the wrong shape.
        """
        x, u, lead = self._inputs(x, u)
        out = np.asarray(self.f(x, u))
        want = (*lead, self.n_states)
        if out.shape != want:
            raise ShapeError(f"{self.name}: f(x, u) returned shape {out.shape}; expected {want}")
        return out

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``jac(x, u)``, batched (see :meth:`ModelBase.jacobian`).

        Raises
        ------
        ShapeError
            If the supplied ``jac`` returns the wrong shape.
        """
        x, u, lead = self._inputs(x, u)
        out = np.asarray(self.jac(x, u))
        n = self.n_states
        want = (*lead, n, n)
        if out.shape != want:
            raise ShapeError(
                f"{self.name}: the Jacobian jac(x, u) returned shape {out.shape}; expected {want}"
            )
        return out

    def replace(self, **changes: Unpack[NonlinearModelFields]) -> NonlinearModel:
        """Return a copy with fields replaced (validated again).

        The sampling time is part of the discrete transition, so changing ``dt`` without passing a
        new ``f`` and ``jac`` is a :class:`ParameterError` (rebuild the model, e.g. ``eha4(dt=...)``).
        """
        if "dt" in changes and not {"f", "jac"} <= set(changes):
            raise ParameterError(
                f"{self.name}: dt is built into the discrete transition f; pass new f and jac with dt "
                "or rebuild the model from its factory"
            )
        return replace(self, **changes)

    def fingerprint(self) -> str:
        """SHA-256 of the transition's identity, the parameters, C, Q, R and dt."""
        h = hashlib.sha256()
        h.update(_callable_id(self.f).encode())
        h.update(_callable_id(self.jac).encode())
        for fn in (self.h, self.h_jac):
            if fn is not None:
                h.update(_callable_id(fn).encode())
        h.update(json.dumps(self.parameters, sort_keys=True).encode())
        hash_arrays(h, (self.C, self.Q, self.R, np.array([self.dt])))
        return h.hexdigest()

    def to_dict(self) -> dict[str, object]:
        """JSON-ready description (the transition is named, not serialized)."""
        return {
            "name": self.name,
            "kind": "nonlinear",
            "transition": _callable_id(self.f).split("|")[0],
            "parameters": dict(self.parameters),
            "dt": self.dt,
            "C": self.C.tolist(),
            "Q": self.Q.tolist(),
            "R": self.R.tolist(),
            "state_names": list(self.state_names),
            "state_units": list(self.state_units),
            "output_names": list(self.output_names),
            "input_names": list(self.input_names),
            "output_units": list(self.output_units),
        }


#: A plant model: what scenarios, filters and detectors take.
Model: TypeAlias = LinearModel | NonlinearModel


def is_linear(model: object) -> TypeGuard[LinearModel]:
    """True for a :class:`~chatterspec.plants.models.LinearModel` (A, B matrices available).

    Parameters
    ----------
    model : object
        A plant model.
    """
    return isinstance(model, LinearModel)


def require_linear(model: object, what: str) -> LinearModel:
    """Return ``model`` if it is a ``LinearModel``; raise :class:`ModelKindError` otherwise.

    Parameters
    ----------
    model : object
        The model handed to a linear-only code path.
    what : str
        What needs the linear model (named in the message), e.g. ``"the expected spectrum"``.

    Raises
    ------
    ModelKindError
        If ``model`` is a :class:`NonlinearModel` (or anything else without ``A``/``B``).
    """
    if isinstance(model, LinearModel):
        return model
    if isinstance(model, NonlinearModel):
        raise ModelKindError(
            f"{what} needs a linear model (A, B matrices); {model.name!r} is nonlinear. "
            "Use model.linearize(x0, u0) for a small-signal model, or a method that supports "
            "nonlinear plants (the estimators, or thresholds calibrated on healthy runs)"
        )
    raise ModelKindError(f"{what} needs a LinearModel; got {type(model).__name__}")


def same_dynamics(a: Model, b: Model) -> bool:
    """True when two models have the same dynamics and measurement (noise covariances ignored).

    ``LinearModel``: equal ``A``, ``B``, ``C``. ``NonlinearModel``: the same transition (function and
    bound coefficients), equal ``C`` and ``dt``. A linear and a nonlinear model never match.

    Parameters
    ----------
    a, b : LinearModel or NonlinearModel
        The models to compare.
    """
    if a is b:
        return True
    if isinstance(a, LinearModel) and isinstance(b, LinearModel):
        return np.array_equal(a.A, b.A) and np.array_equal(a.B, b.B) and np.array_equal(a.C, b.C)
    if isinstance(a, NonlinearModel) and isinstance(b, NonlinearModel):
        return (
            _callable_id(a.f) == _callable_id(b.f)
            and a.dt == b.dt
            and a.C.shape == b.C.shape
            and np.array_equal(a.C, b.C)
        )
    return False
