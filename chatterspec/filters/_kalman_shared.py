"""Linear Kalman filter with a shared, data-independent covariance (private).

For a :class:`~chatterspec.plants.models.LinearModel` started from one shared ``P0`` the
covariance and gain depend only on k: :func:`riccati` computes them once per sample for all
realizations, and :func:`kf_shared_states` runs the state recursion per realization (compiled
kernel, or numpy when :func:`chatterspec._jit.enabled` is false).
"""

from __future__ import annotations

import numpy as np

from .. import _jit
from ._engine import FIELDS, LOG2PI, MAP_CONST, _alloc
from ._engine import chol_np as _chol_np


@_jit.njit
def _kf_shared_kernel(
    x, ep, epp, z, Bu, A, C, KgT, Sinv, logdet, flags, o_xprior, o_xpost, o_e, o_ll, o_ep
):  # pragma: no cover
    """State recursion of the Kalman filter with a precomputed, shared gain sequence."""
    runs, K, m = z.shape
    n = x.shape[1]
    shared_bu = Bu.shape[0] == 1
    xp = np.empty(n)
    e = np.empty(m)
    for r in range(runs):
        br = 0 if shared_bu else r
        for k in range(K):
            for i in range(n):
                s = Bu[br, k, i]
                for j in range(n):
                    s += A[i, j] * x[r, j]
                xp[i] = s
            for i in range(m):
                s = z[r, k, i]
                for j in range(n):
                    s -= C[i, j] * xp[j]
                e[i] = s
            for i in range(n):
                s = xp[i]
                for j in range(m):
                    s += KgT[k, j, i] * e[j]
                x[r, i] = s
            quad = 0.0
            for i in range(m):
                s = 0.0
                for j in range(m):
                    s += Sinv[k, i, j] * e[j]
                quad += e[i] * s
            for i in range(m):
                epp[r, i] = ep[r, i]
                s = z[r, k, i]
                for j in range(n):
                    s -= C[i, j] * x[r, j]
                ep[r, i] = s
            if flags[0]:
                for i in range(n):
                    o_xprior[r, k, i] = xp[i]
            if flags[1]:
                for i in range(n):
                    o_xpost[r, k, i] = x[r, i]
            if flags[2]:
                for i in range(m):
                    o_e[r, k, i] = e[i]
            if flags[4]:
                o_ll[r, k] = -0.5 * (m * 1.8378770664093453 + logdet[k] + quad)
            if flags[5]:
                for i in range(m):
                    o_ep[r, k, i] = ep[r, i]
    return 0


def kf_shared_states(
    x: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    z: np.ndarray,
    Bu: np.ndarray,
    A: np.ndarray,
    C: np.ndarray,
    Kg: np.ndarray,
    Sinv: np.ndarray,
    logdet: np.ndarray,
    keep: frozenset[str],
) -> dict[str, np.ndarray | None]:
    """State recursion of the linear KF with a shared gain sequence ``Kg`` (K, n, m); in place."""
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
    KgT = np.ascontiguousarray(np.swapaxes(Kg, -1, -2))
    if _jit.enabled():
        _kf_shared_kernel(
            x,
            ep,
            epp,
            np.ascontiguousarray(z),
            np.ascontiguousarray(Bu),
            np.ascontiguousarray(A),
            np.ascontiguousarray(C),
            KgT,
            np.ascontiguousarray(Sinv),
            np.ascontiguousarray(logdet),
            flags,
            out["x_prior"],
            out["x_post"],
            out["innovation"],
            out["loglik"],
            out["e_post"],
        )
    else:
        AT, CT = A.T, C.T
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
    eye = np.eye(n)
    for k in range(K):
        Pp = A @ P @ A.T + Q
        PCt = Pp @ C.T
        S = C @ PCt + R
        L = _chol_np(S, MAP_CONST)
        Sinv = np.linalg.inv(S)
        Kg = PCt @ Sinv
        IKC = eye - Kg @ C
        P = IKC @ Pp @ IKC.T + Kg @ R @ Kg.T
        Pp_all[k], Pq_all[k], S_all[k], Kg_all[k], Sinv_all[k] = Pp, P, S, Kg, Sinv
        logdet[k] = 2.0 * np.sum(np.log(np.diag(L)))
    return P, Pp_all, Pq_all, S_all, Kg_all, Sinv_all, logdet
