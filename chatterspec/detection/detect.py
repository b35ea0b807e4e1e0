"""Detection verdicts, severity scores and onset/offset localization (``DESIGN.md`` section 5).

A channel is flagged when its spectrum exceeds the threshold at any **tested**
bin (DC and Nyquist excluded; the DC ratio is reported separately because a
step input puts a large DC term into any mismatch). The default detector is the
``exact`` threshold with Bonferroni correction at family-wise alpha = 0.1 %.

Severity scores (both grow with fault size within a fault family):

``peak_ratio``
    ``max_n S(f_n) / threshold(f_n)`` over the tested bins (the paper's peak
    height relative to its bound; > 1 means detected).
``excess_power``
    ``sum_n (S(f_n) - E[S(f_n)]) / sum_n E[S(f_n)]`` over the tested bins: the
    fraction of power above the healthy expectation (about 0 when healthy,
    with standard deviation ``1 / sqrt(n_tested)`` for a single record).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .._validate import open_unit
from ..errors import ParameterError, ShapeError
from ..plants.models import LinearModel
from .pipeline import ChatteringRecord
from .spectral import DEFAULT_STFT, Spectrogram, STFTConfig, expected_spectrum, periodogram, spectrogram
from .thresholds import Correction, Threshold, exact_threshold, frame_threshold, paper_threshold

__all__ = [
    "ChannelVerdict",
    "DetectionReport",
    "FrameDetection",
    "SpectrumDetection",
    "detect_frames",
    "detect_record",
    "detect_spectrum",
    "frame_intervals",
    "stft_detect",
]


@dataclass(frozen=True)
class ChannelVerdict:
    """Verdict for one channel of one spectrum (scipy.stats-style named result).

    Attributes
    ----------
    channel : str
    detected : bool
        Any tested bin above the threshold.
    peak_hz : float
        Frequency (Hz) of the tested bin with the largest ``S / threshold``.
    peak_ratio : float
        ``max S / threshold`` over the tested bins.
    excess_power : float
        ``sum (S - E[S]) / sum E[S]`` over the tested bins.
    dc_ratio : float
        ``S(0) / threshold(0)`` (not used for the verdict).
    threshold_kind : str
    alpha : float
    alpha_meaning : str
    """

    channel: str
    detected: bool
    peak_hz: float
    peak_ratio: float
    excess_power: float
    dc_ratio: float
    threshold_kind: str
    alpha: float
    alpha_meaning: str

    def to_dict(self) -> dict[str, object]:
        """JSON-ready ``{"channel", "detected", "peak_hz", "peak_ratio", "excess_power", "dc_ratio"}``."""
        return {
            "channel": self.channel,
            "detected": bool(self.detected),
            "peak_hz": float(self.peak_hz),
            "peak_ratio": float(self.peak_ratio),
            "excess_power": float(self.excess_power),
            "dc_ratio": float(self.dc_ratio),
        }


@dataclass(frozen=True, eq=False)
class SpectrumDetection:
    """Verdicts for many spectra at once: every field is an array ``(..., m)``.

    Attributes
    ----------
    detected, peak_hz, peak_ratio, excess_power, dc_ratio : (..., m) arrays
        See :class:`ChannelVerdict`; the leading axes are those of the spectra.
    channels : tuple of str
    threshold : Threshold
    """

    detected: np.ndarray
    peak_hz: np.ndarray
    peak_ratio: np.ndarray
    excess_power: np.ndarray
    dc_ratio: np.ndarray
    channels: tuple[str, ...]
    threshold: Threshold

    @property
    def any_channel(self) -> np.ndarray:
        """``(...)`` bool: any channel detected."""
        return self.detected.any(axis=-1)

    @property
    def detection_rate(self) -> np.ndarray:
        """``(m,)`` fraction of the spectra (all leading axes pooled) detected per channel."""
        return self.detected.reshape(-1, self.detected.shape[-1]).mean(axis=0)

    def verdicts(self, index: int | tuple[int, ...] = ()) -> tuple[ChannelVerdict, ...]:
        """Per-channel :class:`ChannelVerdict` of the spectrum at leading ``index`` (``()`` if none)."""
        th = self.threshold
        return tuple(
            ChannelVerdict(
                channel=name,
                detected=bool(self.detected[index][i]),
                peak_hz=float(self.peak_hz[index][i]),
                peak_ratio=float(self.peak_ratio[index][i]),
                excess_power=float(self.excess_power[index][i]),
                dc_ratio=float(self.dc_ratio[index][i]),
                threshold_kind=th.kind,
                alpha=th.alpha,
                alpha_meaning=th.alpha_meaning,
            )
            for i, name in enumerate(self.channels)
        )


def _channel_names(channels: Sequence[str] | None, m: int) -> tuple[str, ...]:
    if channels is None:
        return tuple(f"z{i + 1}" for i in range(m))
    names = tuple(str(c) for c in channels)
    if len(names) != m:
        raise ShapeError(f"channels must name {m} channels; got {len(names)}")
    return names


def detect_spectrum(
    power: np.ndarray,
    threshold: Threshold,
    expected: np.ndarray | None = None,
    channels: Sequence[str] | None = None,
) -> SpectrumDetection:
    """Compare spectra ``(..., bins, m)`` with a threshold, vectorized over the leading axes.

    Parameters
    ----------
    power : (..., bins, m) array
        Periodograms (or averaged periodograms) on the threshold's frequency grid.
    threshold : Threshold
    expected : (bins, m) array, optional
        Healthy expectation for ``excess_power``; defaults to ``threshold.expected``
        (required for the ``paper`` threshold, which carries none).
    channels : sequence of str, optional
        Channel names (default ``z1..zm``).

    Raises
    ------
    ShapeError
        If ``power`` or ``expected`` does not match the threshold's ``(bins, m)``.
    """
    power = threshold.check_spectrum(power)
    if expected is None:
        expected = threshold.expected
    if expected is None:
        raise ParameterError(
            f"the {threshold.kind!r} threshold carries no expected spectrum: pass expected= "
            "(chatterspec.detection.spectral.expected_spectrum) to compute excess_power"
        )
    expected = np.asarray(expected, dtype=float)
    if expected.shape != threshold.values.shape:
        raise ShapeError(f"expected must have shape {threshold.values.shape}; got {expected.shape}")
    tested = threshold.tested
    ratio = power[..., tested, :] / threshold.values[tested]
    k = np.argmax(ratio, axis=-2)  # (..., m)
    peak_ratio = np.take_along_axis(ratio, k[..., None, :], axis=-2)[..., 0, :]
    peak_hz = threshold.freqs_hz[tested][k]
    e_sum = expected[tested].sum(axis=0)
    excess = (power[..., tested, :].sum(axis=-2) - e_sum) / e_sum
    dc = np.flatnonzero(threshold.freqs_hz == 0.0)
    if dc.size:
        dc_ratio = power[..., dc[0], :] / threshold.values[dc[0]]
    else:
        dc_ratio = np.full(peak_ratio.shape, np.nan)
    return SpectrumDetection(
        detected=peak_ratio > 1.0,
        peak_hz=peak_hz,
        peak_ratio=peak_ratio,
        excess_power=excess,
        dc_ratio=dc_ratio,
        channels=_channel_names(channels, power.shape[-1]),
        threshold=threshold,
    )


# ---------------------------------------------------------------------------
# STFT: frames and intervals
# ---------------------------------------------------------------------------
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
    """
    power = frame_threshold.check_spectrum(spec.power)
    tested = frame_threshold.tested
    return (power[..., tested, :] > frame_threshold.values[tested]).any(axis=-2)


