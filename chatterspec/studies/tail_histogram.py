"""Bounded-memory order-statistic quantiles: per-cell tail histograms with pilot-placed fine windows.

The exact calibration path (:mod:`~chatterspec.studies.calibration`) keeps, per bin and channel,
the ``k`` largest normalized powers ``S / E[S]`` over all runs and reads the order statistics of
the ``(1 - alpha)``-quantile and its interval from them; ``k`` grows like ``runs x alpha`` (and
``runs x frames x alpha`` for STFT frames), so memory grows with the run count. This module is
the path used instead when those tails would exceed a memory budget
(:data:`DEFAULT_TAIL_BUDGET`, bytes):

1. **Pilot.** The first ``P = max(runs / 16, 64 / alpha)`` realizations (at most a quarter of
   the runs; the main pass sees them again) are binned into a fixed window
   (:data:`PILOT_WINDOW` = ``[1e-2, 1e2)``, 512 buckets of 1.8 %) for every cell (bin x channel,
   or channel). From these counts each cell gets its window ``[lo, hi)``, which contains, with
   probability ``>= 1 - 1e-9`` per side, the full study's order statistics at the point and
   interval ranks: the full study's ranks of :func:`~.intervals._pooled_ranks` are moved outward
   by ``WINDOW_Z = 6`` binomial standard errors (the full sample's own scatter), and the pilot's
   one-sided ``1 - 1e-9`` order-statistic bounds of those levels, read outward to the pilot's
   bucket edges, are the window edges. ``64 / alpha`` runs put ~64 pilot values above each
   bin's quantile, enough to bound the window above.
2. **Main pass.** Every realization ``[0, runs)`` adds, per cell, one count to a bucket:
   :data:`FINE_BUCKETS` log-spaced buckets inside the window, and :data:`COARSE_BUCKETS`
   log-spaced buckets over ``[COARSE_LO, COARSE_HI)`` (plus an underflow and an overflow
   bucket) separately below and above it. Chunks merge by adding integer counts: the result is
   identical whatever ``chunk_runs``, ``workers`` or scheduler (no floating-point order effect).
3. **Reading.** The bucket holding each rank is found from the cumulative counts. The interval
   ends are widened outward to bucket edges (``low`` = lower edge of the bucket of rank
   ``lo``, ``high`` = upper edge of the bucket of rank ``hi``), so the histogram interval
   always *contains* the exact order-statistic interval of the same realizations. The point
   estimate is the *upper* edge of the bucket of the point rank: at most one bucket above the
   exact order statistic, never below it (a threshold slightly on the safe side).

Resolution: a fine bucket is ``ln(hi / lo) / FINE_BUCKETS`` wide in relative terms. Measured
on chi-squared (2 dof) samples (the healthy normalized power) with the pilot sizes above, at
alpha = 1e-2 (fine bucket, max over cells, vs the width of the 99 % order-statistic interval):
3 x 10^4 runs, bin 1.7e-3 vs 6.5e-2, frame 6.0e-4 vs 3.3e-2; 10^5 runs, bin 1.2e-3 vs 3.5e-2,
frame 4.9e-4 vs 1.8e-2; 10^6 runs, bin 3.5e-4 vs 1.1e-2, frame 1.8e-4 vs 5.6e-3 (alpha = 1e-3,
10^6 runs: bin 9.1e-4 vs 2.4e-2): one bucket is 25-55 times narrower than the interval wherever
the default budget selects this path. ``tails["fine_rel_width"]`` of the result reports the
widest fine bucket actually used, and ``tails["outside_window"]`` counts the cells whose rank
fell outside their fine window (then read at the coarse resolution, still conservative; chance
<= 2e-9 per cell and quantity).

Memory: ``(2 * (COARSE_BUCKETS + 2) + FINE_BUCKETS)`` 8-byte counts per cell, ~39 MB for the
EHA record (2001 bins) and frame (501 bins) spectra of 3 channels, whatever the run count.
The family-wise record maximum (``runs_max``, one float per run and channel: 24 bytes per run
for 3 channels) stays exact; it is the only per-run array left.
"""

from __future__ import annotations

import math

import numpy as np

from .intervals import _pooled_ranks

__all__ = [
    "COARSE_BUCKETS",
    "DEFAULT_TAIL_BUDGET",
    "FINE_BUCKETS",
    "tail_bytes",
]

