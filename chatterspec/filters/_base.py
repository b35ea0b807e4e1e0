"""Shared ``initialize / update / run`` of the covariance-carrying filters (private)."""

from __future__ import annotations

from collections.abc import Collection
from typing import TypeGuard, cast

import numpy as np

from .. import _jit
from .._validate import finite_array
from ..errors import ParameterError, ShapeError, SingularMatrixError
from ..plants.models import LinearModel
from ..plants.nonlinear import Model, has_measurement_function
from ..plants.steps import PlantSteps, measurement_steps, plant_steps
from . import _engine
from ._engine import given_prediction, linear_prediction, model_call_loop, model_prediction
from .one_sample import OnlineFilter
from .protocol import FilterOutput, FilterState, check_chunk, initial_state, require_finite, resolve_store
from .svsf_recursion import rows_times as _rows_times

#: What ``_advance`` returns: the covariance after the chunk and the stored outputs.
Advanced = tuple[np.ndarray, dict[str, np.ndarray | None]]

_MODEL_ATTRS = ("transition", "jacobian", "C", "Q", "R", "dt", "n_states", "n_outputs", "n_inputs")


def check_model(model: Model) -> None:
    """Duck-type check of the model interface the filters use."""
    missing = [a for a in _MODEL_ATTRS if not hasattr(model, a)]
    if missing:
        raise TypeError(
            f"model must provide {', '.join(_MODEL_ATTRS)} (like LinearModel); "
            f"{type(model).__name__} lacks {', '.join(missing)}"
        )
    n, m = int(model.n_states), int(model.n_outputs)
    for name, shape in (("C", (m, n)), ("Q", (n, n)), ("R", (m, m))):
        M = finite_array(f"model.{name}", getattr(model, name), shape=shape)
        if name != "C":
            if np.max(np.abs(M - M.T), initial=0.0) > 1e-10 * max(1.0, float(np.max(np.abs(M)))):
                raise ParameterError(f"model.{name} must be symmetric (a covariance)")
            if np.min(np.linalg.eigvalsh(M)) < -1e-12 * max(1.0, float(np.max(np.abs(M)))):
                raise ParameterError(f"model.{name} must be positive semi-definite (a covariance)")


