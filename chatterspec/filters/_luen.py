"""Reduced-order (Luenberger) correction of the SVSF-type filters, ``docs/design.md`` §7.4 (private).

In measurement-aligned coordinates ``y = T x`` (``C T^-1 = [I 0]``), ``Phi = T F T^-1`` and
``A_l = Phi22 Phi12^-1`` (n = 2m, Phi12 invertible):

* first order (chattering paper eq 9-11): ``d_u = kappa_u o e``, ``d_l = kappa_l o (A_l e)``
  with ``kappa_u = (|e| + g|ebar|)/max(|e|, psi_u)``,
  ``kappa_l = (|A_l e| + g|Phi12^-1 ebar|)/max(|A_l e|, psi_l)``;
  gain ``[diag(kappa_u); diag(kappa_l) A_l]`` (exact: ``K e = d``);
* second order: ``d_u = e - r``, ``d_l = A_l e - Phi12^-1 r``, ``r = (g + L) ebar - g L ebar(k-1)``;
  covariance gain ``[diag(q); A_l diag(q)]`` with ``q = clip(d_u / e)`` (exact when r = 0).

Then ``K = T^-1 Ky`` and ``x(k+1|k+1) = x(k+1|k) + T^-1 [d_u; d_l]``. :func:`luen_correction` is
the numpy form (vectorized over realizations); :func:`luen_first_order` and
:func:`luen_second_order` the compiled steps the IMM bank's loop inlines (parameters in ``fp``,
:func:`chatterspec.filters._engine.svsf_parameters`).
"""

from __future__ import annotations

import numpy as np

from .. import _jit
from ..errors import SingularMatrixError
from ._engine import SINGULAR_PHI12, SVSF2, product_step, svsf_offsets


