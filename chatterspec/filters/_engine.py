"""The shared per-sample recursion of the covariance-carrying filters (private).

One step, for every realization (notation of ``docs/design.md`` §7)::

    x(k+1|k) = f(x(k|k), u(k)),            F = df/dx at x(k|k)      (linear: A x + B u, F = A)
    P(k+1|k) = F P(k|k) F^T + Q
    e = z(k+1) - C x(k+1|k),   S = C P(k+1|k) C^T + R,   loglik = log N(e; 0, S)
    correction:  dx = M dz,    gain for the covariance  K = M diag(g)  (KF: K = P C^T S^-1, dx = K e)
    P(k+1|k+1) = (I - K C) P(k+1|k) (I - K C)^T + K R K^T            (Joseph form)
    x(k+1|k+1) = x(k+1|k) + dx,   e(k+1|k+1) = z(k+1) - C x(k+1|k+1)

``kind`` selects the correction: 0 = Kalman gain; 1 = SVSF with covariance, division-free
form of [SMM] eq (2.5): g_i = (|e_i| + gamma_i |e_i(k|k)|) / max(|e_i|, psi_i), dz = g o e;
2 = dynamic second-order SVSF, [DETC] eq (9): dz = e - (gamma + Lambda) e(k|k) +
gamma Lambda e(k-1|k-1), g = clip(dz / e, lo, hi) (1 where e = 0; covariance only);
3 = SVSF with the variable boundary layer: the Kalman gain when the VBL
psi_vbl,i = (|e_i| + gamma_i |e_i(k|k)|) / (C K_KF)_ii is <= psi_i in every channel, else kind 1.
``mapping`` gives M: 0 = a constant matrix (C^-1 for ``full``, C^+ for ``pinv``),
1 = ``cov``: M = P(k+1|k) C^T (C P(k+1|k) C^T)^-1, 2 = ``luen``: the reduced-order Luenberger
form (:func:`chatterspec.filters._luen.luen_correction`; numpy path only). The linear KF with a
shared covariance has its own state kernel in :mod:`chatterspec.filters._kalman_shared`.

There are two implementations of the same arithmetic: :func:`_cov_kernel` (scalar loops over
runs and time, compiled by :func:`chatterspec._jit.njit`) and :func:`cov_numpy` (vectorized
over runs, a Python loop over time), used when :func:`chatterspec._jit.enabled` is false.
They agree to rounding (different summation order / LAPACK vs hand-written Cholesky).
"""

from __future__ import annotations

import numpy as np

from .. import _jit
from ..errors import SingularMatrixError

KF, SVSF1, SVSF2, VBL = 0, 1, 2, 3
MAP_CONST, MAP_COV, MAP_LUEN = 0, 1, 2
LOG2PI = float(np.log(2.0 * np.pi))
FIELDS = ("x_prior", "x_post", "innovation", "S", "loglik", "e_post", "P_prior", "P_post")


# ----------------------------------------------------------------------------- compiled kernels
@_jit.njit
def _chol(A, L, m):  # pragma: no cover - compiled
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


@_jit.njit
def _chol_solve_rows(L, B, X, m, ncol):  # pragma: no cover - compiled
    """X = (L L^T)^-1 B for B of shape (m, ncol)."""
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


