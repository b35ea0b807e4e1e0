"""Linear-algebra steps of the covariance filters (private): Cholesky, solves, products, prediction.

Small steps of :mod:`chatterspec._jit`, inlined by the loops of :mod:`chatterspec.filters._engine`,
the banks (:mod:`chatterspec.filters.imm`, :mod:`chatterspec.filters.smm_svsf`) and the
reduced-order form (:mod:`chatterspec.filters._luen`). Every sum runs from its first term (or 0.0)
over q = 0, 1, ...: the same order as the loops these steps replaced, hence the same bits.
"""

from __future__ import annotations

import numpy as np

from .. import _jit

__all__ = [
    "chol_solve_step",
    "chol_step",
    "gain_update_step",
    "half_logdet_step",
    "innovation_step",
    "joseph_step",
    "loglik_given_step",
    "loglik_step",
    "predict_cov_step",
    "product_step",
    "residual_step",
]


@_jit.step
def chol_step(A: np.ndarray, L: np.ndarray, m: int) -> bool:  # pragma: no cover - compiled
    """Lower Cholesky factor of the (m, m) matrix A into L; False if A is not positive definite."""
    for i in range(m):
        for j in range(i + 1):
            s = A[i, j]
            for q in range(j):
                s -= L[i, q] * L[j, q]
            if i == j:
                if not s > 0.0:
                    return False
                L[i, i] = np.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    return True


@_jit.step
def chol_solve_step(
    L: np.ndarray, B: np.ndarray, X: np.ndarray, m: int, ncol: int
) -> None:  # pragma: no cover
    """X = (L L^T)^-1 B for B of shape (m, ncol): forward then back substitution, column by column."""
    for c in range(ncol):
        for i in range(m):
            s = B[i, c]
            for q in range(i):
                s -= L[i, q] * X[q, c]
            X[i, c] = s / L[i, i]
        for i in range(m - 1, -1, -1):
            s = X[i, c]
            for q in range(i + 1, m):
                s -= L[q, i] * X[q, c]
            X[i, c] = s / L[i, i]


@_jit.step
def product_step(
    A: np.ndarray, B: np.ndarray, out: np.ndarray, ni: int, nj: int, nq: int, a_t: bool, b_t: bool
) -> None:  # pragma: no cover - compiled
    """``out[i, j] = sum_q A[i, q] B[q, j]`` from 0.0, q = 0, 1, ...; ``a_t``/``b_t``: read A^T / B^T."""
    for i in range(ni):
        for j in range(nj):
            s = 0.0
            for q in range(nq):
                s += (A[q, i] if a_t else A[i, q]) * (B[j, q] if b_t else B[q, j])
            out[i, j] = s


@_jit.step
def residual_step(zk: np.ndarray, C: np.ndarray, x: np.ndarray, out: np.ndarray, n: int, m: int) -> None:
    """``out = z - C x`` (the innovation of a prediction, or the a-posteriori residual)."""
    for i in range(m):
        s = zk[i]
        for j in range(n):
            s -= C[i, j] * x[j]
        out[i] = s


@_jit.step
def gain_update_step(xp: np.ndarray, KgT: np.ndarray, e: np.ndarray, x: np.ndarray, n: int, m: int) -> None:
    """``x = x(k+1|k) + K e`` with the gain given as ``K^T`` (m, n)."""
    for i in range(n):
        s = xp[i]
        for j in range(m):
            s += KgT[j, i] * e[j]
        x[i] = s


@_jit.step
def predict_cov_step(
    F: np.ndarray, P: np.ndarray, Q: np.ndarray, T1: np.ndarray, Pp: np.ndarray, n: int
) -> None:
    """``Pp = F P F^T + Q`` (``T1 = F P`` first; the upper triangle summed, then mirrored)."""
    product_step(F, P, T1, n, n, n, False, False)
    for i in range(n):  # symmetric: upper triangle, mirrored
        for j in range(i, n):
            s = Q[i, j]
            for q in range(n):
                s += T1[i, q] * F[j, q]
            Pp[i, j] = s
            Pp[j, i] = s


