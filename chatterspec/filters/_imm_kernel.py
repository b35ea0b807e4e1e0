"""Compiled fused IMM step: mixing, mode-matched predict/update, likelihoods, combination (private).

One sample of :meth:`chatterspec.filters.multiple_model.IMM.update` for every realization, in one
compiled loop over runs (outer) and time (inner), instead of three protocol ``update`` calls and a
dozen numpy calls on (runs, 3, 4) arrays per sample. The arithmetic is that of the protocol path
([IMM] eq 15-33 as corrected in ``docs/design.md`` §7.6)::

    (19) c_j = sum_i pi_ij mu_i,  c_j >= 1e-300   (18) w_ij = mu_i pi_ij / c_j
    (20) x_0j = sum_i w_ij x_i                    (21) P_0j = sum_i w_ij [P_i + (x_i - x_0j)(.)^T]
    (22)-(28) the step of :func:`chatterspec.filters._engine._cov_kernel` from (x_0j, P_0j) with
         e(k|k) = z(k) - C_0 x_0j (the stored residual before the first sample), kind 0 (Kalman
         gain, EKF), 1 (SVSF-cov, [SMM] eq 2.5) or 2 (second-order SVSF, [DETC] eq 9)
    (29) log N(e_j; 0, S_j) on the correlation-scaled S (eigenvalue floor 1e-12, see below)
    (30) mu_j ∝ c_j Lambda_j in the log domain, optional floor
    (31)-(33) x = sum_j mu_j x_j,  P = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]

Supported modes (:func:`chatterspec.filters.multiple_model` checks them, else the protocol path):
models of the nonlinear EHA (:func:`chatterspec.plants.eha4.eha4`, whose compiled
``_step_kernel`` / ``_jacobian_kernel`` are called per mode with that mode's coefficients) or
:class:`~chatterspec.plants.models.LinearModel` (``A x + B u``, ``F = A``); filters
:class:`~chatterspec.filters.kalman.ExtendedKalmanFilter`,
:class:`~chatterspec.filters.svsf_cov.SVSFCov` (not ``vbl``, not ``luen``) and
:class:`~chatterspec.filters.svsf2.SecondOrderSVSF` (not ``luen``).

**Likelihood.** :func:`chatterspec.filters.multiple_model.log_gaussian` floors the eigenvalues of the
correlation matrix ``Sc`` at 1e-12. The kernel takes the Cholesky factor of ``Sc`` instead of its
eigendecomposition when ``1 / trace(Sc^-1)`` -- a lower bound of the smallest eigenvalue -- exceeds
1e-10, so the floor cannot be active; then ``quad = ec^T Sc^-1 ec`` and ``log det Sc = 2 sum log L_ii``
are the same numbers up to rounding (a few ulps). Otherwise it calls ``np.linalg.eigh`` like the numpy
function and applies the floor.

**Equality.** The kernel is not bit-identical to the protocol path: numpy evaluates ``mu @ pi``, the
mixing and combination ``einsum`` and the likelihood (eigh) in other summation orders than the
kernel's loops. The differences are a few ulps per sample; the tests bound them (tolerances stated
there). Runs are independent and every sample starts from the stored state, so any chunking of runs
or samples gives the same bits as one call.
"""

from __future__ import annotations

import numpy as np

from .. import _jit
from ..plants.eha4 import _jacobian_kernel, _step_kernel

#: Model kinds of the fused kernel.
MODEL_EHA4, MODEL_LINEAR = 0, 1
#: Lower bound of the smallest eigenvalue of Sc above which the Cholesky likelihood is used.
CHOL_SAFE = 1e-10
_EIG_FLOOR = 1e-12
_TINY = float(np.finfo(float).tiny)
_LOG2PI = 1.8378770664093453