@_jit.njit
def _cov_kernel(
    kind,
    mapping,
    linear,
    x,
    P,
    ep,
    epp,
    z,
    Bu,
    A,
    xp_in,
    F_in,
    C,
    Q,
    R,
    M_const,
    gamma,
    lam,
    psi,
    lo,
    hi,
    flags,
    o_xprior,
    o_xpost,
    o_e,
    o_S,
    o_ll,
    o_ep,
    o_Pprior,
    o_Ppost,
):  # pragma: no cover - compiled
    """The step of the module docstring over runs (outer) and time (inner); returns 0 or 1 + bad run."""
    runs, K, m = z.shape
    n = x.shape[1]
    shared_bu = Bu.shape[0] == 1
    xp = np.empty(n)
    T1 = np.empty((n, n))
    Pp = np.empty((n, n))
    PCt = np.empty((n, m))
    PCtT = np.empty((m, n))
    S = np.empty((m, m))
    D = np.empty((m, m))
    L = np.zeros((m, m))
    e = np.empty(m)
    w = np.empty((m, 1))
    eb = np.empty((m, 1))
    KgT = np.empty((m, n))
    MpT = np.empty((m, n))
    dz = np.empty(m)
    g = np.empty(m)
    IKC = np.empty((n, n))
    KR = np.empty((n, m))
    for r in range(runs):
        br = 0 if shared_bu else r
        for k in range(K):
            # prediction: x(k+1|k), P(k+1|k) = F P F^T + Q
            if linear:
                F = A
                for i in range(n):
                    s = Bu[br, k, i]
                    for j in range(n):
                        s += A[i, j] * x[r, j]
                    xp[i] = s
            else:
                F = F_in[r]
                for i in range(n):
                    xp[i] = xp_in[r, i]
            for i in range(n):
                for j in range(n):
                    s = 0.0
                    for q in range(n):
                        s += F[i, q] * P[r, q, j]
                    T1[i, j] = s
            for i in range(n):  # symmetric: upper triangle, mirrored
                for j in range(i, n):
                    s = Q[i, j]
                    for q in range(n):
                        s += T1[i, q] * F[j, q]
                    Pp[i, j] = s
                    Pp[j, i] = s
            # innovation, S, log-likelihood
            for i in range(m):
                s = z[r, k, i]
                for j in range(n):
                    s -= C[i, j] * xp[j]
                e[i] = s
                eb[i, 0] = s
            for i in range(n):
                for j in range(m):
                    s = 0.0
                    for q in range(n):
                        s += Pp[i, q] * C[j, q]
                    PCt[i, j] = s
                    PCtT[j, i] = s
            for i in range(m):
                for j in range(m):
                    s = 0.0
                    for q in range(n):
                        s += C[i, q] * PCt[q, j]
                    D[i, j] = s
                    S[i, j] = s + R[i, j]
            if not _chol(S, L, m):
                return 1 + r
            _chol_solve_rows(L, eb, w, m, 1)
            quad = 0.0
            logdet = 0.0
            for i in range(m):
                quad += e[i] * w[i, 0]
                logdet += np.log(L[i, i])
            ll = -0.5 * (m * 1.8378770664093453 + 2.0 * logdet + quad)
            # correction
            use_kf = kind == KF
            if kind == VBL:
                # Kalman gain where psi_vbl,i = (|e_i| + gamma_i |e_i(k|k)|) / (C K_KF)_ii <= psi_i for all i
                _chol_solve_rows(L, PCtT, KgT, m, n)
                use_kf = True
                for i in range(m):
                    ck = 0.0
                    for q in range(n):
                        ck += C[i, q] * KgT[i, q]
                    need = abs(e[i]) + gamma[i] * abs(ep[r, i])
                    if not (ck > 0.0 and need <= psi[i] * ck):
                        use_kf = False
            elif kind == KF:
                _chol_solve_rows(L, PCtT, KgT, m, n)
            if use_kf:
                for i in range(n):
                    s = xp[i]
                    for j in range(m):
                        s += KgT[j, i] * e[j]
                    x[r, i] = s
            else:
                if mapping == MAP_COV:
                    if not _chol(D, L, m):
                        return 1 + r
                    _chol_solve_rows(L, PCtT, MpT, m, n)
                else:
                    for i in range(m):
                        for j in range(n):
                            MpT[i, j] = M_const[j, i]
                for i in range(m):
                    if kind != SVSF2:
                        a = abs(e[i])
                        den = a if a > psi[i] else psi[i]
                        g[i] = (a + gamma[i] * abs(ep[r, i])) / den
                        dz[i] = g[i] * e[i]
                    else:
                        dz[i] = e[i] - (gamma[i] + lam[i]) * ep[r, i] + gamma[i] * lam[i] * epp[r, i]
                        if e[i] != 0.0:
                            gi = dz[i] / e[i]
                            g[i] = lo if gi < lo else (hi if gi > hi else gi)
                        else:
                            g[i] = 1.0
                for i in range(m):
                    for j in range(n):
                        KgT[i, j] = MpT[i, j] * g[i]
                for i in range(n):
                    s = xp[i]
                    for j in range(m):
                        s += MpT[j, i] * dz[j]
                    x[r, i] = s
            # Joseph form: P = (I - K C) Pp (I - K C)^T + K R K^T
            for i in range(n):
                for j in range(n):
                    s = 1.0 if i == j else 0.0
                    for q in range(m):
                        s -= KgT[q, i] * C[q, j]
                    IKC[i, j] = s
            for i in range(n):
                for j in range(n):
                    s = 0.0
                    for q in range(n):
                        s += IKC[i, q] * Pp[q, j]
                    T1[i, j] = s
            for i in range(n):
                for j in range(m):
                    s = 0.0
                    for q in range(m):
                        s += KgT[q, i] * R[q, j]
                    KR[i, j] = s
            for i in range(n):  # symmetric: upper triangle, mirrored
                for j in range(i, n):
                    s = 0.0
                    for q in range(n):
                        s += T1[i, q] * IKC[j, q]
                    for q in range(m):
                        s += KR[i, q] * KgT[q, j]
                    P[r, i, j] = s
                    P[r, j, i] = s
            # residuals
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
            if flags[3]:
                for i in range(m):
                    for j in range(m):
                        o_S[r, k, i, j] = S[i, j]
            if flags[4]:
                o_ll[r, k] = ll
            if flags[5]:
                for i in range(m):
                    o_ep[r, k, i] = ep[r, i]
            if flags[6]:
                for i in range(n):
                    for j in range(n):
                        o_Pprior[r, k, i, j] = Pp[i, j]
            if flags[7]:
                for i in range(n):
                    for j in range(n):
                        o_Ppost[r, k, i, j] = P[r, i, j]
    return 0


