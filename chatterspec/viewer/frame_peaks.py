"""Per-frame peak frequency of the Rerun ``peak_hz`` series (:func:`peak_bins`), compiled when numba is on.

Private helper of :mod:`chatterspec.viewer.column_batches` (:class:`FramePeaks`): the same rule as
the batch report's ``peak_hz`` (:mod:`chatterspec.detection.detect`), applied to every frame of a batch
in one pass.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._jit import enabled, njit
from ..online.monitor import ChatteringMonitor

__all__ = ["FramePeaks", "peak_bins"]


@njit
def _peak_bins_kernel(
    power: np.ndarray,
    tested: np.ndarray,
    expected: np.ndarray,
    thr: np.ndarray,
    out: np.ndarray,
    ratio: np.ndarray | None = None,
) -> None:  # pragma: no cover - compiled; its py_func is tested
    """:func:`peak_bins` in one pass over the tested bins of each frame and channel (first maximum
    wins, as ``np.argmax``; only subtractions and comparisons: the same bits as the numpy path), and
    the peak bin's ``S / threshold`` into ``ratio`` when given (one division, as the numpy path)."""
    n_frames, m, n_tested = power.shape[0], power.shape[2], tested.shape[0]
    for f in range(n_frames):
        for c in range(m):
            best, v_best, over, v_over = 0, -np.inf, -1, -np.inf
            for j in range(n_tested):
                p = power[f, tested[j], c]
                ex = p - expected[j, c]
                if ex > v_best:
                    best, v_best = j, ex
                if p > thr[j, c] and (over < 0 or ex > v_over):
                    over, v_over = j, ex
            k = over if over >= 0 else best
            out[f, c] = k
            if ratio is not None:
                ratio[f, c] = power[f, tested[k], c] / thr[k, c]


def _peak_bins_numpy(
    power: np.ndarray, tested: np.ndarray, expected: np.ndarray, thr: np.ndarray
) -> np.ndarray:
    """Numpy path of :func:`peak_bins` (channel-major, so every reduction runs over contiguous bins)."""
    p = np.ascontiguousarray(np.moveaxis(power[:, tested, :], 2, 0))  # (m, F, k)
    over = p > thr.T[:, None, :]
    excess = p - expected.T[:, None, :]
    k = excess.argmax(axis=2)
    rows = np.flatnonzero(over.any(axis=2))  # the (channel, frame) pairs with a bin over the threshold
    if rows.size:
        n = p.shape[2]
        masked = np.where(over.reshape(-1, n)[rows], excess.reshape(-1, n)[rows], -np.inf)
        k.reshape(-1)[rows] = masked.argmax(axis=1)
    return k.T


def peak_bins(
    power: np.ndarray,
    tested: np.ndarray,
    expected: np.ndarray,
    thr: np.ndarray,
    out: np.ndarray | None = None,
    ratio: np.ndarray | None = None,
) -> np.ndarray:
    """Index (into ``tested``) of each frame's largest excess power ``S - E`` among the bins over the
    threshold, or among all tested bins when none is over: the rule of the batch report's ``peak_hz``.

    Parameters
    ----------
    power : (F, bins, m) float array
        Frame spectra ``S`` (the monitor's frame power).
    tested : (k,) int array
        The tested bins (indices into ``bins``).
    expected : (k, m) float array
        Expected healthy spectrum ``E`` at the tested bins.
    thr : (k, m) float array
        Frame threshold at the tested bins (a bin is over when ``S > thr``).
    out : (F, m) int64 array, optional
        Written in place and returned (the logger fills one batch array block by block).
    ratio : (F, m) float array, optional
        Filled in place with ``S / threshold`` at each peak bin.

    Returns
    -------
    (F, m) int64 array
        Position in ``tested`` of the peak bin of each frame and channel.
    """
    power = np.asarray(power, dtype=float)
    if not enabled():
        k = _peak_bins_numpy(power, tested, expected, thr)
        if ratio is not None:
            cols = np.arange(k.shape[1])
            ratio[...] = power[np.arange(k.shape[0])[:, None], tested[k], cols] / thr[k, cols]
        if out is None:
            return k
        out[...] = k
        return out
    if out is None:
        out = np.empty((power.shape[0], power.shape[2]), dtype=np.int64)
    if ratio is None:
        _peak_bins_kernel(power, tested, expected, thr, out)
    else:
        _peak_bins_kernel(power, tested, expected, thr, out, ratio)
    return out


class FramePeaks:
    """Peak frequency (Hz) of every frame of a batch among a monitor's tested bins (:func:`peak_bins`).

    Parameters
    ----------
    monitor : ChatteringMonitor
        Gives the frequencies (Hz), the tested bins and the frame threshold.
    expected : (bins, m) float array
        Expected healthy frame spectrum ``E``.
    """

    def __init__(self, monitor: ChatteringMonitor, expected: np.ndarray) -> None:
        thr = monitor.threshold
        tested = np.flatnonzero(thr.tested)  # the bins tested by the detector
        self._tested_idx = tested.astype(np.int64)
        self._tested_hz = monitor.freqs_hz[tested]
        self._tested_expected = np.ascontiguousarray(expected[tested])  # (k, m)
        self._tested_thr = np.ascontiguousarray(thr.values[tested])  # (k, m)

    def __call__(self, frames: list[Any]) -> tuple[np.ndarray, np.ndarray]:
        """(F, m) tested bin (Hz) with the largest excess power ``S - E`` among the bins over the threshold
        when a frame has any (as the batch report's ``peak_hz``: a frame's overall largest excess sits on
        noise once a fault fades), else among all tested bins (:func:`peak_bins`); and (F, m) its
        ``S / threshold``, for the frame blocks ``frames`` (each with ``power`` (n, bins, m)) in order."""
        m = self._tested_thr.shape[1]
        F = sum(f.n_frames for f in frames)
        k = np.empty((F, m), dtype=np.int64)
        ratio = np.empty((F, m))
        a = 0
        for f in frames:
            b = a + f.n_frames
            idx, ex, thr = self._tested_idx, self._tested_expected, self._tested_thr
            peak_bins(f.power, idx, ex, thr, out=k[a:b], ratio=ratio[a:b])
            a = b
        return self._tested_hz[k], ratio
