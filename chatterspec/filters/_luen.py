"""Reduced-order (Luenberger) correction of the SVSF-type filters, ``docs/design.md`` §7.4 (private)."""

from __future__ import annotations

import numpy as np

from ..errors import SingularMatrixError
from ._engine import SVSF2


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
    """Reduced-order (Luenberger) correction (``docs/design.md`` §7.4): ``(K (runs, n, m), dx (runs, n))``.

    In measurement-aligned coordinates ``y = T x`` (``C T^-1 = [I 0]``), ``Phi = T F T^-1`` and
    ``A_l = Phi22 Phi12^-1`` (n = 2m, Phi12 invertible):

    * first order (chattering paper eq 9-11): ``d_u = kappa_u o e``, ``d_l = kappa_l o (A_l e)``
      with ``kappa_u = (|e| + g|ebar|)/max(|e|, psi_u)``,
      ``kappa_l = (|A_l e| + g|Phi12^-1 ebar|)/max(|A_l e|, psi_l)``;
      gain ``[diag(kappa_u); diag(kappa_l) A_l]`` (exact: ``K e = d``);
    * second order: ``d_u = e - r``, ``d_l = A_l e - Phi12^-1 r``, ``r = (g + L) ebar - g L ebar(k-1)``;
      covariance gain ``[diag(q); A_l diag(q)]`` with ``q = clip(d_u / e)`` (exact when r = 0).
    """
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
