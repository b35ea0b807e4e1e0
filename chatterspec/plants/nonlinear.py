"""Nonlinear discrete-time plant models: ``x(k+1) = f(x(k), u(k)) + v(k)``, ``z(k) = C x(k) + w(k)``.

The estimator papers ([SMM] eq 4.1-4.5, [IMM] eq 34-38; tags as in ``docs/design.md``) print their
nonlinear plants directly in discrete time, as the explicit Euler step of the continuous equations.
:class:`NonlinearModel` therefore stores the *discrete* transition ``f`` and its Jacobian ``F = df/dx``;
:meth:`NonlinearModel.from_continuous` builds both from continuous-time ``x' = g(x, u)`` by the same
explicit Euler step (``f = x + dt g``, ``F = I + dt dg/dx``).

The measurement is linear (``C``) in every paper; a user model may give a nonlinear measurement
``h(x)`` with its Jacobian ``h_jac`` instead, which :func:`~chatterspec.simulate` and the
:class:`~chatterspec.filters.kalman.ExtendedKalmanFilter` use (the SVSF family, whose switching
term needs a linear ``C``, refuses such a model: :mod:`chatterspec.plants.measurement`). The filters
only need ``model.transition(x, u)``, ``model.jacobian(x, u)``, ``model.C``, ``model.Q``, ``model.R``,
``model.dt`` and the sizes, which :class:`~chatterspec.plants.models.LinearModel` offers under the
same names. :meth:`NonlinearModel.linearize` returns the small-signal ``LinearModel`` about an
operating point. Callables must be picklable for local workers and Dask (module-level functions or
:func:`functools.partial` of them, as :mod:`chatterspec.plants.eha4` does).
:meth:`NonlinearModel.from_steps` takes the functions written for one sample instead, which the
filters then run compiled (:mod:`chatterspec.plants.sample_functions`).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import TypeAlias, TypedDict, TypeGuard, Unpack

import numpy as np

from .._repr import short_repr
from .._validate import finite_array, positive, positive_int, readonly
from ..errors import ModelKindError, NonFiniteError, ParameterError, ShapeError, SingularMatrixError
from .euler import ContinuousEuler, Transition
from .linear_model import LinearModel
from .linearization import Linearization
from .measurement import Measurement, measure, measurement_jacobian, measurement_matrix
from .model_base import (
    ModelBase,
    check_measurement_matrix,
    check_noise,
    frozen,
    hash_arrays,
    set_channel_labels,
)
from .sample_functions import FromSteps

__all__ = ["Model", "NonlinearModel", "is_linear", "require_linear", "same_dynamics"]


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

    # -- measurement (chatterspec.plants.measurement) ---------------------------
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