@_jit.njit
def _chol_into(A, L, m):  # pragma: no cover - compiled
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
def _invert(A, Ainv, m):  # pragma: no cover - compiled
    """Ainv = A^-1 by Gauss-Jordan elimination with partial pivoting; False if A is singular."""
    W = np.empty((m, 2 * m))
    for i in range(m):
        for j in range(m):
            W[i, j] = A[i, j]
            W[i, m + j] = 1.0 if i == j else 0.0
    for c in range(m):
        piv = c
        for i in range(c + 1, m):
            if abs(W[i, c]) > abs(W[piv, c]):
                piv = i
        if W[piv, c] == 0.0:
            return False
        if piv != c:
            for j in range(2 * m):
                t = W[c, j]
                W[c, j] = W[piv, j]
                W[piv, j] = t
        d = W[c, c]
        for j in range(2 * m):
            W[c, j] = W[c, j] / d
        for i in range(m):
            if i != c:
                f = W[i, c]
                if f != 0.0:
                    for j in range(2 * m):
                        W[i, j] = W[i, j] - f * W[c, j]
    for i in range(m):
        for j in range(m):
            Ainv[i, j] = W[i, m + j]
    return True


@_jit.njit
def _solve_col(L, b, out, m):  # pragma: no cover - compiled
    """out = (L L^T)^-1 b for a vector b."""
    for i in range(m):
        s = b[i]
        for q in range(i):
            s -= L[i, q] * out[q]
        out[i] = s / L[i, i]
    for i in range(m - 1, -1, -1):
        s = out[i]
        for q in range(i + 1, m):
            s -= L[q, i] * out[q]
        out[i] = s / L[i, i]


@_jit.njit
def _log_gaussian_1(e, S, m, Sc, L, ec, col, tmp):  # pragma: no cover - compiled
    """``log N(e; 0, S)`` of one innovation, as :func:`~chatterspec.filters.multiple_model.log_gaussian`."""
    logd = 0.0
    for i in range(m):
        di = S[i, i]
        if not di > _TINY:
            di = _TINY
        d = np.sqrt(di)
        tmp[i] = d
        ec[i] = e[i] / d
        logd += np.log(d)
    for i in range(m):
        for j in range(m):
            Sc[i, j] = S[i, j] / (tmp[i] * tmp[j])
    ok = _chol_into(Sc, L, m)
    if ok:
        tr = 0.0  # trace(Sc^-1) = sum_i (Sc^-1)_ii
        for i in range(m):
            for q in range(m):
                col[q] = 1.0 if q == i else 0.0
            _solve_col(L, col, tmp[m:], m)
            tr += tmp[m + i]
        ok = tr > 0.0 and 1.0 / tr > CHOL_SAFE
    if ok:
        _solve_col(L, ec, col, m)
        quad = 0.0
        logdet = 0.0
        for i in range(m):
            quad += ec[i] * col[i]
            logdet += np.log(L[i, i])
        logdet = 2.0 * logdet
    else:  # the eigenvalue floor may be active: the numpy function's own arithmetic
        w, V = np.linalg.eigh(Sc)
        quad = 0.0
        logdet = 0.0
        for j in range(m):
            wj = w[j] if w[j] > _EIG_FLOOR else _EIG_FLOOR
            p = 0.0
            for i in range(m):
                p += V[i, j] * ec[i]
            quad += p * p / wj
            logdet += np.log(wj)
    return -0.5 * (quad + logdet + 2.0 * logd + m * _LOG2PI)


