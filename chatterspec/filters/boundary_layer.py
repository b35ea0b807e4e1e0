"""Smoothing-boundary-layer selection from healthy chattering statistics (section II-III, Fig 2).

This module holds the analytic part (:func:`healthy_chattering_variance`); the Monte Carlo
estimate and the Fig 2 study are in :mod:`chatterspec.studies.boundary_layer`.

The SVSF chatters (eq 13) whenever ``|e_i(k|k-1)| > psi_i``. Under healthy
conditions the auxiliary (``sgn``) filter started at ``x(0|0) = C^-1 z(0)``
(or ``z(0)`` on the measured coordinates of the reduced-order filter) is a
*linear* filter: ``e(k|k) = 0`` for every k, the measured coordinates of the
a-posteriori estimate equal the measurements, and the unmeasured ones are
corrected by ``L e(k+1|k)`` with ``L = Phi22 Phi12^-1`` (eq 10). With the error
``eps(k) = S x(k) - y(k|k)`` in the filter's measurement-aligned coordinates
``y = S x`` (``Phi = S A S^-1``, ``H = [I 0]``, ``J = [I; L]``)::

    eps(k+1)  = (I - J H) (Phi eps(k) + S v(k)) - J w(k+1)
    e(k+1|k)  = H Phi eps(k) + H S v(k) + w(k+1)

so the healthy chattering is zero-mean Gaussian with the stationary variance

    Var e = H Phi P Phi^T H^T + H S Q S^T H^T + R,
    P = F P F^T + (I - J H) S Q S^T (I - J H)^T + J R J^T,   F = (I - J H) Phi

(:func:`healthy_chattering_variance`). For full measurement ``F = 0`` and this
is ``gamma0 = diag(C Q C^T + R + M R M^T)``, ``M = -C A C^-1`` (eq 23). For the
reduced-order Fig 2 setup (f0 2 Hz, zeta 0, C = [1 0], q = (1e-10, 1e-8),
r = 1e-8) the measured chattering is the MA(2) sequence::

    e(k+2|k+1) = w(k+2) - (1 + A22) w(k+1) + (A22 - Ts A21) w(k)
                 + v1(k+1) - A22 v1(k) + Ts v2(k)

whose variance is ``r (1 + 4 + (1 + Ts^2 w0^2)^2) + 2 q1 + Ts^2 q2 = 6.02e-8``.
Eq (34) keeps only ``w(k) - w(k-1)`` and one ``v1`` pair and prints
``2.02e-8`` (``docs/design.md`` C7); the paper's "0.067" after eq (35) is a
percentage, not a probability.

:func:`estimate_boundary_layer` measures the same distribution by Monte Carlo
and proposes ``psi = sigma * Phi^-1(1 - p/2)`` for a target per-sample
chattering probability ``p`` of the auxiliary filter; :func:`boundary_layer_study`
reproduces the Fig 2 study. No plotting here (see :mod:`chatterspec.figures.plotting`).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.stats

from ..plants.models import LinearModel
from .svsf import auxiliary_svsf

__all__ = ["healthy_chattering_variance"]


def _filter_matrices(model: LinearModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(S, Phi, L)`` of the SVSF in measurement-aligned coordinates (L is (n-m, m), maybe empty)."""
    aux = auxiliary_svsf(model)  # validates C / Phi12 and builds the transformation
    S = aux._S
    Phi = aux._PhiT.T
    m, n = model.n_outputs, model.n_states
    L = np.zeros((n - m, m)) if aux._L is None else aux._L
    return S, Phi, L


def healthy_chattering_variance(model: LinearModel) -> tuple[np.ndarray, np.ndarray]:
    """Stationary variance of the auxiliary SVSF's chattering when the plant equals ``model``.

    Parameters
    ----------
    model : LinearModel
        Nominal model, which is also the true plant (healthy case); full or
        reduced-order measurement.

    Returns
    -------
    (var_measured, var_lower) : tuple of ndarray
        ``var_measured`` (m,): variance of ``e_i(k+1|k)`` (output units squared);
        ``var_lower`` (n - m,): variance of ``L e(k+1|k)``, the argument of the
        unmeasured coordinates' switching term (eq 10); empty for full measurement.
        See the module docstring for the derivation (the error dynamics of the
        sgn filter are linear and, for full measurement, memoryless).
    """
    S, Phi, L = _filter_matrices(model)
    m, n = model.n_outputs, model.n_states
    H = np.hstack([np.eye(m), np.zeros((m, n - m))])
    J = np.vstack([np.eye(m), L])
    IJH = np.eye(n) - J @ H
    F = IJH @ Phi
    SQS = S @ model.Q @ S.T
    W = IJH @ SQS @ IJH.T + J @ model.R @ J.T
    P = scipy.linalg.solve_discrete_lyapunov(F, W)
    HPhi = H @ Phi
    cov = HPhi @ P @ HPhi.T + H @ SQS @ H.T + model.R
    return np.diag(cov).copy(), np.diag(L @ cov @ L.T).copy()
