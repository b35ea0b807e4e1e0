"""STFT frame verdicts and fault intervals: one verdict rule for batch records and the online monitor.

:func:`frame_verdicts` (and its precomputed form :class:`FrameVerdicts`, which the online monitor
keeps between pushes) flags a frame on a channel when its spectrum exceeds the per-frame threshold
at any tested bin; :func:`detect_frames` and :func:`frame_statistic` are its flags and peak ratios
for a :class:`~chatterspec.detection.spectral.Spectrogram`. :func:`frame_intervals` turns flags
into onset/offset times, :func:`stft_detect` does all of it for one record.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._repr import short_repr
from ..errors import ParameterError, ShapeError
from ..plants.nonlinear import Model
from ._verdict import peak_channel, peak_kernel
from .spectral import DEFAULT_STFT, Spectrogram, STFTConfig, spectrogram, spectrum_model
from .spectrum_verdicts import _channel_names
from .thresholds import (
    Band,
    Correction,
    Threshold,
    frame_threshold,
)

__all__ = [
    "FrameDetection",
    "FrameVerdicts",
    "detect_frames",
    "frame_intervals",
    "frame_statistic",
    "frame_verdicts",
    "healthy_frame_level",
    "peak_channel",
    "stft_detect",
]


class FrameVerdicts:
    """:func:`frame_verdicts` with the tested bins and their threshold precomputed (the monitor's per-push
    cost).

    Parameters
    ----------
    threshold : Threshold
        Per-frame threshold (:func:`chatterspec.detection.thresholds.frame_threshold`).
    compiled : bool
        Take the compiled one-pass loop (:data:`chatterspec.detection._verdict.peak_kernel`) for
        ``(frames, bins, m)`` spectra when the tested bins are contiguous (same numbers).

    See Also
    --------
    frame_verdicts : the checked function form.
    """

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
        # the monitor's case (contiguous tested bins, one-pass rule) in one compiled pass when enabled:
        # the detection verdict's loop without the excess and the sum (detection._verdict.peak_kernel)
        self.compiled = compiled and self.one_pass and isinstance(self.sel, slice)
        self._positions = np.arange(tested.size, dtype=np.int64)
        self._no_expected = np.empty((0, 0))

    def __call__(self, power: np.ndarray, finite: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(flags, peak_hz, peak_ratio)`` of frame spectra ``power`` ``(..., F, bins, m)``, unchecked.

        ``finite``: ``power`` holds no NaN / inf (always so in the monitor: its input is checked).
        """
        if self.compiled and finite and power.ndim == 3:
            F, m = power.shape[0], power.shape[2]
            k, peak_ratio = np.empty((F, m), dtype=np.int64), np.empty((F, m))
            peak_kernel(
                power[:, self.sel],
                self.values,
                self._no_expected,
                self._positions,
                k,
                peak_ratio,
                k,
                peak_ratio,
            )
            return peak_ratio > 1.0, self.freqs[k], peak_ratio
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


