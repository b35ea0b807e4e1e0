"""Compiled per-push loops of the online monitor (see :mod:`chatterspec._jit`).

Each kernel does, in one pass, what a few numpy calls do in
:mod:`chatterspec.online.monitor`, with the same correctly rounded operations,
so that the monitor's numbers do not depend on whether numba is installed
(tests/test_monitor.py compares both paths bit for bit).
"""

from __future__ import annotations

import numpy as np

from .. import _jit
from ..filters.svsf import _closed_form_kernel, _svsf_kernel

__all__: list[str] = []


@_jit.njit
def _verdict_kernel(
    power: np.ndarray,
    lo: int,
    values: np.ndarray,
    freqs: np.ndarray,
    flags: np.ndarray,
    peak_hz: np.ndarray,
    peak_ratio: np.ndarray,
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_monitor.py)
    """Per-frame verdicts over the tested bins ``lo .. lo + len(values) - 1`` of ``power`` (F, bins, m).

    ``ratio = power / values`` per bin (one division, as numpy's ``p / values``); the peak is the
    first bin of largest ratio (``np.argmax``'s rule for NaN-free input: only a strictly larger
    ratio replaces the current one); ``flags = peak_ratio > 1``, which equals ``any(p > values)``
    for finite ``p`` and finite normal ``values > 0`` (see ``_Verdicts``). The caller passes only
    such inputs. Outputs ``flags`` (F, m) bool, ``peak_hz`` and ``peak_ratio`` (F, m).
    """
    F = power.shape[0]
    m = power.shape[2]
    nt = values.shape[0]
    for f in range(F):
        for c in range(m):
            best = power[f, lo, c] / values[0, c]
            kb = 0
            for k in range(1, nt):
                r = power[f, lo + k, c] / values[k, c]
                if r > best:
                    best = r
                    kb = k
            peak_ratio[f, c] = best
            peak_hz[f, c] = freqs[kb]
            flags[f, c] = best > 1.0


@_jit.njit
def _filters_kernel(
    z: np.ndarray,
    u: np.ndarray,
    GT: np.ndarray,
    aux_PhiT: np.ndarray,
    aux_y: np.ndarray,
    e_out: np.ndarray,
    Gu: np.ndarray,
    run_sat: bool,
    PhiT: np.ndarray,
    L: np.ndarray,
    P: np.ndarray,
    inv_psi: np.ndarray,
    gamma: float,
    S_inv: np.ndarray,
    y: np.ndarray,
    ep: np.ndarray,
    sat_e: np.ndarray,
    x_out: np.ndarray,
    none: np.ndarray,
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_monitor.py)
    """One push of the monitor's two filters in one call: G u(k), the aux chattering, the sat SVSF.

    ``z`` (1, K, m) = z(k+1); ``u`` (K, p), p >= 1, = u(k); ``GT`` = G^T (p, n). ``Gu`` (1, K, n)
    receives ``G u(k)`` summed as ``_rows_times`` does (``u_0 G_0`` then ``+= u_j G_j``, j = 1 ..),
    then :func:`~chatterspec.filters.svsf._closed_form_kernel` writes the chattering (eq 23) into
    ``e_out`` (1, K, m) from ``aux_y`` = y(k|k) and, when ``run_sat``,
    :func:`~chatterspec.filters.svsf._svsf_kernel` advances the sat SVSF (``y``, ``ep`` in place;
    ``sat_e`` and ``x_out`` (1, K, n) outputs; ``none`` an empty (0, 0, 0) array). The same
    kernels and the same sums as ``SVSF.update``, so the same bits (tests/test_monitor.py).
    """
    K = z.shape[1]
    p, n = GT.shape
    for k in range(K):
        for i in range(n):
            g = u[k, 0] * GT[0, i]
            for j in range(1, p):
                g += u[k, j] * GT[j, i]
            Gu[0, k, i] = g
    _closed_form_kernel(z, Gu, aux_PhiT, aux_y, e_out, True)
    if run_sat:
        _svsf_kernel(z, Gu, PhiT, L, P, inv_psi, gamma, S_inv, y, ep, sat_e, x_out, none, none)