@_jit.njit
def _imm_kernel(
    model_kind,
    coef,
    A,
    B,
    kind,
    mapping,
    Q,
    C,
    R,
    M_const,
    Tm,
    Tinv,
    gamma,
    lam,
    psi,
    lo,
    hi,
    pi,
    floor,
    z,
    u,
    first,
    mu,
    xs,
    Ps,
    eps,
    epps,
    zl,
    x,
    P,
    o_x,
    o_mu,
    o_ll,
    o_P,
    o_mx,
):  # pragma: no cover - compiled
    """The fused IMM step of the module docstring; state arrays updated in place.

    Returns 0, ``1 + run`` when an innovation covariance (or the ``cov`` mapping's ``C P C^T``) is
    not positive definite, ``-(1 + run)`` when every mode likelihood is zero or non-finite, or
    ``-(1 + runs + run)`` when the ``luen`` form meets a singular ``Phi12``.
    """
    runs, K, m = z.shape
    nm = mu.shape[1]
    n = x.shape[1]
    p = u.shape[2]
    shared_u = u.shape[0] == 1
    want_P = o_P.shape[0] > 0
    want_mx = o_mx.shape[0] > 0
    c = np.empty(nm)
    w = np.empty((nm, nm))
    x0 = np.empty((nm, n))
    P0 = np.empty((nm, n, n))
    xp2 = np.empty((1, n))
    J = np.zeros((1, n, n))
    T1 = np.empty((n, n))
    Pp = np.empty((n, n))
    PCt = np.empty((n, m))
    PCtT = np.empty((m, n))
    S = np.empty((m, m))
    D = np.empty((m, m))
    L = np.zeros((m, m))
    e = np.empty(m)
    em = np.empty(m)
    eb = np.empty((m, 1))
    KgT = np.empty((m, n))
    MpT = np.empty((m, n))
    dz = np.empty(m)
    g = np.empty(m)
    IKC = np.empty((n, n))
    KR = np.empty((n, m))
    ll = np.empty(nm)
    lw = np.empty(nm)
    Sc = np.empty((m, m))
    Lc = np.zeros((m, m))
    ec = np.empty(m)
    col = np.empty(m)
    tmp = np.empty(2 * m)
    Phi = np.empty((n, n))
    G12 = np.empty((m, m))
    P12i = np.empty((m, m))
    Al = np.empty((n - m, m))
    Ae = np.empty(n - m)
    rr = np.empty(m)
    dy = np.empty(n)
    Ky = np.empty((n, m))
    for r in range(runs):
        ur = 0 if shared_u else r
        for k in range(K):
            # (19), (18): predicted mode probabilities and mixing weights
            for j in range(nm):
                s = 0.0
                for i in range(nm):
                    s += mu[r, i] * pi[i, j]
                c[j] = s if s > 1e-300 else 1e-300
            for i in range(nm):
                for j in range(nm):
                    w[i, j] = mu[r, i] * pi[i, j] / c[j]
            # (20), (21): mixed initial conditions
            for j in range(nm):
                for a in range(n):
                    s = 0.0
                    for i in range(nm):
                        s += w[i, j] * xs[r, i, a]
                    x0[j, a] = s
                for a in range(n):
                    for b in range(n):
                        s = 0.0
                        for i in range(nm):
                            da = xs[r, i, a] - x0[j, a]
                            s += w[i, j] * (Ps[r, i, a, b] + da * (xs[r, i, b] - x0[j, b]))
                        P0[j, a, b] = s
            # (22)-(29): mode-matched filters
            for j in range(nm):
                Cj = C[j]
                Rj = R[j]
                for i in range(m):  # e(k|k) of mode j: residual of its mixed estimate (design.md I4)
                    if first and k == 0:
                        em[i] = eps[r, j, i]
                    else:
                        s = zl[r, i]
                        for q in range(n):
                            s -= C[0, i, q] * x0[j, q]
                        em[i] = s
                if model_kind[j] == MODEL_EHA4:
                    cf = coef[j]
                    uw = u[ur, k, 0]
                    _step_kernel(
                        x0[j : j + 1], uw, xp2, cf[0], cf[1], cf[2], cf[3], cf[4], cf[5], cf[6], cf[7],
                        cf[8], cf[9], cf[10], cf[11], cf[12],
                    )  # fmt: skip
                    _jacobian_kernel(
                        x0[j : j + 1], J, cf[0], cf[1], cf[2], cf[3], cf[4], cf[5], cf[6], cf[7], cf[8],
                        cf[9], cf[10], cf[11], cf[12],
                    )  # fmt: skip
                    F = J[0]
                else:
                    F = A[j]
                    for i in range(n):
                        s = 0.0
                        for q in range(p):
                            s += u[ur, k, q] * B[j, i, q]
                        for q in range(n):
                            s += A[j, i, q] * x0[j, q]
                        xp2[0, i] = s
                xp = xp2[0]
                Pj = P0[j]
                for i in range(n):
                    for jj in range(n):
                        s = 0.0
                        for q in range(n):
                            s += F[i, q] * Pj[q, jj]
                        T1[i, jj] = s
                for i in range(n):
                    for jj in range(i, n):
                        s = Q[j, i, jj]
                        for q in range(n):
                            s += T1[i, q] * F[jj, q]
                        Pp[i, jj] = s
                        Pp[jj, i] = s
                for i in range(m):
                    s = z[r, k, i]
                    for q in range(n):
                        s -= Cj[i, q] * xp[q]
                    e[i] = s
                    eb[i, 0] = s
                for i in range(n):
                    for jj in range(m):
                        s = 0.0
                        for q in range(n):
                            s += Pp[i, q] * Cj[jj, q]
                        PCt[i, jj] = s
                        PCtT[jj, i] = s
                for i in range(m):
                    for jj in range(m):
                        s = 0.0
                        for q in range(n):
                            s += Cj[i, q] * PCt[q, jj]
                        D[i, jj] = s
                        S[i, jj] = s + Rj[i, jj]
                if not _chol_into(S, L, m):
                    return 1 + r
                kj = kind[j]
                if kj == 0:
                    for cc in range(n):  # Kalman gain K^T = S^-1 (P C^T)^T
                        for i in range(m):
                            s = PCtT[i, cc]
                            for q in range(i):
                                s -= L[i, q] * KgT[q, cc]
                            KgT[i, cc] = s / L[i, i]
                        for i in range(m - 1, -1, -1):
                            s = KgT[i, cc]
                            for q in range(i + 1, m):
                                s -= L[q, i] * KgT[q, cc]
                            KgT[i, cc] = s / L[i, i]
                    for i in range(n):
                        s = xp[i]
                        for q in range(m):
                            s += KgT[q, i] * e[q]
                        xs[r, j, i] = s
                elif mapping[j] == 2:
                    # reduced-order (Luenberger) form, _luen.luen_correction: y = T x, Phi = T F T^-1
                    Tj = Tm[j]
                    Ti = Tinv[j]
                    for i in range(n):
                        for jj in range(n):
                            s = 0.0
                            for q in range(n):
                                s += Tj[i, q] * F[q, jj]
                            T1[i, jj] = s
                    for i in range(n):
                        for jj in range(n):
                            s = 0.0
                            for q in range(n):
                                s += T1[i, q] * Ti[q, jj]
                            Phi[i, jj] = s
                    for i in range(m):
                        for jj in range(m):
                            G12[i, jj] = Phi[i, m + jj]
                    if not _invert(G12, P12i, m):
                        return -(1 + runs + r)
                    for i in range(m):
                        for jj in range(m):
                            s = 0.0
                            for q in range(m):
                                s += Phi[m + i, m + q] * P12i[q, jj]
                            Al[i, jj] = s
                    for i in range(m):
                        s = 0.0
                        for q in range(m):
                            s += Al[i, q] * e[q]
                        Ae[i] = s
                    if kj == 2:
                        for i in range(m):
                            rr[i] = (gamma[j, i] + lam[j, i]) * em[i] - gamma[j, i] * lam[j, i] * epps[
                                r, j, i
                            ]
                        for i in range(m):
                            dy[i] = e[i] - rr[i]
                            s = Ae[i]
                            for q in range(m):
                                s -= P12i[i, q] * rr[q]
                            dy[m + i] = s
                            if e[i] != 0.0:
                                gi = dy[i] / e[i]
                                g[i] = lo[j] if gi < lo[j] else (hi[j] if gi > hi[j] else gi)
                            else:
                                g[i] = 1.0
                        for i in range(m):  # Ky = [diag(q); Al diag(q)]
                            for q in range(m):
                                Ky[i, q] = g[q] if i == q else 0.0
                                Ky[m + i, q] = Al[i, q] * g[q]
                    else:
                        for i in range(m):
                            a = abs(e[i])
                            den = a if a > psi[j, i] else psi[j, i]
                            g[i] = (a + gamma[j, i] * abs(em[i])) / den
                            s = 0.0
                            for q in range(m):
                                s += P12i[i, q] * em[q]
                            al = abs(Ae[i])
                            den = al if al > psi[j, m + i] else psi[j, m + i]
                            kl = (al + gamma[j, i] * abs(s)) / den
                            dy[i] = g[i] * e[i]
                            dy[m + i] = kl * Ae[i]
                            for q in range(m):  # Ky = [diag(ku); diag(kl) Al]
                                Ky[i, q] = g[i] if i == q else 0.0
                                Ky[m + i, q] = kl * Al[i, q]
                    for i in range(n):  # K = T^-1 Ky, dx = T^-1 [d_u; d_l]
                        for q in range(m):
                            s = 0.0
                            for t in range(n):
                                s += Ti[i, t] * Ky[t, q]
                            KgT[q, i] = s
                        s = 0.0
                        for t in range(n):
                            s += dy[t] * Ti[i, t]
                        xs[r, j, i] = xp[i] + s
                else:
                    if mapping[j] == 1:
                        if not _chol_into(D, L, m):
                            return 1 + r
                        for cc in range(n):
                            for i in range(m):
                                s = PCtT[i, cc]
                                for q in range(i):
                                    s -= L[i, q] * MpT[q, cc]
                                MpT[i, cc] = s / L[i, i]
                            for i in range(m - 1, -1, -1):
                                s = MpT[i, cc]
                                for q in range(i + 1, m):
                                    s -= L[q, i] * MpT[q, cc]
                                MpT[i, cc] = s / L[i, i]
                    else:
                        for i in range(m):
                            for q in range(n):
                                MpT[i, q] = M_const[j, q, i]
                    for i in range(m):
                        if kj == 1:
                            a = abs(e[i])
                            den = a if a > psi[j, i] else psi[j, i]
                            g[i] = (a + gamma[j, i] * abs(em[i])) / den
                            dz[i] = g[i] * e[i]
                        else:
                            dz[i] = (
                                e[i]
                                - (gamma[j, i] + lam[j, i]) * em[i]
                                + gamma[j, i] * lam[j, i] * epps[r, j, i]
                            )
                            if e[i] != 0.0:
                                gi = dz[i] / e[i]
                                g[i] = lo[j] if gi < lo[j] else (hi[j] if gi > hi[j] else gi)
                            else:
                                g[i] = 1.0
                    for i in range(m):
                        for q in range(n):
                            KgT[i, q] = MpT[i, q] * g[i]
                    for i in range(n):
                        s = xp[i]
                        for q in range(m):
                            s += MpT[q, i] * dz[q]
                        xs[r, j, i] = s
                # Joseph form
                for i in range(n):
                    for jj in range(n):
                        s = 1.0 if i == jj else 0.0
                        for q in range(m):
                            s -= KgT[q, i] * Cj[q, jj]
                        IKC[i, jj] = s
                for i in range(n):
                    for jj in range(n):
                        s = 0.0
                        for q in range(n):
                            s += IKC[i, q] * Pp[q, jj]
                        T1[i, jj] = s
                for i in range(n):
                    for jj in range(m):
                        s = 0.0
                        for q in range(m):
                            s += KgT[q, i] * Rj[q, jj]
                        KR[i, jj] = s
                for i in range(n):
                    for jj in range(i, n):
                        s = 0.0
                        for q in range(n):
                            s += T1[i, q] * IKC[jj, q]
                        for q in range(m):
                            s += KR[i, q] * KgT[q, jj]
                        Ps[r, j, i, jj] = s
                        Ps[r, j, jj, i] = s
                for i in range(m):
                    epps[r, j, i] = em[i]
                    s = z[r, k, i]
                    for q in range(n):
                        s -= Cj[i, q] * xs[r, j, q]
                    eps[r, j, i] = s
                ll[j] = _log_gaussian_1(e, S, m, Sc, Lc, ec, col, tmp)  # (29)
            # (30): log-domain mode probabilities, optional floor
            top = -np.inf
            for j in range(nm):
                lw[j] = np.log(c[j]) + ll[j]
                if lw[j] > top:
                    top = lw[j]
            if not np.isfinite(top):
                return -(1 + r)
            s = 0.0
            for j in range(nm):
                lw[j] = np.exp(lw[j] - top)
                s += lw[j]
            for j in range(nm):
                mu[r, j] = lw[j] / s
            if floor > 0.0:
                s = 0.0
                for j in range(nm):
                    if mu[r, j] < floor:
                        mu[r, j] = floor
                    s += mu[r, j]
                for j in range(nm):
                    mu[r, j] = mu[r, j] / s
            # (31)-(33): combination
            for a in range(n):
                s = 0.0
                for j in range(nm):
                    s += mu[r, j] * xs[r, j, a]
                x[r, a] = s
            for a in range(n):
                for b in range(n):
                    s = 0.0
                    for j in range(nm):
                        da = xs[r, j, a] - x[r, a]
                        s += mu[r, j] * (Ps[r, j, a, b] + da * (xs[r, j, b] - x[r, b]))
                    P[r, a, b] = s
            for i in range(m):
                zl[r, i] = z[r, k, i]
            for a in range(n):
                o_x[r, k, a] = x[r, a]
            for j in range(nm):
                o_mu[r, k, j] = mu[r, j]
                o_ll[r, k, j] = ll[j]
            if want_P:
                for a in range(n):
                    for b in range(n):
                        o_P[r, k, a, b] = P[r, a, b]
            if want_mx:
                for j in range(nm):
                    for a in range(n):
                        o_mx[r, k, j, a] = xs[r, j, a]
    return 0


