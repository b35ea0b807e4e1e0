"""Compiled exceedance counts of the healthy Monte Carlo studies (false alarms, calibration).

:meth:`chatterspec.studies.healthy.HealthyStudy._summarize` compares every spectrum bin
with K thresholds and counts. In numpy that is a ``(K, runs, frames, bins, m)`` boolean
array and half a dozen reductions over it; this kernel reads each power value once and
increments two integer tables, from which every count of the study follows by integer
sums (exact, so the numbers are those of the numpy path whatever the order).
"""

from __future__ import annotations

import numpy as np

from .. import _jit

__all__ = ["exceedance_counts"]


@_jit.njit
def _exceedance_kernel(
    power: np.ndarray,
    thr: np.ndarray,
    tested: np.ndarray,
    bin_exceed: np.ndarray,
    n_false: np.ndarray,
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_e2e_kernels.py)
    """``bin_exceed[k, b, c] += #{(r, f): S > thr_k}``, ``n_false[k, r, f, c] = #{tested b: S > thr_k}``.

    ``power`` is ``(R, F, bins, m)``, ``thr`` ``(K, bins, m)``, ``tested`` ``(K, bins)``;
    ``bin_exceed`` ``(K, bins, m)`` and ``n_false`` ``(K, R, F, m)`` start at zero.
    """
    R, F, B, m = power.shape
    K = thr.shape[0]
    for r in range(R):
        for f in range(F):
            for b in range(B):
                for c in range(m):
                    s = power[r, f, b, c]
                    for k in range(K):
                        if s > thr[k, b, c]:
                            bin_exceed[k, b, c] += 1
                            if tested[k, b]:
                                n_false[k, r, f, c] += 1


def exceedance_counts(
    power: np.ndarray, thr: np.ndarray, tested: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Exceedances of ``power`` over K thresholds, counted in one compiled pass.

    Parameters
    ----------
    power : (R, F, bins, m) array
        Spectra (F = 1 for whole records, the STFT frames otherwise), squared output units.
    thr : (K, bins, m) array
        Thresholds in the units of ``power``.
    tested : (K, bins) bool array
        Bins each threshold tests.

    Returns
    -------
    bin_exceed : (K, bins, m) int64 array
        Spectra (records x frames) over the threshold, per bin and channel (all bins).
    n_false : (K, R, F, m) int64 array
        Tested bins over the threshold, per spectrum and channel.
    """
    K = thr.shape[0]
    R, F, B, m = power.shape
    bin_exceed = np.zeros((K, B, m), dtype=np.int64)
    n_false = np.zeros((K, R, F, m), dtype=np.int64)
    _exceedance_kernel(power, thr, np.ascontiguousarray(tested, dtype=np.bool_), bin_exceed, n_false)
    return bin_exceed, n_false