def frame_intervals(
    flags: np.ndarray, times_s: np.ndarray, config: STFTConfig, dt: float
) -> list[tuple[float, float]]:
    """Merge runs of contiguous flagged frames into ``(onset_s, offset_s)`` estimates.

    Estimator: a frame is assumed to be flagged once its centre lies inside the
    fault (about half its window faulty), so the onset is placed half-way
    between the centres of the last unflagged and the first flagged frame,
    ``onset = c_first - H dt / 2``, and the offset half-way after the last
    flagged centre, ``offset = c_last + H dt / 2``. If the first (last) frame of
    the record is flagged the fault may predate (outlast) it: the onset (offset)
    is then the start (end) of that frame's window. Strong faults flag frames
    that overlap the fault by a single hop, which biases onsets early and
    offsets late by up to ``(W - H) dt / 2``.

    Parameters
    ----------
    flags : (frames,) bool array
        One channel (or the any-channel combination) of :func:`detect_frames` for one run.
    times_s : (frames,) array
        Frame-centre times (:attr:`Spectrogram.times_s`).
    config : STFTConfig
    dt : float
        Sampling time (s).
    """
    flags = np.asarray(flags, dtype=bool)
    times = np.asarray(times_s, dtype=float)
    if flags.ndim != 1 or times.shape != flags.shape:
        raise ShapeError(
            f"flags and times_s must be 1-D of equal length (one run, one channel); got {flags.shape} "
            f"and {times.shape}"
        )
    if not flags.any():
        return []
    half_hop = config.n_hop(dt) * dt / 2.0
    half_win = (config.n_window(dt) - 1) * dt / 2.0
    padded = np.concatenate(([False], flags, [False]))
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    out = []
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        last = stop - 1
        onset = times[start] - (half_win if start == 0 else half_hop)
        offset = times[last] + (half_win + dt if last == flags.size - 1 else half_hop)
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
        Per channel and under ``"any"`` (any channel flagged), for run 0.
    """

    spectrogram: Spectrogram
    threshold: Threshold
    flags: np.ndarray
    intervals: dict[str, list[tuple[float, float]]]


def stft_detect(
    x: np.ndarray,
    model: LinearModel,
    *,
    t0: float = 0.0,
    config: STFTConfig = DEFAULT_STFT,
    alpha: float = 1e-3,
    correction: Correction = "bonferroni",
    channels: Sequence[str] | None = None,
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

    Raises
    ------
    ShapeError
        If the record is shorter than one window.
    """
    spec = spectrogram(x, model.dt, config, t0=t0)
    th = frame_threshold(model, spec.freqs_hz, config, model.dt, alpha, correction)
    flags = detect_frames(spec, th)
    names = _channel_names(channels or model.output_names, flags.shape[-1])
    first = flags.reshape(-1, *flags.shape[-2:])[0]
    intervals = {n: frame_intervals(first[:, i], spec.times_s, config, model.dt) for i, n in enumerate(names)}
    intervals["any"] = frame_intervals(first.any(axis=-1), spec.times_s, config, model.dt)
    return FrameDetection(spec, th, flags, intervals)


