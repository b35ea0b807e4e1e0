"""Healthy-run scenarios and the streaming summary of a healthy Monte Carlo study.

:class:`HealthyStudy` summarizes chunks of healthy runs for calibration, false-alarm and power
studies: the largest normalized values (top-k tails), the exceedance counts of K thresholds and,
above a memory budget, tail histograms.

Compiled exceedance counts (:func:`exceedance_counts`): :meth:`HealthyStudy._summarize` compares
every spectrum bin with K thresholds and counts. In numpy that is a ``(K, runs, frames, bins, m)`` boolean
array and half a dozen reductions over it; this kernel reads each power value once and
increments two integer tables, from which every count of the study follows by integer
sums (exact, so the numbers are those of the numpy path whatever the order).

Bounded-memory order-statistic quantiles: per-cell tail histograms with pilot-placed fine windows.

The exact calibration path (:func:`~chatterspec.studies.calibration.thresholds.calibrate`) keeps,
per bin and channel, the ``k`` largest normalized powers ``S / E[S]`` over all runs and reads
the order statistics of the ``(1 - alpha)``-quantile and its interval from them; ``k`` grows like
``runs x alpha`` (and ``runs x frames x alpha`` for STFT frames), so memory grows with the run count.
The tail histogram is the path used instead when those tails would exceed a memory budget
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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np

from ... import _jit
from ..._validate import open_unit
from ...detection.pipeline import iter_chattering
from ...detection.spectral import STFTConfig, periodogram, periodogram_freqs
from ...detection.spectral import spectrogram as stft_spectrogram
from ...detection.thresholds import Threshold, exact_threshold, frame_threshold, paper_threshold
from ...errors import ParameterError
from ...plants.models import LinearModel
from ...plants.scenarios import Scenario
from ..intervals import _pooled_ranks

__all__ = [
    "COARSE_BUCKETS",
    "DEFAULT_TAIL_BUDGET",
    "FINE_BUCKETS",
    "exceedance_counts",
    "tail_bytes",
]


# --------------------------------------------------------------------------- summaries
def _merge_top(a: np.ndarray, b: np.ndarray, k: int) -> np.ndarray:
    both = np.concatenate([a, b], axis=0)
    if both.shape[0] <= k:
        return both
    # copy: the slice of the partitioned 2k rows would keep all of them alive in the accumulator
    return np.partition(both, both.shape[0] - k, axis=0)[both.shape[0] - k :].copy()


def _reduce_dict(
    acc: dict[str, np.ndarray] | None, part: dict[str, np.ndarray], k_top: dict[str, int]
) -> dict[str, np.ndarray]:
    if acc is None:
        return dict(part)
    out: dict[str, np.ndarray] = {}
    for key, val in part.items():
        if key.startswith("top_"):
            out[key] = _merge_top(acc[key], val, k_top[key])
        elif key.startswith("runs_"):
            out[key] = np.concatenate([acc[key], val], axis=0)
        else:
            out[key] = acc[key] + val
    return out


class _SummedChunks:
    """Base of a study whose chunk summaries are dicts of counts and sums, added chunk by chunk."""

    def reduce(self, acc: dict[str, np.ndarray] | None, part: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``acc`` with one chunk's summary ``part`` folded in (``acc`` is None for the first chunk)."""
        return _reduce_dict(acc, part, {})