#: Default memory budget (bytes) of the exact top-k tails; above it the histogram path is used.
DEFAULT_TAIL_BUDGET = 128 * 2**20
#: Log-spaced buckets inside each cell's pilot window.
FINE_BUCKETS = 512
#: Log-spaced buckets over [COARSE_LO, COARSE_HI) below and above the window (one each side).
COARSE_BUCKETS = 64
COARSE_LO, COARSE_HI = 1e-6, 1e6
#: One-sided miss probability of each pilot window edge, and the full study's scatter in SEs.
WINDOW_EPS = 1e-9
WINDOW_Z = 6.0
#: Window of the pilot's own histogram (normalized power; 512 buckets of 1.8 %), and the pilot's
#: target number of values above the quantile per cell.
PILOT_WINDOW = (1e-2, 1e2)
PILOT_TAIL = 64
_NC = COARSE_BUCKETS + 2  # coarse buckets of one side, with underflow and overflow
N_BUCKETS = 2 * _NC + FINE_BUCKETS
_DC = math.log(COARSE_HI / COARSE_LO) / COARSE_BUCKETS
_BLOCK_VALUES = 2**19  # values binned at once (bounds the temporaries of bucket_counts)
_OUT = 1e-12  # reported edges are widened by this relative amount (floating rounding of the logs)


def tail_bytes(k_top: int, kf_top: int, bins: int, fbins: int, m: int) -> int:
    """Bytes of the exact tails (top-k per bin, per frame bin and frame maximum), merge copy included.

    Parameters
    ----------
    k_top, kf_top : int
        Values kept per record bin and per frame bin (and per channel for the frame maximum).
    bins, fbins : int
        Record and frame frequency bins.
    m : int
        Output channels.

    Returns
    -------
    int
        ``2 * 8 * (k_top bins m + kf_top fbins m + kf_top m)``: the accumulated tail plus the
        chunk's tail concatenated to it while merging.
    """
    return 16 * (k_top * bins * m + kf_top * (fbins + 1) * m)