# ---------------------------------------------------------------------------
# Record-level report
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class DetectionReport:
    """Detection of a :class:`~chatterspec.detection.pipeline.ChatteringRecord`.

    Attributes
    ----------
    scenario : str or None
        Scenario name.
    channels : tuple of str
    runs : int
    per_run : SpectrumDetection
        ``(runs, m)`` verdict arrays, one per realization.
    averaged : SpectrumDetection or None
        ``(m,)`` verdict of the Monte Carlo averaged spectrum (Fig 6) against the
        averaged threshold (``nu = 2K``, K = runs); None when runs == 1.
    frames : FrameDetection or None
        STFT detection (multi-segment scenarios, or when requested).
    """

    scenario: str | None
    channels: tuple[str, ...]
    runs: int
    per_run: SpectrumDetection
    averaged: SpectrumDetection | None = None
    frames: FrameDetection | None = field(default=None)

    @property
    def verdicts(self) -> tuple[ChannelVerdict, ...]:
        """Single-run verdicts (runs == 1) or the averaged-spectrum verdicts (runs > 1)."""
        if self.averaged is not None:
            return self.averaged.verdicts()
        return self.per_run.verdicts(0)

    @property
    def detected(self) -> bool:
        """Any channel of :attr:`verdicts` detected."""
        return any(v.detected for v in self.verdicts)

    @property
    def detection_rate(self) -> dict[str, float]:
        """Fraction of the runs detected, per channel."""
        return {c: float(r) for c, r in zip(self.channels, self.per_run.detection_rate, strict=True)}

    def to_dict(self) -> dict[str, object]:
        """JSON-ready report.

        Keys: ``scenario``, ``runs``, ``detected``, ``threshold`` (kind, alpha,
        alpha_meaning, correction, description), ``channels`` (list of
        ``{"channel", "detected", "peak_hz", "peak_ratio", "excess_power", "dc_ratio"}``:
        the single run, or with ``runs > 1`` the averaged-spectrum verdict plus
        ``"detection_rate"``, the fraction of single runs detected),
        ``"averaged"`` (bool) and, when the STFT was run, ``"intervals"``
        (list of ``{"channel", "onset_s", "offset_s"}`` for run 0, channel ``"any"`` included).
        """
        th = self.per_run.threshold
        chans = []
        rates = self.detection_rate
        for v in self.verdicts:
            d = v.to_dict()
            if self.runs > 1:
                d["detection_rate"] = rates[v.channel]
            chans.append(d)
        out: dict[str, object] = {
            "scenario": self.scenario,
            "runs": self.runs,
            "detected": bool(self.detected),
            "averaged": self.averaged is not None,
            "threshold": {
                "kind": th.kind,
                "alpha": th.alpha,
                "alpha_meaning": th.alpha_meaning,
                "correction": th.correction,
                "description": th.describe(),
            },
            "channels": chans,
        }
        if self.averaged is not None:
            ath = self.averaged.threshold
            out["averaged_threshold"] = {
                "kind": ath.kind,
                "alpha": ath.alpha,
                "alpha_meaning": ath.alpha_meaning,
                "correction": ath.correction,
                "records": ath.averaged,
                "description": ath.describe(),
            }
        if self.frames is not None:
            out["intervals"] = [
                {"channel": ch, "onset_s": on, "offset_s": off}
                for ch, ivs in self.frames.intervals.items()
                for on, off in ivs
            ]
        return out