def _keep_top(x: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` largest values along axis 0 (unsorted)."""
    if k <= 0:
        return x[:0]
    if x.shape[0] <= k:
        return x
    return np.partition(x, x.shape[0] - k, axis=0)[x.shape[0] - k :]


@dataclass(frozen=True, eq=False)
class HealthyStudy:
    """Chunk function of calibration and false-alarm studies (picklable; see :mod:`chatterspec.montecarlo`).

    Thresholds are passed as stacked arrays so that workers do not rebuild them.
    Each chunk simulates healthy chattering, takes its periodogram (and STFT
    frames if ``config`` and ``fthr_values`` are set) and counts exceedances.
    Exported as ``FalseAlarmStudy``.

    Attributes
    ----------
    scenario : Scenario
        Healthy scenario to simulate.
    thr_values : (K, bins, m) array
        Power thresholds of the K record-level kinds, in the squared output
        units of the periodogram (e.g. Pa^2 for pressure).
    thr_tested : (K, bins) bool array
        Bins each kind tests (DC and Nyquist excluded).
    expected : (bins, m) array
        Expected healthy periodogram E[S] (eq 56), used to normalize ``S / E[S]``.
    tested : (bins,) bool array
        Bins over which the normalized per-record maximum is taken.
    config : STFTConfig, optional
        STFT settings of the per-frame kinds; None skips the frame statistics.
    fthr_values : (Kf, fbins, m) array, optional
        Per-frame thresholds of the Kf frame kinds.
    fthr_tested : (Kf, fbins) bool array, optional
        Frame bins each frame kind tests.
    fexpected : (fbins, m) array, optional
        Expected healthy frame spectrum; needed only when ``kf_top > 0``.
    k_top : int
        Largest normalized bin powers to keep (for the empirical per-bin
        quantile interval); 0 keeps none.
    kf_top : int
        Largest normalized frame powers to keep (empirical per-frame quantile).
    keep_max : bool
        Keep each record's normalized maximum over ``tested`` bins (for the
        empirical family-wise threshold).
    bin_window, frame_window, frame_max_window : (lo, hi) pairs of arrays, optional
        Bounded-memory alternative to ``k_top`` / ``kf_top`` (used when those are 0):
        per-cell windows of the tail histograms of the tail histogram below for the
        normalized bin powers ``(bins, m)``, frame powers ``(fbins, m)`` and frame
        maxima ``(m,)``; the summary then holds ``hist_*`` bucket counts.
    """

    scenario: Scenario
    thr_values: np.ndarray  # (K, bins, m)
    thr_tested: np.ndarray  # (K, bins)
    expected: np.ndarray  # (bins, m)
    tested: np.ndarray  # (bins,) bins of the normalized maximum
    config: STFTConfig | None = None
    fthr_values: np.ndarray | None = None  # (Kf, fbins, m)
    fthr_tested: np.ndarray | None = None  # (Kf, fbins)
    fexpected: np.ndarray | None = None  # (fbins, m)
    k_top: int = 0
    kf_top: int = 0
    keep_max: bool = False
    bin_window: tuple[np.ndarray, np.ndarray] | None = None
    frame_window: tuple[np.ndarray, np.ndarray] | None = None
    frame_max_window: tuple[np.ndarray, np.ndarray] | None = None

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> dict[str, np.ndarray]:
        """The summary of realizations ``first_run .. first_run + runs - 1`` (a Monte Carlo chunk)."""
        acc = None
        for rec in iter_chattering(self.scenario, runs, seed, chunk_runs=runs, first_run=first_run):
            acc = self.reduce(acc, self._summarize(rec.values, rec.dt))
        assert acc is not None  # (runs >= 1 records)
        return acc

    def _summarize(self, x: np.ndarray, dt: float) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {"runs": np.array(x.shape[0])}
        S = periodogram(x, dt).power  # (r, bins, m)
        compiled = _jit.enabled()  # one pass of integer counts, the numbers of the numpy lines
        if compiled:
            out["bin_exceed"], n_false = exceedance_counts(S[:, None], self.thr_values, self.thr_tested)
            n_false = n_false[:, :, 0]  # (K, r, m)
        else:
            exc = S[None] > self.thr_values[:, None]  # (K, r, bins, m)
            out["bin_exceed"] = exc.sum(axis=1)
            masked = exc & self.thr_tested[:, None, :, None]
            n_false = masked.sum(axis=2)  # (K, r, m)
        out["false_bins"] = n_false.sum(axis=1)
        out["false_bins_sq"] = (n_false.astype(np.int64) ** 2).sum(axis=1)
        # per-record squares: the false-alarm intervals come from run-level counts (cluster Clopper-Pearson)
        out["false_total_sq"] = (n_false.sum(axis=-1).astype(np.int64) ** 2).sum(axis=1)  # (K,)
        fw = n_false > 0
        out["fw"] = fw.sum(axis=1)  # (K, m)
        out["fw_any"] = fw.any(axis=-1).sum(axis=1)  # (K,)
        if self.keep_max or self.k_top or self.bin_window is not None:
            Y = S / self.expected
        if self.keep_max:
            out["runs_max"] = Y[:, self.tested].max(axis=1)  # (r, m)
        if self.k_top:
            out["top_bin"] = _keep_top(Y, self.k_top)
        elif self.bin_window is not None:
            out["hist_bin"] = bucket_counts(Y, *self.bin_window)
        if self.config is not None and self.fthr_values is not None:
            fthr_tested = self.fthr_tested
            assert fthr_tested is not None  # (set with fthr_values)
            P = stft_spectrogram(x, dt, self.config).power  # (r, F, fb, m)
            out["frames"] = np.array(P.shape[0] * P.shape[1])
            if compiled:
                out["frame_bin_exceed"], f_n = exceedance_counts(P, self.fthr_values, fthr_tested)
                flags = f_n > 0  # (Kf, r, F, m)
                f_false = f_n.sum(axis=2)  # (Kf, r, m) false frame-bins per record
            else:
                fexc = P[None] > self.fthr_values[:, None, None]  # (Kf, r, F, fb, m)
                out["frame_bin_exceed"] = fexc.sum(axis=(1, 2))  # (Kf, fb, m)
                fmasked = fexc & fthr_tested[:, None, None, :, None]
                flags = fmasked.any(axis=3)  # (Kf, r, F, m)
                f_false = fmasked.sum(axis=(2, 3)).astype(np.int64)  # (Kf, r, m) false frame-bins per record
            out["frame_flag"] = flags.sum(axis=(1, 2))  # (Kf, m)
            out["frame_flag_any"] = flags.any(axis=-1).sum(axis=(1, 2))  # (Kf,)
            # per-record sums of squares (overlapping frames of one record are dependent trials)
            out["frame_false_sq"] = (f_false**2).sum(axis=1)  # (Kf, m)
            out["frame_false_total_sq"] = (f_false.sum(axis=-1) ** 2).sum(axis=1)  # (Kf,)
            f_flag = flags.sum(axis=2).astype(np.int64)  # (Kf, r, m) flagged frames per record
            out["frame_flag_sq"] = (f_flag**2).sum(axis=1)  # (Kf, m)
            out["frame_flag_any_sq"] = (flags.any(axis=-1).sum(axis=2).astype(np.int64) ** 2).sum(axis=1)
            if self.kf_top:
                Yf = (P / cast(np.ndarray, self.fexpected)).reshape(-1, *P.shape[-2:])  # (set with kf_top)
                out["top_frame"] = _keep_top(Yf, self.kf_top)
                if self.keep_max:  # per frame: the largest normalized tested bin (frame family-wise)
                    out["top_frame_max"] = _keep_top(Yf[:, fthr_tested[0]].max(axis=1), self.kf_top)
            elif self.frame_window is not None:
                fexp = cast(np.ndarray, self.fexpected)  # (set with the window)
                Yf = (P / fexp).reshape(-1, *P.shape[-2:])
                out["hist_frame"] = bucket_counts(Yf, *self.frame_window)
                if self.keep_max and self.frame_max_window is not None:
                    out["hist_frame_max"] = bucket_counts(
                        Yf[:, fthr_tested[0]].max(axis=1), *self.frame_max_window
                    )
        return out

    def reduce(self, acc: dict[str, np.ndarray] | None, part: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``acc`` with one chunk's summary ``part`` folded in (``acc`` is None for the first chunk)."""
        return _reduce_dict(
            acc, part, {"top_bin": self.k_top, "top_frame": self.kf_top, "top_frame_max": self.kf_top}
        )


def _analytic_thresholds(
    model: LinearModel, n_samples: int, alpha: float
) -> tuple[np.ndarray, dict[str, Threshold]]:
    freqs = periodogram_freqs(n_samples, model.dt)
    return freqs, {
        "paper": paper_threshold(model, freqs, alpha),
        "exact": exact_threshold(model, freqs, n_samples, alpha, correction="none"),
        "exact-bonferroni": exact_threshold(model, freqs, n_samples, alpha, correction="bonferroni"),
        "exact-sidak": exact_threshold(model, freqs, n_samples, alpha, correction="sidak"),
    }


def _frame_thresholds(
    model: LinearModel, config: STFTConfig, alpha: float
) -> tuple[np.ndarray, dict[str, Threshold]]:
    freqs = config.freqs_hz(model.dt)
    return freqs, {
        "frame": frame_threshold(model, freqs, config, model.dt, alpha, correction="none"),
        "frame-bonferroni": frame_threshold(model, freqs, config, model.dt, alpha, correction="bonferroni"),
    }


def _check_alphas(alpha: float | Sequence[float]) -> tuple[float, ...]:
    alphas = (cast(float, alpha),) if np.isscalar(alpha) else tuple(cast(Sequence[float], alpha))
    if not alphas:
        raise ParameterError("alpha: give at least one value")
    return tuple(open_unit("alpha", a) for a in alphas)


def _n_frames(n_samples: int, config: STFTConfig, dt: float) -> int:
    W, H = config.n_window(dt), config.n_hop(dt)
    return max(0, (n_samples - W) // H + 1)


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
