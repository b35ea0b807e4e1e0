"""Compiled per-push loops of the online monitor (see :mod:`chatterspec._jit`).

Each kernel does, in one pass, what a few numpy calls do in
:mod:`chatterspec.online.monitor`, with the same correctly rounded operations,
so that the monitor's numbers do not depend on whether numba is installed
(tests/test_monitor.py compares both paths bit for bit).
"""

from __future__ import annotations

import numpy as np

from .. import _jit

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
