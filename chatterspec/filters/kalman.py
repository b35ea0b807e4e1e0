"""Kalman filter and extended Kalman filter, batched over realizations (``docs/design.md`` §7.1).

Equations ([DETC] and [IMM] baselines)::

    x(k+1|k) = f(x(k|k), u(k))                  (linear: A x + B u)
    P(k+1|k) = F P(k|k) F^T + Q,                F = df/dx at x(k|k)   (linear: F = A)
    S = C P(k+1|k) C^T + R,   K = P(k+1|k) C^T S^-1,   x(k+1|k+1) = x(k+1|k) + K e(k+1|k)
    P(k+1|k+1) = (I - K C) P(k+1|k) (I - K C)^T + K R K^T      (Joseph form)

For a :class:`~chatterspec.plants.models.LinearModel` started from one shared ``P0``, the
covariance and gain do not depend on the data: :class:`KalmanFilter` computes them once per
sample for all realizations (``P`` stays ``(n, n)``, ``S`` is one ``(K, m, m)`` sequence) and runs only the
state recursion per realization (:mod:`chatterspec.filters._kalman_shared`; compiled, any number of
runs, with the per-run filter's steps: the same bits as ``P0`` given per run). A per-run ``P`` (e.g.
after a bank's mixing) takes the per-run path, and so does a single stream when the compiled kernels
are on. The numpy path's shared sequence (BLAS products, ``S^-1``) equals the per-run path to
rounding. Outputs have a leading runs axis on every path (``S`` is ``(runs, K, m, m)``; on the shared
path a read-only broadcast view of the one ``(K, m, m)`` sequence).
:class:`ExtendedKalmanFilter` uses the model's own ``transition`` and batched ``jacobian`` and works
with any model that provides them; with a nonlinear measurement ``h`` it uses ``H = dh/dx`` at the
prior in place of ``C`` (:func:`chatterspec.filters._engine_numpy.cov_numpy` with ``h_model``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _jit
from .._repr import short_repr
from ..plants.models import LinearModel
from ..plants.nonlinear import Model
from ..plants.scenarios import FilterSettings
from . import _engine, _engine_numpy, _kalman_shared
from ._base import CovarianceFilterBase, check_model
from ._engine import chol_solve_step, gain_update_step


@_jit.step
def kalman_correct(fp: np.ndarray, e: np.ndarray, ep: np.ndarray, epp: np.ndarray, xp: np.ndarray,
    PCtT: np.ndarray, D: np.ndarray, L: np.ndarray, C: np.ndarray, F: np.ndarray, x: np.ndarray,
    KgT: np.ndarray, ws: tuple[np.ndarray, ...], n: int, m: int) -> int:  # fmt: skip
    """The Kalman correction (compiled step): ``K^T = S^-1 (P C^T)^T`` from the factor ``L`` of ``S``,
    ``x(k+1|k+1) = x(k+1|k) + K e``. Signature of :mod:`chatterspec.filters._engine`; returns 0."""
    chol_solve_step(L, PCtT, KgT, m, n)
    gain_update_step(xp, KgT, e, x, n, m)
    return 0


def kalman_correct_numpy(pr: _engine.NumpyPrior) -> tuple[np.ndarray, np.ndarray]:
    """:func:`kalman_correct` vectorized over realizations: ``(K, x(k+1|k+1))``."""
    Kg = _engine_numpy.kalman_gain_numpy(pr.S, pr.PCt)
    return Kg, pr.xp + np.einsum("rij,rj->ri", Kg, pr.e)


_KF_STEP = _engine.CorrectionStep("kf", kalman_correct, np.zeros(1), kalman_correct_numpy)

__all__ = ["ExtendedKalmanFilter", "KalmanFilter"]


@dataclass(frozen=True, eq=False)
class KalmanFilter(CovarianceFilterBase):
    """Linear Kalman filter with the Joseph-form covariance update, batched over realizations.

    Implements the :class:`~chatterspec.filters.protocol.Filter` protocol.

    Parameters
    ----------
    model : LinearModel
        Filter model (A, B, C, Q, R).

    Raises
    ------
    TypeError
        If ``model`` is not a LinearModel (use :class:`ExtendedKalmanFilter`).
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    model: LinearModel

    def __post_init__(self) -> None:
        if not isinstance(self.model, LinearModel):
            raise TypeError(
                f"KalmanFilter needs a LinearModel; got {type(self.model).__name__} "
                "(use ExtendedKalmanFilter for a nonlinear model)"
            )

    _linear = True
    _shared_ok = True

    def _correction_step(self) -> _engine.CorrectionStep:
        return _KF_STEP

    def _advance(
        self,
        x: np.ndarray,
        P: np.ndarray,
        ep: np.ndarray,
        epp: np.ndarray,
        z: np.ndarray,
        u: np.ndarray,
        keep: frozenset[str],
    ) -> tuple[np.ndarray, dict[str, np.ndarray | None]]:
        if P.ndim == 3:
            return super()._advance(x, P, ep, epp, z, u, keep)
        if x.shape[0] == 1 and _jit.enabled() and _jit.fits(x.shape[1], z.shape[2]):
            # one stream: the per-run compiled loop (the shared path's bits, without its (K, ...) sequences)
            P1, res = super()._advance(x, P[None].copy(), ep, epp, z, u, keep)
            return P1[0], res
        m = self.model
        return _kalman_shared.shared_gain(P, m.A, m.B, m.C, m.Q, m.R, x, ep, epp, z, u, keep)

    def gain_sequence(self, P0: np.ndarray, K: int) -> tuple[np.ndarray, np.ndarray]:
        """Data-independent gains and posterior covariances from a shared ``P0``.

        Parameters
        ----------
        P0 : (n, n) array
            ``P(0|0)``, symmetric positive definite.
        K : int
            Number of samples.

        Returns
        -------
        (gains (K, n, m), P_post (K, n, n))
        """
        state = self.initialize(np.zeros(self.model.n_states), P0)
        m = self.model
        return _kalman_shared.gain_sequence(state.P, m.A, m.C, m.Q, m.R, K)


