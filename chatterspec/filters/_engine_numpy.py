"""numpy form of the covariance filters' step (private): vectorized over realizations, a loop over samples.

:func:`cov_numpy` is :func:`chatterspec.filters._engine.cov_loop`'s arithmetic with numpy: the same
step with the filter's numpy correction (``CorrectionStep.numpy``). It runs when
:func:`chatterspec._jit.enabled` is false, and for the ``luen`` mapping of a single filter. The two
agree to rounding (summation order; LAPACK vs the hand-written Cholesky). The prediction is given as
a function of the sample (:data:`Prediction`): a linear model's ``A x + B u``, a model's Python
``transition``/``jacobian``, or one sample's prior computed by the caller.

For a model that measures through ``h`` (``NonlinearModel(..., h=..., h_jac=...)``; only the EKF
accepts one), the same step runs with ``C`` replaced by ``H = dh/dx`` at the prior::

    e = z(k+1) - h(x(k+1|k)),     H = dh/dx at x(k+1|k),         S = H P(k+1|k) H^T + R
    K = P(k+1|k) H^T S^-1,        x(k+1|k+1) = x(k+1|k) + K e
    P(k+1|k+1) = (I - K H) P(k+1|k) (I - K H)^T + K R K^T                    (Joseph form)
    e(k+1|k+1) = z(k+1) - h(x(k+1|k+1))

The model's ``transition``/``jacobian``/``h`` are Python callables, so that loop over samples is in
Python; realizations are vectorized.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import ShapeError, SingularMatrixError
from ..plants.nonlinear import Model, measure, measurement_jacobian
from . import _engine
from ._engine import FIELDS, LOG2PI, MAP_COV, CorrectionStep, _alloc, _not_pd_message, _shapes

__all__ = [
    "chol_np",
    "cov_numpy",
    "given_prediction",
    "joseph_numpy",
    "kalman_gain_numpy",
    "linear_prediction",
    "map_numpy",
    "model_call_loop",
    "model_prediction",
]

#: ``predict(k, x) -> (x(k+1|k), F)``: the prediction of sample k from ``x(k|k)`` (runs, n), with
#: ``F`` (n, n) or (runs, n, n) the Jacobian of the transition.
Prediction = Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray]]


def chol_np(M: np.ndarray, mapping: int) -> np.ndarray:
    """numpy Cholesky of every block of ``M``; SingularMatrixError (naming the run) if one is not PD."""
    try:
        return np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        bad = np.flatnonzero(~np.all(np.linalg.eigvalsh(M) > 0, axis=-1))
        raise SingularMatrixError(_not_pd_message(mapping, int(bad[0]) if bad.size else 0)) from None


def joseph_numpy(Kg: np.ndarray, C: np.ndarray, Pp: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Joseph form ``(I - K C) Pp (I - K C)^T + K R K^T`` over leading axes: the numpy twin of
    :func:`~chatterspec.filters._linalg.joseph_step` (``Kg`` (..., n, m), ``C`` (..., m, n))."""
    IKC = np.eye(Pp.shape[-1]) - Kg @ C
    return IKC @ Pp @ np.swapaxes(IKC, -1, -2) + Kg @ R @ np.swapaxes(Kg, -1, -2)


def map_numpy(mapping: int, D: np.ndarray, PCt: np.ndarray, M: np.ndarray | None, runs: int) -> np.ndarray:
    """numpy twin of :func:`map_step`: ``M`` (runs, n, m)."""
    if mapping == MAP_COV:
        chol_np(D, mapping)
        return np.swapaxes(np.linalg.solve(D, np.swapaxes(PCt, -1, -2)), -1, -2)
    assert M is not None  # a fixed mapping matrix for every mapping but ``cov``
    return np.broadcast_to(M, (runs, *M.shape))


def kalman_gain_numpy(S: np.ndarray, PCt: np.ndarray) -> np.ndarray:
    """``K = P C^T S^-1`` for every run (numpy)."""
    return np.swapaxes(np.linalg.solve(S, np.swapaxes(PCt, -1, -2)), -1, -2)


def linear_prediction(A: np.ndarray, Bu: np.ndarray) -> Prediction:
    """The prediction of a linear model: ``x(k+1|k) = A x(k|k) + B u(k)``, ``F = A``.

    ``Bu`` (1|runs, K, n) holds ``B u(k)`` for every sample of the chunk.
    """
    return lambda k, x: (x @ A.T + Bu[:, k], A)


def given_prediction(xp_in: np.ndarray, F_in: np.ndarray) -> Prediction:
    """A prediction the caller computed for one sample: ``x(k+1|k) = xp_in`` (runs, n), ``F = F_in``."""
    return lambda k, x: (np.array(xp_in, dtype=float), F_in)