def frame_verdicts(power: np.ndarray, threshold: Threshold) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-frame verdicts from frame spectra.

    Parameters
    ----------
    power : (..., F, bins, m) array
        Frame spectra (see :func:`chatterspec.detection.spectral.frame_columns`).
    threshold : Threshold
        Per-frame threshold (:func:`chatterspec.detection.thresholds.frame_threshold`).

    Returns
    -------
    (flags, peak_hz, peak_ratio)
        Each ``(..., F, m)``: a frame is flagged on a channel when any tested bin
        exceeds the threshold, i.e. when the largest ``S / threshold`` over the
        tested bins is > 1; ``peak_hz`` is that bin's frequency (Hz).

    See Also
    --------
    detect_frames : the flags of a :class:`~chatterspec.detection.spectral.Spectrogram`.
    frame_statistic : the peak ratios of a spectrogram.
    chatterspec.online.monitor.ChatteringMonitor : the same verdicts, frame by frame.
    """
    power = threshold.check_spectrum(power)
    return FrameVerdicts(threshold)(power, finite=bool(np.isfinite(power).all()))


def detect_frames(spec: Spectrogram, frame_threshold: Threshold) -> np.ndarray:
    """``(..., frames, m)`` bool: frame spectrum above the per-frame threshold at any tested bin.

    DC and Nyquist are excluded (``frame_threshold.tested``).

    Parameters
    ----------
    spec : Spectrogram
        Frame spectra ``(..., frames, bins, m)``.
    frame_threshold : Threshold
        Per-frame threshold on the same frequency grid
        (:func:`chatterspec.detection.thresholds.frame_threshold`).

    Raises
    ------
    ShapeError
        If the spectrogram's ``(bins, m)`` does not match the threshold.

    See Also
    --------
    frame_statistic : the peak ratio of each frame (flagged when > 1).
    frame_verdicts : flags, peak frequencies and ratios in one pass.
    """
    return frame_verdicts(spec.power, frame_threshold)[0]


def frame_statistic(spec: Spectrogram, frame_threshold: Threshold) -> np.ndarray:
    """``(..., frames, m)``: the per-frame statistic ``max_n S(f_n) / threshold(f_n)`` over the tested bins.

    A frame is flagged by :func:`detect_frames` exactly when this exceeds 1.

    Parameters
    ----------
    spec : Spectrogram
        Frame spectra ``(..., frames, bins, m)``.
    frame_threshold : Threshold
        Per-frame threshold on the same frequency grid.

    See Also
    --------
    detect_frames : the flags.
    frame_verdicts : flags, peak frequencies and ratios in one pass.
    """
    return frame_verdicts(spec.power, frame_threshold)[2]


def healthy_frame_level(frame_threshold: Threshold) -> float:
    """Median of the per-frame statistic (:func:`frame_statistic`) on a healthy frame.

    With ``n`` tested bins, each at per-bin level ``a`` (after the correction), and the
    chi2(2)/2 law of a healthy bin (``P(S / t > x) = a^x``; bins independent),
    ``P(max <= x) = (1 - a^x)^n``, so the median is ``m0 = ln(1 - 2^(-1/n)) / ln a``
    (0.50 for 499 bins at family-wise 0.1 % Bonferroni; the exact-law value is close:
    0.50 observed over healthy frames). Clipped to ``(0, 1]``; 1 (the threshold) when the
    threshold has no per-bin level (empirical thresholds).

    Parameters
    ----------
    frame_threshold : Threshold
        Per-frame threshold.
    """
    a, n = frame_threshold.per_test_alpha, frame_threshold.n_tested
    if not np.isfinite(a) or not 0.0 < a < 1.0:
        return 1.0
    m0 = float(np.log(-np.expm1(-np.log(2.0) / n)) / np.log(a))
    return float(min(1.0, max(m0, 1e-12)))


def frame_intervals(
    flags: np.ndarray,
    times_s: np.ndarray,
    config: STFTConfig,
    dt: float,
    statistic: np.ndarray | None = None,
    level: float = 1.0,
) -> list[tuple[float, float]]:
    """Merge runs of contiguous flagged frames into ``(onset_s, offset_s)`` estimates.

    **Window-extent estimator** (with ``statistic``, used by :func:`stft_detect`):
    a frame whose window ``[s_j, s_j + W dt)`` overlaps the fault can flag, one that
    does not has the healthy law. So the onset of a run whose first flagged frame is
    ``f`` lies in ``[s_{f-1} + W dt, s_f + W dt]`` (end of the last unflagged window, end
    of the first flagged one) and the offset of a run whose last flagged frame is ``l``
    in ``[s_l, s_{l+1}]``. Inside each bracket the per-frame statistic ``r_j``
    (:func:`frame_statistic`) locates the edge: ``log r`` is interpolated linearly
    between the two frames and the crossing of ``log level`` (the healthy median
    :func:`healthy_frame_level`, the value of a window that just touches the fault)
    gives the position ``s*`` (clipped to the bracket) of the window that just touches
    the fault: ``onset = s* + W dt`` (its end), ``offset = s*`` (its start). A run
    shorter than a window whose estimates cross (onset > offset) is reported as a
    zero-length interval at their mean. A run touching the start (end) of the record
    gets the start of the first (end of the last) window: the fault may predate
    (outlast) it. Resolution: a strong fault edge is found within the bracket of one
    hop ``H dt``; a fault whose signature fades before it ends (a decaying transient)
    is ended where it becomes invisible (``docs/paper-notes.md``, STFT onset/offset).

    **Frame-centre estimator** (``statistic=None``, the online monitor's): a frame is
    assumed flagged once its centre lies inside the fault, ``onset = c_first - H dt / 2``,
    ``offset = c_last + H dt / 2``; strong faults flag frames that overlap them by a
    single hop, which biases it outward by up to ``(W - H) dt / 2``.

    Parameters
    ----------
    flags : (frames,) bool array
        One channel (or the any-channel combination) of :func:`detect_frames` for one run.
    times_s : (frames,) array
        Frame-centre times (:attr:`Spectrogram.times_s`).
    config : STFTConfig
    dt : float
        Sampling time (s).
    statistic : (frames,) array, optional
        Per-frame statistic ``max S / threshold`` (:func:`frame_statistic`, same channel);
        selects the window-extent estimator.
    level : float
        Healthy median of the statistic (:func:`healthy_frame_level`), in (0, 1].
    """
    flags = np.asarray(flags, dtype=bool)
    times = np.asarray(times_s, dtype=float)
    if flags.ndim != 1 or times.shape != flags.shape:
        raise ShapeError(
            f"flags and times_s must be 1-D of equal length (one run, one channel); got {flags.shape} "
            f"and {times.shape}"
        )
    if statistic is not None:
        stat = np.asarray(statistic, dtype=float)
        if stat.shape != flags.shape:
            raise ShapeError(f"statistic must have the shape of flags {flags.shape}; got {stat.shape}")
        if not 0.0 < float(level) <= 1.0:
            raise ParameterError(
                f"level must lie in (0, 1] (a healthy median of max S / threshold); got {level}"
            )
    if not flags.any():
        return []
    hop = config.n_hop(dt) * dt
    half_hop = hop / 2.0
    half_win = (config.n_window(dt) - 1) * dt / 2.0
    padded = np.concatenate(([False], flags, [False]))
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    out = []
    if statistic is None:
        for start, stop in zip(edges[::2], edges[1::2], strict=True):
            last = stop - 1
            onset = times[start] - (half_win if start == 0 else half_hop)
            offset = times[last] + (half_win + dt if last == flags.size - 1 else half_hop)
            out.append((float(onset), float(offset)))
        return out
    win = config.n_window(dt) * dt
    starts = times - half_win  # first sample of each window
    logr = np.log(np.maximum(stat, 1e-300))
    lvl = np.log(level)

    def crossing(inside: int, outside: int) -> float:
        """Fraction (0..1) of the way from frame ``inside`` to ``outside`` where log r reaches lvl."""
        drop = logr[inside] - logr[outside]
        return float(np.clip((logr[inside] - lvl) / drop, 0.0, 1.0)) if drop > 0 else 1.0

    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        last = stop - 1
        if start == 0:
            onset = starts[0]
        else:
            onset = starts[start] - crossing(start, start - 1) * hop + win
        if last == flags.size - 1:
            offset = starts[last] + win
        else:
            offset = starts[last] + crossing(last, last + 1) * hop
        if onset > offset:
            onset = offset = 0.5 * (onset + offset)
        out.append((float(onset), float(offset)))
    return out


@dataclass(frozen=True, eq=False)
class FrameDetection:
    """STFT detection of one record: spectrogram, per-frame threshold, flags and intervals.

    Attributes
    ----------
    spectrogram : Spectrogram
    threshold : Threshold
        Per-frame threshold (``alpha_meaning="per-frame"``).
    flags : (..., frames, m) bool array
    intervals : dict of str -> list of (onset_s, offset_s)
        Per channel and under ``"any"`` (any channel flagged), for run 0
        (window-extent estimator of :func:`frame_intervals`).
    statistic : (..., frames, m) array or None
        Per-frame statistic ``max S / threshold`` (:func:`frame_statistic`).
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    spectrogram: Spectrogram
    threshold: Threshold
    flags: np.ndarray
    intervals: dict[str, list[tuple[float, float]]]
    statistic: np.ndarray | None = None


def stft_detect(
    x: np.ndarray,
    model: Model,
    *,
    t0: float = 0.0,
    config: STFTConfig = DEFAULT_STFT,
    alpha: float = 1e-3,
    correction: Correction = "bonferroni",
    channels: Sequence[str] | None = None,
    band: Band | None = None,
    threshold: Threshold | None = None,
) -> FrameDetection:
    """Spectrogram + per-frame threshold + flags + intervals for chattering ``x`` (..., N, m).

    Parameters
    ----------
    x : (..., N, m) array
        Chattering; time on axis -2.
    model : LinearModel
        Nominal model (expected frame spectrum, sampling time).
    t0 : float
        Time (s) of ``x``'s first sample.
    config : STFTConfig
        Window settings (default 1 s Hamming, 0.2 s hop).
    alpha : float
        Per-frame false-alarm probability in (0, 1).
    correction : {"bonferroni", "sidak", "none"}
        Family-wise control over the bins of one frame.
    channels : sequence of str, optional
        Channel names (default ``model.output_names``).
    band : (float, float), optional
        ``(lo, hi)`` in Hz: frame bins tested (the correction counts only these).
    threshold : Threshold, optional
        Per-frame threshold to use instead of the analytic one (``alpha`` and ``correction`` are
        then ignored), e.g. a calibration's ``threshold("frame-family-wise")``; required for a
        nonlinear model, which has no closed-form frame spectrum.

    Raises
    ------
    ShapeError
        If the record is shorter than one window.
    """
    spec = spectrogram(x, model.dt, config, t0=t0)
    if threshold is not None:
        th = threshold.restricted(band)
        if th.values.shape != spec.power.shape[-2:]:
            raise ShapeError(
                f"the per-frame threshold covers {th.values.shape} (bins, channels); these frames have "
                f"{spec.power.shape[-2:]}: it was made for another STFT window or model"
            )
    else:
        th = frame_threshold(
            spectrum_model(model), spec.freqs_hz, config, model.dt, alpha, correction, band=band
        )
    flags, _, stat = frame_verdicts(spec.power, th)
    level = healthy_frame_level(th)
    names = _channel_names(channels or model.output_names, flags.shape[-1])
    first = flags.reshape(-1, *flags.shape[-2:])[0]
    first_stat = stat.reshape(-1, *stat.shape[-2:])[0]
    times, dt = spec.times_s, model.dt
    intervals = {
        n: frame_intervals(first[:, i], times, config, dt, first_stat[:, i], level)
        for i, n in enumerate(names)
    }
    # any channel: the frame's largest statistic over the channels
    intervals["any"] = frame_intervals(first.any(axis=-1), times, config, dt, first_stat.max(axis=-1), level)
    return FrameDetection(spec, th, flags, intervals, stat)