# ----------------------------------------------------------------------------- drivers
def _alloc(
    keep: frozenset[str], shapes: dict[str, tuple[int, ...]]
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    flags = np.array([f in keep for f in FIELDS], dtype=np.bool_)
    arrays = {}
    for f in FIELDS:
        arrays[f] = np.empty(shapes[f] if f in keep else (0,) * len(shapes[f]))
    return flags, arrays


def cov_step(
    kind: int,
    mapping: int,
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
    Bu: np.ndarray | None = None,
    A: np.ndarray | None = None,
    xp_in: np.ndarray | None = None,
    F_in: np.ndarray | None = None,
    M_const: np.ndarray | None = None,
    gamma: np.ndarray | None = None,
    lam: np.ndarray | None = None,
    psi: np.ndarray | None = None,
    lo: float = 0.0,
    hi: float = 2.0,
    luen: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, np.ndarray | None]:
    """Advance ``x, P, ep, epp`` (modified in place) over ``z`` (runs, K, m).

    Linear when ``A`` and ``Bu`` (1|runs, K, n) are given; otherwise ``xp_in`` (runs, n) and
    ``F_in`` (runs, n, n) are the prediction and Jacobian of the single sample (K = 1).
    """
    runs, K, m = z.shape
    n = x.shape[1]
    linear = A is not None
    shapes = {
        "x_prior": (runs, K, n),
        "x_post": (runs, K, n),
        "innovation": (runs, K, m),
        "S": (runs, K, m, m),
        "loglik": (runs, K),
        "e_post": (runs, K, m),
        "P_prior": (runs, K, n, n),
        "P_post": (runs, K, n, n),
    }
    flags, out = _alloc(keep, shapes)
    zeros_m = np.zeros(m)
    args = dict(
        gamma=zeros_m if gamma is None else gamma,
        lam=zeros_m if lam is None else lam,
        psi=np.ones(m) if psi is None else psi,
        M_const=np.zeros((n, m)) if M_const is None else np.ascontiguousarray(M_const),
    )
    if linear:
        Bu, A = np.ascontiguousarray(Bu), np.ascontiguousarray(A)
        xp_in, F_in = np.zeros((1, n)), np.zeros((1, n, n))
    else:
        if K != 1:
            raise ValueError("nonlinear steps take one sample at a time")
        Bu, A = np.zeros((1, 1, n)), np.zeros((n, n))
        xp_in, F_in = np.ascontiguousarray(xp_in, dtype=float), np.ascontiguousarray(F_in, dtype=float)
    if _jit.enabled() and mapping != MAP_LUEN:
        status = _cov_kernel(
            kind,
            mapping,
            linear,
            x,
            P,
            ep,
            epp,
            np.ascontiguousarray(z),
            Bu,
            A,
            xp_in,
            F_in,
            np.ascontiguousarray(C),
            np.ascontiguousarray(Q),
            np.ascontiguousarray(R),
            args["M_const"],
            args["gamma"],
            args["lam"],
            args["psi"],
            float(lo),
            float(hi),
            flags,
            out["x_prior"],
            out["x_post"],
            out["innovation"],
            out["S"],
            out["loglik"],
            out["e_post"],
            out["P_prior"],
            out["P_post"],
        )
        if status:
            raise SingularMatrixError(_not_pd_message(mapping, status - 1))
    else:
        _cov_numpy(
            kind,
            mapping,
            linear,
            x,
            P,
            ep,
            epp,
            z,
            Bu,
            A,
            xp_in,
            F_in,
            C,
            Q,
            R,
            lo,
            hi,
            flags,
            out,
            luen=luen,
            **args,
        )
    return {f: (out[f] if f in keep else None) for f in FIELDS}


def _not_pd_message(mapping: int, run: int) -> str:
    what = "S = C P C^T + R" if mapping != MAP_COV else "S = C P C^T + R or C P C^T (the 'cov' mapping)"
    return (
        f"{what} is not positive definite in run {run}: check that R (and P0) are positive definite "
        "and that the model does not diverge"
    )


def _chol_np(M: np.ndarray, mapping: int) -> np.ndarray:
    try:
        return np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        bad = np.flatnonzero(~np.all(np.linalg.eigvalsh(M) > 0, axis=-1))
        raise SingularMatrixError(_not_pd_message(mapping, int(bad[0]) if bad.size else 0)) from None


def _cov_numpy(
    kind,
    mapping,
    linear,
    x,
    P,
    ep,
    epp,
    z,
    Bu,
    A,
    xp_in,
    F_in,
    C,
    Q,
    R,
    lo,
    hi,
    flags,
    out,
    *,
    gamma,
    lam,
    psi,
    M_const,
    luen=None,
):
    """Numpy twin of :func:`_cov_kernel`: vectorized over runs, loop over time."""
    runs, K, m = z.shape
    n = x.shape[1]
    CT = C.T
    eye = np.eye(n)
    for k in range(K):
        if linear:
            F = A
            xp = x @ A.T + Bu[:, k]
        else:
            F = F_in
            xp = np.array(xp_in, dtype=float)
        Pp = F @ P @ np.swapaxes(F, -1, -2) + Q
        e = z[:, k] - xp @ CT
        PCt = Pp @ CT
        D = C @ PCt
        S = D + R
        L = _chol_np(S, mapping)
        w = np.linalg.solve(S, e[..., None])[..., 0]
        ll = -0.5 * (m * LOG2PI + 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1))
        ll = ll - 0.5 * np.einsum("ri,ri->r", e, w)
        if kind in (KF, VBL):
            Kkf = np.swapaxes(np.linalg.solve(S, np.swapaxes(PCt, -1, -2)), -1, -2)
        if kind == KF:
            Kg = Kkf
            x[...] = xp + np.einsum("rij,rj->ri", Kg, e)
        elif mapping == MAP_LUEN:
            from ._luen import luen_correction  # deferred: _luen imports this module's constants

            Kg, dx = luen_correction(kind, F, e, ep, epp, luen[0], luen[1], gamma, lam, psi, lo, hi)
            x[...] = xp + dx
        else:
            if mapping == MAP_COV:
                _chol_np(D, mapping)
                Mp = np.swapaxes(np.linalg.solve(D, np.swapaxes(PCt, -1, -2)), -1, -2)
            else:
                Mp = np.broadcast_to(M_const, (runs, n, m))
            if kind != SVSF2:
                a = np.abs(e)
                g = (a + gamma * np.abs(ep)) / np.maximum(a, psi)
                dz = g * e
            else:
                dz = e - (gamma + lam) * ep + gamma * lam * epp
                with np.errstate(divide="ignore", invalid="ignore"):
                    g = np.where(e != 0.0, np.clip(dz / np.where(e != 0.0, e, 1.0), lo, hi), 1.0)
            Kg = Mp * g[:, None, :]
            x[...] = xp + np.einsum("rij,rj->ri", Mp, dz)
            if kind == VBL:
                ck = np.einsum("iq,rqi->ri", C, Kkf)
                use_kf = np.all((ck > 0.0) & (np.abs(e) + gamma * np.abs(ep) <= psi * ck), axis=1)
                Kg = np.where(use_kf[:, None, None], Kkf, Kg)
                x[...] = np.where(use_kf[:, None], xp + np.einsum("rij,rj->ri", Kkf, e), x)
        IKC = eye - Kg @ C
        P[...] = IKC @ Pp @ np.swapaxes(IKC, -1, -2) + Kg @ R @ np.swapaxes(Kg, -1, -2)
        epp[...] = ep
        ep[...] = z[:, k] - x @ CT
        for f, flag, val in zip(FIELDS, flags, (xp, x, e, S, ll, ep, Pp, P), strict=True):
            if flag:
                out[f][:, k] = val