def detect_record(
    record: ChatteringRecord,
    alpha: float = 1e-3,
    threshold: str | Threshold = "exact",
    correction: Correction = "bonferroni",
    *,
    stft: bool | None = None,
    config: STFTConfig = DEFAULT_STFT,
) -> DetectionReport:
    """Detect model mismatch in a chattering record (default: exact + Bonferroni, family-wise 0.1 %).

    Parameters
    ----------
    record : ChatteringRecord
        ``values`` (runs, N, m) and the nominal model.
    alpha : float
        False-alarm probability in (0, 1); family-wise for ``"exact"`` with a
        correction, per-bin for ``"paper"`` (the paper's rule).
    threshold : {"exact", "paper"} or Threshold
        Threshold kind, or a ready :class:`~chatterspec.detection.thresholds.Threshold`
        (e.g. the empirical one of a saved calibration,
        ``Calibration.threshold("family-wise")``), used as is: its ``alpha``
        replaces ``alpha`` and it must cover this record's periodogram bins.
    correction : {"bonferroni", "sidak", "none"}
        Used by ``"exact"`` (ignored by ``"paper"``).
    stft : bool, optional
        Also run the STFT detector (intervals). Default: when the record's
        scenario has more than one segment and the record holds one window.
    config : STFTConfig

    Notes
    -----
    With ``runs > 1`` the report holds every run's verdict (detection rate per
    channel) and the verdict of the averaged spectrum against the averaged
    ``exact`` threshold with K = runs (for ``"paper"`` at per-bin alpha, with
    the same correction otherwise). Runs are assumed independent realizations.
    """
    alpha = open_unit("alpha", alpha)
    if not isinstance(record, ChatteringRecord):
        raise ParameterError(f"record must be a ChatteringRecord; got {type(record).__name__}")
    model = record.model
    pg = periodogram(record.values, record.dt)
    E = expected_spectrum(model, pg.freqs_hz, pg.n_samples)
    if isinstance(threshold, Threshold):
        th = threshold
        if th.values.shape != pg.power.shape[-2:] or not np.allclose(th.freqs_hz, pg.freqs_hz):
            raise ShapeError(
                f"the given threshold covers {th.values.shape[0]} bins x {th.values.shape[1]} channels "
                f"at other frequencies than this record's periodogram {pg.power.shape[-2:]}: it was "
                "calibrated for another record length or model"
            )
        alpha = th.alpha
    elif threshold == "exact":
        th = exact_threshold(model, pg.freqs_hz, pg.n_samples, alpha, correction)
    elif threshold == "paper":
        th = paper_threshold(model, pg.freqs_hz, alpha)
    else:
        raise ParameterError(f"unknown threshold kind {threshold!r}; choose 'exact' or 'paper'")
    channels = record.channels
    per_run = detect_spectrum(pg.power, th, E, channels)
    averaged = None
    if record.runs > 1:
        corr = "none" if threshold == "paper" else correction
        th_avg = exact_threshold(model, pg.freqs_hz, pg.n_samples, alpha, corr, averaged=record.runs)
        averaged = detect_spectrum(pg.power.mean(axis=0), th_avg, E, channels)
    sc = record.scenario
    if stft is None:
        stft = sc is not None and len(sc.segments) > 1 and record.n_samples >= config.n_window(record.dt)
    frames = None
    if stft:
        frames = stft_detect(
            record.values, model, t0=float(record.t[0]), config=config, alpha=alpha, channels=channels
        )
    return DetectionReport(
        scenario=None if sc is None else sc.name,
        channels=channels,
        runs=record.runs,
        per_run=per_run,
        averaged=averaged,
        frames=frames,
    )
