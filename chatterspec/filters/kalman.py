"""Kalman filter and extended Kalman filter, batched over realizations (``docs/design.md`` §7.1).

Equations ([DETC] and [IMM] baselines)::

    x(k+1|k) = f(x(k|k), u(k))                  (linear: A x + B u)
    P(k+1|k) = F P(k|k) F^T + Q,                F = df/dx at x(k|k)   (linear: F = A)
    S = C P(k+1|k) C^T + R,   K = P(k+1|k) C^T S^-1,   x(k+1|k+1) = x(k+1|k) + K e(k+1|k)
    P(k+1|k+1) = (I - K C) P(k+1|k) (I - K C)^T + K R K^T      (Joseph form)

For a :class:`~chatterspec.plants.models.LinearModel` started from one shared ``P0``, the
covariance and gain do not depend on the data: :class:`KalmanFilter` computes them once per
sample for all realizations (``P`` stays ``(n, n)``, ``S`` is one ``(K, m, m)`` sequence) and runs only the
state recursion per realization (compiled: :func:`_riccati_loop`, the covariance
half of the per-run step, and :func:`_kf_shared_loop`, its state half; any number of runs, with the
per-run filter's steps: the same bits as ``P0`` given per run). A per-run ``P`` (e.g.
after a bank's mixing) takes the per-run path, and so does a single stream when the compiled kernels
are on. The numpy path's shared sequence (BLAS products, ``S^-1``) equals the per-run path to
rounding. Outputs have a leading runs axis on every path (``S`` is ``(runs, K, m, m)``; on the shared
path a read-only broadcast view of the one ``(K, m, m)`` sequence).
:class:`ExtendedKalmanFilter` uses the model's own ``transition`` and batched ``jacobian`` and works
with any model that provides them; with a nonlinear measurement ``h`` it uses ``H = dh/dx`` at the
prior in place of ``C`` (:func:`chatterspec.filters._engine.cov_numpy` with ``h_model``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .. import _jit
from .._repr import short_repr
from ..errors import SingularMatrixError
from ..plants.models import LinearModel
from ..plants.nonlinear import Model
from ..plants.scenarios import FilterSettings
from ..plants.steps import parameters, predict_step
from . import _engine
from ._base import CovarianceFilterBase, check_model
from ._engine import (
    FIELDS,
    LOG2PI,
    MAP_CONST,
    _alloc,
    _not_pd_message,
    chol_solve_step,
    chol_step,
    gain_update_step,
    half_logdet_step,
    innovation_step,
    joseph_numpy,
    joseph_step,
    kernel_input,
    loglik_given_step,
    predict_cov_step,
    residual_step,
    store_step,
)
from ._engine import chol_np as _chol_np
from .svsf_recursion import copy_pair_step
from .svsf_recursion import rows_times as _rows_times

__all__ = [
    "ExtendedKalmanFilter",
    "KalmanFilter",
]


# ----------------------------------------------------------------------------- (from kalman)
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
    Kg = _engine.kalman_gain_numpy(pr.S, pr.PCt)
    return Kg, pr.xp + np.einsum("rij,rj->ri", Kg, pr.e)


_KF_STEP = _engine.CorrectionStep("kf", kalman_correct, np.zeros(1), kalman_correct_numpy)


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
        runs, K, m = z.shape
        compiled = _jit.enabled() and _jit.fits(x.shape[1], m)
        if x.shape[0] == 1 and compiled:
            # one stream: the per-run compiled loop (the shared path's bits, without its (K, ...) sequences)
            P1, res = super()._advance(x, P[None].copy(), ep, epp, z, u, keep)
            return P1[0], res
        # a shared P (n, n): the gains once for all runs, the state recursion per run (the per-run
        # filter's bits when compiled); S, P_prior, P_post come back as read-only (runs, K, ...)
        # broadcast views of the one sequence
        A, B, C, Q, R = self.model.A, self.model.B, self.model.C, self.model.Q, self.model.R
        if compiled:
            P, Pp, Pq, S, KgT, L, hld = riccati_compiled(P, A, C, Q, R, K)
            res = kf_shared_states(x, ep, epp, z, u, A, B, C, KgT, keep, L=L, half_logdet=hld)
        else:
            P, Pp, Pq, S, Kg, Sinv, logdet = riccati(P, A, C, Q, R, K)
            res = kf_shared_states(
                x, ep, epp, z, u, A, B, C, np.swapaxes(Kg, -1, -2), keep, Sinv=Sinv, logdet=logdet
            )
        for f, val in (("S", S), ("P_prior", Pp), ("P_post", Pq)):
            res[f] = np.broadcast_to(val, (runs, *val.shape)) if f in keep else None
        return P, res

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
        return gain_sequence(state.P, m.A, m.C, m.Q, m.R, K)


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


# ----------------------------------------------------------------------------- shared covariance
#: Sizes of :func:`_kf_shared_loop`, bound per model by :func:`_kf_shared_kernel` (0: read from the arrays).
NX = NZ = 0


def _riccati_loop(
    A: np.ndarray,
    C: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    P: np.ndarray,
    Pp_all: np.ndarray,
    Pq_all: np.ndarray,
    S_all: np.ndarray,
    KgT_all: np.ndarray,
    L_all: np.ndarray,
    hld_all: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """The shared covariance sequence: the covariance half of the per-run step, K times from ``P`` (in place).

    Per sample: ``Pp = A P A^T + Q``, ``S = C Pp C^T + R`` and its Cholesky factor ``L``, the Kalman
    gain ``K^T = S^-1 (Pp C^T)^T`` (:func:`~chatterspec.filters.kalman.kalman_correct`'s solve), the
    Joseph form: the steps of :func:`chatterspec.filters._engine._sample` in its order, hence its bits.
    Outputs (K, ...): ``Pp_all``, ``Pq_all`` (P(k+1|k+1)), ``S_all``, ``KgT_all`` (K, m, n), ``L_all``,
    ``hld_all`` (K,) = ``sum log L_ii`` (:func:`~chatterspec.filters._engine.half_logdet_step`). Returns
    0, or ``1 + k`` when ``S`` of sample k is not positive definite.
    """
    b = _jit.borrow
    A, C, Q, R, P = b(A), b(C), b(Q), b(R), b(P)
    Pp_all, Pq_all, S_all, KgT_all, L_all = b(Pp_all), b(Pq_all), b(S_all), b(KgT_all), b(L_all)
    hld_all = b(hld_all)
    K = Pp_all.shape[0]
    n = NX if NX > 0 else A.shape[0]
    m = NZ if NZ > 0 else C.shape[0]
    T1, Pp, IKC = _jit.scratch2(n, n), _jit.scratch2(n, n), _jit.scratch2(n, n)
    PCt, PCtT, KgT, KR = _jit.scratch2(n, m), _jit.scratch2(m, n), _jit.scratch2(m, n), _jit.scratch2(n, m)
    S, D, L, e = _jit.scratch2(m, m), _jit.scratch2(m, m), _jit.scratch2(m, m), _jit.scratch(m)
    zero = _jit.scratch(n + m)  # z = 0 and x(k+1|k) = 0: the innovation itself is not needed
    for i in range(n + m):
        zero[i] = 0.0
    for k in range(K):
        predict_cov_step(A, P, Q, T1, Pp, n)
        innovation_step(zero, zero, Pp, C, R, e, PCt, PCtT, D, S, n, m)
        if not chol_step(S, L, m):
            return 1 + k
        hld_all[k] = half_logdet_step(L, m)
        chol_solve_step(L, PCtT, KgT, m, n)
        joseph_step(KgT, C, Pp, R, T1, IKC, KR, P, n, m)
        for i in range(n):
            for j in range(n):
                Pp_all[k, i, j] = Pp[i, j]
                Pq_all[k, i, j] = P[i, j]
        for i in range(m):
            for j in range(m):
                S_all[k, i, j] = S[i, j]
                L_all[k, i, j] = L[i, j]
            for j in range(n):
                KgT_all[k, i, j] = KgT[i, j]
    return 0


def _kf_shared_loop(
    prm: np.ndarray,
    u: np.ndarray,
    z: np.ndarray,
    x: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    C: np.ndarray,
    KgT: np.ndarray,
    L: np.ndarray,
    half_logdet: np.ndarray,
    flags: np.ndarray,
    outs: tuple[np.ndarray, ...],
) -> int:  # pragma: no cover - compiled
    """State recursion of the Kalman filter with a precomputed, shared gain sequence ``KgT`` (K, m, n).

    Per run and sample: the linear plant's prediction (:func:`~chatterspec.plants.steps.predict_step`,
    ``prm`` of :func:`~chatterspec.plants.steps.parameters`), the innovation, ``x = x(k+1|k)
    + K e``, the log-likelihood (when stored) from the Cholesky factor ``L`` (K, m, m) of ``S`` and its
    ``half_logdet`` (K,) = ``sum log L_ii``, the residuals: the steps of the per-run filter
    (:mod:`chatterspec.filters._engine`), hence its bits. ``outs``: the
    eight outputs of ``FIELDS`` (S and the covariances, which the shared path returns itself, empty
    and not flagged).
    """
    b = _jit.borrow
    prm, u, z, x, ep, epp, C, KgT, L = b(prm), b(u), b(z), b(x), b(ep), b(epp), b(C), b(KgT), b(L)
    half_logdet = b(half_logdet)
    o0, o1, o2, o3, o4, o5, o6, o7 = outs
    # borrowed: no reference counts per sample
    outs = (b(o0), b(o1), b(o2), b(o3), b(o4), b(o5), b(o6), b(o7))
    runs, K, _ = z.shape
    n = NX if NX > 0 else x.shape[1]
    m = NZ if NZ > 0 else z.shape[2]
    p = u.shape[2]
    shared_u = u.shape[0] == 1
    want_ll = flags[4]
    xp = _jit.scratch(n)
    e = _jit.scratch(m)
    eb = _jit.scratch2(m, 1)
    wv = _jit.scratch2(m, 1)
    xr = _jit.scratch(n)  # run r's state and residual, on the stack for the run (written back after it)
    epr = _jit.scratch(m)
    none2 = _jit.scratch2(0, 0)
    for r in range(runs):
        ur = 0 if shared_u else r
        copy_pair_step(x[r], ep[r], xr, epr, n, m)
        for k in range(K):
            predict_step(prm, xr, u[ur, k], xp, n, p)
            residual_step(z[r, k], C, xp, e, n, m)
            ll = loglik_given_step(L[k], e, eb, wv, half_logdet[k], m) if want_ll else 0.0
            gain_update_step(xp, KgT[k], e, xr, n, m)
            for i in range(m):
                epp[r, i] = epr[i]
            residual_step(z[r, k], C, xr, epr, n, m)
            store_step(flags, outs, r, k, xp, xr, e, none2, ll, epr, none2, none2, n, m)
        copy_pair_step(xr, epr, x[r], ep[r], n, m)
    return 0


def _kf_shared_kernel(n: int, m: int) -> Callable[..., int]:
    """:func:`_kf_shared_loop` compiled for n states and m outputs (literal sizes up to
    :data:`chatterspec._jit.MAX_UNROLL`: the per-channel loops unrolled, as the per-run filters')."""
    return _jit.specialize_sizes(_kf_shared_loop, "kfshared", {"NX": n, "NZ": m})


def _riccati_kernel(n: int, m: int) -> Callable[..., int]:
    """:func:`_riccati_loop` compiled for n states and m outputs (literal sizes up to 4)."""
    return _jit.specialize_sizes(_riccati_loop, "riccati", {"NX": n, "NZ": m})


def riccati_compiled(
    P: np.ndarray, A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray, K: int
) -> tuple[np.ndarray, ...]:
    """:func:`riccati` by :func:`_riccati_loop`: ``(P_end, P_prior, P_post, S, KgT (K, m, n), L, hld)``.

    Raises
    ------
    SingularMatrixError
        An innovation covariance that is not positive definite (or not finite).
    """
    n, m = A.shape[0], C.shape[0]
    c = kernel_input
    P = np.array(P, dtype=float, order="C")
    out = (
        np.empty((K, n, n)),
        np.empty((K, n, n)),
        np.empty((K, m, m)),
        np.empty((K, m, n)),
        np.empty((K, m, m)),
        np.empty(K),
    )
    status = _riccati_kernel(n, m)(c(A), c(C), c(Q), c(R), P, *out)
    if status:
        raise SingularMatrixError(_not_pd_message(MAP_CONST, 0))
    return (P, *out)


def gain_sequence(
    P: np.ndarray, A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray, K: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(gains (K, n, m), P_post (K, n, n))`` from a shared ``P``, as :class:`KalmanFilter` computes them."""
    if _jit.enabled() and _jit.fits(A.shape[0], C.shape[0]):
        _, _, Pq, _, KgT, _, _ = riccati_compiled(P, A, C, Q, R, K)
        return np.swapaxes(KgT, -1, -2), Pq
    _, _, Pq, _, Kg, _, _ = riccati(P, A, C, Q, R, K)
    return Kg, Pq


def kf_shared_states(
    x: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    z: np.ndarray,
    u: np.ndarray,
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    KgT: np.ndarray,
    keep: frozenset[str],
    *,
    L: np.ndarray | None = None,
    half_logdet: np.ndarray | None = None,
    Sinv: np.ndarray | None = None,
    logdet: np.ndarray | None = None,
) -> dict[str, np.ndarray | None]:
    """State recursion of the linear KF with a shared gain sequence ``KgT`` (K, m, n); in place.

    ``u`` is (1 | runs, K, p). With ``L`` and ``half_logdet`` (the Cholesky factors of ``S`` and their
    ``sum log L_ii``, from :func:`riccati_compiled`) the compiled loop; with ``Sinv`` and ``logdet``
    (:func:`riccati`) numpy, which sums ``B u`` as ``_rows_times`` does.
    """
    runs, K, m = z.shape
    n = x.shape[1]
    shapes = {
        "x_prior": (runs, K, n),
        "x_post": (runs, K, n),
        "innovation": (runs, K, m),
        "S": (0, 0, 0, 0),
        "loglik": (runs, K),
        "e_post": (runs, K, m),
        "P_prior": (0, 0, 0, 0),
        "P_post": (0, 0, 0, 0),
    }
    flags, out = _alloc(keep, shapes)
    # S and the covariances are shared (K, ...) arrays that the caller returns itself
    flags[[FIELDS.index("S"), FIELDS.index("P_prior"), FIELDS.index("P_post")]] = False
    KgT = np.ascontiguousarray(KgT)
    if L is not None:
        assert half_logdet is not None  # (compiled: the caller passes riccati_compiled's)
        c = kernel_input
        _kf_shared_kernel(n, m)(
            c(parameters(A, B)), c(u), c(z), x, ep, epp, c(C), c(KgT), c(L), c(half_logdet), flags,
            tuple(out[f] for f in FIELDS),
        )  # fmt: skip
    else:
        assert Sinv is not None and logdet is not None  # (numpy: the caller passes riccati's)
        AT, CT = A.T, C.T
        Bu = _rows_times(u, np.ascontiguousarray(B.T))
        for k in range(K):
            xp = x @ AT + Bu[:, k]
            e = z[:, k] - xp @ CT
            x[...] = xp + e @ KgT[k]
            if flags[4]:
                out["loglik"][:, k] = -0.5 * (
                    m * LOG2PI + logdet[k] + np.einsum("ri,ij,rj->r", e, Sinv[k], e)
                )
            epp[...] = ep
            ep[...] = z[:, k] - x @ CT
            for f, flag, val in (
                ("x_prior", flags[0], xp),
                ("x_post", flags[1], x),
                ("innovation", flags[2], e),
            ):
                if flag:
                    out[f][:, k] = val
            if flags[5]:
                out["e_post"][:, k] = ep
    return {
        f: (out[f] if (f in keep and f in ("x_prior", "x_post", "innovation", "loglik", "e_post")) else None)
        for f in FIELDS
    }


def riccati(
    P: np.ndarray, A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray, K: int
) -> tuple[np.ndarray, ...]:
    """Shared covariance sequence of the linear KF over K steps (Joseph form).

    Returns ``(P_end, P_prior (K,n,n), P_post (K,n,n), S (K,m,m), Kg (K,n,m), Sinv (K,m,m), logdet (K,))``,
    ``logdet`` = log det(2 pi S) - m log(2 pi) = log det S.
    """
    n, m = A.shape[0], C.shape[0]
    Pp_all = np.empty((K, n, n))
    Pq_all = np.empty((K, n, n))
    S_all = np.empty((K, m, m))
    Kg_all = np.empty((K, n, m))
    Sinv_all = np.empty((K, m, m))
    logdet = np.empty(K)
    for k in range(K):
        Pp = A @ P @ A.T + Q
        PCt = Pp @ C.T
        S = C @ PCt + R
        L = _chol_np(S, MAP_CONST)
        Sinv = np.linalg.inv(S)
        Kg = PCt @ Sinv
        P = joseph_numpy(Kg, C, Pp, R)
        Pp_all[k], Pq_all[k], S_all[k], Kg_all[k], Sinv_all[k] = Pp, P, S, Kg, Sinv
        logdet[k] = 2.0 * np.sum(np.log(np.diag(L)))
    return P, Pp_all, Pq_all, S_all, Kg_all, Sinv_all, logdet