@dataclass(frozen=True, eq=False)
class ExtendedKalmanFilter(CovarianceFilterBase):
    """Extended Kalman filter: the model's ``transition`` and batched ``jacobian`` (Joseph form).

    Implements the :class:`~chatterspec.filters.protocol.Filter` protocol; covariances are per
    run ``(runs, n, n)`` because the Jacobian depends on the estimate.

    Parameters
    ----------
    model : model object
        Anything with ``transition(x, u)`` (runs, n), ``jacobian(x, u)`` (runs, n, n), ``C``,
        ``Q``, ``R``, ``dt``, ``n_states``, ``n_outputs``, ``n_inputs`` (e.g. LinearModel or the
        nonlinear EHA). With a LinearModel the EKF equals the KF (tested). A model with a
        nonlinear measurement (``NonlinearModel(..., h=, h_jac=)``) is filtered with
        ``e = z - h(x(k+1|k))`` and ``H = dh/dx`` at the prior in place of ``C``
        (``docs/filters.md``; equal to filterpy's EKF, tested).

    Examples
    --------
    >>> import numpy as np, chatterspec as cs
    >>> A = np.array([[1.0, 0.01], [-0.04, 0.998]])
    >>> m = cs.NonlinearModel(lambda x, u: x @ A.T, lambda x, u: np.broadcast_to(A, (*x.shape[:-1], 2, 2)),
    ...                       None, np.diag([1e-8, 1e-6]), np.eye(1) * 1e-4, 0.01,
    ...                       h=lambda x: np.sin(x[..., :1]),
    ...                       h_jac=lambda x: np.stack([np.cos(x[..., 0]), 0 * x[..., 0]], -1)[..., None, :])
    >>> out = cs.ExtendedKalmanFilter(m).run(np.zeros((50, 1)), x0=np.zeros(2), P0=np.eye(2))
    >>> out.x_post.shape
    (1, 50, 2)
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    model: Model

    def __post_init__(self) -> None:
        check_model(self.model)

    def _correction_step(self) -> _engine.CorrectionStep:
        return _KF_STEP

    # The EKF always calls the model (no linear shortcut), so it is the reference for nonlinear models.
    _linear = False
    _shared_ok = False


def kf_from_settings(
    model: Model, settings: FilterSettings, source: str
) -> KalmanFilter | ExtendedKalmanFilter:
    """Registry builder of ``kf``: the Kalman filter on a linear model, the EKF otherwise (no tuning)."""
    return KalmanFilter(model) if isinstance(model, LinearModel) else ExtendedKalmanFilter(model)


def ekf_from_settings(model: Model, settings: FilterSettings, source: str) -> ExtendedKalmanFilter:
    """Registry builder of ``ekf``: the extended Kalman filter (no tuning)."""
    return ExtendedKalmanFilter(model)