def luen_correction(
    kind: int,
    F: np.ndarray,
    e: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    T: np.ndarray,
    Tinv: np.ndarray,
    gamma: np.ndarray,
    lam: np.ndarray,
    psi: np.ndarray,
    lo: float,
    hi: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The correction of the module docstring, numpy: ``(K (runs, n, m), dx (runs, n))``."""
    runs, m = e.shape
    Phi = np.broadcast_to(T @ F @ Tinv, (runs, 2 * m, 2 * m))
    try:
        P12i = np.linalg.inv(Phi[:, :m, m:])
    except np.linalg.LinAlgError:
        raise SingularMatrixError(
            "the Luenberger form needs Phi12 = d(measured)/d(unmeasured) invertible at the estimate (eq 10)"
        ) from None
    Al = Phi[:, m:, m:] @ P12i
    Ae = np.einsum("rij,rj->ri", Al, e)
    if kind == SVSF2:
        r = (gamma + lam) * ep - gamma * lam * epp
        du = e - r
        dl = Ae - np.einsum("rij,rj->ri", P12i, r)
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.where(e != 0.0, np.clip(du / np.where(e != 0.0, e, 1.0), lo, hi), 1.0)
        Ky = np.concatenate([q[:, :, None] * np.eye(m), Al * q[:, None, :]], axis=1)
    else:
        a = np.abs(e)
        ku = (a + gamma * np.abs(ep)) / np.maximum(a, psi[:m])
        al = np.abs(Ae)
        kl = (al + gamma * np.abs(np.einsum("rij,rj->ri", P12i, ep))) / np.maximum(al, psi[m:])
        du, dl = ku * e, kl * Ae
        Ky = np.concatenate([ku[:, :, None] * np.eye(m), kl[:, :, None] * Al], axis=1)
    return Tinv @ Ky, np.concatenate([du, dl], axis=1) @ Tinv.T


# ----------------------------------------------------------------------------- compiled steps
@_jit.step
def invert_step(A: np.ndarray, Ainv: np.ndarray, W: np.ndarray, m: int) -> bool:  # pragma: no cover
    """Ainv = A^-1, Gauss-Jordan with partial pivoting (scratch ``W`` (m, 2m)); False if singular."""
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


@_jit.step
def _phi_blocks(
    fp: np.ndarray, F: np.ndarray, e: np.ndarray, ws: tuple, n: int, m: int
) -> bool:  # pragma: no cover
    """``Phi = T F T^-1``, ``Phi12^-1`` (``P12i``), ``A_l = Phi22 Phi12^-1`` and ``A_l e`` into ``ws``."""
    T1, Phi, G12, P12i, Al, Ae, W = ws[0], ws[17], ws[18], ws[19], ws[20], ws[21], ws[25]
    _, _, _, _, _, o_T, o_Ti = svsf_offsets(n, m)
    product_step(fp[o_T : o_T + n * n].reshape((n, n)), F, T1, n, n, n, False, False)
    product_step(T1, fp[o_Ti : o_Ti + n * n].reshape((n, n)), Phi, n, n, n, False, False)
    for i in range(m):
        for jj in range(m):
            G12[i, jj] = Phi[i, m + jj]
    if not invert_step(G12, P12i, W, m):
        return False
    product_step(Phi[m:, m:], P12i, Al, m, m, m, False, False)
    product_step(Al, e.reshape((m, 1)), Ae.reshape((m, 1)), m, 1, m, False, False)
    return True


@_jit.step
def _luen_update(
    fp: np.ndarray, xp: np.ndarray, x: np.ndarray, KgT: np.ndarray, ws: tuple, n: int, m: int
) -> None:  # pragma: no cover - compiled
    """``K = T^-1 Ky`` (into ``KgT``) and ``x = x(k+1|k) + T^-1 dy``."""
    dy, Ky = ws[23], ws[24]
    o_Ti = svsf_offsets(n, m)[6]
    Tinv = fp[o_Ti : o_Ti + n * n].reshape((n, n))
    product_step(Tinv, Ky, KgT.T, n, m, n, False, False)
    for i in range(n):
        s = 0.0
        for t in range(n):
            s += dy[t] * Tinv[i, t]
        x[i] = xp[i] + s


@_jit.step
def luen_first_order(fp: np.ndarray, e: np.ndarray, ep: np.ndarray, epp: np.ndarray, xp: np.ndarray,
    PCtT: np.ndarray, D: np.ndarray, L: np.ndarray, C: np.ndarray, F: np.ndarray, x: np.ndarray,
    KgT: np.ndarray, ws: tuple[np.ndarray, ...], n: int, m: int) -> int:  # fmt: skip
    """The first-order correction of the module docstring (the correction-step signature of
    :mod:`chatterspec.filters._engine`); returns 0 or ``SINGULAR_PHI12``."""
    if not _phi_blocks(fp, F, e, ws, n, m):
        return SINGULAR_PHI12
    P12i, Al, Ae, g, dy, Ky = ws[19], ws[20], ws[21], ws[15], ws[23], ws[24]
    o_g, _, o_psi, _, _, _, _ = svsf_offsets(n, m)
    for i in range(m):
        a = abs(e[i])
        den = a if a > fp[o_psi + i] else fp[o_psi + i]
        g[i] = (a + fp[o_g + i] * abs(ep[i])) / den
        s = 0.0
        for q in range(m):
            s += P12i[i, q] * ep[q]
        al = abs(Ae[i])
        den = al if al > fp[o_psi + m + i] else fp[o_psi + m + i]
        kl = (al + fp[o_g + i] * abs(s)) / den
        dy[i] = g[i] * e[i]
        dy[m + i] = kl * Ae[i]
        for q in range(m):  # Ky = [diag(ku); diag(kl) Al]
            Ky[i, q] = g[i] if i == q else 0.0
            Ky[m + i, q] = kl * Al[i, q]
    _luen_update(fp, xp, x, KgT, ws, n, m)
    return 0


@_jit.step
def luen_second_order(fp: np.ndarray, e: np.ndarray, ep: np.ndarray, epp: np.ndarray, xp: np.ndarray,
    PCtT: np.ndarray, D: np.ndarray, L: np.ndarray, C: np.ndarray, F: np.ndarray, x: np.ndarray,
    KgT: np.ndarray, ws: tuple[np.ndarray, ...], n: int, m: int) -> int:  # fmt: skip
    """The second-order correction of the module docstring (the correction-step signature of
    :mod:`chatterspec.filters._engine`); returns 0 or ``SINGULAR_PHI12``."""
    if not _phi_blocks(fp, F, e, ws, n, m):
        return SINGULAR_PHI12
    P12i, Al, Ae, g, rr, dy, Ky = ws[19], ws[20], ws[21], ws[15], ws[22], ws[23], ws[24]
    o_g, o_l, _, o_lo, _, _, _ = svsf_offsets(n, m)
    lo, hi = fp[o_lo], fp[o_lo + 1]
    for i in range(m):
        gi, li = fp[o_g + i], fp[o_l + i]
        rr[i] = (gi + li) * ep[i] - gi * li * epp[i]
    for i in range(m):
        dy[i] = e[i] - rr[i]
        s = Ae[i]
        for q in range(m):
            s -= P12i[i, q] * rr[q]
        dy[m + i] = s
        if e[i] != 0.0:
            q_i = dy[i] / e[i]
            g[i] = lo if q_i < lo else (hi if q_i > hi else q_i)
        else:
            g[i] = 1.0
    for i in range(m):  # Ky = [diag(q); Al diag(q)]
        for q in range(m):
            Ky[i, q] = g[q] if i == q else 0.0
            Ky[m + i, q] = Al[i, q] * g[q]
    _luen_update(fp, xp, x, KgT, ws, n, m)
    return 0