# ----------------------------------------------------------------------------- Python side
def fused_spec(filters: tuple[object, ...]) -> dict[str, np.ndarray] | None:
    """Per-mode arrays of the fused kernel, or None when a filter or model is not supported.

    Parameters
    ----------
    filters : tuple of Filter
        The IMM's mode-matched filters.

    Returns
    -------
    dict of str to ndarray, or None
    """
    from functools import partial

    from ..plants.eha4 import eha4_jacobian, eha4_transition
    from ..plants.models import LinearModel
    from ..plants.nonlinear import NonlinearModel
    from . import _engine
    from .kalman import ExtendedKalmanFilter, KalmanFilter
    from .svsf2 import SecondOrderSVSF
    from .svsf_cov import SVSFCov

    r = len(filters)
    mdl0 = filters[0].model  # type: ignore[attr-defined]
    n, m, p = int(mdl0.n_states), int(mdl0.n_outputs), int(mdl0.n_inputs)
    spec = {
        "model_kind": np.zeros(r, dtype=np.int64),
        "coef": np.zeros((r, 13)),
        "A": np.zeros((r, n, n)),
        "B": np.zeros((r, n, p)),
        "kind": np.zeros(r, dtype=np.int64),
        "mapping": np.zeros(r, dtype=np.int64),
        "Q": np.zeros((r, n, n)),
        "C": np.zeros((r, m, n)),
        "R": np.zeros((r, m, m)),
        "M_const": np.zeros((r, n, m)),
        "T": np.zeros((r, n, n)),
        "Tinv": np.zeros((r, n, n)),
        "gamma": np.zeros((r, m)),
        "lam": np.zeros((r, m)),
        "psi": np.ones((r, n)),
        "lo": np.zeros(r),
        "hi": np.full(r, 2.0),
    }
    for j, f in enumerate(filters):
        mdl = f.model  # type: ignore[attr-defined]
        if type(mdl) is LinearModel:
            spec["model_kind"][j] = MODEL_LINEAR
            spec["A"][j], spec["B"][j] = mdl.A, mdl.B
        elif (
            type(mdl) is NonlinearModel
            and isinstance(mdl.f, partial)
            and isinstance(mdl.jac, partial)
            and mdl.f.func is eha4_transition
            and mdl.jac.func is eha4_jacobian
            and not mdl.f.args
            and not mdl.jac.args
            and set(mdl.f.keywords) == {"c"}
            and set(mdl.jac.keywords) == {"c"}
            and mdl.f.keywords["c"] == mdl.jac.keywords["c"]
            and n == 4
            and p == 1
        ):
            spec["model_kind"][j] = MODEL_EHA4
            spec["coef"][j] = np.asarray(tuple(mdl.f.keywords["c"]), dtype=float)
        else:
            return None
        spec["Q"][j], spec["C"][j], spec["R"][j] = mdl.Q, mdl.C, mdl.R
        if type(f) in (ExtendedKalmanFilter, KalmanFilter):
            spec["kind"][j] = _engine.KF
            continue
        if type(f) not in (SVSFCov, SecondOrderSVSF):
            return None
        if type(f) is SVSFCov and not f.vbl:
            spec["kind"][j] = _engine.SVSF1
            spec["psi"][j, : len(f.psi)] = f.psi  # m entries, n with "luen" (measured first)
        elif type(f) is SecondOrderSVSF:
            spec["kind"][j] = _engine.SVSF2
            spec["lam"][j] = f.lam
            spec["lo"][j], spec["hi"][j] = f.ratio_clip
        else:
            return None
        spec["gamma"][j] = f.gamma
        if f._luen is not None:
            spec["mapping"][j] = _engine.MAP_LUEN
            spec["T"][j], spec["Tinv"][j] = f._luen
        elif f._M is None:
            spec["mapping"][j] = _engine.MAP_COV
        else:
            spec["mapping"][j] = _engine.MAP_CONST
            spec["M_const"][j] = f._M
    return spec