@_jit.step
def innovation_step(
    zk: np.ndarray,
    xp: np.ndarray,
    Pp: np.ndarray,
    C: np.ndarray,
    R: np.ndarray,
    e: np.ndarray,
    PCt: np.ndarray,
    PCtT: np.ndarray,
    D: np.ndarray,
    S: np.ndarray,
    n: int,
    m: int,
) -> None:  # pragma: no cover - compiled
    """``e = z - C xp``, ``PCt = Pp C^T`` (and its transpose), ``D = C Pp C^T``, ``S = D + R``."""
    residual_step(zk, C, xp, e, n, m)
    product_step(Pp, C, PCt, n, m, n, False, True)
    for i in range(n):
        for j in range(m):
            PCtT[j, i] = PCt[i, j]
    product_step(C, PCt, D, m, m, n, False, False)
    for i in range(m):
        for j in range(m):
            S[i, j] = D[i, j] + R[i, j]


@_jit.step
def loglik_step(
    L: np.ndarray, e: np.ndarray, eb: np.ndarray, wv: np.ndarray, m: int
) -> float:  # pragma: no cover
    """``log N(e; 0, S)`` from the Cholesky factor ``L`` of ``S``: ``S^-1 e`` by :func:`chol_solve_step`
    (``e`` copied into the column ``eb`` (m, 1), solution in ``wv``), ``log det S = 2 sum log L_ii``
    (:func:`half_logdet_step`)."""
    return loglik_given_step(L, e, eb, wv, half_logdet_step(L, m), m)


@_jit.step
def half_logdet_step(L: np.ndarray, m: int) -> float:  # pragma: no cover - compiled
    """``sum_i log L_ii`` (half of ``log det S`` for the Cholesky factor ``L`` of ``S``), i = 0, 1, ..."""
    logdet = 0.0
    for i in range(m):
        logdet += np.log(L[i, i])
    return logdet


@_jit.step
def loglik_given_step(
    L: np.ndarray, e: np.ndarray, eb: np.ndarray, wv: np.ndarray, half_logdet: float, m: int
) -> float:  # pragma: no cover - compiled
    """:func:`loglik_step` with ``sum log L_ii`` given (the shared Kalman filter has it once per sample)."""
    for i in range(m):
        eb[i, 0] = e[i]
    chol_solve_step(L, eb, wv, m, 1)
    quad = 0.0
    for i in range(m):
        quad += e[i] * wv[i, 0]
    return -0.5 * (m * 1.8378770664093453 + 2.0 * half_logdet + quad)


@_jit.step
def joseph_step(
    KgT: np.ndarray,
    C: np.ndarray,
    Pp: np.ndarray,
    R: np.ndarray,
    T1: np.ndarray,
    IKC: np.ndarray,
    KR: np.ndarray,
    P: np.ndarray,
    n: int,
    m: int,
) -> None:  # pragma: no cover - compiled
    """Joseph form ``P = (I - K C) Pp (I - K C)^T + K R K^T`` with the gain given as ``K^T`` (m, n).

    Scratch ``T1`` (n, n) = ``(I - K C) Pp``, ``IKC`` (n, n), ``KR`` (n, m); the upper triangle is
    summed, then mirrored.
    """
    for i in range(n):
        for j in range(n):
            s = 1.0 if i == j else 0.0
            for q in range(m):
                s -= KgT[q, i] * C[q, j]
            IKC[i, j] = s
    product_step(IKC, Pp, T1, n, n, n, False, False)
    product_step(KgT, R, KR, n, m, m, True, False)
    for i in range(n):  # symmetric: upper triangle, mirrored
        for j in range(i, n):
            s = 0.0
            for q in range(n):
                s += T1[i, q] * IKC[j, q]
            for q in range(m):
                s += KR[i, q] * KgT[q, j]
            P[i, j] = s
            P[j, i] = s