def model_prediction(model: Model, u: np.ndarray) -> Prediction:
    """The prediction from a model's Python ``transition`` and ``jacobian`` at ``x(k|k)``, ``u(k)``.

    ``u`` is (1|runs, K, p); one input for every run is passed as (p,), so a model's compiled
    batched kernel applies (eha4). The Jacobian may be (n, n) (shared) or (runs, n, n).

    Raises
    ------
    ShapeError
        ``transition`` or ``jacobian`` returned the wrong shape (when the prediction is called).
    """
    shared_u = u.shape[0] == 1

    def predict(k: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uk = u[0, k] if shared_u else u[:, k]
        xp = np.asarray(model.transition(x, uk), dtype=float)
        F = np.asarray(model.jacobian(x, uk), dtype=float)
        want_F = (*x.shape, x.shape[1])
        if xp.shape != x.shape or F.shape not in (want_F, want_F[1:]):
            raise ShapeError(
                f"model.transition/jacobian must return {x.shape} and {want_F}; got {xp.shape} and {F.shape}"
            )
        return xp, np.broadcast_to(F, want_F)

    return predict


def cov_numpy(
    correct: CorrectionStep,
    predict: Prediction,
    x: np.ndarray,
    P: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    z: np.ndarray,
    C: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    keep: frozenset[str],
    *,
    h_model: Model | None = None,
) -> dict[str, np.ndarray | None]:
    """numpy twin of :func:`cov_loop`: vectorized over runs, a loop over samples; in place.

    ``predict(k, x)`` gives ``(x(k+1|k), F)`` (:func:`linear_prediction`, :func:`given_prediction`,
    :func:`model_prediction`). With ``h_model`` (a model measuring through ``h``, the EKF only),
    ``C`` is replaced by ``H = dh/dx`` at ``x(k+1|k)`` and ``C x`` by ``h(x)``, sample by sample.
    """
    runs, K, m = z.shape
    n = x.shape[1]
    flags, out = _alloc(keep, _shapes(runs, K, n, m))
    CT = C.T
    for k in range(K):
        xp, F = predict(k, x)
        Pp = F @ P @ np.swapaxes(F, -1, -2) + Q
        if h_model is None:
            Ck = C
            e = z[:, k] - xp @ CT
            PCt = Pp @ CT
        else:
            Ck = measurement_jacobian(h_model, xp)
            e = z[:, k] - measure(h_model, xp)
            PCt = Pp @ np.swapaxes(Ck, -1, -2)
        D = Ck @ PCt
        S = D + R
        L = chol_np(S, correct.mapping)
        w = np.linalg.solve(S, e[..., None])[..., 0]
        ll = -0.5 * (m * LOG2PI + 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1))
        ll = ll - 0.5 * np.einsum("ri,ri->r", e, w)
        Kg, x_new = correct.numpy(_engine.NumpyPrior(e, ep, epp, xp, PCt, D, S, Ck, F))
        x[...] = x_new
        P[...] = joseph_numpy(Kg, Ck, Pp, R)
        epp[...] = ep
        ep[...] = z[:, k] - (x @ CT if h_model is None else measure(h_model, x))
        for f, flag, val in zip(FIELDS, flags, (xp, x, e, S, ll, ep, Pp, P), strict=True):
            if flag:
                out[f][:, k] = val
    return {f: (out[f] if f in keep else None) for f in FIELDS}


def model_call_loop(
    model: Model,
    corr: CorrectionStep,
    compiled: bool,
    x: np.ndarray,
    P: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    z: np.ndarray,
    u: np.ndarray,
    C: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    keep: frozenset[str],
) -> dict[str, np.ndarray | None]:
    """The step for a model without compiled plant steps: its ``transition``/``jacobian`` per sample.

    Each sample's prediction comes from the model's Python methods (:func:`model_prediction`); the
    rest of the step is the compiled loop (``compiled``, one sample at a time, the outputs of every
    sample concatenated along axis 1) or :func:`cov_numpy`. ``x``, ``P``, ``ep``, ``epp`` are
    updated in place.

    Raises
    ------
    ShapeError
        ``transition`` or ``jacobian`` returned the wrong shape.
    """
    predict = model_prediction(model, u)
    if not compiled:
        return cov_numpy(corr, predict, x, P, ep, epp, z, C, Q, R, keep)
    steps = []
    for k in range(z.shape[1]):
        xp, F = predict(k, x)
        zk = z[:, k : k + 1]
        steps.append(
            _engine.cov_loop(corr, None, x, P, ep, epp, zk, u[:, k : k + 1], C, Q, R, keep, xp_in=xp, F_in=F)
        )
    res = {
        f: (None if steps[0][f] is None else np.concatenate([s[f] for s in steps], axis=1)) for f in steps[0]
    }
    return res
