"""Linear Kalman filter with a shared, data-independent covariance (private).

For a :class:`~chatterspec.plants.models.LinearModel` started from one shared ``P0`` the
covariance and gain depend only on k: :func:`riccati` computes them once per sample for all
realizations (numpy), and :func:`kf_shared_states` runs the state recursion per realization
(compiled from the plant's and the per-run filter's steps, or numpy when
:func:`chatterspec._jit.enabled` is false).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .. import _jit
from ..plants.linear_steps import parameters, predict_step
from ._engine import FIELDS, LOG2PI, MAP_CONST, _alloc, gain_update_step, residual_step, store_step
from ._engine_numpy import chol_np as _chol_np
from .svsf_steps import rows_times as _rows_times

#: Sizes of :func:`_kf_shared_loop`, bound per model by :func:`_kf_shared_kernel` (0: read from the arrays).
NX = NZ = 0


def _kf_shared_loop(
    prm: np.ndarray,
    u: np.ndarray,
    z: np.ndarray,
    x: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    C: np.ndarray,
    KgT: np.ndarray,
    Sinv: np.ndarray,
    logdet: np.ndarray,
    flags: np.ndarray,
    outs: tuple[np.ndarray, ...],
) -> int:  # pragma: no cover - compiled
    """State recursion of the Kalman filter with a precomputed, shared gain sequence ``KgT`` (K, m, n).

    Per run and sample: the linear plant's prediction (:func:`~chatterspec.plants.linear_steps.predict_step`,
    ``prm`` of :func:`~chatterspec.plants.linear_steps.parameters`), the innovation, ``x = x(k+1|k)
    + K e``, the log-likelihood from ``Sinv`` and ``logdet``, the residuals: the steps of the per-run
    filter (:mod:`chatterspec.filters._engine`). ``outs``: the eight outputs of ``FIELDS`` (S and the
    covariances, which the shared path returns itself, empty and not flagged).
    """
    b = _jit.borrow
    prm, u, z, x, ep, epp, C, KgT, Sinv, logdet = (
        b(prm),
        b(u),
        b(z),
        b(x),
        b(ep),
        b(epp),
        b(C),
        b(KgT),
        b(Sinv),
        b(logdet),
    )
    o0, o1, o2, o3, o4, o5, o6, o7 = outs
    # borrowed: no reference counts per sample
    outs = (b(o0), b(o1), b(o2), b(o3), b(o4), b(o5), b(o6), b(o7))
    runs, K, _ = z.shape
    n = NX if NX > 0 else x.shape[1]
    m = NZ if NZ > 0 else z.shape[2]
    p = u.shape[2]
    shared_u = u.shape[0] == 1
    xp = _jit.scratch(n)
    e = _jit.scratch(m)
    xr = _jit.scratch(n)  # run r's state and residual, on the stack for the run (written back after it)
    epr = _jit.scratch(m)
    none2 = _jit.scratch2(0, 0)
    for r in range(runs):
        ur = 0 if shared_u else r
        for i in range(n):
            xr[i] = x[r, i]
        for i in range(m):
            epr[i] = ep[r, i]
        for k in range(K):
            predict_step(prm, xr, u[ur, k], xp, n, p)
            residual_step(z[r, k], C, xp, e, n, m)
            gain_update_step(xp, KgT[k], e, xr, n, m)
            quad = 0.0
            for i in range(m):
                s = 0.0
                for j in range(m):
                    s += Sinv[k, i, j] * e[j]
                quad += e[i] * s
            for i in range(m):
                epp[r, i] = epr[i]
            residual_step(z[r, k], C, xr, epr, n, m)
            ll = -0.5 * (m * 1.8378770664093453 + logdet[k] + quad)
            store_step(flags, outs, r, k, xp, xr, e, none2, ll, epr, none2, none2, n, m)
        for i in range(n):
            x[r, i] = xr[i]
        for i in range(m):
            ep[r, i] = epr[i]
    return 0


def _kf_shared_kernel(n: int, m: int) -> Callable[..., int]:
    """:func:`_kf_shared_loop` compiled for n states and m outputs (literal sizes up to
    :data:`chatterspec._jit.MAX_UNROLL`: the per-channel loops unrolled, as the per-run filters')."""
    return _jit.specialize_sizes(_kf_shared_loop, "kfshared", {"NX": n, "NZ": m})


def kf_shared_states(
    x: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    z: np.ndarray,
    u: np.ndarray,
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    Kg: np.ndarray,
    Sinv: np.ndarray,
    logdet: np.ndarray,
    keep: frozenset[str],
) -> dict[str, np.ndarray | None]:
    """State recursion of the linear KF with a shared gain sequence ``Kg`` (K, n, m); in place.

    ``u`` is (1 | runs, K, p); the numpy path sums ``B u`` as ``_rows_times`` does.
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
    KgT = np.ascontiguousarray(np.swapaxes(Kg, -1, -2))
    if _jit.enabled() and _jit.fits(n, m, vectors_only=True):
        c = np.ascontiguousarray
        _kf_shared_kernel(n, m)(
            parameters(A, B), c(u, dtype=float), c(z), x, ep, epp, c(C), KgT, c(Sinv), c(logdet), flags,
            tuple(out[f] for f in FIELDS),
        )  # fmt: skip
    else:
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