def run_fused(
    spec: dict[str, np.ndarray],
    pi: np.ndarray,
    floor: float,
    state: object,
    z: np.ndarray,
    u: np.ndarray,
    store_covariance: bool,
    store_modes: bool,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray | None]]:
    """Advance an IMM state over ``z`` (runs, K, m) with the compiled kernel.

    Parameters
    ----------
    spec : dict
        From :func:`fused_spec`.
    pi : (r, r) array
        Transition matrix.
    floor : float
        Mode-probability floor.
    state : MultipleModelState
        The IMM state after sample k.
    z : (runs, K, m) array
        Measurements (validated).
    u : (1 | runs, K, p) array
        Inputs (validated).
    store_covariance, store_modes : bool
        Outputs wanted (see :meth:`IMM.update`).

    Returns
    -------
    (state arrays, outputs)
        ``mu, xs, Ps, eps, epps, zl, x, P`` after the last sample, and ``x, mu, ll, P, mx``.

    Raises
    ------
    SingularMatrixError
        An innovation covariance that is not positive definite, or every mode likelihood zero.
    """
    from ..errors import SingularMatrixError
    from ._engine import MAP_CONST, _not_pd_message

    runs, K, _m = z.shape
    n = state.x.shape[1]  # type: ignore[attr-defined]
    sts = state.mode_states  # type: ignore[attr-defined]
    r = len(sts)
    st = {
        "mu": np.array(state.mu, dtype=float),  # type: ignore[attr-defined]
        "xs": np.ascontiguousarray(np.stack([s.x for s in sts], axis=1), dtype=float),
        "Ps": np.ascontiguousarray(
            np.stack([np.broadcast_to(s.P, (runs, n, n)) for s in sts], axis=1), dtype=float
        ),
        "eps": np.ascontiguousarray(np.stack([s.e_post for s in sts], axis=1), dtype=float),
        "epps": np.ascontiguousarray(np.stack([s.e_prev for s in sts], axis=1), dtype=float),
        "zl": np.array(state.z_last, dtype=float),  # type: ignore[attr-defined]
        "x": np.array(state.x, dtype=float),  # type: ignore[attr-defined]
        "P": np.array(np.broadcast_to(state.P, (runs, n, n)), dtype=float),  # type: ignore[attr-defined]
    }
    out = {
        "x": np.empty((runs, K, n)),
        "mu": np.empty((runs, K, r)),
        "ll": np.empty((runs, K, r)),
        "P": np.empty((runs, K, n, n)) if store_covariance else np.empty((0, 0, 0, 0)),
        "mx": np.empty((runs, K, r, n)) if store_modes else np.empty((0, 0, 0, 0)),
    }
    status = _imm_kernel(
        spec["model_kind"], spec["coef"], spec["A"], spec["B"], spec["kind"], spec["mapping"],
        spec["Q"], spec["C"], spec["R"], spec["M_const"], spec["T"], spec["Tinv"], spec["gamma"],
        spec["lam"], spec["psi"],
        spec["lo"], spec["hi"], np.ascontiguousarray(pi, dtype=float), float(floor),
        np.ascontiguousarray(z, dtype=float), np.ascontiguousarray(u, dtype=float),
        bool(state.k == 0),  # type: ignore[attr-defined]
        st["mu"], st["xs"], st["Ps"], st["eps"], st["epps"], st["zl"], st["x"], st["P"],
        out["x"], out["mu"], out["ll"], out["P"], out["mx"],
    )  # fmt: skip
    if status > 0:
        worst = int(np.max(spec["mapping"]))
        raise SingularMatrixError(_not_pd_message(worst if worst != MAP_CONST else MAP_CONST, status - 1))
    if status < -runs:
        raise SingularMatrixError(
            "the Luenberger form needs Phi12 = d(measured)/d(unmeasured) invertible at the estimate (eq 10)"
        )
    if status < 0:
        raise SingularMatrixError(
            "every mode likelihood is zero or non-finite in some realization; check R and Q of the mode "
            "models (the innovation covariance) and the measurement units"
        )
    return st, {
        "x": out["x"],
        "mu": out["mu"],
        "ll": out["ll"],
        "P": out["P"] if store_covariance else None,
        "mx": out["mx"] if store_modes else None,
    }