class CovarianceFilterBase:
    """Common machinery; subclasses set ``model``, ``_linear`` and implement ``_correction_step``.

    A subclass gives its correction as a :class:`~chatterspec.filters._engine.CorrectionStep`
    (compiled step, parameters, numpy form); the prediction, the covariance and the loops are
    shared (:mod:`chatterspec.filters._engine`): adding a covariance filter is one module with
    its class and its correction step, plus its entry in :mod:`chatterspec.filter_registry`.
    """

    model: Model

    @property
    def _linear(self) -> bool:  # (subclasses: a class attribute or a property)
        return False

    _shared_ok: bool = False

    def _correction_step(self) -> _engine.CorrectionStep:  # pragma: no cover - abstract
        raise NotImplementedError

    def initialize(
        self,
        x0: np.ndarray,
        P0: np.ndarray,
        *,
        runs: int | None = None,
        e0: np.ndarray | None = None,
        e_prev0: np.ndarray | None = None,
    ) -> FilterState:
        """State at k = 0: ``x(0|0) = x0``, ``P(0|0) = P0``, ``e(0|0) = e0``, ``e(-1|-1) = e_prev0``.

        Parameters
        ----------
        x0 : (n,) or (runs, n) array
            Initial estimate.
        P0 : (n, n) or (runs, n, n) array
            Initial covariance, symmetric positive definite (else ParameterError).
        runs : int, optional
            Number of realizations when ``x0`` is shared (default: rows of ``x0``, or 1).
        e0, e_prev0 : (m,) or (runs, m) array, optional
            Initial a-posteriori residuals; default 0 (the papers do not print them, ``docs/design.md`` §7.2).

        Returns
        -------
        FilterState
        """
        return initial_state(self.model, x0, P0, runs=runs, e0=e0, e_prev0=e_prev0, shared_ok=self._shared_ok)

    def online(
        self,
        x0: np.ndarray,
        P0: np.ndarray,
        *,
        e0: np.ndarray | None = None,
        e_prev0: np.ndarray | None = None,
    ) -> OnlineFilter:
        """One realization advanced one sample per call: ``f = filter.online(x0, P0)``, ``x = f.step(z, u)``.

        Parameters
        ----------
        x0 : (n,) array
            ``x(0|0)``.
        P0 : (n, n) array
            ``P(0|0)``, symmetric positive definite.
        e0, e_prev0 : (m,) array, optional
            Initial a-posteriori residuals (default 0), as in :meth:`initialize`.

        Returns
        -------
        OnlineFilter
            Each :meth:`~chatterspec.filters.one_sample.OnlineFilter.step` gives the numbers of
            :meth:`update` on that sample (``docs/filters.md``, "One sample at a time").
        """
        return OnlineFilter(self, self.initialize(x0, P0, runs=1, e0=e0, e_prev0=e_prev0))

    def update(
        self,
        state: FilterState,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        store: Collection[str] | None = None,
        check: bool = True,
    ) -> tuple[FilterState, FilterOutput]:
        """Advance every realization over K samples (K = 1 online, K = T batch; same numbers).

        Parameters
        ----------
        state : FilterState
            Posterior after sample k (from :meth:`initialize` or a previous ``update``).
        z : (runs, K, m) array
            Measurements ``z(k+1) .. z(k+K)`` (``(K, m)`` accepted for one run).
        u : (K, p), (runs, K, p) or (K,) array, optional
            Inputs ``u(k) .. u(k+K-1)`` (``u(k)`` drives ``x(k) -> x(k+1)``); None: no input (zeros).
        store : collection of str, optional
            Output fields to keep (default :data:`~chatterspec.filters.protocol.DEFAULT_STORE`;
            add ``"P_prior"``/``"P_post"`` for the covariances).
        check : bool
            Validate finiteness (turn off only in trusted hot loops).

        Returns
        -------
        (FilterState, FilterOutput)
        """
        keep = resolve_store(store)
        if not isinstance(state, FilterState):
            raise TypeError(f"state must be a FilterState; got {type(state).__name__}")
        z, u = check_chunk(self.model, state, z, u, check)
        n = state.x.shape[1]
        if state.P.shape[-2:] != (n, n) or (state.P.ndim == 3 and state.P.shape[0] != state.runs):
            raise ShapeError(
                f"state.P must have shape ({n}, {n}) or ({state.runs}, {n}, {n}); got {state.P.shape}"
            )
        K = z.shape[1]
        if K == 0:
            out = FilterOutput()
            return state, out
        x, ep, epp, P = state.x.copy(), state.e_post.copy(), state.e_prev.copy(), state.P.copy()
        try:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # checked below
                P, res = self._advance(x, P, ep, epp, z, u, keep)
        except SingularMatrixError:
            if not _jit.enabled():
                raise
            # a compiled kernel stops where S is not positive definite, which a diverging (NaN/inf)
            # covariance also is: the numpy path (same numbers) runs on and locates the first bad sample
            x, ep, epp, P = state.x.copy(), state.e_post.copy(), state.e_prev.copy(), state.P.copy()
            with _jit.numpy_path(), np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                P, res = self._advance(x, P, ep, epp, z, u, keep)
        require_finite(type(self).__name__, (x, P), res, state.k, K)
        new = FilterState(x=x, P=P, e_post=ep, e_prev=epp, k=state.k + K)
        return new, FilterOutput(**res)

    def _plant(self) -> PlantSteps | None:
        """The model's compiled steps for the loop, or None (its Python ``transition`` per sample).

        A filter that is not ``_linear`` on a :class:`LinearModel` (the EKF, which always calls
        its model) does not take the linear steps: its numbers are those of the model's methods.
        """
        if not self._linear and is_linear(self.model):
            return None
        return plant_steps(self.model)

    def _advance(self, x: np.ndarray, P: np.ndarray, ep: np.ndarray, epp: np.ndarray, z: np.ndarray,
                 u: np.ndarray, keep: frozenset[str]) -> Advanced:  # fmt: skip
        model = self.model
        C = np.asarray(model.C, dtype=float)
        Q = np.asarray(model.Q, dtype=float)
        R = np.asarray(model.R, dtype=float)
        if P.ndim == 2:  # shared covariance given to a per-run filter (e.g. replaced by a bank)
            P = np.array(np.broadcast_to(P, (x.shape[0], *P.shape)))
        corr = self._correction_step()
        n, m = x.shape[1], z.shape[2]
        compiled = _jit.enabled() and corr.mapping != _engine.MAP_LUEN and _jit.fits(n, m)
        plant = self._plant()
        hx = measurement_steps(model) if has_measurement_function(model) else None
        if has_measurement_function(model) and not (compiled and plant is not None and hx is not None):
            # EKF with a Python h(x): H = dh/dx in place of C, numpy
            predict = model_prediction(model, u)
            return P, _engine.cov_numpy(corr, predict, x, P, ep, epp, z, C, Q, R, keep, h_model=model)
        if compiled and plant is not None:  # every sample in one compiled loop (h(x) compiled too)
            P = np.ascontiguousarray(P)  # (np.array of a broadcast P keeps its strides: another layout)
            return P, _engine.cov_loop(corr, plant, x, P, ep, epp, z, u, C, Q, R, keep, measurement=hx)
        if self._linear:
            lin = cast(LinearModel, model)  # (``_linear``: a LinearModel)
            Bu = _rows_times(u, np.ascontiguousarray(lin.B.T))
            predict = linear_prediction(lin.A, Bu)
            return P, _engine.cov_numpy(corr, predict, x, P, ep, epp, z, C, Q, R, keep)
        return P, model_call_loop(model, corr, compiled, x, P, ep, epp, z, u, C, Q, R, keep)

    def correct(
        self,
        state: FilterState,
        x_prior: np.ndarray,
        P_prior: np.ndarray,
        z: np.ndarray,
        *,
        store: Collection[str] | None = None,
    ) -> tuple[FilterState, FilterOutput]:
        """Measurement update only, from a prior the caller supplies (one sample).

        For multiple-model schemes that mix predictions rather than posteriors ([SMM] Table 1:
        ``x(k+1|k) = sum_j mu_j x_j(k+1|k)``, ``P(k+1|k) = sum_j mu_j [P_j + spread]``). The
        residual memory ``e(k|k)``, ``e(k-1|k-1)`` and ``k`` come from ``state``. The arithmetic
        after the prediction is that of :meth:`update`: given ``update``'s own ``x_prior`` and
        ``P_prior``, the posterior is bit-identical (tested).

        Parameters
        ----------
        state : FilterState
            Posterior after sample k (only its residuals and ``k`` are used).
        x_prior : (runs, n) array
            ``x(k+1|k)``.
        P_prior : (n, n) or (runs, n, n) array
            ``P(k+1|k)``, symmetric positive definite.
        z : (runs, m) or (runs, 1, m) array
            ``z(k+1)``.
        store : collection of str, optional
            Output fields to keep (see :meth:`update`).

        Returns
        -------
        (FilterState, FilterOutput)
            Outputs have one sample; ``x_prior``/``P_prior`` echo the inputs.
        """
        keep = resolve_store(store)
        if not isinstance(state, FilterState):
            raise TypeError(f"state must be a FilterState; got {type(state).__name__}")
        runs, n = state.x.shape
        m = state.e_post.shape[1]
        xp = finite_array("x_prior", x_prior, shape=(runs, n))
        Pp = finite_array("P_prior", P_prior, ndim=(2, 3))
        if Pp.shape[-2:] != (n, n) or (Pp.ndim == 3 and Pp.shape[0] != runs):
            raise ShapeError(f"P_prior must have shape ({n}, {n}) or ({runs}, {n}, {n}); got {Pp.shape}")
        zz = finite_array("z", z, ndim=(2, 3))
        if zz.ndim == 2:
            zz = zz[:, None]
        if zz.shape != (runs, 1, m):
            raise ShapeError(f"z must have shape ({runs}, {m}) (one sample); got {zz.shape}")
        model = self.model
        C = np.asarray(model.C, dtype=float)
        R = np.asarray(model.R, dtype=float)
        P = np.array(np.broadcast_to(Pp, (runs, n, n)), dtype=float)
        x, ep, epp = np.array(xp, dtype=float), state.e_post.copy(), state.e_prev.copy()
        corr = self._correction_step()
        if corr.mapping == _engine.MAP_LUEN:
            raise ParameterError(
                "correct() is not available with mapping='luen' (it needs the Jacobian at x(k|k))"
            )
        # F = I and Q = 0 make the engine's prediction P(k+1|k) = I P I^T + 0 = P_prior exactly
        eye, Q0 = np.broadcast_to(np.eye(n), (runs, n, n)), np.zeros((n, n))
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # checked just below
            h_model = model if has_measurement_function(model) else None
            if h_model is None and _jit.enabled() and _jit.fits(n, m):
                u0 = np.zeros((1, 1, 0))
                # C order: np.array of a broadcast P keeps its strides, and numba compiles a loop per layout
                P = np.ascontiguousarray(P)
                res = _engine.cov_loop(corr, None, x, P, ep, epp, zz, u0, C, Q0, R, keep, xp_in=xp, F_in=eye)
            else:
                prior = given_prediction(xp, eye)
                res = _engine.cov_numpy(corr, prior, x, P, ep, epp, zz, C, Q0, R, keep, h_model=h_model)
        require_finite(type(self).__name__, (x, P), res, state.k, 1)
        new = FilterState(x=x, P=P, e_post=ep, e_prev=epp, k=state.k + 1)
        return new, FilterOutput(**res)

    def run(
        self,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        x0: np.ndarray,
        P0: np.ndarray,
        store: Collection[str] | None = None,
    ) -> FilterOutput:
        """Filter whole records: :meth:`initialize` then one :meth:`update` (same kernel).

        Parameters
        ----------
        z : (runs, T, m) array
            Measurements ``z(1) .. z(T)`` (``(T, m)`` for one run).
        u : (T, p), (runs, T, p) or (T,) array, optional
            Inputs ``u(0) .. u(T-1)``; None: no input (zeros).
        x0 : (n,) or (runs, n) array
            ``x(0|0)``.
        P0 : (n, n) or (runs, n, n) array
            ``P(0|0)``, symmetric positive definite.
        store : collection of str, optional
            Output fields to keep (see :meth:`update`).

        Returns
        -------
        FilterOutput
            Sample j belongs to time j + 1.
        """
        zz = finite_array("z", z, ndim=(2, 3))
        runs = 1 if zz.ndim == 2 else zz.shape[0]
        state = self.initialize(x0, P0, runs=runs)
        return self.update(state, zz, u, store=store)[1]


def is_linear(model: Model) -> TypeGuard[LinearModel]:
    """True for :class:`LinearModel` (the compiled path loops over time inside the kernel)."""
    return isinstance(model, LinearModel)