def pilot_runs(runs: int, alpha: float, block: int) -> int:
    """Pilot size: ``max(runs / 16, PILOT_TAIL / alpha)`` in whole blocks, within ``[block, runs / 4]``.

    ``PILOT_TAIL / alpha`` runs put ~``PILOT_TAIL`` values above the quantile of each bin (enough
    for a bounded window at ``WINDOW_Z``); ``runs / 16`` narrows the window as the study grows.
    At most a quarter of the runs (and one block at least, then ``min(block, runs)``).
    """
    want = max(runs // 16, math.ceil(PILOT_TAIL / alpha))
    p = min(want, runs // 4) // block * block
    return min(max(p, block), runs)


def pilot_window(shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The pilot's own window: :data:`PILOT_WINDOW` for every cell."""
    return np.full(shape, PILOT_WINDOW[0]), np.full(shape, PILOT_WINDOW[1])


def window(
    counts: np.ndarray, n_p: int, n_p_eff: int, n: int, n_eff: int, q: float, confidence: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per-cell window ``[lo, hi)`` of the main pass from the pilot's bucket counts.

    ``counts`` are the pilot's :func:`bucket_counts` in :func:`pilot_window` (``n_p`` samples,
    ``n_p_eff`` independent ones); ``n`` / ``n_eff`` are the full study's. The pilot's one-sided
    ``1 - WINDOW_EPS`` order-statistic bounds of the levels of :func:`_levels` are read as bucket
    edges (outward), so each edge is on the safe side with probability ``>= 1 - WINDOW_EPS``.
    """
    a_lvl, b_lvl = _levels(n, n_eff, q, confidence)
    shape = counts.shape[:-1]
    plo, phi = pilot_window(shape)
    cum = np.cumsum(counts, axis=-1)
    r_lo = _pooled_ranks(n_p, n_p_eff, a_lvl, 1 - 2 * WINDOW_EPS)[1]
    r_hi = _pooled_ranks(n_p, n_p_eff, b_lvl, 1 - 2 * WINDOW_EPS)[2]
    lo = np.full(shape, COARSE_LO) if r_lo < 1 else _edges(np.sum(cum < r_lo, axis=-1), plo, phi)[0]
    hi = np.full(shape, COARSE_HI) if r_hi > n_p else _edges(np.sum(cum < r_hi, axis=-1), plo, phi)[1]
    lo = np.clip(lo, COARSE_LO, COARSE_HI)
    hi = np.clip(hi, COARSE_LO, COARSE_HI)
    hi = np.where(hi > lo * (1 + 1e-9), hi, lo * (1 + 1e-6))  # ties (or an empty window): keep it open
    return lo.astype(float), hi.astype(float)


def _levels(n: int, n_eff: int, q: float, confidence: float) -> tuple[float, float]:
    """Quantile levels bracketing the full study's point and interval ranks with Z SEs of margin."""
    point, lo, hi = _pooled_ranks(n, n_eff, q, confidence)
    se = math.sqrt(q * (1 - q) / n_eff)
    a_lvl = min(max(lo, 1), point) / n - WINDOW_Z * se
    b_lvl = max(min(hi, n), point) / n + WINDOW_Z * se
    return min(max(a_lvl, 1e-12), 1 - 1e-12), min(max(b_lvl, 1e-12), 1 - 1e-12)


def bucket_counts(y: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Histogram counts ``(*cells, N_BUCKETS)`` of samples ``y`` ``(n, *cells)`` per cell.

    Bucket layout per cell, ascending in value: ``_NC`` coarse buckets of the values below
    ``lo`` (underflow ``[0, COARSE_LO)``, ``COARSE_BUCKETS`` log buckets, overflow), then
    ``FINE_BUCKETS`` log buckets of ``[lo, hi)``, then ``_NC`` coarse buckets of the values
    ``>= hi``. NaN counts as ``+inf``.
    """
    cells = lo.shape
    y = y.reshape(y.shape[0], -1)
    lo_f, hi_f = lo.reshape(-1), hi.reshape(-1)
    llo, lhi = np.log(lo_f), np.log(hi_f)
    dfine = (lhi - llo) / FINE_BUCKETS
    offset = N_BUCKETS * np.arange(y.shape[1])
    counts = np.zeros(y.shape[1] * N_BUCKETS, dtype=np.int64)
    step = max(1, _BLOCK_VALUES // max(y.shape[1], 1))  # rows per block: ~4 MB temporaries
    for start in range(0, y.shape[0], step):
        with np.errstate(divide="ignore", invalid="ignore"):
            yb = y[start : start + step]
            ly = np.log(np.where(np.isnan(yb), np.inf, yb))
        coarse = np.clip(np.floor((ly - math.log(COARSE_LO)) / _DC) + 1, 0, _NC - 1)
        fine = np.clip(np.floor((ly - llo) / dfine), 0, FINE_BUCKETS - 1)
        idx = np.where(ly < llo, coarse, np.where(ly >= lhi, _NC + FINE_BUCKETS + coarse, _NC + fine))
        counts += np.bincount((idx.astype(np.int64) + offset).ravel(), minlength=counts.size)
    return counts.reshape(*cells, N_BUCKETS)


def _edges(j: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper value edges of bucket ``j`` (per cell), widened outward by ``_OUT``."""

    def coarse_lower(k: np.ndarray) -> np.ndarray:
        return np.where(k == 0, 0.0, COARSE_LO * np.exp((k - 1) * _DC))

    def coarse_upper(k: np.ndarray) -> np.ndarray:
        return np.where(k >= _NC - 1, np.inf, COARSE_LO * np.exp(np.minimum(k, _NC - 2) * _DC))

    kb = np.clip(j, 0, _NC - 1)
    i = np.clip(j - _NC, 0, FINE_BUCKETS - 1)
    ka = np.clip(j - _NC - FINE_BUCKETS, 0, _NC - 1)
    d = np.log(hi / lo) / FINE_BUCKETS
    f_lo = lo * np.exp(i * d)
    f_hi = np.where(i == FINE_BUCKETS - 1, hi, lo * np.exp((i + 1) * d))
    is_b, is_a = j < _NC, j >= _NC + FINE_BUCKETS
    lower = np.where(is_b, coarse_lower(kb), np.where(is_a, np.maximum(coarse_lower(ka), hi), f_lo))
    upper = np.where(is_b, np.minimum(coarse_upper(kb), lo), np.where(is_a, coarse_upper(ka), f_hi))
    return lower * (1 - _OUT), upper * (1 + _OUT)


def quantile_from_counts(
    counts: np.ndarray, lo: np.ndarray, hi: np.ndarray, n: int, q: float, confidence: float, n_eff: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Point, interval low and high per cell from bucket counts, and the cells read outside the window.

    Ranks are those of :func:`~.intervals._pooled_ranks` (as the exact path); see the module
    docstring for how each is read. Returns ``(point, low, high, outside)``.
    """
    point, r_lo, r_hi = _pooled_ranks(n, n_eff, q, confidence)
    cum = np.cumsum(counts, axis=-1)

    def bucket(r: int) -> np.ndarray:
        return np.sum(cum < r, axis=-1)

    jp = bucket(point)
    lower_p, upper_p = _edges(jp, lo, hi)
    value = np.where(np.isfinite(upper_p), upper_p, lower_p)
    if r_lo < 1:
        low, jl = np.full(lo.shape, -np.inf), jp
    else:
        jl = bucket(r_lo)
        low = _edges(jl, lo, hi)[0]
    if r_hi > n:
        high, jh = np.full(lo.shape, np.inf), jp
    else:
        jh = bucket(r_hi)
        high = _edges(jh, lo, hi)[1]
    fine = [(j >= _NC) & (j < _NC + FINE_BUCKETS) for j in (jp, jl, jh)]
    outside = int(np.count_nonzero(~(fine[0] & fine[1] & fine[2])))
    return value, low, high, outside


def fine_rel_width(lo: np.ndarray, hi: np.ndarray) -> float:
    """Largest relative width ``exp(ln(hi/lo)/FINE_BUCKETS) - 1`` of a fine bucket over the cells."""
    return float(np.expm1(np.max(np.log(hi / lo)) / FINE_BUCKETS))
