"""Per-push helpers of the online monitor: frame verdicts and compiled loops (see :mod:`chatterspec._jit`).

Each kernel does, in one pass, what a few numpy calls (or Python-level calls of
the SVSF) do in :mod:`chatterspec.online.monitor`, with the same correctly
rounded operations in the same order, so that the monitor's numbers do not
depend on whether numba is installed (tests/test_monitor.py compares the paths
bit for bit; the sat SVSF's numpy fallback is the one exception, equal to
1e-12, see :meth:`chatterspec.filters.svsf.SVSF.update`).
"""

from __future__ import annotations

import numpy as np

from .. import _jit
from ..detection.thresholds import Threshold
from ..filters.svsf import _closed_form_kernel, _svsf_kernel

__all__: list[str] = []


class _Verdicts:
    """:func:`frame_verdicts` with the tested bins and their threshold precomputed (per-push cost)."""

    def __init__(self, threshold: Threshold, compiled: bool = False) -> None:
        tested = np.flatnonzero(threshold.tested)
        contiguous = tested.size > 0 and bool(np.all(np.diff(tested) == 1))
        # a slice is a view (no copy of the spectra); fancy indexing otherwise
        self.sel: slice | np.ndarray = slice(int(tested[0]), int(tested[-1]) + 1) if contiguous else tested
        self.values = np.ascontiguousarray(threshold.values[tested])
        self.freqs = np.ascontiguousarray(threshold.freqs_hz[tested], dtype=float)
        # the one-pass flag rule below needs finite normal thresholds > 0 (else: the direct comparison)
        tiny = np.finfo(float).tiny
        self.one_pass = bool(np.all((self.values >= tiny) & np.isfinite(self.values)))
        # the monitor's case (contiguous tested bins, one-pass rule) in one compiled pass when enabled
        self.compiled = compiled and self.one_pass and isinstance(self.sel, slice)

    def __call__(self, power: np.ndarray, finite: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``finite``: ``power`` holds no NaN / inf (always so in the monitor: its input is checked)."""
        if self.compiled and finite and power.ndim == 3:
            F, m = power.shape[0], power.shape[2]
            flags, peak_hz, peak_ratio = np.empty((F, m), dtype=bool), np.empty((F, m)), np.empty((F, m))
            _verdict_kernel(power, self.sel.start, self.values, self.freqs, flags, peak_hz, peak_ratio)
            return flags, peak_hz, peak_ratio
        p = power[..., self.sel, :]
        ratio = p / self.values
        k = np.argmax(ratio, axis=-2)
        peak_ratio = np.take_along_axis(ratio, k[..., None, :], axis=-2)[..., 0, :]
        # flags = any(p > threshold) (detect_frames' rule) without a second pass over the bins: for
        # a normal v > 0 and finite p >= 0, p > v means p >= v + ulp(v), so p / v >= 1 + ulp(v) / v
        # > 1 + 2^-53 rounds to > 1; p <= v gives fl(p / v) <= 1. Hence fl(p / v) > 1 <=> p > v,
        # and max_k fl(p / v) > 1 <=> any(p > v) (checked at exact ties in tests/test_monitor.py).
        if not (self.one_pass and finite):
            return np.any(p > self.values, axis=-2), self.freqs[k], peak_ratio
        flags = peak_ratio > 1.0
        return flags, self.freqs[k], peak_ratio


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


@_jit.njit
def _filters_run3(
    z: np.ndarray,
    u: np.ndarray,
    GT: np.ndarray,
    aux_PhiT: np.ndarray,
    aux_y: np.ndarray,
    e_out: np.ndarray,
    run_sat: bool,
    PhiT: np.ndarray,
    inv_psi: np.ndarray,
    gamma: float,
    S_inv: np.ndarray,
    y: np.ndarray,
    ep: np.ndarray,
    x_out: np.ndarray,
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_monitor.py)
    """:func:`_filters_kernel` for one stream of a 3-state, 3-output model with full measurement (EHA).

    The same operations in the same order, term by term (``G u``: ``u_0 G_0`` then ``+= u_j G_j``;
    the chattering ``(((z - Gu) - Phi_0 z_0) - Phi_1 z_1) - Phi_2 z_2`` of
    :func:`~chatterspec.filters.svsf._closed_form_kernel`; the sat SVSF's
    ``(((0 + y_0 Phi_0) + y_1 Phi_1) + y_2 Phi_2) + Gu`` and eq (8)/(9)/(12) of
    :func:`~chatterspec.filters.svsf._svsf_kernel`), hence the same bits (tests/test_monitor.py), but
    written out: the states stay in registers and there are no 3-element loops (the generic
    kernel takes 2.6x the time: 1.86 against 0.72 ms per minute of 1 kHz data, both filters).
    ``sat`` switching only (``inv_psi`` has 3 entries); ``e_out`` and ``x_out`` (1, K, 3) outputs;
    ``y`` and ``ep`` (1, 3) updated in place; ``aux_y`` (1, 3) = y(k|k) = z(k) before the push.
    """
    K = z.shape[1]
    p = GT.shape[0]
    zp0, zp1, zp2 = aux_y[0, 0], aux_y[0, 1], aux_y[0, 2]
    y0, y1, y2 = y[0, 0], y[0, 1], y[0, 2]
    ep0, ep1, ep2 = ep[0, 0], ep[0, 1], ep[0, 2]
    for k in range(K):
        g0 = u[k, 0] * GT[0, 0]
        g1 = u[k, 0] * GT[0, 1]
        g2 = u[k, 0] * GT[0, 2]
        for j in range(1, p):
            g0 += u[k, j] * GT[j, 0]
            g1 += u[k, j] * GT[j, 1]
            g2 += u[k, j] * GT[j, 2]
        z0, z1, z2 = z[0, k, 0], z[0, k, 1], z[0, k, 2]
        # the auxiliary (sgn) filter's closed form of eq (23): y(k|k) = z(k)
        e_out[0, k, 0] = (((z0 - g0) - aux_PhiT[0, 0] * zp0) - aux_PhiT[1, 0] * zp1) - aux_PhiT[2, 0] * zp2
        e_out[0, k, 1] = (((z1 - g1) - aux_PhiT[0, 1] * zp0) - aux_PhiT[1, 1] * zp1) - aux_PhiT[2, 1] * zp2
        e_out[0, k, 2] = (((z2 - g2) - aux_PhiT[0, 2] * zp0) - aux_PhiT[1, 2] * zp1) - aux_PhiT[2, 2] * zp2
        zp0, zp1, zp2 = z0, z1, z2
        if run_sat:
            # eq (4) and (6)
            e0 = z0 - ((((0.0 + y0 * PhiT[0, 0]) + y1 * PhiT[1, 0]) + y2 * PhiT[2, 0]) + g0)
            e1 = z1 - ((((0.0 + y0 * PhiT[0, 1]) + y1 * PhiT[1, 1]) + y2 * PhiT[2, 1]) + g1)
            e2 = z2 - ((((0.0 + y0 * PhiT[0, 2]) + y1 * PhiT[1, 2]) + y2 * PhiT[2, 2]) + g2)
            # eq (8)/(9) and (12): e(k+1|k+1) = e - sat(e / psi) (|e| + gamma |e(k|k)|), y = z - e(k+1|k+1)
            ep0 = e0 - min(max(e0 * inv_psi[0], -1.0), 1.0) * (abs(e0) + gamma * abs(ep0))
            ep1 = e1 - min(max(e1 * inv_psi[1], -1.0), 1.0) * (abs(e1) + gamma * abs(ep1))
            ep2 = e2 - min(max(e2 * inv_psi[2], -1.0), 1.0) * (abs(e2) + gamma * abs(ep2))
            y0, y1, y2 = z0 - ep0, z1 - ep1, z2 - ep2
            x_out[0, k, 0] = ((0.0 + S_inv[0, 0] * y0) + S_inv[0, 1] * y1) + S_inv[0, 2] * y2
            x_out[0, k, 1] = ((0.0 + S_inv[1, 0] * y0) + S_inv[1, 1] * y1) + S_inv[1, 2] * y2
            x_out[0, k, 2] = ((0.0 + S_inv[2, 0] * y0) + S_inv[2, 1] * y1) + S_inv[2, 2] * y2
    y[0, 0], y[0, 1], y[0, 2] = y0, y1, y2
    ep[0, 0], ep[0, 1], ep[0, 2] = ep0, ep1, ep2
