"""numpy form of the covariance filters' step (private): vectorized over realizations, a loop over samples.

:func:`cov_numpy` is :func:`chatterspec.filters._engine.cov_loop`'s arithmetic with numpy: the same
step with the filter's numpy correction (``CorrectionStep.numpy``). It runs when
:func:`chatterspec._jit.enabled` is false, and for the ``luen`` mapping of a single filter. The two
agree to rounding (summation order; LAPACK vs the hand-written Cholesky).
"""

from __future__ import annotations

import numpy as np

from ..errors import ShapeError, SingularMatrixError
from . import _engine
from ._engine import FIELDS, LOG2PI, MAP_COV, CorrectionStep, _alloc, _not_pd_message, _shapes

__all__ = ["chol_np", "cov_numpy", "kalman_gain_numpy", "map_numpy", "model_call_loop"]


def chol_np(M: np.ndarray, mapping: int) -> np.ndarray:
    """numpy Cholesky of every block of ``M``; SingularMatrixError (naming the run) if one is not PD."""
    try:
        return np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        bad = np.flatnonzero(~np.all(np.linalg.eigvalsh(M) > 0, axis=-1))
        raise SingularMatrixError(_not_pd_message(mapping, int(bad[0]) if bad.size else 0)) from None


def map_numpy(mapping: int, D: np.ndarray, PCt: np.ndarray, M: np.ndarray | None, runs: int) -> np.ndarray:
    """numpy twin of :func:`map_step`: ``M`` (runs, n, m)."""
    if mapping == MAP_COV:
        chol_np(D, mapping)
        return np.swapaxes(np.linalg.solve(D, np.swapaxes(PCt, -1, -2)), -1, -2)
    return np.broadcast_to(M, (runs, *M.shape))  # type: ignore[union-attr]


def kalman_gain_numpy(S: np.ndarray, PCt: np.ndarray) -> np.ndarray:
    """``K = P C^T S^-1`` for every run (numpy)."""
    return np.swapaxes(np.linalg.solve(S, np.swapaxes(PCt, -1, -2)), -1, -2)


def cov_numpy(
    correct: CorrectionStep,
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
    A: np.ndarray | None = None,
    Bu: np.ndarray | None = None,
    xp_in: np.ndarray | None = None,
    F_in: np.ndarray | None = None,
) -> dict[str, np.ndarray | None]:
    """numpy twin of :func:`cov_loop`: vectorized over runs, a loop over samples; in place.

    Linear when ``A`` and ``Bu`` (1|runs, K, n) = B u(k) are given; otherwise ``xp_in`` (runs, n)
    and ``F_in`` (runs, n, n) are the prediction and Jacobian of the single sample (K = 1).
    """
    runs, K, m = z.shape
    n = x.shape[1]
    flags, out = _alloc(keep, _shapes(runs, K, n, m))
    CT = C.T
    eye = np.eye(n)
    for k in range(K):
        if A is not None:
            F = A
            xp = x @ A.T + Bu[:, k]  # type: ignore[index]
        else:
            F = F_in
            xp = np.array(xp_in, dtype=float)
        Pp = F @ P @ np.swapaxes(F, -1, -2) + Q  # type: ignore[operator]
        e = z[:, k] - xp @ CT
        PCt = Pp @ CT
        D = C @ PCt
        S = D + R
        L = chol_np(S, correct.mapping)
        w = np.linalg.solve(S, e[..., None])[..., 0]
        ll = -0.5 * (m * LOG2PI + 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1))
        ll = ll - 0.5 * np.einsum("ri,ri->r", e, w)
        Kg, x_new = correct.numpy(e, ep, epp, xp, PCt, D, S, C, F)
        x[...] = x_new
        IKC = eye - Kg @ C
        P[...] = IKC @ Pp @ np.swapaxes(IKC, -1, -2) + Kg @ R @ np.swapaxes(Kg, -1, -2)
        epp[...] = ep
        ep[...] = z[:, k] - x @ CT
        for f, flag, val in zip(FIELDS, flags, (xp, x, e, S, ll, ep, Pp, P), strict=True):
            if flag:
                out[f][:, k] = val
    return {f: (out[f] if f in keep else None) for f in FIELDS}


def model_call_loop(
    model: object,
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

    Each sample's prediction comes from the model's Python methods; the rest of the step is the
    compiled loop (``compiled``, one sample at a time) or :func:`cov_numpy`. ``x``, ``P``, ``ep``,
    ``epp`` are updated in place; the outputs of every sample are concatenated along axis 1.

    Raises
    ------
    ShapeError
        ``transition`` or ``jacobian`` returned the wrong shape.
    """
    steps = []
    shared_u = u.shape[0] == 1
    for k in range(z.shape[1]):
        # one input for every run as (p,), so a model's compiled batched kernel applies (eha4)
        uk = u[0, k] if shared_u else u[:, k]
        xp = np.asarray(model.transition(x, uk), dtype=float)  # type: ignore[attr-defined]
        F = np.asarray(model.jacobian(x, uk), dtype=float)  # type: ignore[attr-defined]
        if xp.shape != x.shape or F.shape != (*x.shape, x.shape[1]):
            raise ShapeError(
                f"model.transition/jacobian must return {x.shape} and {(*x.shape, x.shape[1])}; "
                f"got {xp.shape} and {F.shape}"
            )
        F = np.broadcast_to(F, (*x.shape, x.shape[1]))
        zk, given = z[:, k : k + 1], {"xp_in": xp, "F_in": F}
        if compiled:
            steps.append(
                _engine.cov_loop(corr, None, x, P, ep, epp, zk, u[:, k : k + 1], C, Q, R, keep, **given)
            )
        else:
            steps.append(cov_numpy(corr, x, P, ep, epp, zk, C, Q, R, keep, **given))
    res = {
        f: (None if steps[0][f] is None else np.concatenate([s[f] for s in steps], axis=1)) for f in steps[0]
    }
    return res
